"""State-dependent constraint A(x) = Λ(x) Φ(x) with known features ("lambda", §3.3).

Φ(x) ∈ R^{r×q} is known (typically the task Jacobian); only the selection Λ(x),
orthonormal rows in R^r, is learnt, on v_n = Φ(x_n) u_n (samples with ‖v_n‖ < 1e-3
carry no information and are dropped), by the same sequential angle search as alpha.
Prediction: A = ΛΦ, Ñ = I − A⁺A.
"""

from __future__ import annotations

from collections.abc import Callable
from math import isqrt
from typing import Annotated, ClassVar

import numpy as np

from ccl_cli.dataset import HowMade
from ccl_cli.errors import ConfigError, LearningError
from ccl_cli.learn.basis import Basis, make_basis
from ccl_cli.learn.constraint import rank as sel
from ccl_cli.learn.constraint.alpha import AngularConstraintMixin
from ccl_cli.learn.constraint.angular import rows_from_weights
from ccl_cli.learn.constraint.base import ConstraintModel
from ccl_cli.learn.kinematics import ArmFeatures, ArmName
from ccl_cli.learn.linalg import nullspace_projection, row_chunks
from ccl_cli.learn.params import Fields, parameters

Features = Callable[[np.ndarray], np.ndarray]
#: A robot's Jacobian rows: {robot: a URDF / MJCF path or {dh: [[a, d, alpha, theta0], ...], ...},
#: frame, base, rows} (:func:`ccl_cli.learn.robots.robot_features`; ``urdf``: the stored form).
ROBOT = Fields(robot=str | dict, urdf=str, frame=str | None, base=str | None, rows=list | None, kind=str)
#: Φ: a built-in arm's Jacobian (its name, or {arm, rows} to keep some of its rows), a robot's, or
#: a callable.
FeatureSpec = ArmName | Annotated[dict, Fields(arm=ArmName, rows=list | None, kind=str), ROBOT] | Features
#: ‖Φu‖ below this carries no information about Λ.
MIN_TASK_NORM = 1e-3


def make_features(spec: FeatureSpec) -> Features:
    """Φ from a callable (X (N, p) → (N, r, q)), a built-in arm (``"arm2"``, ``"arm7"``, or
    ``{"arm": "arm7", "rows": [0, 1, 2]}``) or a robot (``{"robot": "lwr.urdf", "frame":
    "flange", "rows": [0, 1, 2]}``, also a DH table: ``{"robot": {"dh": [[a, d, α, θ0], ...]}}``)."""
    if callable(spec):
        return spec
    if isinstance(spec, str):
        spec = {"arm": spec}
    if isinstance(spec, dict) and ("robot" in spec or "urdf" in spec):
        from ccl_cli.learn.robots import robot_features

        return robot_features(spec)
    if isinstance(spec, dict) and "arm" in spec:
        try:
            return ArmFeatures(spec["arm"], spec.get("rows"))
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc
    raise ConfigError(f"features must be a callable, a built-in arm (arm2, arm7) or a robot ({{robot: "
                      f"arm.urdf, frame: tool0, rows: [0, 1, 2]}}), got {spec!r}"[:300])


