"""Observability of the gateway and the worker daemons: Prometheus metrics (``metrics``) and
one-JSON-object-per-line logs carrying task ids (``logs``)."""
