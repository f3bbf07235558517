"""One constant constraint per segment of each demonstration, the segments cut where the
constraint changes ("per segment", ALGORITHMS.md §3.1 on each segment; issue 17).

A surface that tilts in steps (a board moved between strokes, a fixture re-clamped) holds a
constant constraint between its moves. Windows fixed in time (:class:`~.windows.PerWindow`)
straddle the moves; here the boundaries follow the data. Each demonstration is cut into blocks
of ``block`` s (j = ⌊t / block⌋); a segment is a run of consecutive blocks [i, j), at most
``window`` s long, with the second moment

    C_ij = Σ_{n ∈ blocks i … j−1} u_n u_nᵀ + ρ n_ij C̄      (as PerWindow's, ρ = ``shrinkage``)

and the cost λ₁(C_ij), its smallest eigenvalue: the motion along the segment's quietest
direction. The segments minimise

    Σ_segments λ₁(C_ij) + β · (number of segments),      β = ``penalty`` · ĝ · ln B_d

(optimal partitioning, solved exactly by dynamic programming over the blocks, Jackson et al.
2005), B_d the demonstration's blocks. ĝ is the price of a cut on noise alone, measured on the
data: the median over adjacent blocks of the recording of what one cut between them buys,
λ₁(C_b + C_b+1) − λ₁(C_b) − λ₁(C_b+1) — almost every pair of neighbours lies within one
constant stretch. It carries the noise's correlation, which a count of samples does not
(velocities derived by a filter that spans many samples: an information criterion with σ̂² per
sample cut a board tilting in 12 steps into 30–60 segments at 200 Hz – 1 kHz); ln B_d pays for
the B_d places a cut may go.

The rows of each segment and their number are then PerWindow's (smallest eigenvectors of C,
the noise rule on every sample's rows). Prediction: a sample takes the rows of the segment of
its demonstration that holds its block, or of the nearest segment (a held-out stretch between
segments); a demonstration not seen in ``fit`` has none (fit again on it, as ``ccl evaluate``
/ ``ccl predict`` do).

Shapes: U (N, q), groups (N,), t (N,) s; ``windows_`` (S, 3) [demonstration id, first block,
end block) of the S segments, ``A_`` (S, s, q).
"""

from __future__ import annotations

import numpy as np

from ccl_cli.learn.constraint.timeblocks import nearest_window, window_index
from ccl_cli.learn.constraint.windows import PerWindow, window_moments
from ccl_cli.learn.params import NonNegative, Seconds, parameters

#: Block length (s): the resolution of the cuts.
BLOCK_S = 0.5
#: The longest segment (s): bounds the dynamic programme's work (blocks × window / block).
MAX_SEGMENT_S = 30.0
#: β in units of ĝ · ln B_d (module docstring).
PENALTY = 4.0


def quietest_motion(C: np.ndarray) -> np.ndarray:
    """λ₁ of each symmetric (..., q, q): the second moment along its quietest direction."""
    return np.linalg.eigvalsh(C)[..., 0]


def cut(S: np.ndarray, counts: np.ndarray, prior: np.ndarray, beta: float, longest: int
        ) -> list[tuple[int, int]]:
    """The segments [i, j) of blocks 0 … B−1 minimising Σ λ₁(C_ij) + β per segment, each at most
    ``longest`` blocks (module docstring). S (B, q, q) the blocks' Σ u uᵀ, counts (B,), prior
    (q, q) = ρ C̄: :func:`cut_demonstrations` of one demonstration."""
    return cut_demonstrations(S, counts, np.array([len(S)]), prior, np.array([beta]), longest)[0]


def cut_demonstrations(S: np.ndarray, counts: np.ndarray, lengths: np.ndarray, prior: np.ndarray,
                       beta: np.ndarray, longest: int) -> list[list[tuple[int, int]]]:
    """:func:`cut` of every demonstration at once: S (B, q, q) and counts (B,) of the blocks of D
    demonstrations one after the other, ``lengths`` (D,) their numbers of blocks, ``beta`` (D,)
    their prices of a segment → the segments [i, j) of each (blocks counted from its first).

    Dynamic programming: best[j] = min_i best[i] + λ₁(C_ij) + β, C_ij from the running sums P
    of Σ u uᵀ (and M of the counts) — a loop over the block position j, each step one batched
    eigvalsh of the ≤ ``longest`` candidate segments of every demonstration still that long
    (those sorted longest first, so they are a prefix): the same sums in the same order as
    one demonstration at a time, with as many steps as the longest demonstration has blocks."""
    D = len(lengths)
    order = np.argsort(-np.asarray(lengths), kind="stable")
    length = np.asarray(lengths)[order]
    first = (np.cumsum(lengths) - lengths)[order]
    beta = np.asarray(beta, dtype=float)[order]
    alive = np.searchsorted(-length, -np.arange(int(length.max()) + 1), side="right")  # demos with ≥ j blocks
    q = S.shape[1]
    P, M = [np.zeros((D, q, q))], [np.zeros(D)]
    for j in range(1, len(alive)):  # a loop over block positions, each batched over demonstrations
        rows = first[: alive[j]] + j - 1
        P.append(P[j - 1][: alive[j]] + S[rows])
        M.append(M[j - 1][: alive[j]] + counts[rows])
    best, start = [np.zeros(D)], [np.zeros(D, np.int64)]
    for j in range(1, len(alive)):
        a = alive[j]
        i = np.arange(max(0, j - longest), j)
        C = np.stack([P[j] - P[k][:a] + (M[j] - M[k][:a])[:, None, None] * prior for k in i])
        total = np.stack([best[k][:a] for k in i]) + quietest_motion(C) + beta[:a]
        pick = np.argmin(total, axis=0)
        best.append(total[pick, np.arange(a)])
        start.append(i[pick])
    out: list[list[tuple[int, int]]] = [[] for _ in range(D)]
    for r in range(D):  # a loop over demonstrations and their segments
        spans, j = [], int(length[r])
        while j > 0:
            spans.append((int(start[j][r]), j))
            j = int(start[j][r])
        out[order[r]] = spans[::-1]
    return out


