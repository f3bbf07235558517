"""The learnt constraint against the ground truth a file carries (issue 30 item 5): report.md,
metrics.json and ``--json`` compare with it, and the verdict says when the answer is far off.

Per sample n of the data judged: the learnt rows Ã(x_n) as the model applies to those data
(rows of zeros where a constraint in stretches does not hold) and the true rows (``truth/A``, or
the eigenvectors of I − N with eigenvalue > 1/2 from ``truth/N``). The angle at a sample is the
largest principal angle between the two row spaces when both have the same number of rows, 90°
when they differ, 0° when neither has any; the figures are its median and 90th percentile over
the samples, the true k (the most common number of true rows), the learnt k and NPPE.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.learn.constraint.sure import angles

#: The answer is far off when the median angle is above this (degrees) or k differs.
FAR_DEG = 10.0
#: Singular values below this share of a sample's largest are not rows.
RANK_TOL = 1e-6
#: A task part the truth holds counts when its variance is at least this share of u's.
TASK_SHARE = 1e-3
#: The angles are read at no more than this many samples, evenly spaced over the data (every
#: sample up to it): their median, 90th percentile and the share where k agrees are read on a
#: bounded, deterministic sample, whatever N.
TRUTH_ROWS = 20_000


def _bases(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per sample the number of independent rows (N,) and an orthonormal basis ordered by
    singular value (N, s, q) of rows (N, s, q)."""
    if rows.shape[1] == 0:
        return np.zeros(len(rows), np.int64), rows
    _, sv, vt = np.linalg.svd(rows, full_matrices=False)
    top = sv[:, :1]
    rank = (sv > RANK_TOL * np.where(top > 0, top, np.inf)).sum(1)
    return rank, vt


def true_rows(d: Demonstrations, at: np.ndarray | None = None) -> np.ndarray:
    """The true constraint rows at every sample (N, s, q), or at the samples ``at`` (m,):
    ``truth/A``, or from ``truth/N`` the directions I − N keeps (eigenvalue > 1/2, the others
    zero)."""
    at = slice(None) if at is None else at
    if d.has_truth("A"):
        return np.asarray(d.truth_per_sample("A")[at], dtype=float)
    N = np.asarray(d.truth_per_sample("N")[at], dtype=float)
    value, vec = np.linalg.eigh(np.eye(N.shape[1]) - 0.5 * (N + np.swapaxes(N, 1, 2)))
    return np.swapaxes(vec * (value > 0.5)[:, None, :], 1, 2)


def per_sample(learnt: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The angle at each sample (N,) in degrees (module docstring), the learnt and the true
    number of rows (N,) each."""
    k_l, B_l = _bases(learnt)
    k_t, B_t = _bases(true)
    out = np.where(k_l == k_t, 0.0, 90.0)
    for r in np.unique(k_l[(k_l == k_t) & (k_l > 0)]):
        at = np.flatnonzero((k_l == r) & (k_t == r))
        out[at] = angles(B_l[at, :r], B_t[at, :r])[1]
    return out, k_l, k_t


def compare(model: Any, d: Demonstrations, Y: np.ndarray, part: str, metrics: dict[str, Any] | None = None,
            task_hint: str = "") -> dict[str, Any] | None:
    """The learnt constraint ``model`` (as it applies to ``d`` with the observations ``Y`` (N, q) it
    was learnt from: its stated rule) against the ground
    truth of ``d`` (None without ``truth/A`` or ``truth/N``): {part, samples, true_k, true_k_varies,
    learnt_k, k_agrees (share of samples with as many learnt as true rows), median_deg, p90_deg
    (None when neither has rows anywhere), NPPE (from ``metrics`` of that part), far, why}.
    ``task_hint``: what to do when the answer is far off (e.g. the constraint was learnt from u
    while the truth holds a task part: :func:`task_hint`). The angles are read at TRUTH_ROWS
    samples at most (``read_at``: how many, when fewer than all)."""
    from ccl_cli.app.scoring import applied_on

    if not (d.has_truth("A") or d.has_truth("N")) or not d.n_samples:
        return None
    applied = applied_on(model, d, Y)
    n = d.n_samples
    at = np.arange(n) if n <= TRUTH_ROWS else np.linspace(0, n - 1, TRUTH_ROWS).round().astype(np.int64)
    learnt = applied.model.constraint(d.X[at], groups=d.demo[at], t=d.t[at])
    deg, k_l, k_t = per_sample(learnt, true_rows(d, at))
    counts = np.bincount(k_t)
    true_k, learnt_k = int(np.argmax(counts)), int(model.n_constraints_)
    any_rows = bool((k_l > 0).any() or (k_t > 0).any())
    median = float(np.median(deg)) if any_rows else None
    p90 = float(np.percentile(deg, 90)) if any_rows else None
    nppe = ((metrics or {}).get("NPPE") or {}).get("value")
    why = ""
    if learnt_k != true_k:
        why = (f"{learnt_k} constraint(s) learnt, the ground truth stored in the file has {true_k}")
    elif median is not None and median > FAR_DEG:
        why = (f"the learnt constraint is {median:.0f}° from the one stored in the file (median over the "
               f"{part} samples; 90th percentile {p90:.0f}°)")
    if why and task_hint:
        why += f" — {task_hint}"
    read = {"read_at": int(len(at))} if len(at) < n else {}
    return {"part": part, "samples": int(d.n_samples), **read, "true_k": true_k,
            "true_k_varies": bool((counts > 0).sum() > 1), "learnt_k": learnt_k,
            "k_agrees": float(np.mean(k_l == k_t)), "median_deg": median, "p90_deg": p90,
            "NPPE": None if nppe is None else float(nppe), "far": bool(why), "why": why}


def task_hint(d: Demonstrations, on: str, learn_v: bool) -> str:
    """What to try when a constraint learnt from u (``on``) is far off while the ground truth of
    ``d`` holds a task part v (at least TASK_SHARE of u's variance), which moves u along the rows;
    ``learn_v``: a learn-v stage ran before. "" otherwise."""
    if on != "u" or not d.has_truth("v") or d.n_samples < 2:
        return ""
    if float(d.truth["v"].var(0).sum()) < TASK_SHARE * float(d.U.var(0).sum()):
        return ""
    said = "the file's actions carry a task part, which moves u along the rows: "
    return said + ("learn-a learnt from u, not learn-v's w̃ (learn-a on: w learns from w̃)" if learn_v else
                   "run learn-v first (stages: [learn-v, learn-a])")
