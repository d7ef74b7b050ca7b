"""Fixtures the CLI tests of the MDRL core share."""

import pytest

from tests.mdrl.test_cli_robustness import QUIET, config, invoke


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A finished tiny run of 64 env steps (checkpoint/, model/, metrics.csv) in a directory
    named ``run``, to resume and load (one per test module)."""
    out = tmp_path_factory.mktemp("trained") / "run"
    res = invoke("train", "--config", config(out.parent), "--steps", 64, "--out", out, *QUIET)
    assert res.exit_code == 0, res.output
    return out
