"""DRLaaS: DRL as a Service. ``drlaas`` is the command line; the library lives in workers/ and backend/."""

__version__ = "0.1.0"
