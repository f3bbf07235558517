"""Evaluation metrics (ALGORITHMS.md §6).

The residuals are those the learners score themselves by
(:mod:`ccl_cli.learn.consistency`); here they are normalised as reported, with ground
truth where the data hold it.

Each metric is a mean squared error divided by a total variance (sum over dimensions
of the per-dimension sample variance, ddof = 1) and returns a :class:`Metric` with the
value, the unnormalised error and the normaliser, so reports can show all three.

``convention="original"`` reproduces the original library's normalisers: NPPE and
NPOE divide by var(π) for state-independent constraints and by var of the true
null-space component w for state-dependent ones; NPE uses ddof = 0.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ccl_cli.errors import ConfigError
from ccl_cli.learn.consistency import apply_projection as _apply
from ccl_cli.learn.consistency import mean_squared, projection_residual, self_projection_residual
from ccl_cli.learn.linalg import total_variance

#: The data a stage's metrics are computed on, in the order summaries show them (metrics.json
#: keys): the training part, blocks held out inside it (a model per demonstration or window),
#: the held-out test part.
SPLITS = ("train", "heldout_blocks", "test")

CONVENTIONS = ("ccl", "original")


@dataclass(frozen=True)
class Metric:
    """A normalised error: ``value = error / normaliser``; with groups (demonstrations or
    held-out time blocks), ``se`` is the standard error of ``value`` over the ``n_groups``
    groups (the spread of the groups' mean errors, each over the same normaliser)."""

    name: str
    value: float
    error: float
    normaliser: float
    normaliser_of: str
    se: float | None = None
    n_groups: int = 0

    def as_dict(self) -> dict:
        out = asdict(self)
        if self.se is None:
            del out["se"], out["n_groups"]
        return out


def group_index(groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's group (0 … G − 1, in ascending order of the ids) and each group's size: as
    ``np.unique(groups, return_inverse=True, return_counts=True)[1:]``, in one pass (no sort)
    when the ids do not decrease (the pieces of :func:`ccl_cli.app.scoring.groups_of`)."""
    groups = np.asarray(groups).ravel()
    if len(groups) and np.all(groups[1:] >= groups[:-1]):
        new = np.r_[False, groups[1:] != groups[:-1]]
        inverse = np.cumsum(new)
        return inverse, np.bincount(inverse)
    _, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
    return inverse.ravel(), counts


def _metric(name: str, diff: np.ndarray, denom: float, of: str, groups: np.ndarray | None = None
            ) -> Metric:
    err = mean_squared(diff)
    if not np.isfinite(denom) or denom <= 0:
        return Metric(name, float("nan"), err, float(denom), of)
    se, n_groups = None, 0
    if groups is not None:
        inverse, counts = group_index(groups)
        n_groups = len(counts)
        if n_groups > 1:
            per_group = np.bincount(inverse, weights=np.sum(np.asarray(diff) ** 2, axis=1)) / counts / denom
            se = float(per_group.std(ddof=1) / np.sqrt(n_groups))
    return Metric(name, err / denom, err, float(denom), of, se, n_groups)


def _convention(convention: str) -> None:
    if convention not in CONVENTIONS:
        raise ConfigError(f"unknown metric convention {convention!r} (use {' or '.join(CONVENTIONS)})")


def nppe(
    N_true: np.ndarray,
    N_est: np.ndarray,
    Pi: np.ndarray,
    U: np.ndarray,
    convention: str = "ccl",
    state_dependent: bool = False,
    groups: np.ndarray | None = None,
) -> Metric:
    """Normalised projected policy error: mean ‖N π − Ñ π‖² / Σ var(U).

    N_true, N_est: (N, q, q) or (q, q); Pi, U: (N, q).
    """
    _convention(convention)
    diff = _apply(N_true, Pi) - _apply(N_est, Pi)
    if convention == "original":
        if state_dependent:
            return _metric("NPPE", diff, total_variance(_apply(N_true, Pi)), "w", groups)
        return _metric("NPPE", diff, total_variance(Pi), "pi", groups)
    return _metric("NPPE", diff, total_variance(U), "u", groups)


def npoe(
    N_est: np.ndarray,
    U: np.ndarray,
    convention: str = "ccl",
    Pi: np.ndarray | None = None,
    W: np.ndarray | None = None,
    V_est: np.ndarray | None = None,
    of: str = "u",
    groups: np.ndarray | None = None,
) -> Metric:
    """Normalised projected observation error: mean ‖z − Ñ z‖² / Σ var(U), z = u − ṽ.

    ``U`` (N, q) are the observations the constraint was learnt from (``of`` names them:
    ``"u"``, or ``"learnt w"`` when a learn-v stage gave w̃); ``V_est`` (N, q) is the
    learnt task part Ã⁺b̃ of a model with a task term (subtracted, so NPOE measures
    only the null-space consistency, never A⁺b). Under ``convention="original"`` the
    normaliser is var(w) (pass the true ``W``, state-dependent case) or var(π) (pass
    ``Pi``); without them the ccl normaliser is used and the label says so.
    """
    _convention(convention)
    Z = U if V_est is None else U - V_est
    diff = projection_residual(N_est, Z)
    if convention == "original":
        if W is not None:
            return _metric("NPOE", diff, total_variance(W), "w", groups)
        if Pi is not None:
            return _metric("NPOE", diff, total_variance(Pi), "pi", groups)
        return _metric("NPOE", diff, total_variance(U), f"{of} (no true pi/w for the original normaliser)",
                       groups)
    return _metric("NPOE", diff, total_variance(U), of, groups)


def npe(U: np.ndarray, W_est: np.ndarray, convention: str = "ccl", groups: np.ndarray | None = None
        ) -> Metric:
    """Null-space projection error: mean ‖P̃ u − w̃‖² / Σ var(U), P̃ = w̃w̃ᵀ/‖w̃‖².

    ddof = 1 (``convention="ccl"``) or 0 (``"original"``).
    """
    _convention(convention)
    ddof = 0 if convention == "original" else 1
    return _metric("NPE", self_projection_residual(W_est, U), total_variance(U, ddof=ddof), "u", groups)


def nupe(Pi: np.ndarray, Pi_est: np.ndarray, name: str = "NUPE", of: str = "pi",
         groups: np.ndarray | None = None) -> Metric:
    """Normalised unconstrained policy error: mean ‖π − π̃‖² / Σ var(π).

    The same normalised error serves other targets (``name="NUPE_w", of="w"`` for the
    null-space component, ``"NUPE_v"`` for the task part, ``"NUPE_dpl"`` for the baseline).
    """
    return _metric(name, Pi - Pi_est, total_variance(Pi), of, groups)


def ncpe(N_true: np.ndarray, Pi: np.ndarray, Pi_est: np.ndarray, groups: np.ndarray | None = None
         ) -> Metric:
    """Normalised constrained policy error: mean ‖N π − N π̃‖² / Σ var(N π)."""
    w = _apply(N_true, Pi)
    return _metric("NCPE", w - _apply(N_true, Pi_est), total_variance(w), "N pi", groups)


def ncpe_observed(N_est: np.ndarray, U: np.ndarray, Pi_est: np.ndarray, V_est: np.ndarray | None = None,
                  of: str = "u", groups: np.ndarray | None = None) -> Metric:
    """NCPE with what is observable: mean ‖z − Ñ π̃‖² / Σ var(z), z = u − ṽ, with the learnt
    Ñ and the observations z (minus a learnt task part ``V_est``) in place of the true N
    and Nπ (reported as ``NCPE_obs``). U, Pi_est, V_est: (N, q)."""
    Z = U if V_est is None else U - V_est
    label = of if V_est is None else f"{of} - learnt task part A+b"  # learn-a's, not learn-v's
    return _metric("NCPE_obs", Z - _apply(N_est, Pi_est), total_variance(Z), label, groups)


def nmse(Y: np.ndarray, Y_est: np.ndarray, ddof: int = 1) -> np.ndarray:
    """Per-dimension normalised MSE: mse_d / var_d, (N, d) → (d,)."""
    Y = np.asarray(Y, dtype=float)
    mse = np.mean((Y - Y_est) ** 2, axis=0)
    var = np.var(Y, axis=0, ddof=ddof)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(var > 0, mse / var, np.nan)


# -- angles between constraints ---------------------------------------------------------------
def row_basis(A: np.ndarray) -> np.ndarray:
    """Orthonormal basis (rows) of the row space of A (s, q), by SVD: (s, q) → (r, q)."""
    _, sv, vh = np.linalg.svd(np.atleast_2d(A), full_matrices=False)
    if sv.size == 0:  # an empty constraint (e.g. a ground truth with no rows)
        return vh[:0]
    return vh[sv > 1e-10 * max(float(sv[0]), 1e-300)]


def subspace_angle(A: np.ndarray, B: np.ndarray) -> float:
    """Largest principal angle (degrees) between the row spaces of A (s, q) and B (s', q),
    over the min(s, s') directions the smaller one spans (for one row each in 3-D: the
    angle between two plane normals); NaN when either is empty."""
    Qa, Qb = row_basis(A), row_basis(B)
    if not len(Qa) or not len(Qb):
        return float("nan")
    small, large = (Qa, Qb) if len(Qa) <= len(Qb) else (Qb, Qa)
    # sin of the largest angle: what of the smaller span lies outside the larger (exact near 0,
    # where arccos of the cosines loses half the digits); the cosines near 90°
    sin = float(np.linalg.svd(small - (small @ large.T) @ large, compute_uv=False).max())
    if sin < np.sqrt(0.5):
        return float(np.degrees(np.arcsin(sin)))
    cos = np.linalg.svd(small @ large.T, compute_uv=False)
    return float(np.degrees(np.arccos(np.clip(cos.min(), -1.0, 1.0))))