def split_price(C: np.ndarray, demo: np.ndarray) -> float:
    """ĝ (module docstring): the median over neighbouring blocks of one demonstration of
    λ₁(C_b + C_b+1) − λ₁(C_b) − λ₁(C_b+1), from the blocks' second moments C (B, q, q) (prior
    included) and their demonstrations (B,); 0 with no neighbours."""
    same = demo[1:] == demo[:-1]
    if not same.any():
        return 0.0
    lam = quietest_motion(C)
    gain = quietest_motion(C[1:][same] + C[:-1][same]) - lam[1:][same] - lam[:-1][same]
    return float(np.median(gain))


@parameters
class PerSegment(PerWindow):
    """A constant constraint (nhat) per segment of each demonstration, cut where it changes.

    Args:
        window: the longest segment (s).
        block: block length (s), the resolution of the cuts.
        penalty: β in units of ĝ · ln B_d (module docstring); larger: fewer cuts.
        n_constraints, shrinkage, heldout: as :class:`~.windows.PerWindow`'s (held-out blocks
            inside every segment, the segments cut again on each training fold).

    Attributes:
        A_ (S, s, q), windows_ (S, 3) [demonstration id, first block, end block), window_ (the
        block length), n_constraints_, n_action_, selection_, n_features_in_, heldout_.
    """

    window: Seconds = MAX_SEGMENT_S
    block: Seconds = BLOCK_S
    penalty: NonNegative = PENALTY

    local_to = "segment"
    #: Columns of ``windows_``: [demonstration id, first block, end block).
    TABLE_WIDTH = 3
    #: What is kept when the model is fitted on a recording it has not seen.
    KEEPS = ("k", "window", "block", "penalty", "shrinkage")

    @property
    def per(self) -> str:
        return "segment (cut where the constraint changes)"

    @property
    def _unit(self) -> float:
        """The table counts blocks: ``window_`` is the block length."""
        return self.block

    def _windows(self, U: np.ndarray, groups: np.ndarray | None, t: np.ndarray | None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """(segment of each sample (N,), table (S, 3) [demonstration id, first block, end
        block)) by :func:`cut` on each demonstration's blocks."""
        blk, blocks = window_index(groups, t, self.block, len(U))
        S, counts, pooled = window_moments(U, blk, len(blocks))
        counts, prior = counts.astype(float), self.shrinkage * pooled
        price = split_price(S + counts[:, None, None] * prior, blocks[:, 0])
        longest = max(1, int(np.floor(self.window / self.block + 1e-9)))
        demos, first, lengths = np.unique(blocks[:, 0], return_index=True, return_counts=True)  # sorted table
        beta = np.array([self.penalty * price * np.log(max(int(n), 2.0)) for n in lengths])
        table, of_block = [], np.empty(len(blocks), np.int64)
        spans = cut_demonstrations(S, counts, lengths, prior, beta, longest)
        for d, f, cuts in zip(demos, first, spans, strict=True):  # a loop over demonstrations' segments
            for i, j in cuts:
                of_block[f + i: f + j] = len(table)
                table.append((int(d), int(blocks[f + i, 1]), int(blocks[f + j - 1, 1]) + 1))
        return of_block[blk], np.asarray(table, np.int64).reshape(-1, 3)

    def fit(self, X: np.ndarray | None, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: dict | bool | None = None) -> PerSegment:
        """As :meth:`PerWindow.fit <ccl_cli.learn.constraint.windows.PerWindow.fit>`, the windows
        being the segments (module docstring)."""
        super().fit(X, U, groups=groups, t=t, derivative=derivative)
        self.selection_["segments"] = self.summary()
        return self

    def summary(self, most: int = 8) -> str:
        """Where the cuts are, in words: "18 segments; demo 0 cut at 6.0, 12.0, … s"."""
        self._check_fitted("A_")
        parts = []
        for d in np.unique(self.windows_[:, 0]):
            first = self.windows_[self.windows_[:, 0] == d, 1][1:] * self.window_
            shown = ", ".join(f"{c:.1f}" for c in first[:most]) + (", …" if len(first) > most else "")
            parts.append(f"demo {int(d)} " + (f"cut at {shown} s" if len(first) else "not cut"))
        return f"{len(self.windows_)} segment(s); " + "; ".join(parts[:most]) + (
            f"; … ({len(parts) - most} more demonstrations)" if len(parts) > most else "")

    def window_of(self, X: np.ndarray, groups: np.ndarray | None = None,
                  t: np.ndarray | None = None) -> np.ndarray:
        """Index (N,) into ``windows_`` of each sample: the segment of its demonstration that
        holds its block, else the nearest one (InputError for a demonstration not seen)."""
        self._check_fitted("A_")
        return nearest_window(self.windows_, self.window_, len(self._check_states(X)), groups, t,
                              "per-segment")
