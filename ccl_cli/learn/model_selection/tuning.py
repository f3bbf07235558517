"""The ``tune`` parameter every learner with a basis shares: :class:`Tunable`, which delegates
``fit`` to :class:`~.search.Tuned` over the learner's grid and splits the fit in parts so that a
search can share work; and the candidate bases (:func:`basis_grid`)."""

from __future__ import annotations

from typing import Annotated, Any, ClassVar

import numpy as np

from ccl_cli.learn import blas
from ccl_cli.learn.base import clone
from ccl_cli.learn.defaults import TUNE
from ccl_cli.learn.model_selection.search import Budget, MaxRows, Searchable, Tuned
from ccl_cli.learn.model_selection.splitters import Folds
from ccl_cli.learn.model_selection.validation import held_out_errors, take_rows
from ccl_cli.learn.params import Fields, NFolds, parameters

#: ``tune`` of a learner: True (the default search), False, or a mapping adjusting it.
TuneSpec = bool | Annotated[dict, Fields(budget=Budget, folds=NFolds, max_rows=MaxRows, grid=dict)]


@parameters
class Tunable(Searchable):
    """The ``tune`` parameter of a learner (True by default): when on, ``fit`` delegates
    to :class:`Tuned` over the learner's default grid (:meth:`_tune_grid`) or the grid
    given in ``tune: {grid: ...}`` and takes over the winner's learnt attributes;
    ``tuning_`` records the search. The constructor parameters are left unchanged.

    A learner lists its basis candidates in :meth:`_basis_candidates`; only a default
    RBF basis is tuned (:func:`rbf_tunable`). Its fit is split so that a search can share
    work: :meth:`_fit_basis` (the feature map), :meth:`_fit_core` (the fit given a fitted
    basis and, optionally, a fitted model to start from) and :meth:`_cv_models` (the models
    of one candidate's cross-validation)."""

    #: Folds of this learner's default search (None: :data:`TUNE_FOLDS`).
    TUNE_FOLDS: ClassVar[int | None] = None
    #: Rows of this learner's search above which it runs on a subset (None: :data:`TUNE_MAX_ROWS`).
    TUNE_MAX_ROWS: ClassVar[int | None] = None
    #: Fits its default search may run (None: :data:`TUNE_BUDGET`).
    TUNE_BUDGET: ClassVar[float | None] = None
    #: Grid parameters whose first value a search leaves only on clear held-out evidence
    #: (regularisation; :func:`search`).
    TUNE_CONSERVATIVE: ClassVar[tuple[str, ...]] = ()
    #: The parameters its feature map depends on (:meth:`_fit_basis`, :meth:`_basis_key`).
    BASIS_PARAMS: ClassVar[tuple[str, ...]] = ("basis", "n_centres", "seed")
    tune: TuneSpec = TUNE

    def _basis_candidates(self) -> list[tuple[tuple[int, ...], tuple[float, ...]]]:
        """(numbers of centres, width factors) of the candidate bases, in order (:func:`basis_grid`)."""
        return []

    def _tune_grid(self, X: np.ndarray, U: np.ndarray) -> dict[str, list[Any]]:
        """The grid searched when ``tune`` is on: ``{"basis": [candidates]}`` with the
        configured basis first, or {} (nothing to tune: a basis the user fixed, or too few
        samples for any candidate)."""
        if not rbf_tunable(self.basis):
            return {}
        grid = [spec for sizes, widths in self._basis_candidates()
                for spec in basis_grid(X, sizes, widths, self.seed)]
        return {"basis": grid} if grid else {}

    # -- the fit in parts ------------------------------------------------------------------
    def _fit_basis(self, X: np.ndarray, U: np.ndarray) -> Any:
        """The learner's feature map (its ``basis``, ``n_centres`` and ``seed``) fitted on the
        states X (N, p) of a fit with actions U (N, q)."""
        from ccl_cli.learn.basis import make_basis

        return make_basis(self.basis, self.n_centres, self.seed).fit(X)

    def _basis_key(self) -> tuple:
        """What :meth:`_fit_basis` depends on (the values of :attr:`BASIS_PARAMS`), hashable:
        candidates with equal keys share one fitted basis in a search."""
        return tuple(_frozen(getattr(self, name)) for name in self.BASIS_PARAMS)

    def _fit_core(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                  basis: Any = None, start: Any = None, **fit_kw: Any) -> Any:
        """The untuned fit on checked X (N, p), U (N, q): with ``basis`` (fitted; None: the
        learner's own, :meth:`_fit_basis`) and ``start``, a fitted model of the same learner
        and basis to start an iterative fit from (None: the learner's own start)."""
        raise NotImplementedError

    def _fit_given(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None, basis: Any = None,
                   start: Any = None, **fit_kw: Any) -> Any:
        """:meth:`_fit_core` of an untuned copy after the checks of ``fit``; returns the copy
        (with ``_fit_rows``, the number of rows it was fitted on)."""
        model = clone(self).set_params(tune=False)
        X, U = model._prepare_fit(X, U)
        model._fit_core(X, U, groups=groups, basis=basis, start=start, **fit_kw)
        model._fit_rows = len(U)  # a fit started from this one reads how many rows it saw
        return model

    def _cv_models(self, X: np.ndarray, U: np.ndarray, groups: np.ndarray, folds: Folds, *,
                   basis: Any = None, shared: dict[Any, Any] | None = None, **fit_kw: Any
                   ) -> tuple[Any, list[Any]]:
        """The models of this candidate's cross-validation (:func:`candidate_models`): one
        basis fitted on all of X (unless given; k-means sees no actions), the candidate
        fitted on all rows, and each training fold fitted starting from that fit (an
        iterative fit run to its tolerance from a start near its optimum; a closed-form
        learner overrides this with downdated normal equations and keeps them in ``shared``,
        the search's store, for its candidates on the same basis)."""
        basis = self._fit_basis(X, U) if basis is None else basis
        full = self._fit_given(X, U, groups=groups, basis=basis, **fit_kw)
        models = [self._fit_given(X[train], U[train], groups=groups[train], basis=basis, start=full,
                                  **take_rows(fit_kw, train))
                  for train, _ in folds.pairs]
        return full, models

    def _held_out_errors(self, models: list[Any], X: np.ndarray, U: np.ndarray, groups: np.ndarray,
                         folds: Folds, *, shared: dict[Any, Any] | None = None, **fit_kw: Any) -> np.ndarray:
        """The held-out errors of this candidate's fold ``models`` (n_folds,): :func:`held_out_errors`
        (a learner may use what its :meth:`_cv_models` kept in ``shared``)."""
        return held_out_errors(models, X, U, groups, folds, **fit_kw)

    def _fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None, **fit_kw: Any) -> Any:
        """The body of every learner's ``fit``: check the parameters and the data, then search
        (``tune``) or fit once, with one BLAS thread (with more, OpenBLAS's results depend on
        their number: eigh, solve and some products change in their last bits)."""
        X, U = self._prepare_fit(X, U)
        with blas.threads(1):
            if not self._fit_tuned(X, U, groups=groups, **fit_kw):
                self._fit_core(X, U, groups=groups, **fit_kw)
        return self

    def _fit_tuned(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None, **fit_kw: Any) -> bool:
        """Search and adopt the winner when ``tune`` is on; False (``tuning_ = None``) when
        there is nothing to tune and the caller fits as usual."""
        spec = self.tune
        opts = spec if isinstance(spec, dict) else {}
        grid = (opts.get("grid") or self._tune_grid(X, U)) if spec else {}
        self.tuning_ = None
        if not grid:
            return False
        search = Tuned(clone(self).set_params(tune=False), grid, folds=opts.get("folds"),
                       budget=opts.get("budget"), max_rows=opts.get("max_rows"), seed=int(self.seed))
        search.fit(X, U, groups=groups, **fit_kw)
        self._adopt(search.best_estimator_)
        self.tuning_ = search.tuning_
        return True


