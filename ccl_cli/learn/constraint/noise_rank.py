"""The number of constraints from the noise the data show (issue 17; ALGORITHMS.md §3.4).

A candidate row a(x) of a constraint learner is a constraint when the actions do not move
along it beyond their noise — or beyond a negligible share of the motion. For rows
a_1 … a_m in the learner's order (constant (m, q), or per sample (N, m, q)), taken as unit
directions â = a/‖a‖:

    e_k  = mean_n (â_kᵀ u_n)²                      the energy of the actions along row k
    σ²_k = the noise variance of â_kᵀu, from second differences in time
           (:mod:`ccl_cli.learn.noise`): for velocities derived from positions
           σ²_x(â_k) Σc² (c the derivative's slope filter), for recorded actions σ²_u(â_k)
    f_k  = e_k / mean_n ‖u_n‖²                     its share of all the motion

Row 1 is a constraint when r_1 = e_1/σ²_1 ≤ MARGIN (motion at the noise level) or
f_1 ≤ SHARE (a contact gives a little — a tool pressing into a table moves along its normal
slightly, above a good sensor's noise — while a free direction carries a fair share of the
motion). A further row k is one when f_k ≤ SHARE or r_k ≤ min(MARGIN, RATIO · max(r_1, 1)):
as quiet as the first, so that a free direction that barely rises above heavy noise is not
taken for a second constraint. s is the number of leading rows that are constraints,
0 … m: "no constraint" is a legal answer. Learners that choose their rows per state or per
stretch of time (learn-a's ``auto``, the per-window model) admit rows after the first by
their noise ratio only (``share_rows``, SHARE_ROWS): such a learner can always find a direction
that carries little of the motion (docs/auto.md).

MARGIN, RATIO and SHARE were chosen on the simulated and reference problems
(``benchmarks/bench_recordings.py --only rank``; docs/recordings.md).

Second differences measure noise only on trajectories sampled in time: when the actions'
total variance is below MIN_SNR × their estimated noise (samples not in time order, or no
motion), :func:`noise_rank` cannot judge and returns None.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ccl_cli.dataset import Derivative, HowMade
from ccl_cli.learn.constraint.rank import Selection
from ccl_cli.learn.linalg import unit_rows
from ccl_cli.learn.noise import default_window, derived_noise_var, white_noise_var

#: A row whose energy is at most MARGIN × its noise variance is at the noise level.
MARGIN = 10.0
#: A row carrying at most this share of the mean squared action is a constraint however far
#: above the noise it is.
SHARE = 1e-2
#: A row after the first may move at most RATIO × as much (over its noise) as the first.
RATIO = 2.0
#: Below this ratio of the actions' total variance to their noise the rule cannot judge.
MIN_SNR = 3.0
RULE = "noise"
#: Rows that may be constraints by their share alone, for learners that choose their rows per
#: state or per stretch (``share_rows`` of :func:`noise_rank`): the first — a contact that
#: gives a little; a further row must be as quiet as the noise says.
SHARE_ROWS = 1


@dataclass
class RowEvidence:
    """What the rule compares for candidate rows k = 1 … m: ``energy`` e_k, ``noise`` σ²_k and
    ``share`` f_k (each (m,)); ``snr`` the actions' total variance over their total noise."""

    energy: np.ndarray
    noise: np.ndarray
    share: np.ndarray
    snr: float

    @property
    def ratio(self) -> np.ndarray:
        """e_k / σ²_k (inf where the noise estimate is 0 and the energy is not)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.noise > 0, self.energy / self.noise, np.where(self.energy > 0, np.inf, 0.0))


def _median_step(t: np.ndarray, demo: np.ndarray) -> float:
    dt = np.diff(t)[demo[1:] == demo[:-1]]
    dt = dt[dt > 0]
    return float(np.median(dt)) if len(dt) else 0.0


def row_evidence(U: np.ndarray, rows: np.ndarray, demo: np.ndarray, t: np.ndarray,
                 X: np.ndarray | None = None, derivative: HowMade = None, *,
                 recorded: bool = True) -> RowEvidence:
    """Energy, noise and share of the actions U (N, q) along candidate ``rows`` ((m, q) or
    (N, m, q)), demonstrations ``demo`` (N,) sampled at ``t`` (N,) s.

    ``derivative`` (a derived :class:`~ccl_cli.dataset.Derivative`) says U was derived from the
    positions X (N, q) by the readers' local polynomial: the noise is then the positions' along
    each row times the filter's gain at the median interval. Without it U is taken as recorded
    (white noise), or, with ``recorded=False`` (how U was made is not known), the noise is the
    larger of U's own white-noise estimate and the derived one with the readers' default filter
    at the data's rate (when X has q columns): recorded actions then get their own noise, derived ones the
    filtered positions' noise (which a white-noise estimate of smoothed velocities misses)."""
    U = np.asarray(U, dtype=float)
    rows = unit_rows(np.asarray(rows, dtype=float))
    demo = np.asarray(demo)
    if rows.ndim == 2:
        along = U @ rows.T
    else:
        along = np.einsum("nkq,nq->nk", rows, U)
    energy = (along**2).mean(0)
    total = float((U**2).sum(1).mean())
    share = energy / total if total > 0 else np.zeros_like(energy)
    dt = _median_step(np.asarray(t, float), demo) if t is not None else 0.0
    derivative = Derivative.of(derivative) if derivative is not None else None
    if derivative is not None and derivative.derived:
        if X is None or np.shape(X)[1] != U.shape[1]:
            raise ValueError("derived actions need the positions X they were derived from, (N, q)")
        if not dt > 0:
            raise ValueError("derived actions need the sample times t")
        window, order = int(derivative.window), int(derivative.order)
        noise = derived_noise_var(X, demo, dt, window, order, rows)
        per_dim = derived_noise_var(X, demo, dt, window, order)
    else:
        noise = white_noise_var(U, demo, rows)
        per_dim = white_noise_var(U, demo)
        if not recorded and X is not None and np.shape(X)[1] == U.shape[1] and dt > 0:
            window = default_window(dt)
            noise = np.maximum(noise, derived_noise_var(X, demo, dt, window, 2, rows))
            per_dim = np.maximum(per_dim, derived_noise_var(X, demo, dt, window, 2))
    var = float(U.var(0, ddof=1).sum()) if len(U) > 1 else 0.0
    noise_total = float(per_dim.sum())
    snr = var / noise_total if noise_total > 0 else (np.inf if var > 0 else 0.0)
    return RowEvidence(energy=energy, noise=noise, share=share, snr=float(snr))


