"""ccl_cli.learn.blas: BLAS threads set at run time around a small problem, restored after."""

import json
from pathlib import Path

import numpy as np
import pytest

from ccl_cli.cli import main
from ccl_cli.learn import blas

CONFIGS = Path(__file__).resolve().parent.parent / "configs"

pytestmark = pytest.mark.skipif(not blas.controllable(), reason="not an OpenBLAS from the NumPy wheel")


def test_threads_are_set_inside_the_block_and_restored_after():
    before = blas.current()
    with blas.threads(1) as n:
        assert n == 1 and blas.current() == 1
        M = np.random.default_rng(0).random((50, 50))
        vals = np.linalg.eigvalsh(M @ M.T)  # BLAS still computes, single-threaded
    assert blas.current() == before
    assert np.all(vals > -1e-9)
    with blas.threads(None) as n:  # None: unchanged, reports the count in force
        assert n == before == blas.current()


def test_threads_are_restored_when_the_block_raises():
    before = blas.current()
    with pytest.raises(RuntimeError), blas.threads(1):
        raise RuntimeError("boom")
    assert blas.current() == before


def test_stage_rule_and_run_json_record_the_choice(tmp_path, capsys):
    assert blas.stage_threads(blas.SMALL_SAMPLES - 1) == 1
    assert blas.stage_threads(blas.SMALL_SAMPLES) is None
    before = blas.current()
    code = main(["run", str(CONFIGS / "toy2d_learn_a.yaml"), "-o", str(tmp_path / "a"), "-q"])
    assert code == 0, capsys.readouterr().err
    run = json.loads((tmp_path / "a" / "run.json").read_text())
    assert run["blas"]["threads"] == 1  # a few thousand samples: single-threaded
    assert blas.current() == before  # and the process's own setting is back
