"""State-dependent constraint with no prior ("alpha", ALGORITHMS.md §3.2).

Each row of Ã(x) is a unit vector a(θ(x)) with θ(x) = W β(x); rows are found one at
a time, each orthogonal to the earlier ones, by minimising Σ_n (a(θ(x_n))ᵀ u_n)²
(see :mod:`ccl_cli.learn.constraint.angular`).
"""

from __future__ import annotations

import numpy as np

from ccl_cli.errors import ConfigError
from ccl_cli.learn.basis import Basis, make_basis
from ccl_cli.learn.constraint import rank as sel
from ccl_cli.learn.constraint.angular import MAX_ITER, chunked_features, fit_sequence, rows_from_weights
from ccl_cli.learn.constraint.base import ConstraintModel, check_xu
from ccl_cli.learn.model_selection import TUNE, basis_grid, rbf_tunable


class AngularConstraintMixin:
    """Shared fitting of the angle maps and the choice of s for alpha and lambda."""

    def _learn_rows(self, B: np.ndarray, V: np.ndarray, Xs: np.ndarray, demo: np.ndarray) -> None:
        """Fit the rows on features B (N, K), observations V (N, d), states Xs (N, p);
        sets weights_ etc. (``self._X``, ``self._U``: the data given to ``fit``, for the
        cross-validated choice of s).
        """
        d = V.shape[1]
        if d < 2:
            raise ConfigError("learning a constraint needs at least 2 action dimensions")
        max_k = min(self.max_constraints or d - 1, d - 1)
        rule = sel.check_rule(self.selection, self.n_constraints)
        if rule == "fixed" and self.n_constraints > max_k:
            raise ConfigError(f"n_constraints must be between 1 and {max_k}")
        limit = self.n_constraints if rule == "fixed" else max_k
        fits = fit_sequence(B, V, Xs, limit, self.n_restarts, self.seed, self.max_iter, self.tol,
                            stop_original=(rule == "threshold"))
        nmse = [f.nmse for f in fits]
        if rule == "fixed":
            chosen = sel.fixed(self.n_constraints, max_k)
        elif rule == "threshold":
            k = len(fits) - 1 if (len(fits) > 1 and nmse[-1] > min(nmse[:-1]) and nmse[-1] > 1e-3) \
                else len(fits)
            reason = (f"constraint {k + 1} raised nmse to {nmse[k]:.3g} (> best and > 1e-3)"
                      if k < len(fits) else f"stopped at the maximum {k}")
            chosen = sel.Selection("threshold", k, nmse, reason)
        elif rule == "eigengap":
            chosen = sel.gap(np.append(nmse, 1.0), self.gap_floor)
            chosen.values = nmse
        elif rule == "ratio":
            chosen = sel.ratio(np.asarray(nmse), max_k, self.gap_floor, criterion="nmse of row k")
        else:
            chosen = sel.cross_validated(self, self._X, self._U, self._demo, max_k, self.cv_folds, self.seed)
        self.n_constraints_ = chosen.n_constraints
        self.weights_ = [f.W for f in fits[: self.n_constraints_]]
        self.nmse_ = nmse
        self.selection_ = chosen.as_dict()


