"""What the end-to-end comparisons of learnt constraints share (tests/test_invariance.py,
tests/test_real_logs.py, benchmarks/bench_recordings.py): ``ccl learn-a`` run in-process as a
user runs it, the learnt rows at every sample as ``ccl predict`` gives them (the eigenvectors
of I − Ñ(x) with eigenvalue above ½, as /work/shared/tools/devset.py scores them), and the
largest principal angle between row spaces, sample by sample."""

from __future__ import annotations

import contextlib
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ccl_cli.app.evaluate import predict
from ccl_cli.cli import main
from ccl_cli.dataset import Demonstrations
from ccl_cli.io import read_dataset
from ccl_cli.models import load_model


@dataclass
class Learnt:
    """One ``ccl learn-a`` run: its exit code, ``--json`` summary, learn-a's metrics (with its
    ``selection``), the data as learn-a read them, Ñ (N, q, q) at every sample and the learnt
    rows of each sample (a list of (k_n, q))."""

    code: int
    summary: dict[str, Any]
    metrics: dict[str, Any]
    data: Demonstrations
    N: np.ndarray
    rows: list[np.ndarray]

    @property
    def k(self) -> int | None:
        return ((self.summary.get("stages") or {}).get("learn-a") or {}).get("n_constraints")

    @property
    def status(self) -> str | None:
        return self.summary.get("status")

    @property
    def chose(self) -> str:
        sel = self.metrics.get("selection") or {}
        return f"{sel.get('model')} ({sel.get('decided_by', 'velocities')})"


def learn_a(files: list[Path] | None, out: Path, data: dict[str, Any] | None = None,
            config: Path | None = None) -> Learnt:
    """``ccl learn-a FILES -o OUT --json`` with the ``data`` mapping written as a config (or the
    ``config`` file as it is; ``files`` None: the config's own), learn-a's defaults otherwise;
    then the learnt model applied to the data as ``ccl predict`` applies it."""
    argv = ["learn-a", *[str(f) for f in files or []], "-o", str(out), "--json", "-q", "--force"]
    base = None
    if data is not None:
        config = out.parent / f"{out.name}.yaml"
        config.write_text(yaml.safe_dump({"data": data}))
    if config is not None:
        argv += ["-c", str(config)]
        options = yaml.safe_load(config.read_text())["data"]
        base = config.parent
    else:
        options = {}
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        code = main(argv)
    summary = json.loads(buf.getvalue().strip().splitlines()[-1]) if buf.getvalue().strip() else {}
    if code != 0:
        nothing = Demonstrations(np.zeros((1, 1)), np.zeros((1, 1)))
        return Learnt(code, summary, {}, nothing, np.zeros((0, 1, 1)), [])
    metrics = json.loads((out / "metrics.json").read_text())["learn-a"]
    d, _ = read_dataset(options, files, base)
    model, info = load_model(out / "model.h5")
    N = predict(model, info["kind"], d)["N"]
    return Learnt(code, summary, metrics, d, N, rows_of(N))


def rows_of(N: np.ndarray) -> list[np.ndarray]:
    """Per sample, the eigenvectors of I − N (N, q, q) with eigenvalue above ½: (k_n, q) each."""
    M = np.eye(N.shape[-1]) - N
    lam, vec = np.linalg.eigh((M + np.swapaxes(M, 1, 2)) / 2)
    return [vec[i][:, lam[i] > 0.5].T for i in range(len(N))]


def true_rows(d: Demonstrations) -> list[np.ndarray]:
    """The true rows of each sample: the stored A, else those of I − N_true."""
    if "A" in d.truth:
        A = np.asarray(d.truth_per_sample("A"))
        return list(A)
    return rows_of(np.asarray(d.true_projection()))


def largest_angles(R1: list[np.ndarray], R2: list[np.ndarray]) -> np.ndarray:
    """Largest principal angle (degrees) between the row spaces of R1[n] and R2[n], per sample;
    90 where their numbers of rows differ, 0 where both are empty: (N,)."""
    out = np.full(len(R1), 90.0)
    k1 = np.array([len(r) for r in R1])
    k2 = np.array([len(r) for r in R2])
    out[(k1 == 0) & (k2 == 0)] = 0.0
    for k in np.unique(k1[(k1 == k2) & (k1 > 0)]):  # a batch per rank
        idx = np.flatnonzero((k1 == k) & (k2 == k))
        Q1 = np.linalg.qr(np.swapaxes(np.stack([R1[i] for i in idx]), 1, 2))[0]
        Q2 = np.linalg.qr(np.swapaxes(np.stack([R2[i] for i in idx]), 1, 2))[0]
        s = np.linalg.svd(np.swapaxes(Q1, 1, 2) @ Q2, compute_uv=False)
        out[idx] = np.degrees(np.arccos(np.clip(s.min(axis=1), 0.0, 1.0)))
    return out


def by_position(d: Demonstrations) -> np.ndarray:
    """The order of the samples sorted by their states (lexicographic): the same samples read
    in another order, or from files in another order, line up (N,)."""
    return np.lexsort(d.X.T[::-1])
