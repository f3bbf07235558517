"""State-dependent constraint with no prior ("alpha", ALGORITHMS.md §3.2).

Each row of Ã(x) is a unit vector a(θ(x)) with θ(x) = W β(x); rows are found one at
a time, each orthogonal to the earlier ones, by minimising Σ_n (a(θ(x_n))ᵀ u_n)²
(see :mod:`ccl_cli.learn.constraint.angular`).
"""

from __future__ import annotations

from typing import Annotated, ClassVar

import numpy as np

from ccl_cli.dataset import HowMade
from ccl_cli.errors import ConfigError
from ccl_cli.learn.basis import Basis, BasisParams, NCentres
from ccl_cli.learn.constraint import geometry
from ccl_cli.learn.constraint import noise_rank as nr
from ccl_cli.learn.constraint import rank as sel
from ccl_cli.learn.constraint.angular import (
    MAX_ITER,
    REFINE_PASSES,
    SEARCH_ROWS,
    fit_sequence,
    rows_from_weights,
)
from ccl_cli.learn.constraint.base import (
    ConstraintModel,
    UntunedAtOneAction,
    check_rows_asked,
    one_action_selection,
)
from ccl_cli.learn.linalg import row_chunks
from ccl_cli.learn.model_selection import Tunable
from ccl_cli.learn.params import Interval, MaxIter, SeedParams, Tolerance, out_of_range, parameters


@parameters
class AngularConstraintMixin(UntunedAtOneAction, Tunable, BasisParams, sel.SelectionParams, SeedParams):
    """Shared fitting of the angle maps and the choice of s for alpha and lambda; its
    parameters: ``n_restarts`` LM starts per row, at most ``max_iter`` passes per row, the
    relative tolerance ``tol`` (and the basis, selection, seed and tune groups)."""

    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "n_action_": "value", "selection_": "value",
        "nmse_": "value", "weights_": "arrays", "basis_": "basis"}
    #: The search runs on at most SEARCH_ROWS rows: a candidate's fit on them is then its
    #: subsample search alone, and the winner is refined on all rows (docs/measurements.md,
    #: "Tuning": the same test errors at N = 1e5 as with 20000 rows, for half the time).
    TUNE_MAX_ROWS = SEARCH_ROWS
    n_restarts: Annotated[int, Interval(1, 10_000)] = 3
    max_iter: MaxIter = MAX_ITER
    tol: Tolerance = 1e-9

    def _learn_rows(self, basis: Basis, Xs: np.ndarray, V: np.ndarray, X: np.ndarray, U: np.ndarray,
                    groups: np.ndarray | None, start: AngularConstraintMixin | None) -> None:
        """Fit the rows on observations V (n, d) at states Xs (n, p) with the fitted ``basis``,
        each row from ``start``'s weights when given (a fit of the same basis on other rows of
        the data: run to convergence from a fit on more rows, a fold's; refined by at most
        REFINE_PASSES passes from one on fewer rows, a search's subset);
        sets weights_, nmse_, n_constraints_, selection_. X (N, p), U (N, q), groups (N,):
        the data given to ``fit``, for the cross-validated choice of s. One action dimension
        (q = 1): no rows (:data:`~.base.ONE_ACTION`)."""
        d = V.shape[1]
        if self.n_action_ == 1:  # a row would forbid all motion (base.ONE_ACTION)
            check_rows_asked(1, self.n_constraints)
            self._row_weights, self.weights_, self.nmse_ = [], [], []
            self.n_constraints_ = 0
            self.selection_ = one_action_selection()
            return
        if d < 2:  # lambda: Φ with one task row leaves Λ no direction to choose
            raise ConfigError(f"the features give {d} task row: learning the selection Λ needs at least 2")
        max_k = min(self.max_constraints or d - 1, d - 1)
        rule = sel.rule_of(self)
        if rule == "fixed" and self.n_constraints > max_k:
            raise ConfigError(out_of_range("n_constraints", self.n_constraints, Interval(1, max_k, type=int)))
        limit = self.n_constraints if rule == "fixed" else max_k
        fits = fit_sequence(basis, Xs, V, limit, self.n_restarts, self.seed, self.max_iter, self.tol,
                            stop_original=(rule == "threshold"),
                            starts=None if start is None else start._row_weights,
                            refine=REFINE_PASSES if start is not None and start._fit_rows < len(X) else None)
        self._row_weights = [f.W for f in fits]
        nmse = [f.nmse for f in fits]

        def threshold() -> sel.Selection:
            k = len(fits) - 1 if (len(fits) > 1 and nmse[-1] > min(nmse[:-1]) and nmse[-1] > 1e-3) \
                else len(fits)
            reason = (f"constraint {k + 1} raised nmse to {nmse[k]:.3g} (> best and > 1e-3)"
                      if k < len(fits) else f"stopped at the maximum {k}")
            last = [max(min(nmse[:-1]), 1e-3)] if len(fits) > 1 else []
            return sel.Selection("threshold", k, nmse, reason, "nmse of row k",
                                 limits=[None] * (len(fits) - len(last)) + last,
                                 limit_rule="the last row fitted counts unless its nmse rose above the best "
                                            "before it and above 1e-3 (the original's rule)")

        def noise() -> sel.Selection | None:  # the rows of every fit at every sample, (N, m, q)
            timing = getattr(self, "_timing", (None, None))
            data = nr.Sample.of(X, U, groups, *timing)
            rows = np.empty((len(X), len(self._row_weights), self.n_action_))
            for chunk in row_chunks(len(X)):  # the features of a block of samples at a time
                rows[chunk] = self._rows_at(basis, X[chunk], self._row_weights)
            chosen = nr.noise_rank(data.rows_evidence(rows), max_k)
            return geometry.add_still_rows(chosen, rows, X, U, data.groups, *timing, max_k)

        chosen = sel.choose(self, ratio_values=np.asarray(nmse), gap_values=np.append(nmse, 1.0),
                            max_k=max_k, fixed_max=max_k, criterion="nmse of row k", threshold=threshold,
                            X=X, U=U, groups=groups, noise=noise)
        if chosen.rule == "eigengap":
            chosen.values = nmse  # the appended 1.0 only closes the last gap
        self.n_constraints_ = chosen.n_constraints
        self.weights_ = [f.W for f in fits[: self.n_constraints_]]
        self.nmse_ = nmse
        self.selection_ = chosen.as_dict()

    def _rows_at(self, basis: Basis, X: np.ndarray, weights: list[np.ndarray]) -> np.ndarray:
        """The rows of angle ``weights`` at states X (N, p), in action space: (N, m, q)."""
        return rows_from_weights(basis.transform(X), weights, self.n_action_)

    def _angle_dim(self) -> int:
        """d, the space the unit rows a(θ) live in (q; lambda: r, the rows of Φ)."""
        return int(self.n_action_)

    def check_shapes(self) -> None:
        """weights_: row k (d − 1 − k, K) for the s ≤ d − 1 rows, K the basis's features."""
        K, d = self._basis_width(), self._angle_dim()
        if self.n_constraints_ > d - 1 or any(w.shape != (d - 1 - k, K) for k, w in enumerate(self.weights_)):
            raise self._shape_error("weights_")
        super().check_shapes()

    def _fit_timed(self, X: np.ndarray, U: np.ndarray, groups: np.ndarray | None, t: np.ndarray | None,
                   derivative: HowMade) -> AngularConstraintMixin:
        """``_fit`` with the sample times and how U was made, for the ``noise`` rule."""
        self._timing = (None if t is None else np.asarray(t, dtype=float), derivative)
        try:
            return self._fit(X, U, groups=groups)
        finally:
            del self._timing