def _frozen(value: Any) -> Any:
    """A hashable stand-in for a parameter value: mappings and sequences as tuples, arrays by
    their shape and a digest of their bytes, callables and other objects by identity."""
    if isinstance(value, dict):
        return tuple(sorted((k, _frozen(v)) for k, v in value.items()))
    if isinstance(value, list | tuple):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, np.ndarray):
        import hashlib

        data = np.ascontiguousarray(value)
        digest = hashlib.blake2b(data.view(np.uint8), digest_size=16).digest()
        return ("array", data.shape, str(data.dtype), digest)
    if isinstance(value, str | int | float | bool | type(None)):
        return value
    return ("object", id(value))


def rbf_tunable(basis: Any) -> bool:
    """Only a default RBF basis (a name or a dict without explicit centres/width) is tuned;
    a linear basis, a basis object or explicit centres/σ² are the user's choice."""
    if basis is None or basis == "rbf":
        return True
    return isinstance(basis, dict) and basis.get("kind", "rbf") == "rbf" and \
        "sigma2" not in basis and not isinstance(basis.get("centres"), list | np.ndarray)


def basis_grid(X: np.ndarray, sizes: tuple[int, ...], widths: tuple[float, ...], seed: int = 0,
               centres: str = "kmeans") -> list[dict[str, Any]]:
    """Candidate RBF bases (``basis`` parameter values): for each number of centres K
    (at most N/2; repeated values dropped) and width factor f, σ² = f · σ²_default(K)
    (the default rule of ALGORITHMS.md §2 on those centres; f = 1 is left to the rule)."""
    from ccl_cli.learn.basis import RBFBasis

    X = np.asarray(X, dtype=float)
    out: list[dict[str, Any]] = []
    for K in dict.fromkeys(int(k) for k in sizes):
        if K > max(1, len(X) // 2):
            continue
        s0 = RBFBasis(n_centres=K, centres=centres, seed=seed).fit(X).sigma2_ if any(
            f != 1 for f in widths) else 1.0
        for f in widths:
            spec: dict[str, Any] = {"kind": "rbf", "n_centres": int(K), "centres": centres}
            if f != 1:
                spec["sigma2"] = float(f * s0)
            out.append(spec)
    return out