@parameters
class KnownFeatureConstraint(AngularConstraintMixin, ConstraintModel):
    """Ã(x) = Λ̃(x) Φ(x) with Λ̃ rows a(W_k β(x)) in R^r.

    Args:
        features: Φ — a callable X → (N, r, q), or a built-in arm name/spec.
        n_centres: RBF centres when ``basis`` is a name (16).
        tune: as alpha's; grid: the configured K centres and the next square number of
            centres, (⌊√K⌋ + 1)² (16 → 25, 1 → 4), default widths, k-means-placed.
        Other arguments as :class:`~ccl_cli.learn.constraint.alpha.StateDependentConstraint`.

    Attributes:
        basis_, weights_, n_constraints_, nmse_, selection_, n_dropped_, n_task_ (r),
        n_features_in_, tuning_.
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {
        **AngularConstraintMixin._fitted_attributes, "n_task_": "value", "n_dropped_": "value"}
    features: FeatureSpec = "arm2"
    #: The noise test on the learnt rows (rank.py): on ``ccl simulate arm7 --constraint jacobian``
    #: it finds both Jacobian rows in 20 of 20 seeds, ``ratio`` in 3 (docs/auto.md).
    selection: sel.Rule = "noise"
    BASIS_PARAMS = ("basis", "n_centres", "seed", "features")

    def _basis_candidates(self) -> list[tuple[tuple[int, ...], tuple[float, ...]]]:
        k = int(self.n_centres)
        return [((k, (isqrt(k) + 1) ** 2), (1.0,))]

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None) -> KnownFeatureConstraint:
        """Learn Λ̃(x) from states X (N, p) and joint-space actions U (N, q); ``groups``
        (N,): demonstration ids, for the folds of tuning and of the ``cv`` rule; ``t`` (N,) s
        and ``derivative`` (how U was made: the readers' {"window", "order"}, False when
        recorded, None when not known) for the noise of the ``noise`` rule. Φ must fit the data
        (ConfigError / InputError, both ValueErrors: the built-in ``arm2`` needs p = q = 2). One
        action dimension (q = 1): no rows (k = 0, :data:`~.base.ONE_ACTION`; nothing tuned)."""
        return self._fit_timed(X, U, groups, t, derivative)

    def _angle_dim(self) -> int:
        return int(self.n_task_)

    def _rows_at(self, basis: Basis, X: np.ndarray, weights: list[np.ndarray]) -> np.ndarray:
        """Λ(X)Φ(X) of angle ``weights`` (:meth:`AngularConstraintMixin._rows_at`): (N, m, q)."""
        lam = rows_from_weights(basis.transform(X), weights, self.n_task_)
        return np.einsum("nkr,nrq->nkq", lam, self.features_(X))

    def _task_actions(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """v_n = Φ(x_n) u_n (N, r), computed in row blocks (Φ is (N, r, q)), and the mask of
        the samples with ‖v_n‖ ≥ MIN_TASK_NORM (N,)."""
        features = make_features(self.features)
        V = None
        for rows in row_chunks(len(X)):
            Phi = features(X[rows])
            if Phi.ndim != 3 or Phi.shape[0] != len(X[rows]):
                raise ConfigError(f"features must give (N, r, {U.shape[1]}) matrices, got {Phi.shape}")
            if Phi.shape[2] != U.shape[1]:
                raise ConfigError(f"the features give Φ (r, q) = {Phi.shape[1:]} for q = {Phi.shape[2]} "
                                  f"actions; U has q = {U.shape[1]}")
            V = np.empty((len(X), Phi.shape[1])) if V is None else V
            V[rows] = np.einsum("nrq,nq->nr", Phi, U[rows])
        return V, np.linalg.norm(V, axis=1) >= MIN_TASK_NORM

    def _fit_basis(self, X: np.ndarray, U: np.ndarray) -> Basis:
        """The feature map fitted on the states of the samples with ‖Φu‖ ≥ MIN_TASK_NORM."""
        keep = self._task_actions(X, U)[1]
        return make_basis(self.basis, self.n_centres, self.seed).fit(X[keep])

    def _fit_core(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                  basis: Basis | None = None, start: KnownFeatureConstraint | None = None
                  ) -> KnownFeatureConstraint:
        """The fit with a fitted ``basis`` (None: this learner's own), from ``start``'s rows."""
        self.features_ = make_features(self.features)
        V, keep = self._task_actions(X, U)
        self.n_dropped_ = int((~keep).sum())
        if keep.sum() < 2:
            raise LearningError(f"only {int(keep.sum())} samples have ‖Φu‖ ≥ {MIN_TASK_NORM}")
        self.n_action_ = U.shape[1]
        self.n_task_ = V.shape[1]
        Xk, Vk = (X, V) if self.n_dropped_ == 0 else (X[keep], V[keep])
        self.basis_ = make_basis(self.basis, self.n_centres, self.seed).fit(Xk) if basis is None else basis
        self._learn_rows(self.basis_, Xk, Vk, X, U, groups, start)
        return self

    def projection_k(self, X: np.ndarray, k: int | None) -> np.ndarray:
        """Ñ(X) = I − Ã⁺Ã of the first ``k`` learnt rows (the rows are nested): (N, p) → (N, q, q)."""
        return nullspace_projection(self._constraint(X, k))

    def selection_matrix(self, X: np.ndarray) -> np.ndarray:
        """Λ̃(X): (N, s, r)."""
        self._check_fitted("weights_")
        return rows_from_weights(self.basis_.transform(self._check_states(X)), self.weights_, self.n_task_)

    def _constraint(self, X: np.ndarray, k: int | None = None) -> np.ndarray:
        """Λ̃(X) Φ(X) of the first ``k`` rows (all when None): (N, k, q)."""
        self._check_fitted("weights_")
        X = self._check_states(X)
        lam = rows_from_weights(self.basis_.transform(X), self.weights_[:k], self.n_task_)
        return np.einsum("nkr,nrq->nkq", lam, self.features_(X))

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã(X) = Λ̃(X) Φ(X): (N, s, q)."""
        return self._constraint(X)
