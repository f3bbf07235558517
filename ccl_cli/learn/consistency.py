"""The consistency errors a learner scores itself by (its ``score`` is minus one of them).

Each is computed from what the learner predicts and the observed actions alone — never
ground truth — so it serves cross-validation on any data:

* constraint models: NPOE (ALGORITHMS.md §6), ``mean ‖u − Ñ(x)u‖² / Σ var(u)``;
* null-space component (ncl): NPE (§6), ``mean ‖P̃u − w̃‖² / Σ var(u)``, P̃ = w̃w̃ᵀ/‖w̃‖²;
* policies: the normalised inconsistency error (§5), ``mean ‖u − ûûᵀπ̃(x)‖² / Σ var(u)``
  (pi-weighted: each term weighted by ‖u‖², its own criterion; pi-coupled:
  ``mean ‖u − Ñπ̃(x)‖² / Σ var(u)`` with the given projections).

The residuals are shared with :mod:`ccl_cli.metrics`, which reports the same errors with
ground truth and the conventions of the original library.
"""

from __future__ import annotations

import numpy as np


def apply_projection(P: np.ndarray, V: np.ndarray) -> np.ndarray:
    """P_n v_n for a stack P (N, q, q) or one matrix (q, q), and V (N, q) → (N, q)."""
    P = np.asarray(P, dtype=float)
    return V @ P.T if P.ndim == 2 else np.einsum("nij,nj->ni", P, V)


def projection_residual(N: np.ndarray, U: np.ndarray) -> np.ndarray:
    """u − Ñu per sample: N (N, q, q) or (q, q), U (N, q) → (N, q)."""
    return U - apply_projection(N, U)


def self_projection_residual(W: np.ndarray, U: np.ndarray) -> np.ndarray:
    """P̃u − w̃ per sample with P̃ = w̃w̃ᵀ/‖w̃‖² (P̃u = 0 where w̃ = 0): W, U (N, q) → (N, q)."""
    c = np.sum(W**2, axis=1, keepdims=True)
    a = np.sum(U * W, axis=1, keepdims=True)
    return np.where(c > 0, a / np.where(c > 0, c, 1.0), 0.0) * W - W


def mean_squared(R: np.ndarray) -> float:
    """mean_n ‖r_n‖² of residuals R (N, d)."""
    return float(np.mean(np.sum(R**2, axis=1)))


def action_variance(U: np.ndarray) -> float:
    """Σ var(u) (ddof = 1) of U (N, q); when it is 0 (or N = 1), mean ‖u‖², else 1, so a
    held-out fold of constant actions still gets a finite error."""
    v = float(np.var(U, axis=0, ddof=1).sum()) if len(U) > 1 else 0.0
    return v if v > 0 else float(np.mean(np.sum(U**2, 1))) or 1.0


def npoe_error(N: np.ndarray, U: np.ndarray, normaliser: np.ndarray | None = None) -> float:
    """NPOE = mean ‖u − Ñu‖² / Σ var(u): N (N, q, q), U (N, q); the variance of
    ``normaliser`` (N, q) instead when given (U less a task part is normalised by u's)."""
    return mean_squared(projection_residual(N, U)) / action_variance(U if normaliser is None else normaliser)


def npe_error(W: np.ndarray, U: np.ndarray) -> float:
    """NPE = mean ‖P̃u − w̃‖² / Σ var(u): W, U (N, q)."""
    return mean_squared(self_projection_residual(W, U)) / action_variance(U)


def inconsistency_error(P: np.ndarray, U: np.ndarray, N: np.ndarray | None = None,
                        weighted: bool = False) -> float:
    """mean ‖u − ûûᵀπ̃‖² / Σ var(u) (§5) for π̃ = P (N, q); with projections N (N, q, q),
    mean ‖u − Ñπ̃‖²; ``weighted`` (pi-weighted's own criterion): each sample's term
    weighted by ‖u‖² / mean ‖u‖². Samples with u = 0 carry no direction and are left out."""
    if N is not None:
        res = U - apply_projection(N, P)
        w = np.ones(len(U))
    else:
        norm = np.linalg.norm(U, axis=1)
        keep = norm > 0
        uh = U[keep] / norm[keep, None]
        res = U[keep] - uh * np.sum(uh * P[keep], 1)[:, None]
        w = norm[keep] ** 2 if weighted else np.ones(int(keep.sum()))
    return float(np.sum(w * np.sum(res**2, 1)) / max(np.sum(w), 1e-300) / action_variance(U))


#: Energies below this share of the total are floored in :func:`split_likelihood` (exact data).
LIKELIHOOD_FLOOR = 1e-12


def split_likelihood(N: np.ndarray, U: np.ndarray) -> float:
    """How much better the split of the actions U (N, q) by a constraint with projections N
    (N, q, q) explains them than no split, per action dimension — a score comparable across the
    number of constraints k (higher is better, 0 for k = 0):

        ½ [q log(E/q) − k log(E_c/k) − (q − k) log(E_f/(q − k))] / q,

    the Gaussian log-likelihood of the actions with one variance along the k constraint rows,
    E_c/k (E_c = mean ‖u − Ñu‖²), and another across the q − k free directions, E_f/(q − k)
    (E_f = mean ‖Ñu‖²), against one variance in every direction, E/q (E = E_c + E_f); k is the
    mean rank of I − Ñ. A true constraint row, quiet, gains; a row along which the actions move
    spends the constraint variance on motion and loses; a missed quiet row gains nothing."""
    N = np.asarray(N, dtype=float)
    U = np.asarray(U, dtype=float)
    q = U.shape[1]
    free = apply_projection(N, U)
    Ef, Ec = mean_squared(free), mean_squared(U - free)
    E = Ef + Ec
    k = float(np.mean(np.trace(np.eye(q) - N, axis1=-2, axis2=-1))) if N.ndim == 3 else float(
        np.trace(np.eye(q) - N))
    k = min(max(k, 0.0), float(q))
    if not E > 0 or k < 1e-9 or k > q - 1e-9:
        return 0.0
    floor = LIKELIHOOD_FLOOR * E
    Ec, Ef = max(Ec, floor), max(Ef, floor)
    return 0.5 * (q * np.log(E / q) - k * np.log(Ec / k) - (q - k) * np.log(Ef / (q - k))) / q
