"""Domain errors: a request broke a named rule of the platform.

Services, auth and the indexer raise these; they know nothing of HTTP. The gateway maps each
kind to a status code and the ``{"detail": {"rule", "msg"}}`` body in one place
(``backend.api.errors``), so the layers below the API never import it (``.importlinter``).
``rule`` is a stable snake_case name clients switch on; ``msg`` is for humans.
"""

from __future__ import annotations


class DomainError(Exception):
    """Base of every rule failure; subclasses say what kind of failure it is."""

    def __init__(self, rule: str, msg: str, *, retry_after: float | None = None) -> None:
        super().__init__(f"{rule}: {msg}")
        self.rule = rule
        self.msg = msg
        self.retry_after = retry_after


class Invalid(DomainError):
    """The input is well-formed but breaks a rule about its values."""


class BadRequest(DomainError):
    """The input cannot be read at all (not a transaction, not JSON...)."""


class Unauthorized(DomainError):
    """No valid credentials: sign in first."""


class PaymentRequired(DomainError):
    """The sender cannot pay: gas money or the value a contract asks for."""


class Forbidden(DomainError):
    """Signed in, but this caller may not do this."""


class NotFound(DomainError):
    """The named thing does not exist."""


class Conflict(DomainError):
    """The current state forbids it (a contract rule, a duplicate, a used nonce)."""


class TooLarge(DomainError):
    """More bytes or more work than the platform accepts."""


class RateLimited(DomainError):
    """Too many requests of this kind: retry after ``retry_after`` seconds."""


class Unavailable(DomainError):
    """A service behind the gateway is down or saturated: retry later."""
