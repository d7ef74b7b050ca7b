"""Typer sub-apps of the ``drlaas`` command for the platform: ``up``, the REST client
(``task``, ``model``, ``worker``, ``requester``) and ``demo-scenario``."""
