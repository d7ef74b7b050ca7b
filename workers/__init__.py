"""The worker side of DRLaaS: the MDRL core (``workers.mdrl``) and the worker daemon.

One BLAS thread unless the user says otherwise, set here so the library, the daemon and
scripts that import ``workers`` before numpy all get it: the env and observers run many small
matrix products (ODMTL downsizing, the belief filter), which a second OpenBLAS thread slows
down on a loaded 2-core machine (measured: 130k instead of 638k agent-steps/s at 30 x 30,
``benchmarks/env_throughput.py``; PPO on ``ch4-a3w3-sparse-route`` 1,630 instead of 2,530 env
steps/s with another run on the other core). A numpy already loaded (a script that imported
torch first) has read the environment: its BLAS is limited at run time instead. Torch's
threads are ``RunConfig.threads``.
"""

import os
import sys

_USER_BLAS = "OPENBLAS_NUM_THREADS" in os.environ or "MKL_NUM_THREADS" in os.environ
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
if "numpy" in sys.modules and not _USER_BLAS:
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
