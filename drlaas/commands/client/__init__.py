"""The REST client CLI, one module per resource: ``drlaas requester|worker|task|model ...``
against a gateway (``session`` holds what they share: sign-in, relayed writes, output)."""

from drlaas.commands.client.models import model_app
from drlaas.commands.client.session import write
from drlaas.commands.client.tasks import task_app
from drlaas.commands.client.users import requester_app
from drlaas.commands.client.workers import worker_app

__all__ = ["model_app", "requester_app", "task_app", "worker_app", "write"]
