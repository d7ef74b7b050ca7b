"""The worker daemon (issue 4, item 5): a Celery worker that accepts offers on chain, trains with
the MDRL core, checkpoints, posts progress and submits the model's manifest CID.

Modules: ``capabilities`` (measured CPU/RAM/GPU), ``keys`` (local key files), ``manifest``
(model upload/pull as a content-addressed manifest), ``job`` (a resumable training job),
``gateway`` (REST client with EIP-4361 sign-in),
``links`` (chain + store connections of a worker), ``tasks`` (the Celery job
``drlaas.handle_offer``), ``command`` (``drlaas worker``). The task spec is the core's
``workers.mdrl.trainingspec.TrainingSpec``.
"""