class StateDependentConstraint(AngularConstraintMixin, ConstraintModel):
    """Ã(x) with unit rows a(W_k β(x)), learnt without prior knowledge.

    Args:
        basis: feature map of θ(x) (``"rbf"``, ``"linear"``, a dict or a basis object).
        n_centres: RBF centres when ``basis`` is a name.
        selection: ``ratio`` (the noise-aware default, on the per-row nmse sequence),
            ``threshold`` (the original stopping rule), ``eigengap``, ``cv``; or fix
            ``n_constraints`` (see :mod:`ccl_cli.learn.constraint.rank`).
        max_constraints: at most this many rows (default q − 1).
        n_restarts: LM starts per row (the first the best constant direction).
        max_iter: LM passes per row at most (:data:`~ccl_cli.learn.constraint.angular.MAX_ITER`).
        seed, tol, gap_floor, cv_folds.
        tune: choose the basis by cross-validation (:func:`ccl_cli.learn.model_selection.tune`; True by
            default, a dict ``{budget, grid, folds}`` to adjust, False for the fixed settings).

    Attributes:
        basis_, weights_ (list of (q−k, K) arrays), n_constraints_, nmse_, selection_.
    """

    def __init__(
        self,
        *,
        basis: str | dict | Basis | None = "rbf",
        n_centres: int = 25,
        selection: str = sel.DEFAULT_RULE,
        n_constraints: int | None = None,
        max_constraints: int | None = None,
        n_restarts: int = 3,
        seed: int = 0,
        max_iter: int = MAX_ITER,
        tol: float = 1e-9,
        gap_floor: float = 1e-9,
        cv_folds: int = 5,
        tune: bool | dict = TUNE,
    ) -> None:
        self.basis = basis
        self.n_centres = n_centres
        self.selection = selection
        self.n_constraints = n_constraints
        self.max_constraints = max_constraints
        self.n_restarts = n_restarts
        self.seed = seed
        self.max_iter = max_iter
        self.tol = tol
        self.gap_floor = gap_floor
        self.cv_folds = cv_folds
        self.tune = tune

    def _tune_grid(self, X: np.ndarray, U: np.ndarray) -> dict[str, list]:
        """The configured K centres, 9 centres, then K centres twice as wide (σ² × 2), all
        k-means-placed, in that order (the budget of :func:`ccl_cli.learn.model_selection.tune` may skip
        the last, the slowest: wide bases need many LM passes).

        Measured (issue 9; median test error over seeds 0–4, untuned K = 25 → tuned;
        ``python benchmarks/bench_tuning.py --only angles``): parabola toy (test NPPE)
        0.039 → 0.029 (25 wide chosen in 3/5 seeds, 25 and 9 in one each); tracker bowl at
        1 mm (NPOE on held-out blocks) 0.018 → 0.011 (9 centres in 5/5 seeds); fit 0.02 →
        0.25 s and 0.2 → 1.7 s (busy 2-core VM). On the parabola held-out NPOE is a noisy guide
        (the fits have local optima and NPOE cannot see the constraint where u ≈ 0): {25, 9}
        alone chose 9 in 2/5 seeds and raised the median to 0.14; the wide 25 wins those
        seeds back. Wider grids (16 or 36 centres, σ² × ½) were worse or no better on one of
        the two problems; the LM cut-off (1e-16 … 1e-6) only made the parabola worse (median
        0.039 → 0.07–0.24), so it is not tuned."""
        if not rbf_tunable(self.basis):
            return {}
        grid = [*basis_grid(X, (self.n_centres, 9), (1.0,), self.seed),
                *basis_grid(X, (self.n_centres,), (2.0,), self.seed)]
        return {"basis": grid} if grid else {}  # too few samples for any candidate: fit as given

    def fit(self, X: np.ndarray, U: np.ndarray, demo: np.ndarray | None = None
            ) -> StateDependentConstraint:
        X, U = check_xu(X, U)
        self._set_n_features(X)
        if self._fit_tuned(X, U, demo=demo):
            return self
        self.basis_ = make_basis(self.basis, self.n_centres, self.seed).fit(X)
        self.n_action_ = U.shape[1]
        B = chunked_features(self.basis_, X)
        demo = np.zeros(len(X), int) if demo is None else np.asarray(demo)
        self._X, self._U, self._demo = X, U, demo
        self._learn_rows(B, U, X, demo)
        del self._X, self._U, self._demo
        return self

    def projection_k(self, X: np.ndarray, k: int) -> np.ndarray:
        """Ñ(X) of the first ``k`` learnt rows (the rows are nested): (N, p) → (N, q, q)."""
        self._check_fitted("weights_")
        rows = rows_from_weights(self.basis_.transform(np.asarray(X, dtype=float)), self.weights_[:k],
                                 self.n_action_)
        return np.eye(self.n_action_) - np.einsum("nki,nkj->nij", rows, rows)

    def constraint(self, X: np.ndarray, demo: np.ndarray | None = None) -> np.ndarray:
        self._check_fitted("weights_")
        return rows_from_weights(self.basis_.transform(X), self.weights_, self.n_action_)

    def projection(self, X: np.ndarray, demo: np.ndarray | None = None) -> np.ndarray:
        """Ñ(x) = I − Ã(x)ᵀÃ(x) (rows orthonormal): (N, p) → (N, q, q)."""
        rows = self.constraint(X)
        return np.eye(self.n_action_) - np.einsum("nki,nkj->nij", rows, rows)
