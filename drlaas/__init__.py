"""DRLaaS: DRL as a Service. ``drlaas`` is the command line; the library is workers/ + backend/."""

import workers  # noqa: F401 - before numpy: one BLAS thread (workers/__init__.py says why)

__version__ = "0.1.0"
