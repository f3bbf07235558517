"""How many constraints the states' own geometry shows (DESIGN.md "Evidence for a constraint").

When the action is the derivative of the state, constraint-consistent motion keeps each
demonstration on a manifold — a line along a slide, a circle about a hinge, a plane or a curved
surface under a finger — and the manifold shows in the positions themselves, with no
differentiation. :func:`decide` looks for it with :class:`~.manifold.ManifoldConstraint`:

*Held-out drift.* A model of k level functions is fitted without a demonstration (or without a
block of one recording) and its levels h_j are read along the samples held out: along a true
constraint they stay constant, whatever the motion along the free directions. The drift of row
j is RMS(h_j − mean) / RMS(x − mean) over the held-out stretches — a ratio of lengths, so the
same at any rate, length unit or frame. Compliance, tremor and filtering move h only a little
and do not accumulate; a free direction carries the motion.

*The shape over a demonstration and agreement with the others* (a single smooth trajectory is
locally a curve, whatever the constraint):

==================  =====================================================================
rail (k = q − 1)    every held-out demonstration on a line or circle of the family fitted to
                    the others, each at its own offset (``linear``, ``sphere``; conics too in
                    2-D), drift ≤ :data:`RAIL`; or one circle per demonstration (3-D) whose
                    axes agree within :data:`AXIS_DEG` and radii within :data:`RADIUS_SPREAD`
surface (k < q − 1) demonstrations that come back over their own ground (:func:`revisits`)
                    and stay within :data:`SURFACE` of a surface (also per demonstration, and
                    ``quadric``); without such returns, a plane or sphere (not a quadric: a
                    quadric bends through any bundle of curves) within :data:`THIN`
==================  =====================================================================

k is the largest rank some model reaches (q − 1 first); among the models of that rank the
simplest (global before per demonstration; linear, sphere, quadric) whose worst drift is within
:data:`PARSIMONY` × the best one's wins — judged by the same measure, and even if it misses the
limit itself: the evidence sets k, parsimony the shape (a tilting table is still a plane).
k = 0 when none holds: the states show no constraint (the velocities may still show one).

The thresholds were set on real recordings (docs/auto.md): hinges and drawers drift 0.5–3 %,
tracker surfaces 10–16 %, a robot's wipes 11 %, free reaching ≥ 10 % with no returns.

Shapes: X (N, q) positions, groups (N,) demonstration ids (samples of one are contiguous).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.dataset import Derivative, HowMade, group_rows
from ccl_cli.errors import InputError
from ccl_cli.learn.constraint.manifold import BASES, ManifoldConstraint, within_covariance
from ccl_cli.learn.constraint.rank import Selection
from ccl_cli.learn.linalg import generalized_eigh, row_chunks

#: A demonstration shows a shape with at least MIN_SAMPLES samples and a spread above STILL × the
#: median demonstration's.
MIN_SAMPLES = 10
STILL = 1e-3
#: Largest drift of a rail (k = q − 1).
RAIL = 0.04
#: Largest drift of a surface shown by demonstrations that come back over their ground.
SURFACE = 0.2
#: Largest drift of a plane or sphere shown by single passes.
THIN = 0.05
#: A learnt constraint holds on other data of the same recordings (a held-out part) while the
#: positions drift along its rows by at most this share of their spread (:func:`rows_drift`) where
#: the demonstrations come back over their ground (a check that nothing carries the states off
#: the rows, looser than the limits that choose k); on single passes the limits of :func:`decide`.
HOLDS = 0.35
#: Largest residual of the line or circle fitted to each demonstration (q ≤ 3), over its spread
#: (hinges and slides of real recordings: 0.006–0.03, free curves 0.14 and more).
RAIL_FIT = 0.08
#: A demonstration comes back over its ground when at least REVISIT_SHARE of its samples have two
#: other passes of it within REVISIT_RADIUS × its spread; surfaces may be judged per
#: demonstration and by a quadric when at least half of the demonstrations do.
REVISIT_RADIUS = 0.3
REVISIT_SHARE = 0.25
#: Lines in different directions are one constraint per demonstration when there are at least
#: MIN_LINES of them and no point comes within MEET × a demonstration's spread of every one (lines
#: through one point are straight reaches to one goal).
MIN_LINES = 3
MEET = 0.3
#: Largest pooled residual of rows that each demonstration moves along at its own constant rate (a
#: constant task part, :func:`task_residual`): strict, since a steady drift of a free motion (a pen
#: progressing across a page) comes within 0.11–0.3.
TASK_FIT = 0.02
RIDGE_TIME = 1e-9
#: A demonstration's circle of radius at least FLAT × its spread is a (bowed) line.
FLAT = 5.0
#: Circles fitted one per demonstration agree: axes within AXIS_DEG, radii within ± RADIUS_SPREAD.
AXIS_DEG = 10.0
RADIUS_SPREAD = 0.1
#: A more complex model wins only by more than this factor of drift.
PARSIMONY = 2.0
#: Held-out folds: one demonstration each up to this many, else this many folds of whole demonstrations;
#: one demonstration: BLOCKS contiguous blocks with GAP_SHARE of the recording dropped at each boundary.
MAX_FOLDS = 12
BLOCKS = 5
GAP_SHARE = 0.01
#: At most this many query samples per demonstration in :func:`returning` (work bounded at any N).
REVISIT_QUERIES = 400
#: Samples of a demonstration up to which :func:`returning` measures all distances (400 × n of
#: them) instead of building a k-d tree.
BRUTE_ROWS = 50_000
#: The evidence is read on at most about EVIDENCE_ROWS samples (work bounded at any N): when the
#: moving demonstrations hold more, at most max(EVIDENCE_DEMOS, EVIDENCE_ROWS / their median
#: length) whole demonstrations, evenly spaced in :func:`demo_order` (near the centre of the states
#: to far from it), thinned in time by one common stride (:func:`evidence_rows`), and the surfaces
#: per demonstration judged on at most EVIDENCE_DEMOS of them; the model that shows the constraint
#: is then fitted on all rows.
EVIDENCE_ROWS = 20_000
EVIDENCE_DEMOS = 50
#: Phases: the samples that come back over their ground within PHASE_RADIUS × the spread are where
#: a surface may hold while the rest moves freely (approach, retract), when the free share of the
#: samples is between FREE_SHARE and 1 − FREE_SHARE; runs shorter than MIN_RUN_SHARE of their
#: demonstration are not a phase.
PHASE_RADIUS = 0.15
FREE_SHARE = 0.15
MIN_RUN_SHARE = 0.05


@dataclass
class Tried:
    """One model of the states' manifold: its rank k, ``scope`` ("global": one family over all the
    demonstrations, each at its own offset; "per_demo": one per demonstration), basis, the held-out
    drift of each row, whether it holds and why."""

    k: int
    scope: str
    basis: str
    drift: np.ndarray
    limit: float
    holds: bool
    why: str
    measure: str = "held-out drift"

    @property
    def worst(self) -> float:
        return float(np.max(self.drift)) if len(self.drift) else 0.0

    def row(self, chosen: bool) -> dict[str, Any]:
        return {"k": self.k, "scope": self.scope, "basis": self.basis, "measure": self.measure,
                "drift": [float(v) for v in self.drift], "limit": self.limit, "holds": self.holds,
                "chosen": chosen, "reason": self.why}


@dataclass
class Geometry:
    """What :func:`decide` found: ``k`` (0: no constraint in the states), the winner (None for 0),
    every model tried, each demonstration's share of samples with returns, and a sentence."""

    k: int
    winner: Tried | None
    tried: list[Tried] = field(default_factory=list)
    revisits: dict[int, float] = field(default_factory=dict)
    reason: str = ""

    def evidence(self, k: int) -> Tried | None:
        """The best model of rank k (the winner at the chosen k), or None."""
        at = [t for t in self.tried if t.k == k]
        return min(at, key=lambda t: t.worst) if at else None


