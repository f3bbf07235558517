"""``ccl --help`` and ``ccl --version`` start without the numerical stack (issue 31): counted in
imported modules in a fresh process, not timed."""

import json
import subprocess
import sys

import pytest

HEAVY = ("numpy", "pydantic", "scipy", "h5py", "matplotlib", "ccl_cli.spec")

PROBE = """
import contextlib, io, json, sys
sys.argv = ["ccl", *json.loads(sys.argv[1])]
from ccl_cli.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    code = main()
print(json.dumps({"code": code, "out": out.getvalue(), "modules": sorted(sys.modules)}))
"""


def probe(args: list[str]) -> dict:
    """What ``ccl ARGS`` returned, printed and imported, in a fresh process."""
    proc = subprocess.run([sys.executable, "-c", PROBE, json.dumps(args)], capture_output=True, text=True,
                          check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("args", [["--help"], ["--version"], ["learn-a", "--help"], ["run", "--help"]])
def test_help_and_version_import_neither_numpy_nor_pydantic(args):
    found = probe(args)
    assert found["code"] == 0
    assert "ccl" in found["out"]
    # a command's own --help goes through typer's adapters, which import pydantic themselves
    heavy = HEAVY if len(args) == 1 else tuple(h for h in HEAVY if h != "pydantic")
    loaded = [name for name in heavy if name in found["modules"]]
    assert loaded == [], f"ccl {' '.join(args)} imported {loaded}"
    assert not any(m.startswith(("numpy.", "scipy.")) for m in found["modules"])


def test_the_same_probe_sees_the_stack_of_a_command_that_learns(tmp_path):
    """The probe counts what a command imports: ``ccl simulate`` needs NumPy and the spec."""
    out = tmp_path / "toy.h5"
    found = probe(["simulate", "toy2d", "-o", str(out), "-q"])
    assert found["code"] == 0 and out.exists()
    assert "numpy" in found["modules"] and "pydantic" in found["modules"]


def test_a_run_that_fits_no_manifold_imports_no_scipy(tmp_path):
    """configs/toy2d_learn_pi.yaml (a linear constraint, a policy) learns with NumPy alone: SciPy's
    linalg (the manifold's generalised eigenproblem) is imported only where it is used."""
    from pathlib import Path

    config = Path(__file__).resolve().parent.parent / "configs" / "toy2d_learn_pi.yaml"
    found = probe(["run", str(config), "-o", str(tmp_path / "run"), "-q"])
    assert found["code"] == 0 and (tmp_path / "run" / "metrics.json").exists()
    assert "numpy" in found["modules"]
    assert not any(m == "scipy" or m.startswith("scipy.") for m in found["modules"])


def test_the_default_pipeline_on_a_tracker_plane_imports_no_scipy(tmp_path):
    """learn-a's auto fits the states' manifolds (the generalised eigenproblem, NumPy's Cholesky
    and eigh) and asks which samples come back over their ground (all distances up to
    geometry.BRUTE_ROWS samples) without SciPy: its linalg and spatial cost a run 35 MiB."""
    data = tmp_path / "plane.h5"
    made = probe(["simulate", "tracker_plane", "--n-recordings", "3", "--duration", "20", "-o", str(data),
                  "-q"])
    assert made["code"] == 0
    config = tmp_path / "c.yaml"
    config.write_text("stages: [learn-a]\noutput: {plots: false}\n")
    found = probe(["run", str(config), "--data", str(data), "-o", str(tmp_path / "run"), "-q"])
    assert found["code"] == 0 and (tmp_path / "run" / "metrics.json").exists()
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["learn-a"]["selection"]["decided_by"] == "states"  # the manifolds were fitted
    assert not any(m == "scipy" or m.startswith("scipy.") for m in found["modules"])


START = """
import gc, json, os, sys
sys.argv = ["ccl", *json.loads(sys.argv[1])]
from ccl_cli.cli import main
from ccl_cli.io.blockwise import cores
from ccl_cli.learn.blas import THREAD_VARS, affinity_cores
before = [g["collections"] for g in gc.get_stats()]
code = main()
from threadpoolctl import threadpool_info
blas = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
print(json.dumps({"code": code, "blas": blas,
                  "env": {v: os.environ[v] for v in THREAD_VARS if v in os.environ},
                  "cores": cores(), "affinity": affinity_cores(),
                  "collections": [g["collections"] - b for g, b in zip(gc.get_stats(), before)]}))
"""


def start(args: list[str], **env: str) -> dict:
    """How ``ccl ARGS`` left its process (BLAS threads, thread variables, collections), run
    fresh without the user's thread variables (plus ``env``)."""
    import os

    from ccl_cli.learn.blas import THREAD_VARS

    clean = {k: v for k, v in os.environ.items() if k not in THREAD_VARS} | env
    proc = subprocess.run([sys.executable, "-c", START, json.dumps(args)], capture_output=True, text=True,
                          check=True, env=clean)
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(__import__("os").cpu_count() < 2, reason="one core: OpenBLAS starts one thread anyway")
def test_a_learning_command_starts_the_blas_at_the_runs_one_thread_and_leaves_the_variables(tmp_path):
    """A run's every product is single-threaded (``blas.RUN_THREADS``): NumPy's OpenBLAS is
    loaded at that count instead of a thread per core (``import numpy``: 0.14 → 0.08 s CPU), the
    variables removed after, so the block threads and a batch's workers see what the user set;
    a user's own setting is left alone. The cyclic collector ran 102 times in this run (9 of
    them the middle generation, 1 the oldest) at Python's default threshold, 23 now."""
    from pathlib import Path

    config = Path(__file__).resolve().parent.parent / "configs" / "toy2d_learn_pi.yaml"
    args = ["run", str(config), "-o", str(tmp_path / "run"), "-q"]
    found = start(args)
    assert found["code"] == 0 and (tmp_path / "run" / "metrics.json").exists()
    if found["blas"]:  # a BLAS threadpoolctl can see (the NumPy wheel's OpenBLAS)
        assert found["blas"] == [1] * len(found["blas"])
    assert found["env"] == {} and found["cores"] == found["affinity"]
    assert found["collections"][0] < 50 and found["collections"][2] == 0

    users = start([*args[:3], str(tmp_path / "run2"), "-q"], OPENBLAS_NUM_THREADS="2")
    assert users["code"] == 0 and users["env"] == {"OPENBLAS_NUM_THREADS": "2"}
    if users["blas"]:
        assert users["blas"] == [2] * len(users["blas"])  # the run limits its products, not the load

    other = start(["simulate", "toy2d", "-o", str(tmp_path / "toy.h5"), "-q"])  # not a learning command
    assert other["code"] == 0 and other["env"] == {}
    if other["blas"]:
        assert other["blas"] != [1] * len(other["blas"])
