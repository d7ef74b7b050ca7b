"""DRLaaS: DRL as a Service. ``drlaas`` is the command line; the library is workers/ + backend/."""

import os

# One BLAS thread unless the user says otherwise: the env and observers run many small matrix
# products (ODMTL downsizing), which a second BLAS thread slows down on a loaded 2-core machine
# (measured: 130k instead of 638k agent-steps/s at 30 x 30, benchmarks/env_throughput.py).
# Set before anything imports numpy; torch's threads are RunConfig.threads.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
