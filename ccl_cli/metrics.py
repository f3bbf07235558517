"""Evaluation metrics (ALGORITHMS.md §6).

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

from ccl_cli.errors import ConfigError, InputError
from ccl_cli.linalg import total_variance

CONVENTIONS = ("ccl", "original")


@dataclass(frozen=True)
class Metric:
    """A normalised error: ``value = error / normaliser``."""

    name: str
    value: float
    error: float
    normaliser: float
    normaliser_of: str

    def as_dict(self) -> dict:
        return asdict(self)


def _apply(P: np.ndarray, V: np.ndarray) -> np.ndarray:
    """P_n v_n for stacks P (N, q, q) or one matrix (q, q), V (N, q)."""
    P = np.asarray(P, dtype=float)
    return V @ P.T if P.ndim == 2 else np.einsum("nij,nj->ni", P, V)



def _metric(name: str, diff: np.ndarray, denom: float, of: str) -> Metric:
    err = float(np.mean(np.sum(diff**2, axis=1)))
    if not np.isfinite(denom) or denom <= 0:
        return Metric(name, float("nan"), err, float(denom), of)
    return Metric(name, err / denom, err, float(denom), of)


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
) -> Metric:
    """Normalised projected policy error: mean ‖N π − Ñ π‖² / Σ var(U).

    N_true, N_est: (N, q, q) or (q, q); Pi, U: (N, q).
    """
    _convention(convention)
    diff = _apply(N_true, Pi) - _apply(N_est, Pi)
    if convention == "original":
        if state_dependent:
            return _metric("NPPE", diff, total_variance(_apply(N_true, Pi)), "w")
        return _metric("NPPE", diff, total_variance(Pi), "pi")
    return _metric("NPPE", diff, total_variance(U), "u")


def npoe(
    N_est: np.ndarray,
    U: np.ndarray,
    convention: str = "ccl",
    Pi: np.ndarray | None = None,
    W: np.ndarray | None = None,
) -> Metric:
    """Normalised projected observation error: mean ‖u − Ñ u‖² / Σ var(U).

    Under ``convention="original"`` the normaliser is var(π) (pass ``Pi``) or var(w)
    (pass ``W``, state-dependent case).
    """
    _convention(convention)
    diff = U - _apply(N_est, U)
    if convention == "original":
        if W is not None:
            return _metric("NPOE", diff, total_variance(W), "w")
        if Pi is not None:
            return _metric("NPOE", diff, total_variance(Pi), "pi")
        raise InputError("NPOE with the original convention needs the true pi or w")
    return _metric("NPOE", diff, total_variance(U), "u")


def npe(U: np.ndarray, W_est: np.ndarray, convention: str = "ccl") -> Metric:
    """Null-space projection error: mean ‖P̃ u − w̃‖² / Σ var(U), P̃ = w̃w̃ᵀ/‖w̃‖².

    ddof = 1 (``convention="ccl"``) or 0 (``"original"``).
    """
    _convention(convention)
    c = np.sum(W_est**2, axis=1, keepdims=True)
    a = np.sum(U * W_est, axis=1, keepdims=True)
    proj = np.where(c > 0, a / np.where(c > 0, c, 1.0), 0.0) * W_est
    ddof = 0 if convention == "original" else 1
    return _metric("NPE", proj - W_est, total_variance(U, ddof=ddof), "u")


def nupe(Pi: np.ndarray, Pi_est: np.ndarray, name: str = "NUPE", of: str = "pi") -> Metric:
    """Normalised unconstrained policy error: mean ‖π − π̃‖² / Σ var(π).

    The same normalised error serves other targets (``name="NUPE_w", of="w"`` for the
    null-space component, ``"NUPE_v"`` for the task part, ``"NUPE_dpl"`` for the baseline).
    """
    return _metric(name, Pi - Pi_est, total_variance(Pi), of)


def ncpe(N_true: np.ndarray, Pi: np.ndarray, Pi_est: np.ndarray) -> Metric:
    """Normalised constrained policy error: mean ‖N π − N π̃‖² / Σ var(N π)."""
    w = _apply(N_true, Pi)
    return _metric("NCPE", w - _apply(N_true, Pi_est), total_variance(w), "N pi")


def ncpe_observed(N_est: np.ndarray, U: np.ndarray, Pi_est: np.ndarray) -> Metric:
    """NCPE with what is observable: mean ‖u − Ñ π̃‖² / Σ var(U), with the learnt Ñ and the
    observed u in place of the true N and Nπ (reported as ``NCPE_obs``)."""
    return _metric("NCPE_obs", U - _apply(N_est, Pi_est), total_variance(U), "u")


def nmse(Y: np.ndarray, Y_est: np.ndarray, ddof: int = 1) -> np.ndarray:
    """Per-dimension normalised MSE: mse_d / var_d, (N, d) → (d,)."""
    Y = np.asarray(Y, dtype=float)
    mse = np.mean((Y - Y_est) ** 2, axis=0)
    var = np.var(Y, axis=0, ddof=ddof)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(var > 0, mse / var, np.nan)
