"""The constraint of the manifold the states stay on ("manifold": holonomic constraints learnt
from positions, without differentiation).

When the action is the time derivative of the state (positions and their velocities), a
holonomic constraint A(x)u = 0 with A = ∇h keeps every demonstration on a level set of h:
h(x(t)) is constant along it — each demonstration at its own level (a handle grasped 2 cm
higher draws a parallel line). The k functions are sought in a small space of features,

    h_j(x) = w_jᵀ φ(x),      φ: ``linear``  z                      (planes; lines)
                                ``sphere``  [z, ‖z‖²]              (spheres and planes;
                                                                    circles and lines)
                                ``quadric`` [z, z_a z_b (a ≤ b)]    (every quadric surface)

with z = (x − μ)/s the states centred and scaled (so the answer does not depend on the frame
or the length unit), by making them as constant as possible along every stretch of samples
(a demonstration) while their gradients keep unit size on average:

    min_W tr(Wᵀ C W)   subject to   Wᵀ G W = I,
    C = Σ_d Σ_{n∈d} (φ(x_n) − φ̄_d)(φ(x_n) − φ̄_d)ᵀ / N    (within-demonstration covariance),
    G = Σ_n J_φ(x_n) J_φ(x_n)ᵀ / N                      (J_φ = ∂φ/∂x, (F, q)).

This is the generalised symmetric eigenproblem C w = λ G w; the k eigenvectors with the
smallest λ are the constraint functions, λ_j the mean squared variation of h_j along the
demonstrations (in squared length units, since the gradients have unit mean size). The
learnt rows at x are the gradients ∇h_j(x) = J_φ(x)ᵀ w_j, orthonormalised: Ã(x) (k, q).

Shapes: X (N, p) with p = q, groups (N,) demonstration ids.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.learn.constraint.base import ONE_ACTION, ConstraintModel, check_rows_asked
from ccl_cli.learn.linalg import generalized_eigh
from ccl_cli.learn.params import Interval, parameters

Family = Literal["linear", "sphere", "quadric"]
#: The feature spaces, simplest first.
BASES: tuple[str, ...] = ("linear", "sphere", "quadric")
#: Relative ridge on G (a feature with no gradient along the data cannot be normalised).
RIDGE = 1e-9


def n_features(basis: str, q: int) -> int:
    """F, the number of features of ``basis`` in q dimensions."""
    return {"linear": q, "sphere": q + 1, "quadric": q + q * (q + 1) // 2}[basis]


def features(basis: str, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """φ(z) (N, F) and its Jacobian ∂φ/∂z (N, F, q) at scaled states Z (N, q)."""
    n, q = Z.shape
    eye = np.broadcast_to(np.eye(q), (n, q, q))
    if basis == "linear":
        return Z, eye
    if basis == "sphere":
        return np.c_[Z, (Z**2).sum(1)], np.concatenate([eye, 2.0 * Z[:, None, :]], axis=1)
    a, b = np.triu_indices(q)
    J = np.zeros((n, len(a), q))
    J[:, np.arange(len(a)), a] += Z[:, b]
    J[:, np.arange(len(a)), b] += Z[:, a]
    return np.c_[Z, Z[:, a] * Z[:, b]], np.concatenate([eye, J], axis=1)


def within_covariance(Phi: np.ndarray, pieces: np.ndarray) -> np.ndarray:
    """C = Σ_d Σ_{n∈d} (φ_n − φ̄_d)(φ_n − φ̄_d)ᵀ / N for contiguous ``pieces`` (N,): (F, F)."""
    _, inverse, counts = np.unique(pieces, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), Phi.shape[1]))
    np.add.at(sums, inverse, Phi)
    D = Phi - (sums / counts[:, None])[inverse]
    return D.T @ D / len(Phi)


@parameters
class ManifoldConstraint(ConstraintModel):
    """k level functions of the states, constant along every demonstration (module docstring).

    Args:
        family: the level functions' features: ``linear`` (planes, lines: constant rows),
            ``sphere`` (spheres, circles: a hinge's radial row) or ``quadric`` (curved surfaces).
        n_constraints: k (None: the rows whose mean squared variation along the
            demonstrations is at most ``tolerance`` times the states' own, at least one).
        tolerance: of that choice: the largest allowed ratio of a level's RMS variation along
            the demonstrations to the RMS spread of the states about each one's mean.

    Attributes:
        weights_ (F, F): the feature weights of every level function, columns in order of
        variation; variation_ (F,): each one's mean squared variation λ_j; centre_ (q,),
        scale_: z = (x − centre_)/scale_; n_constraints_, n_action_, selection_, n_features_in_.
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "n_action_": "value", "selection_": "value",
        "weights_": "array", "variation_": "array", "centre_": "array", "scale_": "value"}
    family: Family = "sphere"
    n_constraints: Annotated[int, Interval(1, 100_000)] | None = None
    tolerance: Annotated[float, Interval(0, None)] = 0.05

    @property
    def varies_with_state(self) -> bool:  # type: ignore[override]
        """Planes and lines (``linear``) have constant rows; spheres, circles, quadrics turn."""
        return self.family != "linear"

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: object = None) -> ManifoldConstraint:
        """Learn the level functions from the states X (N, q) of the demonstrations ``groups``
        (N,; None: one); U (N, q), the states' velocities, is used for its shape only, and
        neither the times ``t`` nor how U was made are read (positions need no differentiation).
        InputError unless p = q; one dimension (p = q = 1): no rows (k = 0, :data:`~.base.ONE_ACTION`)."""
        X, U = self._prepare_fit(X, U)
        q = U.shape[1]
        if X.shape[1] != q:
            raise InputError(f"the manifold of the states needs states and actions of one dimension "
                             f"(positions and their velocities), got p = {X.shape[1]}, q = {q}")
        check_rows_asked(q, self.n_constraints)
        groups = np.zeros(len(X), np.int64) if groups is None else np.asarray(groups)
        self.n_action_ = q
        self.centre_ = X.mean(0)
        self.scale_ = float(np.sqrt(((X - self.centre_) ** 2).sum(1).mean()))
        if not self.scale_ > 0:
            raise InputError("the states do not move: no manifold to learn")
        Phi, J = features(self.family, self._scaled(X))
        C = within_covariance(Phi, groups)
        G = np.einsum("nfq,ngq->fg", J, J) / len(X)
        G += RIDGE * np.trace(G) / len(G) * np.eye(len(G))
        lam, W = generalized_eigh(C, G)
        self.variation_ = np.maximum(lam, 0.0) * self.scale_**2  # in squared length units
        self.weights_ = W
        spread = float(within_covariance(X, groups).trace())
        ratio = np.sqrt(self.variation_[: q - 1] / spread) if spread > 0 else np.full(q - 1, np.inf)
        if q == 1:  # a level of one coordinate would hold the state still
            k, reason = 0, ONE_ACTION
        elif self.n_constraints is not None:
            k = int(self.n_constraints)
            reason = f"fixed by the user at {k}"
        else:
            k = max(int(np.sum(np.cumprod(ratio <= self.tolerance))), 1)
            reason = (f"{k} level function(s) vary along the demonstrations by at most {self.tolerance:g} × "
                      "the spread of the states" if ratio[0] <= self.tolerance else
                      f"the quietest level function varies by {ratio[0]:.3g} × the spread (one row kept)")
        self.n_constraints_ = k
        rule = "one action" if q == 1 else "manifold" if self.n_constraints is None else "fixed"
        self.selection_ = {"rule": rule, "n_constraints": k,
                           "values": [float(v) for v in ratio], "reason": reason,
                           "criterion": "RMS variation of level function k along the demonstrations / "
                                        "RMS spread of the states"}
        if self.n_constraints is None:
            self.selection_.update(limits=[float(self.tolerance)] * len(ratio), limit_rule=(
                f"level function k counts while it varies by at most {self.tolerance:g} × the spread "
                "(row 1 always counts)"))
        return self

    def check_shapes(self) -> None:
        """weights_ (F, F), variation_ (F,), centre_ (q,) for the basis and q; scale_ > 0; 1 ≤ k < q
        (k = 0 at q = 1)."""
        q = self.n_action_
        F = n_features(self.family, q)
        for name, want in (("weights_", (F, F)), ("variation_", (F,)), ("centre_", (q,))):
            if getattr(self, name, None) is None or np.shape(getattr(self, name)) != want:
                raise self._shape_error(name)
        if not (isinstance(self.scale_, float | int) and self.scale_ > 0):
            raise self._shape_error("scale_")
        if not (self.n_constraints_ == 0 if q == 1 else 1 <= self.n_constraints_ < q):
            raise self._shape_error("n_constraints_")
        super().check_shapes()

    def _scaled(self, X: np.ndarray) -> np.ndarray:
        return (X - self.centre_) / self.scale_

    def levels(self, X: np.ndarray, k: int | None = None) -> np.ndarray:
        """h_1 … h_k at states X (N, q), in length units: (N, k)."""
        self._check_fitted("weights_")
        k = self.n_constraints_ if k is None else k
        Phi, _ = features(self.family, self._scaled(self._check_states(X)))
        return Phi @ self.weights_[:, :k] * self.scale_

    def gradients(self, X: np.ndarray, k: int | None = None) -> np.ndarray:
        """∇h_1 … ∇h_k at states X (N, q), not normalised: (N, k, q)."""
        self._check_fitted("weights_")
        k = self.n_constraints_ if k is None else k
        _, J = features(self.family, self._scaled(self._check_states(X)))
        return np.einsum("fk,nfq->nkq", self.weights_[:, :k], J)

    def constant_rows(self) -> np.ndarray | None:
        """The rows (k, q) of a ``linear`` model (its gradients do not depend on x), else None."""
        if self.family != "linear":
            return None
        self._check_fitted("weights_")
        return self.constraint(self.centre_[None])[0]

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None, t: np.ndarray | None = None,
                   k: int | None = None) -> np.ndarray:
        """Ã(X): the gradients of the first k level functions, orthonormalised (Gram–Schmidt in
        their order): (N, p) → (N, k, q)."""
        A = self.gradients(X, k)
        Q, R = np.linalg.qr(np.swapaxes(A, 1, 2))
        signs = np.sign(np.einsum("nkk->nk", R))  # keep each row's direction (QR's sign is arbitrary)
        signs[signs == 0] = 1.0
        return np.swapaxes(Q, 1, 2) * signs[:, :, None]


