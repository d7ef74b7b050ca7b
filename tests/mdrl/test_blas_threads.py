"""The library runs numpy's BLAS on one thread unless the user says otherwise: a second
OpenBLAS thread made ODMTL's small products up to 300x slower with another process on the
other core (workers/__init__.py)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
PROBE = ("import {module}, os; "
         "print(','.join(os.environ.get(v, '-') for v in {vars!r}))")


def _threads_after_import(module: str, **env: str) -> list[str]:
    clean = {k: v for k, v in os.environ.items() if k not in VARS} | env
    out = subprocess.run([sys.executable, "-c", PROBE.format(module=module, vars=VARS)],
                         cwd=REPO, env=clean, capture_output=True, text=True, check=True)
    return out.stdout.strip().split(",")


@pytest.mark.parametrize("module", ["workers.mdrl.train", "workers.daemon.app", "drlaas.cli"])
def test_importing_the_library_sets_one_blas_thread(module):
    assert _threads_after_import(module) == ["1", "1", "1"]


def test_a_users_own_thread_count_is_kept():
    assert _threads_after_import("workers.mdrl.train", OPENBLAS_NUM_THREADS="2")[0] == "2"


def test_a_numpy_loaded_before_the_library_is_limited_to_one_blas_thread():
    """A script that imports torch (and so numpy) first: the environment is read already, so
    the library limits OpenBLAS at run time."""
    probe = ("import numpy, threadpoolctl; import workers.mdrl.train; "
             "print(max(p['num_threads'] for p in threadpoolctl.threadpool_info() "
             "if p['user_api'] == 'blas'))")
    clean = {k: v for k, v in os.environ.items() if k not in VARS}
    out = subprocess.run([sys.executable, "-c", probe], cwd=REPO, env=clean,
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "1"
