"""DRLaaS: DRL as a Service. ``drlaas`` is the command line; the library is workers/ + backend/."""

__version__ = "0.1.0"
