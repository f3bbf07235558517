"""Closed-form, linear-in-parameters constraints (ALGORITHMS.md §3.5).

The constraint is A(x) = W Φ_A(x), optionally with a task term b(x) = W_b φ_b(x),
so that every observation satisfies W [Φ_A(x_n) u_n ; −φ_b(x_n)] = 0. Stacking the
regressors h_n as columns of H, the s left singular vectors of H with the smallest
singular values give W — no iterative optimisation. Rows of H are scaled to unit RMS
against the covariance that noise on u induces in them (a generalised eigenproblem),
which removes the total-least-squares bias of unscaled, over-complete regressors;
a few closed-form reweighting steps then give each sample the weight of a unit row.

Regressor families (``regressors``):
* ``identity`` — Φ_A = I_q (a constant constraint);
* ``rbf`` — Φ_A(x) = β(x) ⊗ I_q, i.e. A(x) = Σ_k β_k(x) W_k;
* ``polynomial`` — monomials of x up to ``degree`` (1 included) ⊗ I_q;
* a callable X (N, p) → (N, m, q) (e.g. rows of a Jacobian).
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import combinations_with_replacement
from math import comb
from typing import Annotated, Any, ClassVar, get_args

import numpy as np

from ccl_cli.dataset import HowMade
from ccl_cli.errors import InputError
from ccl_cli.learn.basis import Basis, BasisParams, make_basis
from ccl_cli.learn.constraint import rank as sel
from ccl_cli.learn.constraint.base import ONE_ACTION, ConstraintModel, UntunedAtOneAction
from ccl_cli.learn.constraint.lambda_ import ROBOT, make_features
from ccl_cli.learn.linalg import nullspace_projection, row_chunks
from ccl_cli.learn.model_selection import Tunable
from ccl_cli.learn.params import Interval, Regressors, SeedParams, TaskRegressors, Whiten, parameters

REGRESSORS = get_args(Regressors)
#: Regressor rows of all samples are cached between the reweighting passes up to this size.
H_CACHE_BYTES = 256 * 2**20


def polynomial_features(X: np.ndarray, degree: int) -> np.ndarray:
    """Monomials of the columns of X up to ``degree``, constant first: (N, p) → (N, M)."""
    X = np.asarray(X, dtype=float)
    cols = [np.ones(X.shape[0])]
    for deg in range(1, degree + 1):
        for combo in combinations_with_replacement(range(X.shape[1]), deg):
            cols.append(np.prod(X[:, list(combo)], axis=1))
    return np.stack(cols, 1)


@parameters
class LinearConstraint(UntunedAtOneAction, Tunable, ConstraintModel, BasisParams, sel.SelectionParams,
                       sel.ThresholdParams, SeedParams):
    """A(x) = W Φ_A(x) estimated in closed form.

    Args:
        regressors: ``identity``, ``rbf``, ``polynomial`` or a callable (N, m, q).
        degree: of ``polynomial``.
        basis, n_centres: feature map of ``rbf``.
        task: also estimate a task term b(x) = W_b φ_b(x) (A u = b).
        task_regressors: φ_b: ``constant`` (b const), ``polynomial`` (same degree) or ``rbf``.
        whiten: ``rms`` (default: each regressor scaled to unit RMS), ``errors``
            (generalised eigenproblem with the covariance that noise on u induces in
            the regressors; consistent for exact families) or ``none`` (plain SVD).
        reweight: closed-form reweighting steps: each sample is weighted by
            s / tr(Ã_n Ã_nᵀ) of the previous estimate, so the residual is that of unit
            constraint rows (the objective of §3) and samples where the unnormalised
            Ã(x) is large do not dominate; 0 gives the plain SVD.
        selection, n_constraints, gap_floor, threshold, max_constraints, cv_folds, seed:
            choice of s; the default (``ratio``, :mod:`ccl_cli.learn.constraint.rank`) reads
            the squared singular values.
        tune: with ``regressors="rbf"``, choose the basis by cross-validation
            (:class:`ccl_cli.learn.model_selection.Tuned`; True by default, False for fixed
            settings); grid: K ∈ {n_centres, 16, 9, 25, 36} × σ² factors {1, ½}.

    Attributes:
        W_ (s, m), Wb_ (s, m_b) or None, singular_values_ (ascending), n_constraints_,
        selection_, scale_ (m + m_b,) (ones unless whiten='rms').
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "n_action_": "value", "selection_": "value",
        "W_": "array", "Wb_": "array", "singular_values_": "array", "scale_": "array", "basis_": "basis"}
    regressors: Regressors | Annotated[dict, ROBOT] | Callable[[np.ndarray], np.ndarray] = "polynomial"
    degree: Annotated[int, Interval(0, 10)] = 1
    task: bool = False
    task_regressors: TaskRegressors = "constant"
    whiten: Whiten = "rms"
    reweight: Annotated[int, Interval(0, 1000)] = 3
    BASIS_PARAMS = ("basis", "n_centres", "seed", "regressors", "task", "task_regressors")

    def _basis_candidates(self) -> list[tuple[tuple[int, ...], tuple[float, ...]]]:
        return [((self.n_centres, 16, 9, 25, 36), (1.0, 0.5))] if self.regressors == "rbf" else []

    # -- regressors -------------------------------------------------------------------
    def _family(self, kind: str, X: np.ndarray) -> np.ndarray:
        """f(x) (N, M) of a regressor family: identity / constant → 1, polynomial →
        monomials up to ``degree``, rbf → β(x)."""
        if kind in ("identity", "constant"):
            return np.ones((X.shape[0], 1))
        if kind == "polynomial":
            return polynomial_features(X, self.degree)
        return self.basis_.transform(X)

    def _matrix_regressors(self) -> Any:
        """Φ_A as a callable (N, p) → (N, m, q) for a callable or a robot's Jacobian rows
        (``regressors: {robot: ..., rows: [...]}``: A(q) = W J(q)[rows]), else None."""
        if callable(self.regressors):
            return self.regressors
        if isinstance(self.regressors, dict):
            if getattr(self, "regressors_", None) is None:
                self.regressors_ = make_features(self.regressors)
            return self.regressors_
        return None

    def _features(self, X: np.ndarray) -> np.ndarray | None:
        """f(x) (N, M) such that Φ_A(x) = f(x) ⊗ I_q; None for matrix regressors."""
        return None if self._matrix_regressors() is not None else self._family(self.regressors, X)

    def _phi(self, X: np.ndarray) -> np.ndarray:
        """Φ_A(X): (N, m, q)."""
        f = self._features(X)
        if f is None:
            return np.asarray(self._matrix_regressors()(X), dtype=float)
        q = self.n_action_
        return np.einsum("nk,ij->nkij", f, np.eye(q)).reshape(len(X), -1, q)

    def _task_features(self, X: np.ndarray) -> np.ndarray:
        """φ_b(x) (N, m_b) of the task term."""
        return self._family(self.task_regressors, X)

    def _stack(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Rows h_n = [Φ_A(x_n) u_n ; −φ_b(x_n)]: (N, m + m_b)."""
        f = self._features(X)
        if f is None:
            H = np.einsum("nmq,nq->nm", self._phi(X), U)
        else:
            H = (f[:, :, None] * U[:, None, :]).reshape(len(X), -1)
        if self.task:
            H = np.hstack([H, -self._task_features(X)])
        return H

    # -- fitting ----------------------------------------------------------------------
    @property
    def _reweight_steps(self) -> int:
        """The reweighting steps that change anything: none with identity regressors, where
        Ã_n = W for every sample, so the weights are equal and, normalised to mean 1, leave S
        as it is."""
        return 0 if isinstance(self.regressors, str) and self.regressors == "identity" else self.reweight

    def _solve(self, X: np.ndarray, U: np.ndarray, k: int = 1
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Generalised eigenvectors of (S, T), ascending: (vals, vecs (d, d), scale, msq).

        S = Σ_n ω_n h_n h_nᵀ. With ``whiten="errors"`` T = Σ_n ω_n ∂h_n/∂u ∂h_n/∂uᵀ is
        the covariance that isotropic noise on u induces in h (zero on the noise-free
        task rows), which makes the smallest eigenvectors a consistent estimate
        (errors-in-variables); ``"rms"`` scales h to unit RMS per row and uses T = I;
        ``"none"`` takes the plain SVD. ``k`` rows define the reweighting ω (normalised
        to mean 1). msq = mean_n ‖h_n / scale‖².

        Every sum runs over blocks of rows (:func:`~ccl_cli.learn.linalg.row_chunks`), one pass
        per reweighting step (plus one for the RMS scale): h, Φ_A are never formed for
        all N at once.
        """
        n = len(X)
        chunks = row_chunks(n)
        first = self._stack(X[:1], U[:1])
        # Regressor rows are kept per block when they fit in H_CACHE_BYTES (the reweighting
        # passes then reuse them), else rebuilt per pass: memory stays O(chunk) in N.
        cached = [self._stack(X[r], U[r]) for r in chunks] \
            if n * first.shape[1] * 8 <= H_CACHE_BYTES else None

        def rows_of(i: int, r: slice) -> np.ndarray:
            return cached[i] if cached is not None else self._stack(X[r], U[r])

        colsq = sum(np.sum(rows_of(i, r) ** 2, axis=0) for i, r in enumerate(chunks))
        d = colsq.shape[0]
        if self.whiten == "rms":
            scale = np.sqrt(colsq / n)
            scale = np.where(scale > 0, scale, 1.0)
        else:
            scale = np.ones(d)
        msq = float(np.sum(colsq / scale**2) / n)
        steps = self._reweight_steps
        W = None
        for step in range(steps + 1):
            S, T, wsum = np.zeros((d, d)), None, 0.0
            for i, rows in enumerate(chunks):
                Hs = rows_of(i, rows) / scale
                f = self._features(X[rows]) if W is not None else None
                phi = self._phi(X[rows]) if self.whiten == "errors" or (
                    W is not None and f is None) else None
                if W is None:
                    weight = np.ones(len(Hs))
                else:  # Ã_n = W Φ_A(x_n); with Φ_A = f ⊗ I_q, Ã_n = Σ_j f_j W_j (no Φ_A)
                    A = np.einsum("km,nmq->nkq", W, phi) if f is None else \
                        np.einsum("nj,kjq->nkq", f, W.reshape(len(W), f.shape[1], -1))
                    weight = k / np.maximum(np.sum(A**2, axis=(1, 2)), 1e-12)
                wsum += float(weight.sum())
                S += (Hs * weight[:, None]).T @ Hs
                if self.whiten == "errors":
                    m = phi.shape[1]
                    Tb = np.einsum("nmq,nkq->mk", phi * weight[:, None, None], phi)
                    T = Tb if T is None else T + Tb
            S /= wsum / n  # the weights normalised to mean 1
            if self.whiten == "errors":
                Tf = np.zeros((d, d))
                Tf[:m, :m] = T / (wsum / n)
                Tf[np.diag_indices(d)] += 1e-10 * np.trace(Tf) / d + np.finfo(float).tiny
                from scipy.linalg import eigh  # the generalised problem (whiten="errors") only

                vals, vecs = eigh(S, Tf)
            else:
                vals, vecs = np.linalg.eigh(S)
            if step == steps:
                break
            m = self._phi(X[:1]).shape[1]
            W = (vecs[:, :k] / scale[:, None]).T[:, :m]
        return np.maximum(vals, 0.0), vecs, scale, msq

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None) -> LinearConstraint:
        """Estimate W (and W_b) from states X (N, p) and actions U (N, q); ``groups`` (N,):
        demonstration ids, for the folds of tuning and of the ``cv`` rule. Its rules read
        neither the times ``t`` nor ``derivative`` (the protocol's signature). One action
        dimension (q = 1): no rows (k = 0, :data:`~.base.ONE_ACTION`; nothing tuned) unless
        ``n_constraints`` fixes them."""
        return self._fit(X, U, groups=groups)

    def _fit_basis(self, X: np.ndarray, U: np.ndarray) -> Basis | None:
        """The RBF feature map of ``rbf`` regressors (or task regressors) fitted on X; None
        when no regressor family needs one."""
        if self.regressors == "rbf" or (self.task and self.task_regressors == "rbf"):
            return make_basis(self.basis, self.n_centres, self.seed).fit(X)
        return None

    def _fit_core(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                  basis: Basis | None = None, start: LinearConstraint | None = None) -> LinearConstraint:
        """The closed-form estimate with a fitted ``basis`` (None: this learner's own);
        ``start`` is not needed (nothing iterates)."""
        self.n_action_ = U.shape[1]
        basis = self._fit_basis(X, U) if basis is None else basis
        if basis is not None:
            self.basis_ = basis
        vals, vecs, scale, msq = self._solve(X, U, 1)
        d = vecs.shape[0]
        max_k = min(self.max_constraints or self.n_action_ - 1, d - 1)
        max_k = max(1, max_k)

        def threshold() -> sel.Selection:
            nmse = (vals / len(X)) / max(msq, 1e-300)
            k = 1
            while k < max_k and nmse[k] < self.threshold:
                k += 1
            return sel.Selection("threshold", k, list(nmse[:max_k]), f"nmse below {self.threshold}",
                                 "nmse of row k",
                                 limits=sel.threshold_limits(min(max_k, len(nmse)), self.threshold),
                                 limit_rule=sel.THRESHOLD_RULE.format(self.threshold))

        if self.n_action_ == 1 and self.n_constraints is None:  # "at least one row" would forbid all motion
            chosen = sel.Selection("one action", 0, [], ONE_ACTION)
        else:
            chosen = sel.choose(self, ratio_values=vals[: max_k + 1] / len(X), gap_values=vals[: max_k + 1],
                                max_k=max_k, fixed_max=d,
                                criterion="squared singular value k of the scaled regressors / N",
                                threshold=threshold, X=X, U=U, groups=groups)
        self.n_constraints_ = chosen.n_constraints
        self.selection_ = chosen.as_dict()
        if self._reweight_steps and self.n_constraints_ > 1:
            vals, vecs, scale, _ = self._solve(X, U, self.n_constraints_)
        self.singular_values_ = np.sqrt(vals)
        self.scale_ = scale
        W = (vecs[:, : self.n_constraints_] / scale[:, None]).T
        m = d - (self._task_features(X[:1]).shape[1] if self.task else 0)
        self.W_ = W[:, :m]
        self.Wb_ = W[:, m:] if self.task else None
        return self

    def projection_k(self, X: np.ndarray, k: int) -> np.ndarray:
        """Ñ(X) = I − Ã⁺Ã of the first ``k`` rows of W_ (nested up to the reweighting): (N, q, q)."""
        return nullspace_projection(self._constraint(X, k))

    def _constraint(self, X: np.ndarray, k: int | None = None) -> np.ndarray:
        """W[:k] Φ_A(X): (N, p) → (N, k, q) (all s rows when None)."""
        self._check_fitted("W_")
        return np.einsum("km,nmq->nkq", self.W_[:k], self._phi(self._check_states(X)))

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã(X) = W Φ_A(X): (N, s, q) (rows not normalised)."""
        return self._constraint(X)

    def task_part(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                  t: np.ndarray | None = None) -> np.ndarray | None:
        """ṽ = Ã⁺b̃ (§1): (N, p) → (N, q); None without a task term."""
        self._check_fitted("W_")
        if self.Wb_ is None:
            return None
        return np.einsum("nqs,ns->nq", np.linalg.pinv(self.constraint(X)), self.task_term(X))

    def task_term(self, X: np.ndarray) -> np.ndarray:
        """b̃(X) = W_b φ_b(X): (N, s); zeros without a task term."""
        self._check_fitted("W_")
        X = self._check_states(X)
        if self.Wb_ is None:
            return np.zeros((len(X), self.n_constraints_))
        return self._task_features(X) @ self.Wb_.T

    # -- a model read from a file ---------------------------------------------------------
    def _widths(self, kind: str) -> list[int]:
        """The column counts f(x) of regressor family ``kind`` may have (×q for Φ_A): 1 for
        identity / constant, K for rbf, a polynomial's for every p up to 1024."""
        if kind in ("identity", "constant"):
            return [1]
        if kind == "rbf":
            basis = vars(self).get("basis_")
            return [basis.n_features] if basis is not None else []
        if not isinstance(self.degree, int) or not 0 <= self.degree <= 64:
            return []
        return [comb(p + self.degree, self.degree) for p in range(1, 1025)]

    def check_shapes(self) -> None:
        """Known regressors; W_ (s, width of Φ_A) — a robot's Jacobian rows (``regressors_``
        rebuilt from the stored URDF first) or f(x) ⊗ I_q — and W_b (s, width of φ_b) with a task
        term (else None)."""
        q, s = self.n_action_, self.n_constraints_
        robot = isinstance(self.regressors, dict) and self.regressors.get("kind") == "robot"
        if "rbf" in (self.regressors, self.task_regressors if self.task else None):
            self._basis_width()
        if (not robot and self.regressors not in ("identity", "polynomial", "rbf")) or \
                self.task_regressors not in ("constant", "polynomial", "rbf"):
            raise InputError(f"unknown regressors {self.regressors!r} / {self.task_regressors!r}"[:300])
        if robot:  # A(q) = W J(q)[rows]: one column of W per Jacobian row
            joints = self.regressors_.n_joints
            if joints != q:
                raise InputError(f"the stored robot has {joints} joints, the model {q} actions")
            widths = [len(self.regressors_.rows or range(6))]
        else:
            widths = [w * q for w in self._widths(self.regressors)]
        W, Wb = self.W_, self.Wb_
        if W is None or W.ndim != 2 or W.shape[0] != s or W.shape[1] not in widths:
            raise self._shape_error("W_")
        if self.task and (Wb is None or Wb.ndim != 2 or Wb.shape[0] != s or
                          Wb.shape[1] not in self._widths(self.task_regressors)):
            raise self._shape_error("Wb_")
        if not self.task:
            self.Wb_ = None
        super().check_shapes()

    def implied_n_features(self) -> int | None:
        """p of the basis, else of polynomial regressors (degree ≥ 1) from W_'s width."""
        found = super().implied_n_features()
        if found is not None or not isinstance(self.degree, int) or self.degree < 1:
            return found
        width = (self.W_.shape[1] // self.n_action_ if self.regressors == "polynomial" else
                 self.Wb_.shape[1] if self.task and self.task_regressors == "polynomial" else None)
        return next((p for p in range(1, 1025) if comb(p + self.degree, self.degree) == width), None)