def demo_order(X: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """The demonstration ids sorted by the distance of their centroid from the centroid of all
    the states (ties by size): an order that does not depend on the files' order, the frame or
    the unit, for assigning demonstrations to folds."""
    ids, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
    sums = np.zeros((len(ids), X.shape[1]))
    np.add.at(sums, inverse, X)
    dist = np.linalg.norm(sums / counts[:, None] - X.mean(0), axis=1)
    return ids[np.lexsort((counts, dist))]


def folds(X: np.ndarray, groups: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Train/test index pairs: whole demonstrations held out (one each up to MAX_FOLDS of them),
    or — one demonstration — BLOCKS contiguous blocks with guard gaps."""
    n = len(X)
    ids = demo_order(X, groups)
    if len(ids) >= 3:
        parts = [ids[j::MAX_FOLDS] for j in range(min(MAX_FOLDS, len(ids)))]
        return [(np.flatnonzero(~np.isin(groups, p)), np.flatnonzero(np.isin(groups, p))) for p in parts]
    gap = int(np.ceil(GAP_SHARE * n))
    out = []
    for block in np.array_split(np.arange(n), BLOCKS):
        keep = np.ones(n, bool)
        keep[max(block[0] - gap, 0): block[-1] + gap + 1] = False
        out.append((np.flatnonzero(keep), block))
    return out


def _stretches(index: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """An id per sample of ``index`` (sorted) for each contiguous run within one demonstration."""
    breaks = (np.diff(index) != 1) | (groups[index][1:] != groups[index][:-1])
    return np.cumsum(np.r_[True, breaks])


def drift(X: np.ndarray, groups: np.ndarray, basis: str, k: int) -> np.ndarray:
    """Held-out drift of the first k level functions of ``basis`` (module docstring): (k,)."""
    q = X.shape[1]
    H = np.zeros((len(X), k))
    piece = np.zeros(len(X), np.int64)
    for j, (train, test) in enumerate(folds(X, groups)):
        try:
            model = ManifoldConstraint(family=basis, n_constraints=k).fit(
                X[train], np.zeros((len(train), q)), groups=_stretches(train, groups))
        except (InputError, np.linalg.LinAlgError):  # a fold whose states do not move: no evidence
            return np.full(k, np.inf)
        H[test] = model.levels(X[test], k)
        piece[test] = j
    pieces = np.cumsum(np.r_[True, (piece[1:] != piece[:-1]) | (groups[1:] != groups[:-1])])
    spread = within_covariance(X, pieces).trace()
    var = np.diag(within_covariance(H, pieces))
    return np.sqrt(var / spread) if spread > 0 else np.full(k, np.inf)


def passes_near(P: np.ndarray, Q: np.ndarray, r: float) -> np.ndarray:
    """For each point of Q (m, q): the number of runs of consecutive samples of P (n, q) within
    distance ``r`` of it (‖p − x‖² ≤ r², summed over the dimensions in order, as a k-d tree's ball
    query): (m,) int. In blocks of about 2¹⁶ distances (they stay in the cache)."""
    out = np.empty(len(Q), dtype=np.int64)
    r2 = r * r
    for rows in row_chunks(len(Q), max(1, 2**16 // max(len(P), 1))):
        d2 = (P[None, :, 0] - Q[rows, None, 0]) ** 2  # (c, n)
        for j in range(1, P.shape[1]):
            d2 += (P[None, :, j] - Q[rows, None, j]) ** 2
        inside = d2 <= r2
        out[rows] = inside[:, 0] + (inside[:, 1:] & ~inside[:, :-1]).sum(1)
    return out


def returning(P: np.ndarray, radius: float = REVISIT_RADIUS) -> np.ndarray:
    """Per sample of a demonstration P (n, q): whether its neighbourhood (``radius`` × the
    demonstration's RMS spread) holds at least two other passes of it (runs of consecutive
    samples): (n,) bool. At most REVISIT_QUERIES samples are asked; the others take the answer of
    the nearest one asked (work bounded at any n). Up to BRUTE_ROWS samples (the bounded samples
    the geometry reads) the neighbourhoods are found from all distances, in blocks, without SciPy
    (whose import costs a run 35 MiB and 0.2 s); above, by SciPy's k-d tree."""
    scale = float(np.abs(P).max()) if P.size else 0.0
    if len(P) < 3 or not 0 < scale < np.inf:
        return np.zeros(len(P), dtype=bool)
    P = P / scale  # within ±1: the tree's squared distances cannot overflow (states near 1e300)
    spread = float(np.sqrt(((P - P.mean(0)) ** 2).sum(1).mean()))
    if not spread > 0:
        return np.zeros(len(P), dtype=bool)
    step = max(1, len(P) // REVISIT_QUERIES)
    queries = np.arange(0, len(P), step)
    if len(P) <= BRUTE_ROWS:
        answer = passes_near(P, P[queries], radius * spread) >= 3
    else:
        from scipy.spatial import cKDTree

        near = cKDTree(P).query_ball_point(P[queries], radius * spread, return_sorted=True)
        answer = np.array([np.count_nonzero(np.diff(nb) != 1) >= 2 for nb in near])  # ≤ REVISIT_QUERIES
    nearest = np.minimum((np.arange(len(P)) + step // 2) // step, len(queries) - 1)
    return answer[nearest]


def revisits(P: np.ndarray) -> float:
    """The share of a demonstration's samples P (n, q) that come back over its own ground
    (:func:`returning`)."""
    return float(returning(P).mean()) if len(P) else 0.0


def circle(P: np.ndarray) -> tuple[np.ndarray, float]:
    """The axis (unit, (3,)) and radius of the circle fitted to the points P (n, 3): the plane by
    SVD, then an algebraic circle fit in it."""
    c0 = P.mean(0)
    e1, e2, axis = np.linalg.svd(P - c0, full_matrices=False)[2]
    Q = np.c_[(P - c0) @ e1, (P - c0) @ e2]
    sol = np.linalg.lstsq(np.c_[2 * Q, np.ones(len(Q))], (Q**2).sum(1), rcond=None)[0]
    return axis, float(np.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 0.0)))


def _per_demo_drift(X: np.ndarray, groups: np.ndarray, basis: str, k: int, which: np.ndarray
                    ) -> np.ndarray:
    """Median over the demonstrations ``which`` of each one's own held-out drift (blocks): (k,)."""
    rows = dict(zip(*group_rows(groups), strict=True))
    values = [drift(X[rows[d]], np.zeros(len(rows[d]), np.int64), basis, k) for d in which]
    return np.median(values, axis=0)


def shape_residual(P: np.ndarray, k: int, basis: str = "sphere") -> np.ndarray:
    """How far one demonstration P (n, q) is from the circle (``sphere``) or line (``linear``)
    fitted to it: the RMS of the first k level functions fitted to it alone, over its RMS
    spread: (k,). A circle or a line has a handful of parameters, so the fit to a few hundred
    samples is judged on those samples."""
    model = ManifoldConstraint(family=basis, n_constraints=k).fit(P, np.zeros_like(P))
    spread = float(np.sqrt(((P - P.mean(0)) ** 2).sum(1).mean()))
    H = model.levels(P, k)
    return np.sqrt(((H - H.mean(0)) ** 2).mean(0)) / spread if spread > 0 else np.full(k, np.inf)


def shapes_agree(X: np.ndarray, groups: np.ndarray) -> tuple[bool, str]:
    """Whether the curves of the demonstrations agree: circles with one axis (within AXIS_DEG) and
    radius (within ± RADIUS_SPREAD of the median), or lines with one direction (within AXIS_DEG),
    and a phrase saying how far apart they are. One demonstration agrees with itself."""
    ids, rows = group_rows(groups)
    if len(ids) == 1:
        return True, "one demonstration"
    q = X.shape[1]
    directions, axes, radii, straight = [], [], [], []
    for mine in rows:  # a loop over the demonstrations (of the bounded evidence sample)
        P = X[mine]
        c0 = P.mean(0)
        V = np.linalg.svd(P - c0, full_matrices=False)[2]
        directions.append(V[0])
        spread = float(np.sqrt(((P - c0) ** 2).sum(1).mean()))
        if q == 3:
            axis, r = circle(P)
            axes.append(axis)
        else:
            Q = (P - c0) @ V[:2].T
            sol = np.linalg.lstsq(np.c_[2 * Q, np.ones(len(Q))], (Q**2).sum(1), rcond=None)[0]
            r = float(np.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 0.0)))
        radii.append(r)
        # a line: the circle fits it no PARSIMONY × better, or bends so little over the demonstration
        # (radius ≥ FLAT × its spread) that it is a bowed line
        line = shape_residual(P, q - 1, "linear").max()
        straight.append(bool(r >= FLAT * spread or line <= 1e-6  # (exact lines: the circle fit is rounding)
                             or line <= PARSIMONY * shape_residual(P, q - 1, "sphere").max()))
    if all(straight):
        D = np.array(directions)
        ref = np.linalg.svd(D, full_matrices=False)[2][0]
        deg = float(np.degrees(np.arccos(np.clip(np.abs(D @ ref), 0.0, 1.0))).max())
        if deg <= AXIS_DEG:
            return True, f"lines within {deg:.1f}° of one direction"
        # lines in different directions: each demonstration under its own constraint — unless they
        # run through one point, as straight reaches to one goal do
        centres = np.array([X[m].mean(0) for m in rows])
        spreads = np.array([np.sqrt(((X[m] - X[m].mean(0)) ** 2).sum(1).mean()) for m in rows])
        miss = _meeting_miss(centres, D)
        meet = len(ids) < MIN_LINES or miss <= MEET * float(np.median(spreads))
        if meet:
            return False, f"lines in directions {deg:.0f}° apart, through one point (within {miss:.3g})"
        return True, (f"lines in directions {deg:.0f}° apart that do not run through one point (the "
                      f"nearest misses them by {miss:.3g} RMS): one constraint per demonstration")
    straight = np.array(straight)
    sizes = np.array([len(m) for m in rows])
    if sizes[straight].sum() > sizes[~straight].sum():
        return False, "lines in most demonstrations, arcs in others"
    # arcs in most: a straight piece is too short to tell a large circle from a line
    r = np.array(radii)[~straight]
    axes = [a for a, s in zip(axes, straight, strict=False) if not s] if axes else axes
    med = float(np.median(r))
    rel = float(np.abs(r - med).max() / med) if med > 0 else np.inf
    deg = 0.0
    if axes:
        A = np.array(axes)
        ref = np.linalg.svd(A, full_matrices=False)[2][0]
        deg = float(np.degrees(np.arccos(np.clip(np.abs(A @ ref), 0.0, 1.0))).max())
    ok = deg <= AXIS_DEG and rel <= RADIUS_SPREAD
    return ok, f"circles with axes within {deg:.1f}°, radii within ±{100 * rel:.0f} % of {med:.3g}"


def _meeting_miss(points: np.ndarray, directions: np.ndarray) -> float:
    """The RMS distance from the point nearest to every line (through ``points`` (L, q), along unit
    ``directions`` (L, q)) to the lines."""
    q = points.shape[1]
    P = np.eye(q)[None] - np.einsum("li,lj->lij", directions, directions)  # projections across each line
    point = np.linalg.lstsq(P.sum(0), np.einsum("lij,lj->i", P, points), rcond=None)[0]
    gaps = np.einsum("lij,lj->li", P, point[None] - points)
    return float(np.sqrt((gaps**2).sum(1).mean()))


def contact_runs(X: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """An id per sample for each run of samples that come back over their ground (PHASE_RADIUS;
    runs of at least MIN_RUN_SHARE of their demonstration), −1 elsewhere: (N,)."""
    mask = np.zeros(len(X), dtype=bool)
    for m in group_rows(groups)[1]:
        mask[m] = returning(X[m], PHASE_RADIUS)
    runs = np.cumsum(np.r_[True, (mask[1:] != mask[:-1]) | (groups[1:] != groups[:-1])])
    ids = np.where(mask, runs, -1)
    _, first, counts = np.unique(runs, return_index=True, return_counts=True)
    sizes = np.bincount(groups.astype(np.int64) - groups.min())
    short = counts < MIN_RUN_SHARE * sizes[groups[first].astype(np.int64) - groups.min()]
    ids[np.isin(runs, np.flatnonzero(short) + 1)] = -1
    return ids


def _phases(X: np.ndarray, groups: np.ndarray, k: int, all_along: list[Tried]) -> Tried | None:
    """A surface of rank k that holds in the runs that come back over their ground while the rest
    of the recording moves freely (:func:`contact_runs`), judged on held-out runs — or None when
    there are no such phases; it holds when within SURFACE and PARSIMONY × better than any surface
    that holds all along."""
    runs = contact_runs(X, groups)
    inside = runs >= 0
    free = 1.0 - inside.mean()
    if not FREE_SHARE <= free <= 1.0 - FREE_SHARE or len(np.unique(runs[inside])) < 2:
        return None
    best_all = min((t.worst for t in all_along if t.holds), default=np.inf)
    why = (f"a surface in the stretches that come back over their ground ({100 * (1 - free):.0f} % of "
           "the samples), free motion elsewhere")
    shapes = [Tried(k, "phases", basis, drift(X[inside], runs[inside], basis, k), SURFACE, False, why)
              for basis in BASES[:2]]  # one table, one bowl: no quadric through a few runs
    best = min(shapes, key=lambda t: t.worst)  # the evidence: the best of them; the shape: the
    found = next(t for t in shapes if t.worst <= PARSIMONY * best.worst)  # simplest within PARSIMONY ×
    found.holds = bool(best.worst <= SURFACE and best.worst * PARSIMONY <= best_all)
    return found


def _moving(X: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """The samples of the demonstrations that can show a shape: at least MIN_SAMPLES samples and
    an RMS spread above STILL × the median demonstration's (a demonstration held still, or a
    scrap of one, shows nothing): (N,) bool."""
    ids, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
    sums = np.zeros((len(ids), X.shape[1]))
    np.add.at(sums, inverse, X)
    centred = X - (sums / counts[:, None])[inverse]
    spread = np.sqrt(np.bincount(inverse, (centred**2).sum(1)) / counts)
    scale = float(np.abs(X).max()) if len(X) else 0.0  # rounding of the mean is not motion
    floor = max(STILL * float(np.median(spread)), 1e-9 * scale, np.finfo(float).tiny)
    ok = (counts >= MIN_SAMPLES) & (spread > floor)
    return ok[inverse.ravel()]


def spaced(ids: np.ndarray, count: int) -> np.ndarray:
    """At most ``count`` of ``ids`` (m,), evenly spaced from the first to the last."""
    if len(ids) <= count:
        return ids
    return ids[np.linspace(0, len(ids) - 1, count).round().astype(np.int64)]


def evidence_rows(X: np.ndarray, groups: np.ndarray, rows: int = EVIDENCE_ROWS,
                  demos: int = EVIDENCE_DEMOS) -> np.ndarray:
    """The rows (sorted indices) the evidence is read on: all when there are at most ``rows``;
    else at most max(``demos``, ``rows`` / their median length) whole demonstrations evenly
    spaced in :func:`demo_order`, each thinned in time by one common stride (every s-th sample,
    from its first; at least MIN_SAMPLES samples kept of each) so that about ``rows`` remain — a
    bounded, stratified, deterministic sample that keeps each demonstration's whole course (its
    shape, returns and phases; the drift and shape measures are ratios of lengths, the same at
    any rate)."""
    n = len(X)
    if n <= rows:
        return np.arange(n)
    ids, members = group_rows(groups)
    sizes = np.array([len(m) for m in members])
    count = min(len(ids), max(demos, rows // max(int(np.median(sizes)), 1)))
    if count < len(ids):
        at = np.searchsorted(ids, np.unique(spaced(demo_order(X, groups), count)))
    else:
        at = np.arange(len(ids))
    stride = max(1, -(-int(sizes[at].sum()) // rows))
    parts = [members[i][:: max(1, min(stride, sizes[i] // MIN_SAMPLES))] for i in at]  # ≤ count of them
    return np.sort(np.concatenate(parts))


def task_residual(X: np.ndarray, groups: np.ndarray, t: np.ndarray, k: int) -> float:
    """How far the demonstrations are from moving along their own k constant rows at their own
    constant rates (a·x − b t constant in each: a constraint with a constant task part, A u = b):
    the RMS of the k quietest such levels fitted to each demonstration alone, pooled, over the
    pooled RMS spread of the positions. X (N, q), groups (N,), t (N,) s."""
    q = X.shape[1]
    num = den = 0.0
    for m in group_rows(groups)[1]:  # a closed form per demonstration
        P, s = X[m] - X[m].mean(0), t[m] - t[m].mean()
        Z = np.c_[P, s / max(float(np.abs(s).max()), np.finfo(float).tiny)]  # time scaled to the unit
        G = np.diag([1.0] * q + [0.0]) + RIDGE_TIME * np.eye(q + 1)
        lam = generalized_eigh(Z.T @ Z, G)[0]
        num += float(np.maximum(lam[:k], 0.0).sum()) / k
        den += float((P**2).sum())
    return float(np.sqrt(num / den)) if den > 0 else np.inf


def decide(X: np.ndarray, groups: np.ndarray | None = None, only_k: int | None = None,
           max_k: int | None = None, t: np.ndarray | None = None) -> Geometry:
    """The number of constraints the positions X (N, q) of demonstrations ``groups`` show, and the
    model that shows it (module docstring); ``only_k``: judge that rank alone; ``max_k``: at most;
    ``t`` (N,) s: the sample times, for rails that move at a constant rate (a task part)."""
    X = np.asarray(X, dtype=float)
    q = X.shape[1]
    groups = np.zeros(len(X), np.int64) if groups is None else np.asarray(groups)
    usable = _moving(X, groups)
    if not usable.any():
        return Geometry(0, None, [], {}, "the states show no constraint: no demonstration moves over "
                        f"{MIN_SAMPLES} samples or more")
    X, groups = X[usable], groups[usable]
    keep = evidence_rows(X, groups)
    bounded = len(keep) < len(X)  # a sample: per-demonstration fits on at most EVIDENCE_DEMOS of them
    X, groups = X[keep], groups[keep]
    t = None if t is None else np.asarray(t, dtype=float)[usable][keep]
    ids, rows = group_rows(groups)
    back = {int(d): revisits(X[mine]) for d, mine in zip(ids, rows, strict=True)}
    returning = np.array([d for d in ids if back[int(d)] >= REVISIT_SHARE])
    surfaces_return = len(returning) >= max(1, len(ids) / 2)
    quadrics = q <= 3
    tried: list[Tried] = []
    top = min(q - 1, max_k if max_k is not None else q - 1)
    for k in ([only_k] if only_k is not None else range(top, 0, -1)):
        rail = k == q - 1
        for basis in BASES:
            if basis == "quadric" and (not quadrics or (rail and q > 2) or
                                       (not rail and not surfaces_return)):
                continue  # a pair of quadrics bends through any bundle of similar curves
            if rail:
                limit, why = RAIL, "a family of lines or circles, each demonstration at its own offset"
            elif surfaces_return:
                limit, why = SURFACE, "a surface the demonstrations come back over"
            else:
                limit, why = THIN, "a plane or sphere shown by single passes"
            d = drift(X, groups, basis, k)
            tried.append(Tried(k, "global", basis, d, limit, bool(d.max() <= limit), why))
        if rail and q <= 3:
            fits = np.array([shape_residual(X[mine], k) for mine in rows])
            agree, how = shapes_agree(X, groups)
            worst = fits.max(axis=0)
            holds = bool(agree and worst.max() <= RAIL_FIT)
            lines = how.startswith("lines")  # straight in every demonstration: constant rows each
            tried.append(Tried(k, "per_demo", "linear" if lines else "sphere", worst, RAIL_FIT, holds,
                               f"a line or circle in every demonstration ({how})", "shape residual"))
        if rail and q <= 3 and t is not None and len(ids) >= MIN_LINES and not any(
                x.holds for x in tried if x.k == k):
            fit = task_residual(X, groups, t, k)
            tried.append(Tried(k, "per_demo_task", "linear", np.full(k, fit), TASK_FIT, bool(fit <= TASK_FIT),
                               "each demonstration moving along its own constant rows at its own constant "
                               "rate (a task part: A u = b)", "shape residual"))
        if not rail and len(returning) and surfaces_return and len(ids) > 1:
            for basis in BASES[: 3 if quadrics else 2]:
                d = _per_demo_drift(X, groups, basis, k, spaced(returning, EVIDENCE_DEMOS)
                                    if bounded else returning)
                tried.append(Tried(k, "per_demo", basis, d, SURFACE, bool(d.max() <= SURFACE),
                                   "one surface per demonstration that comes back over its ground"))
        if not rail and surfaces_return:
            found = _phases(X, groups, k, [t for t in tried if t.k == k])
            if found is not None:
                tried.append(found)
        holding = [t for t in tried if t.k == k and t.holds]
        if holding:  # k from the best evidence; the model: the simplest within PARSIMONY × its drift
            best = min(holding, key=lambda t: t.worst)
            phased = next((t for t in holding if t.scope == "phases"), None)
            if phased is not None:  # a surface that holds in phases beats one claimed all along
                best = phased
            winner = next(t for t in tried if t.k == k and t.worst <= PARSIMONY * best.worst
                          and (t.holds or t.limit == best.limit))
            measure = winner.measure
            reason = (f"the states stay on a manifold of {q - k} dimension(s): {winner.why}, "
                      f"{winner.basis} ({winner.scope.replace('_', ' ')}), {measure} {winner.worst:.3g}"
                      + (f" ≤ {winner.limit:g}" if winner.holds else
                         f" (the simplest within {PARSIMONY:g}× of {best.basis} "
                         f"({best.scope.replace('_', ' ')}), {best.worst:.3g} ≤ {best.limit:g})"))
            return Geometry(k, winner, tried, back, reason)
    return Geometry(0, None, tried, back, "the states show no constraint: no line, circle or surface "
                    "holds the held-out demonstrations")


#: The actions are the states' derivative when finite differences of the states leave at most
#: this share of the actions' mean square unexplained.
KINEMATIC_RESIDUAL = 0.3


def kinematic(X: np.ndarray, U: np.ndarray, groups: np.ndarray, t: np.ndarray | None,
              derivative: HowMade = None) -> tuple[bool, str]:
    """Whether the actions U (N, q) are the time derivative of the states X (N, q) — derived from
    them by the readers (``derivative``), or recorded and matching the states' central
    differences on the stamps t (N,) to within KINEMATIC_RESIDUAL of their mean square — and a
    phrase saying why."""
    if X.shape[1] != U.shape[1]:
        return False, f"states ({X.shape[1]}) and actions ({U.shape[1]}) differ in dimension"
    if Derivative.of(derivative).derived:
        return True, "the actions were derived from the states"
    if t is None:
        return False, "no sample times to differentiate the states on"
    inside = np.flatnonzero((groups[2:] == groups[:-2]) & (t[2:] > t[:-2])) + 1
    if len(inside) < 3:
        return False, "too few samples to differentiate the states"
    dXdt = (X[inside + 1] - X[inside - 1]) / (t[inside + 1] - t[inside - 1])[:, None]
    total = float((U[inside] ** 2).sum())
    share = float(((dXdt - U[inside]) ** 2).sum() / total) if total > 0 else np.inf
    if share <= KINEMATIC_RESIDUAL:
        return True, (f"the actions match the states' differences ({100 * share:.1f} % of their mean "
                      "square apart)")
    return False, f"the actions are not the states' derivative ({100 * min(share, 9.99):.0f} % apart)"


def rows_drift(rows: np.ndarray, X: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """How far the positions X (N, q) of demonstrations ``groups`` move along given constraint
    rows (N, k, q) — the rows at each sample, unit length — integrated along each demonstration:
    z_n = Σ_{m<n} a(x_m)ᵀ(x_{m+1} − x_m) (for constant rows a ᵀ(x_n − x_0)), and the drift of row j
    is RMS(z_j − mean) / RMS(x − mean) within the demonstrations (the measure of :func:`drift`,
    for a model fitted elsewhere): (k,). A true constraint keeps it at the compliance of the
    contact; a free direction carries the motion."""
    rows = np.asarray(rows, dtype=float)
    k = rows.shape[1]
    if k == 0 or len(X) < 2:
        return np.zeros(k)
    norms = np.linalg.norm(rows, axis=2, keepdims=True)
    rows = np.divide(rows, norms, out=np.zeros_like(rows), where=norms > 0)
    same = groups[1:] == groups[:-1]
    # a row is a direction up to its sign: keep each one's sign continuous along a demonstration
    flips = (np.einsum("nkq,nkq->nk", rows[1:], rows[:-1]) < 0) & same[:, None]
    sign = np.where(np.cumsum(flips, axis=0) % 2 == 1, -1.0, 1.0)
    rows = rows * np.vstack([np.ones((1, k)), sign])[:, :, None]
    step = np.einsum("nkq,nq->nk", rows[:-1], np.diff(X, axis=0)) * same[:, None]
    z = np.vstack([np.zeros((1, k)), np.cumsum(step, axis=0)])
    spread = within_covariance(X, groups).trace()
    var = np.diag(within_covariance(z, groups))
    return np.sqrt(var / spread) if spread > 0 else np.full(k, np.inf)


def model_drift(model: Any, rows: np.ndarray, X: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """How far the positions X (N, q) of demonstrations ``groups`` move off a fitted model's
    constraint: a model of level sets (one with ``levels``, :class:`~.manifold.ManifoldConstraint`)
    by its own level functions h(x) — RMS(h − mean) / RMS(x − mean) within the demonstrations,
    the measure of :func:`drift` — others by integrating their rows (N, k, q) along the
    demonstrations (:func:`rows_drift`). Integrating the normalised gradients of a curved surface
    adds up their small tilts over every loop; the level itself does not. A model of level sets
    that holds in phases only (rows of zeros elsewhere) is read where it holds, each stretch at its
    own level: (k,)."""
    levels = getattr(model, "levels", None)
    if not callable(levels):
        return rows_drift(rows, X, groups)
    on = np.abs(rows).max(axis=(1, 2)) > 0 if rows.shape[1] else np.ones(len(X), dtype=bool)
    if not on.all():
        breaks = (groups[1:] != groups[:-1]) | (on[1:] != on[:-1])
        X, groups = X[on], np.cumsum(np.r_[True, breaks])[on]
    H = levels(X)
    spread = within_covariance(X, groups).trace()
    var = np.diag(within_covariance(H, groups))
    return np.sqrt(var / spread) if spread > 0 else np.full(H.shape[1], np.inf)


def integrate(W: np.ndarray, X: np.ndarray, groups: np.ndarray, t: np.ndarray | None) -> np.ndarray:
    """The states a velocity W (N, q) would have carried X (N, q) through: each demonstration
    starts at its first state and adds ∫W dt (trapezoids on the stamps t (N,); unit steps
    without them): (N, q). With W the learnt null-space part w̃, the states with the task part
    taken out."""
    t = np.arange(len(W), dtype=float) if t is None else np.asarray(t, dtype=float)
    same = groups[1:] == groups[:-1]
    step = 0.5 * (W[1:] + W[:-1]) * (np.diff(t) * same)[:, None]
    Z = np.vstack([np.zeros((1, W.shape[1])), np.cumsum(step, axis=0)])
    starts = np.flatnonzero(np.r_[True, ~same])
    first = np.repeat(starts, np.diff(np.r_[starts, len(W)]))
    return X[first] + Z - Z[first]


def holds_limit(X: np.ndarray, groups: np.ndarray, k: int) -> float:
    """The largest drift (:func:`rows_drift`) along k learnt rows with which a constraint holds on
    the positions X (N, q) of demonstrations ``groups``: HOLDS where most demonstrations come back
    over their ground; on single passes RAIL_FIT for k = q − 1 (a line or circle) and THIN below."""
    keep = evidence_rows(X, groups)
    P = X[keep]
    back = np.mean([revisits(P[mine]) >= REVISIT_SHARE for mine in group_rows(groups[keep])[1]]) >= 0.5
    return HOLDS if back else RAIL_FIT if k >= X.shape[1] - 1 else THIN


def add_still_rows(chosen: Selection | None, rows: np.ndarray, X: np.ndarray, U: np.ndarray,
                   groups: np.ndarray, t: np.ndarray | None, derivative: HowMade, max_k: int
                   ) -> Selection | None:
    """The noise rule's choice (:func:`~.noise_rank.noise_rank`) of an explicit learner's rows
    (N, m, q), extended — when the actions are the states' derivative — by the next rows along
    which the positions do not drift (:func:`rows_drift` within :func:`holds_limit`): a compliant
    contact or a hand's tremor moves along a true row far above the noise, and never carries the
    states off it. X (N, q), U (N, q), groups (N,), t (N,) s."""
    if chosen is None or chosen.n_constraints >= max_k or not kinematic(X, U, groups, t, derivative)[0]:
        return chosen
    k = chosen.n_constraints
    drift = rows_drift(rows[:, :max_k], X, groups)
    limit = holds_limit(X, groups, max_k)
    still = drift <= limit
    while k < max_k and still[k]:
        k += 1
    if k > chosen.n_constraints:
        chosen.reason += (f"; rows {chosen.n_constraints + 1}–{k} move above the noise but the positions "
                          f"drift along them by at most {drift[chosen.n_constraints:k].max():.3g} of their "
                          f"spread (≤ {limit:g}): constraints the contact gives a little along")
        chosen.extra.update(drift=[float(v) for v in drift], drift_limit=float(limit),
                            still_rows=list(range(chosen.n_constraints + 1, k + 1)))
        chosen.n_constraints = k
    return chosen
