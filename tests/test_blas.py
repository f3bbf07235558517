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
    assert blas.RUN_THREADS == 1
    before = blas.current()
    code = main(["run", str(CONFIGS / "toy2d_learn_a.yaml"), "-o", str(tmp_path / "a"), "-q"])
    assert code == 0, capsys.readouterr().err
    run = json.loads((tmp_path / "a" / "run.json").read_text())
    assert run["blas"]["threads"] == 1  # a few thousand samples: single-threaded
    assert blas.current() == before  # and the process's own setting is back


def test_a_nested_block_of_the_same_count_scans_nothing_unless_a_module_was_imported(monkeypatch):
    """A search runs each fit in its own threads(1) block inside the stage's: the inner blocks do
    not scan the loaded libraries again — but do after an import (it may have loaded a BLAS)."""
    import sys

    import threadpoolctl

    if not blas.controllable():
        pytest.skip("no BLAS to control")
    scans = []
    real = threadpoolctl.ThreadpoolController.__init__

    def counting(self, *args, **kwargs):
        scans.append(1)
        real(self, *args, **kwargs)

    before = blas.current()
    monkeypatch.setattr(threadpoolctl.ThreadpoolController, "__init__", counting)
    with blas.threads(1):
        for _ in range(5):
            with blas.threads(1) as n:
                assert n == 1
        assert len(scans) == 1
        with blas.threads(2):  # another count: limited, then restored
            assert len(scans) == 2
        monkeypatch.setitem(sys.modules, "ccl_test_fake_module", object())  # an import happened
        with blas.threads(1):
            assert len(scans) == 3  # scanned again, and the libraries found limited ...
        with blas.threads(1):
            assert len(scans) == 3  # ... for the rest of the enclosing block
        assert blas.current() == 1
    assert blas.current() == before