@parameters
class StateDependentConstraint(AngularConstraintMixin, ConstraintModel):
    """Ã(x) with unit rows a(W_k β(x)), learnt without prior knowledge.

    Args:
        basis: feature map of θ(x) (``"rbf"``, ``"linear"``, a dict or a basis object).
        n_centres: RBF centres when ``basis`` is a name. 25 here, 16 elsewhere: alpha's
            angle maps need the finer basis on the parabola tutorial (its regression
            guard, docs/measurements.md), and its tuning grid starts from it.
        selection: ``ratio`` (the noise-aware default, on the per-row nmse sequence),
            ``threshold`` (the original stopping rule), ``eigengap``, ``cv``; or fix
            ``n_constraints`` (see :mod:`ccl_cli.learn.constraint.rank`).
        max_constraints: at most this many rows (default q − 1).
        n_restarts: LM starts per row (the first the best constant direction).
        max_iter: LM passes per row at most (:data:`~ccl_cli.learn.constraint.angular.MAX_ITER`).
        seed, tol, gap_floor, cv_folds.
        tune: choose the basis by cross-validation (:class:`ccl_cli.learn.model_selection.Tuned`;
            True by default, a dict ``{budget, grid, folds, max_rows}`` to adjust, False for
            the fixed settings). Grid: the configured K centres, 9 centres, and 36 centres at ¼
            of the default width, k-means-placed, run from the smallest up while a larger basis
            helps (:func:`ccl_cli.learn.model_selection.search`).

    Attributes:
        basis_, weights_ (list of (q−k, K) arrays), n_constraints_, nmse_, selection_,
        n_features_in_, tuning_.
    """

    n_centres: NCentres = 25

    def _basis_candidates(self) -> list[tuple[tuple[int, ...], tuple[float, ...]]]:
        return [((self.n_centres, 9), (1.0,)), ((36,), (0.25,))]

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None
            ) -> StateDependentConstraint:
        """Learn Ã(x) from states X (N, p) and actions U (N, q); ``groups`` (N,):
        demonstration ids, for the folds of tuning and of the ``cv`` rule; ``t`` (N,) s and
        ``derivative`` (how U was made) for the noise of the ``noise`` rule (as lambda's).
        One action dimension (q = 1): no rows (k = 0, :data:`~.base.ONE_ACTION`; nothing tuned)."""
        return self._fit_timed(X, U, groups, t, derivative)

    def _fit_core(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                  basis: Basis | None = None, start: StateDependentConstraint | None = None
                  ) -> StateDependentConstraint:
        """The fit with a fitted ``basis`` (None: this learner's own), from ``start``'s rows."""
        self.basis_ = self._fit_basis(X, U) if basis is None else basis
        self.n_action_ = U.shape[1]
        self._learn_rows(self.basis_, X, U, X, U, groups, start)
        return self

    def projection_k(self, X: np.ndarray, k: int | None) -> np.ndarray:
        """Ñ(X) = I − Ã(x)ᵀÃ(x) of the first ``k`` learnt rows (the rows are nested and
        orthonormal): (N, p) → (N, q, q)."""
        rows = self._rows(X, k)
        return np.eye(self.n_action_) - np.einsum("nki,nkj->nij", rows, rows)

    def _rows(self, X: np.ndarray, k: int | None = None) -> np.ndarray:
        """The first ``k`` learnt rows (all when None) at X (N, p): (N, k, q)."""
        self._check_fitted("weights_")
        return rows_from_weights(self.basis_.transform(self._check_states(X)), self.weights_[:k],
                                 self.n_action_)

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã(X): (N, p) → (N, s, q), orthonormal rows."""
        return self._rows(X)

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ñ(x) = I − Ã(x)ᵀÃ(x): (N, p) → (N, q, q)."""
        return self.projection_k(X, None)