@dataclass
class Sample:
    """The data of one fit and how its actions were made: ``derived`` the derivative when U was
    derived from the positions X (else None), ``recorded`` True when the actions are known to be
    recorded (:func:`row_evidence`). X (N, p), U (N, q), groups (N,), t (N,) s or None."""

    X: np.ndarray
    U: np.ndarray
    groups: np.ndarray
    t: np.ndarray | None
    derived: Derivative | None
    recorded: bool

    @classmethod
    def of(cls, X: np.ndarray, U: np.ndarray, groups: np.ndarray | None, t: np.ndarray | None,
           derivative: HowMade) -> Sample:
        """From a learner's ``fit`` arguments: ``derivative`` how U was made
        (:meth:`Derivative.of <ccl_cli.dataset.Derivative.of>`); a derivative is used only with
        the times and when X has q columns (the positions U was derived from)."""
        how = Derivative.of(derivative)
        derived = how if how.derived and t is not None and X.shape[1] == U.shape[1] else None
        return cls(X, U, np.zeros(len(U), np.int64) if groups is None else np.asarray(groups), t, derived,
                   recorded=how.derived is False)

    @property
    def derivative(self) -> Derivative:
        """How the actions were made, as a learner's ``fit`` takes it (:meth:`of`)."""
        return self.derived if self.derived else Derivative(False if self.recorded else None)

    def rows_evidence(self, rows: np.ndarray, pieces: np.ndarray | None = None) -> RowEvidence:
        """Energy, noise and share of U along ``rows`` ((m, q) or per sample (N, m, q)); second
        differences within each of the ``pieces`` (N,; None: the demonstrations)."""
        positions = self.X if self.X.shape[1] == self.U.shape[1] else None
        return row_evidence(self.U, rows, self.groups if pieces is None else pieces, self.t, positions,
                            self.derived, recorded=self.recorded)


def row_limits(r: np.ndarray, margin: float = MARGIN, share: float = SHARE, ratio: float = RATIO,
               share_rows: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The limits of the rule (module docstring) for rows with noise ratios r (m,): the largest
    noise ratio of each row that is a constraint (MARGIN for the first, min(MARGIN, RATIO · max(r_1,
    1)) after it) and the largest share (``share`` for the first ``share_rows`` rows, None: every
    row; −inf for the others, which only their noise ratio can admit): ((m,), (m,))."""
    r = np.asarray(r, dtype=float)
    limit = np.full(len(r), float(margin))
    limit[1:] = min(margin, ratio * max(float(r[0]) if len(r) else 1.0, 1.0))
    share_limit = np.full(len(r), float(share))
    if share_rows is not None:
        share_limit[share_rows:] = -np.inf
    return limit, share_limit


def noise_rank(evidence: RowEvidence, max_k: int, margin: float = MARGIN, share: float = SHARE,
               ratio: float = RATIO, min_snr: float = MIN_SNR, share_rows: int | None = None
               ) -> Selection | None:
    """s = the number of leading rows k ≤ ``max_k`` that are constraints by the rule of the
    module docstring (0 … max_k); None when evidence.snr < ``min_snr`` (no judgement).
    ``share_rows``: only the first this many rows may be constraints by their share alone (None:
    every row) — a model that learns its rows per state or per stretch can always find a
    direction carrying little of the motion, which its noise ratio then shows to be motion.
    ``values`` of the Selection: r_k = e_k/σ²_k."""
    if not evidence.snr >= min_snr:
        return None
    r = evidence.ratio
    limit, share_limit = row_limits(r, margin, share, ratio, share_rows)
    quiet = (r <= limit) | (evidence.share <= share_limit)
    m = min(int(max_k), len(quiet))
    k = int(np.argmin(np.r_[quiet[:m], False]))  # the first row that moves
    if k < m:
        why = (f"row {k + 1} moves {r[k]:.3g}× its noise variance (> {limit[k]:.3g}) and carries "
               f"{evidence.share[k]:.2g} of the motion (> {share:g})")
    else:
        why = f"all {k} candidate rows are quiet (at most {m} allowed)"
    if k == 0:
        why = "no constraint: " + why
    return Selection(RULE, k, [float(v) for v in r], why, "energy / noise variance of row k", list(limit),
                     "row k counts while it is quiet: its energy over its noise at most its limit, or its "
                     "share of the motion at most its share limit",
                     extra={"share": [float(v) for v in evidence.share],
                            "share_limits": [float(v) if np.isfinite(v) else None for v in share_limit]})


def choose(U: np.ndarray, rows: np.ndarray, demo: np.ndarray, t: np.ndarray, max_k: int,
           X: np.ndarray | None = None, derivative: HowMade = None) -> Selection | None:
    """:func:`row_evidence` then :func:`noise_rank` with the default thresholds."""
    return noise_rank(row_evidence(U, rows, demo, t, X, derivative), max_k)
