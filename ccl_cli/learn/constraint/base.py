"""The interface every learnt constraint shares (ALGORITHMS.md §1, §3)."""

from __future__ import annotations

import numpy as np

from ccl_cli.errors import ConfigError
from ccl_cli.learn.base import Estimator
from ccl_cli.learn.consistency import npoe_error
from ccl_cli.learn.linalg import nullspace_projection
from ccl_cli.learn.params import Interval, out_of_range


class ConstraintModel(Estimator):
    """A learnt constraint. Subclasses implement :meth:`constraint` (and may give a
    cheaper :meth:`projection`).

    Attributes (after ``fit``): ``n_constraints_``, ``selection_`` (dict with the rule,
    the residuals it looked at and why it chose ``n_constraints_``), ``n_features_in_``.
    """

    #: True when the model needs the demonstration id of each sample to predict.
    needs_demo = False
    #: True when it also needs each sample's time (``projection(X, groups=..., t=...)``).
    needs_time = False

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None) -> np.ndarray:
        """Ã(X): (N, p) → (N, s, q)."""
        raise NotImplementedError

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None) -> np.ndarray:
        """Ñ(X) = I − Ã⁺Ã: (N, p) → (N, q, q) (ALGORITHMS.md §1)."""
        self._check_fitted("n_constraints_")
        return nullspace_projection(self.constraint(X, groups=groups))

    def task_part(self, X: np.ndarray, *, groups: np.ndarray | None = None) -> np.ndarray | None:
        """The learnt task part ṽ = Ã⁺b̃ (§1) at states X (N, p): (N, q); None for a model
        without a task term (then ṽ = 0)."""
        return None

    def score(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None) -> float:
        """−NPOE of actions U (N, q) at states X (N, p) (§6): −mean ‖z − Ñ(x)z‖² / Σ var(u),
        z = u − ṽ (the learnt task part, when the model has one); higher is better, 0 when every
        action (less its task part) lies in the learnt null space."""
        U = np.asarray(U, dtype=float)
        V = self.task_part(X, groups=groups)
        return -npoe_error(self.projection(X, groups=groups), U if V is None else U - V, U)


class TimedConstraint(ConstraintModel):
    """A constraint whose orthonormal rows depend on each sample's demonstration and time (one
    constant A per window, or in the stretches where it holds): :meth:`constraint` takes
    ``groups`` and ``t`` (N,)."""

    needs_demo = True
    needs_time = True

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        raise NotImplementedError

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ñ = I − ÃᵀÃ of each sample (orthonormal rows, or rows of zeros): (N, q, q)."""
        A = self.constraint(X, groups=groups, t=t)
        return np.eye(self.n_action_) - np.einsum("nki,nkj->nij", A, A)

    def score(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
              t: np.ndarray | None = None) -> float:
        """−NPOE of U (N, q) (see :class:`ConstraintModel`)."""
        return -npoe_error(self.projection(X, groups=groups, t=t), np.asarray(U, dtype=float))


def check_rows_asked(q: int, n_constraints: int | None) -> None:
    """ConfigError unless q ≥ 2 action dimensions and a fixed ``n_constraints`` is 0 … q − 1
    (for the learners that may answer no constraint: auto, per window)."""
    if q < 2:
        raise ConfigError("learning a constraint needs at least 2 action dimensions")
    if n_constraints is not None and n_constraints > q - 1:
        raise ConfigError(out_of_range("n_constraints", n_constraints, Interval(0, q - 1, type=int)))


def projection_at(model: ConstraintModel, X: np.ndarray, groups: np.ndarray | None = None,
                  t: np.ndarray | None = None) -> np.ndarray:
    """Ñ of any constraint model at states X (N, p) of demonstrations ``groups`` at times ``t``
    (N,) s: the times go only to models that use them (``needs_time``). → (N, q, q)."""
    if getattr(model, "needs_time", False):
        return model.projection(X, groups=groups, t=t)
    return model.projection(X, groups=groups)


def constraint_at(model: ConstraintModel, X: np.ndarray, groups: np.ndarray | None = None,
                  t: np.ndarray | None = None) -> np.ndarray:
    """Ã of any constraint model at X (N, p) as :func:`projection_at`: → (N, s, q)."""
    if getattr(model, "needs_time", False):
        return model.constraint(X, groups=groups, t=t)
    return model.constraint(X, groups=groups)


def fit_constraint(model: ConstraintModel, X: np.ndarray, U: np.ndarray, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None, derivative: dict | bool | None = None) -> ConstraintModel:
    """``model.fit`` with the sample times ``t`` and how U was made (``derivative``) for the
    models that read the time structure (auto, per window), the plain fit for the others."""
    import inspect

    takes = inspect.signature(model.fit).parameters
    extra = {k: v for k, v in (("t", t), ("derivative", derivative)) if k in takes}
    return model.fit(X, U, groups=groups, **extra)
