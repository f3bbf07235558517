"""State-independent constraint Ã with orthonormal rows ("nhat", ALGORITHMS.md §3.1).

Minimises E[Ã] = Σ_n ‖Ã u_n‖² over Ã with orthonormal rows (eq. §3). With
C = Σ_n u_n u_nᵀ the optimum for s rows is the s eigenvectors of C with the smallest
eigenvalues and the residual is their sum: one pass over the data, O(N q² + q³).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ccl_cli.dataset import HowMade
from ccl_cli.errors import ConfigError
from ccl_cli.learn.angles import unit_vector
from ccl_cli.learn.constraint import rank as sel
from ccl_cli.learn.constraint.base import ConstraintModel, one_action_selection
from ccl_cli.learn.params import NhatMethod as Method
from ccl_cli.learn.params import SeedParams, parameters

#: Grid of the original search: 20 angles per axis in [0, π − π/20].
SEARCH_STEPS = 20
MAX_SEARCH_Q = 6


def _threshold_count(lams: np.ndarray, rows: np.ndarray, cov: np.ndarray, n: int,
                     threshold: float, max_k: int) -> sel.Selection:
    """Original rule: keep the k-th constraint while nmse_k = (λ_k/N) / Σ var(N_k U) < threshold.

    Σ var(N_k U) = tr(Cov) − Σ_{j≤k} a_jᵀ Cov a_j, with Cov the ddof = 1 covariance.
    """
    explained = np.cumsum(np.einsum("ki,ij,kj->k", rows, cov, rows))
    remaining = np.trace(cov) - explained
    with np.errstate(divide="ignore", invalid="ignore"):
        nmse = np.where(remaining > 0, (lams / n) / remaining, np.inf)
    k = 1
    while k < max_k and nmse[k] < threshold:
        k += 1
    return sel.Selection("threshold", k, list(nmse[:max_k]),
                         f"constraint {k + 1} would have nmse {nmse[k]:.3g} ≥ {threshold}"
                         if k < max_k else f"all {k} candidates below {threshold}",
                         "nmse of row k: (λ_k / N) / Σ var(N_k u)",
                         limits=sel.threshold_limits(min(max_k, len(nmse)), threshold),
                         limit_rule=sel.THRESHOLD_RULE.format(threshold))


@parameters
class StateIndependentConstraint(ConstraintModel, sel.SelectionParams, sel.ThresholdParams, SeedParams):
    """Constant constraint matrix Ã (s × q) with orthonormal rows.

    Args:
        method: ``"closed_form"`` (default) or ``"search"`` (the original grid search,
            q ≤ 6; for comparison only).
        selection: how s is chosen (:mod:`ccl_cli.learn.constraint.rank`): ``ratio``
            (the noise-aware default), ``threshold`` (the original), ``eigengap``, ``cv``,
            or fixed via ``n_constraints``.
        n_constraints: fix s.
        threshold: of the ``threshold`` rule (original: 0.1).
        gap_floor: relative floor of the eigen-gap rule.
        max_constraints: upper bound on s (default q − 1).
        cv_folds, seed: cross-validation over demonstrations.

    Attributes:
        A_: (s, q) learnt rows. eigenvalues_: (q,) ascending eigenvalues of Σ u uᵀ.
        n_constraints_, selection_.
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "n_action_": "value", "selection_": "value",
        "A_": "array", "eigenvalues_": "array", "residuals_": "array"}
    method: Method = "closed_form"

    def _candidate_rows(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All q−1 candidate rows in order of use, and their residuals λ_k = a_kᵀ C a_k."""
        C = U.T @ U
        if self.method == "closed_form":
            lams, vecs = np.linalg.eigh(C)
            return vecs.T, np.maximum(lams, 0.0)
        return _search_rows(C)

    varies_with_state = False

    def fit(self, X: np.ndarray | None, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None
            ) -> StateIndependentConstraint:
        """Learn Ã from actions U (N, q); X (N, p) is only used for ``n_features_in_`` (it
        may be None: any p is then accepted); ``groups`` (N,) for the ``cv`` rule's folds.
        Its rules read neither the times ``t`` nor ``derivative`` (the protocol's signature).
        One action dimension (q = 1): no rows (k = 0, :data:`~.base.ONE_ACTION`) unless
        ``n_constraints`` fixes them."""
        X, U = self._prepare_fit(X, U)
        n, q = U.shape
        self.n_action_ = q
        if q == 1 and self.n_constraints is None:  # a rule's "at least one row" would forbid all motion
            self.eigenvalues_ = np.linalg.eigvalsh(U.T @ U)
            self.residuals_ = np.maximum(self.eigenvalues_, 0.0)
            self.A_ = np.zeros((0, 1))
            self.n_constraints_ = 0
            self.selection_ = one_action_selection()
            return self
        max_k = self.max_constraints or q - 1
        max_k = max(1, min(max_k, q - 1 if q > 1 else 1))
        rows, lams = self._candidate_rows(U)
        self.eigenvalues_ = np.linalg.eigvalsh(U.T @ U)

        def threshold() -> sel.Selection:
            cov = np.cov(U, rowvar=False, ddof=1).reshape(q, q)
            return _threshold_count(lams, rows, cov, n, self.threshold, max_k)

        chosen = sel.choose(self, ratio_values=lams[: max_k + 1] / n, gap_values=lams[: max_k + 1],
                            max_k=max_k, fixed_max=q, criterion="eigenvalue k of Σ u uᵀ / N",
                            threshold=threshold, X=X, U=U, groups=groups)
        self.n_constraints_ = chosen.n_constraints
        self.A_ = rows[: self.n_constraints_].copy()
        self.residuals_ = lams
        self.selection_ = chosen.as_dict()
        return self

    def projection_k(self, X: np.ndarray, k: int) -> np.ndarray:
        """Ñ = I − ÃᵀÃ of the first ``k`` rows (the rows are nested and orthonormal),
        broadcast to (N, q, q) for X (N, p)."""
        self._check_fitted("A_")
        X = self._check_states(X)
        A = self.A_[:k]
        N = np.eye(self.n_action_) - A.T @ A
        return np.broadcast_to(N, (X.shape[0], *N.shape)).copy()

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã broadcast to (N, s, q) for X (N, p)."""
        self._check_fitted("A_")
        X = self._check_states(X)
        return np.broadcast_to(self.A_, (X.shape[0], *self.A_.shape))

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ñ = I − ÃᵀÃ, broadcast to (N, q, q)."""
        self._check_fitted("A_")
        return self.projection_k(X, len(self.A_))

    def constant_rows(self) -> np.ndarray:
        """Ã (s, q): the same rows at every sample."""
        self._check_fitted("A_")
        return self.A_

    def check_shapes(self) -> None:
        """A_ (s, q)."""
        if self.A_ is None or self.A_.shape != (self.n_constraints_, self.n_action_):
            raise self._shape_error("A_")
        super().check_shapes()


def _search_rows(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The original grid search: 20^(q−1) unit vectors in hyperspherical angles.

    First row: the grid vector with the smallest aᵀCa; each next row: the best among
    grid vectors whose |dot| with every earlier row is < 0.001.
    """
    q = C.shape[0]
    if q > MAX_SEARCH_Q:
        raise ConfigError(f"the grid search is exponential in q: q = {q} > {MAX_SEARCH_Q}; "
                          "use method closed_form")
    axis = np.linspace(0.0, np.pi - np.pi / SEARCH_STEPS, SEARCH_STEPS)
    mesh = np.meshgrid(*([axis] * (q - 1)), indexing="ij")
    cand = unit_vector(np.stack([m.ravel() for m in mesh], 1))
    cost = np.einsum("mi,ij,mj->m", cand, C, cand)
    rows, lams = [], []
    ok = np.ones(len(cand), bool)
    for _ in range(q):
        if not ok.any():
            break
        best = int(np.flatnonzero(ok)[np.argmin(cost[ok])])
        rows.append(cand[best])
        lams.append(cost[best])
        ok &= np.abs(cand @ cand[best]) < 1e-3
    rows_a = np.array(rows)
    if len(rows) < q:  # complete the basis so callers can index q − 1 candidates
        _, _, vh = np.linalg.svd(rows_a)
        extra = vh[len(rows):]
        rows_a = np.vstack([rows_a, extra])
        lams += list(np.einsum("ki,ij,kj->k", extra, C, extra))
    return rows_a, np.maximum(np.array(lams), 0.0)
