"""Runs configured stages in order, passing results between them.

learn-v → (w̃ on train and test) → learn-a on w̃ or u → (Ñ) → learn-pi, coupled to the
learnt constraint when asked → evaluate. Every stage reports the metrics that the
available ground truth allows (ALGORITHMS.md §6), on train and test.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli import metrics as M
from ccl_cli import selection as S
from ccl_cli.config import Config, stage_entry, stage_options
from ccl_cli.constraint import (
    KnownFeatureConstraint,
    LinearConstraint,
    PerDemonstration,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import ConfigError, InputError, LearningError
from ccl_cli.nullspace import NullSpaceComponent
from ccl_cli.policy import PolicyLearner

log = logging.getLogger("ccl")


@dataclass
class StageResult:
    name: str
    method: str
    model: Any
    metrics: dict[str, dict[str, dict]] = field(default_factory=dict)  # split → name → Metric dict
    info: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    baseline: Any = None


@dataclass
class Split:
    train: Demonstrations
    test: Demonstrations | None
    #: how and why: {kind, reason, n_train_/n_test_ demos or blocks, n_train_/n_test_samples, ...}
    info: dict[str, Any] = field(default_factory=dict)


def guard_gap(cfg: Config) -> int:
    """Samples dropped at each train/test boundary of a time-block split: ``data.test.gap``,
    else the derivative window of derived actions, else :data:`selection.DEFAULT_GAP`."""
    data_cfg = cfg.get("data") or {}
    tcfg = data_cfg.get("test") or {}
    if tcfg.get("gap") is not None:
        return int(tcfg["gap"])
    action = data_cfg.get("action") or {}
    if action.get("derive") and action.get("window"):
        return max(int(action["window"]), 1)
    return S.DEFAULT_GAP


def split_data(data: Demonstrations, cfg: Config, masks: dict[str, list[int]] | None = None) -> Split:
    """The reported train/test split, never silent: ``Split.info`` says which and why.

    Stored masks (canonical HDF5) win unless ``data.test.use_masks: false``; otherwise
    by demonstration when there are at least ``data.test.min_demos`` (default
    :data:`selection.MIN_DEMOS`), else held-out contiguous time blocks with guard gaps
    (:func:`selection.holdout_split`).
    """
    tcfg = (cfg.get("data") or {}).get("test") or {}
    if masks and tcfg.get("use_masks", True) and "train" in masks:
        train = data.select_demos(masks["train"])
        test = data.select_demos(masks["test"]) if masks.get("test") else None
        test = test if test is not None and test.n_samples else None
        info = {"kind": "masks", "reason": "train/test masks stored in the data file",
                "n_train_demos": train.n_demos, "n_test_demos": test.n_demos if test else 0,
                "n_train_samples": train.n_samples, "n_test_samples": test.n_samples if test else 0}
        return Split(train, test, info)
    fraction = float(tcfg.get("fraction", 0.3))
    if fraction <= 0:
        return Split(data, None, {"kind": "none", "reason": "data.test.fraction is 0: no held-out test "
                                  "set, every metric is on training data",
                                  "n_train_samples": data.n_samples, "n_test_samples": 0})
    hold = S.holdout_split(data.demo, fraction, int(tcfg.get("seed", 0)), guard_gap(cfg),
                           int(tcfg.get("min_demos", S.MIN_DEMOS)), int(tcfg.get("blocks", S.N_BLOCKS)))
    train, test = data.subset(hold.train), data.subset(hold.test)
    return Split(train, test if test.n_samples else None, hold.info)


def _kwargs(options: dict, allowed: tuple[str, ...]) -> dict:
    return {k: v for k, v in options.items() if k in allowed and v is not None}


def make_constraint(options: dict, seed: int):
    method = options.get("method", "nhat")
    common = ("selection", "n_constraints", "gap_floor", "max_constraints", "cv_folds")
    if method == "nhat":
        kw = _kwargs(options, (*common, "threshold"))
        model = StateIndependentConstraint(method=options.get("variant", "closed_form"), seed=seed, **kw)
    elif method in ("alpha", "lambda"):
        kw = _kwargs(options, (*common, "basis", "n_centres", "n_restarts", "max_iter", "tol", "tune"))
        if method == "alpha":
            model = StateDependentConstraint(seed=seed, **kw)
        else:
            if "features" not in options:
                raise ConfigError("learn-a method lambda needs features (e.g. features: arm2, or "
                                  "{arm: arm7, rows: [0, 1, 2]})")
            model = KnownFeatureConstraint(features=options["features"], seed=seed, **kw)
    elif method == "linear":
        kw = _kwargs(options, (*common, "threshold", "basis", "n_centres", "regressors", "degree", "task",
                               "task_regressors", "whiten", "reweight", "tune"))
        model = LinearConstraint(seed=seed, **kw)
    else:
        raise ConfigError(f"unknown learn-a method {method!r}")
    return PerDemonstration(model) if options.get("per_demo") else model


def _metrics_dict(*items: M.Metric) -> dict[str, dict]:
    return {m.name: m.as_dict() for m in items}


class Pipeline:
    """Holds the data split and what earlier stages learnt."""

    def __init__(self, cfg: Config, data: Demonstrations, masks: dict | None = None) -> None:
        self.cfg = cfg
        self.data = data
        self.split = split_data(data, cfg, masks)
        self.split_info = self.split.info
        self.seed = int(cfg.get("seed", 0))
        self.convention = (cfg.get("metrics") or {}).get("convention", "ccl")
        self.results: list[StageResult] = []
        self.w: dict[str, np.ndarray] = {}
        self.constraint: Any = None

    # -- helpers ------------------------------------------------------------------------
    def parts(self) -> list[tuple[str, Demonstrations]]:
        out = [("train", self.split.train)]
        if self.split.test is not None:
            out.append(("test", self.split.test))
        return out

    def _target(self, on: str, part: str, data: Demonstrations) -> np.ndarray:
        if on == "w" or (on == "auto" and self.w):
            if part not in self.w:
                raise ConfigError("'on: w' needs a learn-v stage before this one")
            return self.w[part]
        return data.U

    # -- stages -------------------------------------------------------------------------
    def run(self, names: list[tuple[str, dict]], progress=None) -> list[StageResult]:
        for name, extra in names:
            t0 = time.perf_counter()
            opts = stage_options(self.cfg, name, extra)
            log.info("stage %s (%s)", name, opts.get("method", ""))
            result = getattr(self, "_" + name.replace("-", "_"))(opts)
            result.seconds = time.perf_counter() - t0
            self.results.append(result)
            if progress is not None:
                progress()
        return self.results

    def _learn_v(self, opts: dict) -> StageResult:
        tr = self.split.train
        model = NullSpaceComponent(**_kwargs(opts, ("basis", "n_centres", "max_iter", "tol", "tune")),
                                   seed=self.seed).fit(tr.X, tr.U, tr.demo)
        result = StageResult("learn-v", "ncl", model, info={"n_iter": model.n_iter_})
        if getattr(model, "tuning_", None):
            result.info["tuning"] = model.tuning_
        for part, d in self.parts():
            w = model.predict(d.X)
            self.w[part] = w
            result.metrics[part] = nullspace_metrics(w, d, self.convention)
        return result

    def _learn_a(self, opts: dict) -> StageResult:
        tr = self.split.train
        on = opts.get("on", "auto")
        model = make_constraint(opts, self.seed)
        target = self._target(on, "train", tr)
        try:
            model.fit(tr.X, target, tr.demo)
        except (np.linalg.LinAlgError, FloatingPointError) as exc:
            raise LearningError(f"learn-a failed: {exc}") from None
        self.constraint = model
        method = opts.get("method", "nhat") + (" per demonstration" if opts.get("per_demo") else "")
        result = StageResult("learn-a", method, model,
                             info={"n_constraints": int(model.n_constraints_),
                                   "selection": model.selection_,
                                   "on": "w" if (on == "w" or (on == "auto" and self.w)) else "u"})
        if getattr(model, "tuning_", None):
            result.info["tuning"] = model.tuning_
        for part, d in self.parts():
            if isinstance(model, PerDemonstration) and part != "train":
                continue  # a per-demonstration model knows only its own demonstrations
            result.metrics[part] = constraint_metrics(model, d, self._target(on, part, d), self.convention)
        return result

    def _projections(self, opts: dict, part: str, d: Demonstrations) -> np.ndarray | None:
        if opts.get("method") != "pi-coupled":
            return None
        source = opts.get("projections", "auto")
        if source in ("learnt", "auto") and self.constraint is not None:
            return self.constraint.projection(d.X, d.demo)
        if source in ("true", "auto") and (d.has_truth("N") or d.has_truth("A")):
            return d.true_projection()
        raise ConfigError("pi-coupled needs projections: run learn-a first (projections: learnt) or "
                          "use data with ground-truth constraints (projections: true)")

    def _learn_pi(self, opts: dict) -> StageResult:
        tr = self.split.train
        on = opts.get("on", "auto")
        kw = _kwargs(opts, ("basis", "n_centres", "cutoff", "cutoff_rule", "min_norm", "tune"))
        if isinstance(kw.get("cutoff"), str):  # cutoff: absolute | relative (the rule, at 1e-6)
            if kw["cutoff"] not in ("absolute", "relative"):
                raise ConfigError("learn-pi.cutoff must be a number, absolute or relative, "
                                  f"got {kw['cutoff']!r}")
            kw["cutoff_rule"] = kw.pop("cutoff")
        model = PolicyLearner(method=opts.get("method", "pi"), seed=self.seed, **kw)
        model.fit(tr.X, self._target(on, "train", tr), self._projections(opts, "train", tr), demo=tr.demo)
        result = StageResult("learn-pi", model.method, model, info={"n_used": model.n_used_})
        if getattr(model, "tuning_", None):
            result.info["tuning"] = model.tuning_
        if opts.get("baseline", True) and model.method != "dpl":
            base_kw = dict(kw)
            if (model.tuning_ or {}).get("chosen"):  # the baseline regresses on the same basis
                base_kw.update(model.tuning_["chosen"], tune=False)
            result.baseline = PolicyLearner(method="dpl", seed=self.seed, **base_kw).fit(
                tr.X, self._target(on, "train", tr), demo=tr.demo)
        for part, d in self.parts():
            est = model.predict(d.X)
            metrics = policy_metrics(est, d)
            if result.baseline is not None and d.has_truth("pi"):
                b = M.nupe(d.truth["pi"], result.baseline.predict(d.X), "NUPE_dpl")
                metrics[b.name] = b.as_dict()
            if self.constraint is not None and not (isinstance(self.constraint, PerDemonstration)
                                                    and part != "train"):
                m = M.ncpe_observed(self.constraint.projection(d.X, d.demo), self._target(on, part, d), est)
                metrics[m.name] = m.as_dict()
            result.metrics[part] = metrics
        return result

    def _evaluate(self, opts: dict) -> StageResult:
        """Every learnt model of the earlier stages on train and test, under this stage's
        ``convention`` (e.g. ``original`` for the original library's normalisers)."""
        convention = opts.get("convention", self.convention)
        kinds = {"learn-a": "constraint", "learn-v": "nullspace", "learn-pi": "policy"}
        result = StageResult("evaluate", convention, None)
        for part, d in self.parts():
            merged: dict[str, dict] = {}
            for r in self.results:
                if r.model is None or (isinstance(r.model, PerDemonstration) and part != "train"):
                    continue
                for name, m in evaluate_model(r.model, kinds[r.name], d, convention).items():
                    merged[f"{r.name}.{name}"] = {**m, "name": f"{r.name}.{name}"}
            result.metrics[part] = merged
        return result


def stage_list(cfg: Config, default: list[str] | None = None) -> list[tuple[str, dict]]:
    items = cfg.get("stages")
    if not items:
        if default is None:
            raise ConfigError(f"{cfg.source}: no stages to run (add a stages: list)")
        return [(name, {}) for name in default]
    return [stage_entry(item, cfg, i) for i, item in enumerate(items)]


def _has_true_constraint(d: Demonstrations) -> bool:
    return d.has_truth("pi") and (d.has_truth("N") or d.has_truth("A"))


def constraint_metrics(model: Any, d: Demonstrations, Y: np.ndarray, convention: str) -> dict:
    """NPOE of ``Y`` (the observations, or the learnt w̃ they were fitted on) and, with
    ground truth, NPPE (normalised as for a state-dependent model unless it is nhat)."""
    N_est = model.projection(d.X, d.demo)
    items = [M.npoe(N_est, Y, "ccl")]
    if _has_true_constraint(d):
        base = model.estimator if isinstance(model, PerDemonstration) else model
        items.append(M.nppe(d.true_projection(), N_est, d.truth["pi"], d.U, convention,
                            state_dependent=not isinstance(base, StateIndependentConstraint)))
    return _metrics_dict(*items)


def nullspace_metrics(w: np.ndarray, d: Demonstrations, convention: str) -> dict:
    """NPE of the learnt w̃ and, with ground truth, NUPE of w and of v = u − w̃."""
    items = [M.npe(d.U, w, convention)]
    if d.has_truth("w"):
        items.append(M.nupe(d.truth["w"], w, "NUPE_w", "w"))
    if d.has_truth("v"):
        items.append(M.nupe(d.truth["v"], d.U - w, "NUPE_v", "v"))
    return _metrics_dict(*items)


def policy_metrics(est: np.ndarray, d: Demonstrations) -> dict:
    """With ground truth: NUPE of π̃ and NCPE."""
    items = []
    if d.has_truth("pi"):
        items.append(M.nupe(d.truth["pi"], est))
        if _has_true_constraint(d):
            items.append(M.ncpe(d.true_projection(), d.truth["pi"], est))
    return _metrics_dict(*items)


def evaluate_model(model: Any, kind: str, data: Demonstrations, convention: str = "ccl") -> dict:
    """Metrics of a saved model on ``data`` (all samples): the ones its ground truth allows."""
    if kind == "constraint":
        if isinstance(model, PerDemonstration):
            missing = set(np.unique(data.demo)) - set(model.models_)
            if missing:
                raise InputError("this per-demonstration model does not know demonstrations "
                                 f"{sorted(missing)[:5]} of the data")
        return constraint_metrics(model, data, data.U, convention)
    if kind == "nullspace":
        return nullspace_metrics(model.predict(data.X), data, convention)
    est = model.predict(data.X)
    metrics = policy_metrics(est, data)
    nm = M.nmse(data.U, est)
    metrics["NMSE_u_mean"] = M.Metric("NMSE_u_mean", float(np.nanmean(nm)), float("nan"), float("nan"),
                                      "per-dim").as_dict()
    return metrics


def check_dimensions(model: Any, data: Demonstrations) -> None:
    q = getattr(model, "n_action_", None)
    if q is None and isinstance(model, PerDemonstration):
        q = next(iter(model.models_.values())).n_action_
    if q is not None and data.n_action != q:
        raise InputError(f"the model expects {q}-dimensional actions, the data has {data.n_action}")
    basis = getattr(model, "basis_", None) or (getattr(next(iter(model.models_.values())), "basis_", None)
                                               if isinstance(model, PerDemonstration) else None)
    if basis is not None:
        p = basis.centres_.shape[1] if hasattr(basis, "centres_") else basis.n_state_
        if data.n_state != p:
            raise InputError(f"the model expects {p}-dimensional states, the data has {data.n_state}")
