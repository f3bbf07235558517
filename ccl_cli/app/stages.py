"""Runs configured stages in order, passing results between them.

learn-v → (w̃ on train and test) → learn-a on w̃ or u → (Ñ) → learn-pi, coupled to the
learnt constraint when asked → evaluate. Every stage reports the metrics that the
available ground truth allows (ALGORITHMS.md §6), on train and test.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ccl_cli import diagnostics
from ccl_cli.app import scoring, truth
from ccl_cli.app.views import View, constant_rows, describe_constraint, phases, stage_views
from ccl_cli.dataset import Demonstrations, Derivative
from ccl_cli.errors import ConfigError, LearningError
from ccl_cli.learn import model_selection
from ccl_cli.learn.constraint import PerDemonstration, PerWindow, force_evidence, geometry
from ccl_cli.learn.nullspace import NullSpaceComponent
from ccl_cli.learn.policy import PolicyLearner
from ccl_cli.spec import constraint_class

log = logging.getLogger("ccl")


@dataclass
class StageResult:
    name: str
    method: str
    model: Any
    metrics: dict[str, dict[str, dict]] = field(default_factory=dict)  # split → name → Metric dict
    info: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    #: CPU seconds of this process in the stage (every thread; a benchmark's figure, not a result)
    cpu_seconds: float = 0.0
    baseline: Any = None
    #: (part, data, convention) → metrics of this model; the stage and the evaluate stage
    #: both call it, so one model gets one set of numbers wherever it is reported.
    score: Callable[[str, Demonstrations, str], dict] | None = None
    #: the figures of this stage (:meth:`Pipeline.stage_views`; None: not computed yet), drawn
    #: by ccl_cli.render
    views: list[View] | None = None
    #: the verdict: ``ok`` when the held-out evidence is, ``poor`` when a check fired
    #: (:mod:`ccl_cli.diagnostics`: overfit, no_better_than_baseline, constraint_does_not_hold)
    status: str = "ok"
    checks: list[dict[str, str]] = field(default_factory=list)
    #: whether the model speaks for data it was not fitted on (False for a constraint whose rule
    #: for new data carries nothing over: it has no test figures)
    generalises: bool = True


@dataclass
class Split:
    train: Demonstrations
    test: Demonstrations | None
    #: how and why: {kind, reason, n_train_/n_test_ demos or blocks, n_train_/n_test_samples, ...}
    info: dict[str, Any] = field(default_factory=dict)


def guard_gap(spec: Any, data: Demonstrations | None = None) -> int:
    """Samples dropped at each train/test boundary of a time-block split: ``data.test.gap``,
    else the derivative window the reader used for derived actions (configured, or chosen
    from the rate and recorded in the data's metadata), else :data:`model_selection.DEFAULT_GAP`."""
    if spec.data.test.gap is not None:
        return int(spec.data.test.gap)
    if data is not None and data.derivative.derived:
        return max(data.derivative.window, model_selection.DEFAULT_GAP)
    action = spec.data.action
    if action is not None and action.derive and action.window:
        return max(int(action.window), 1)
    return model_selection.DEFAULT_GAP


def split_data(data: Demonstrations, spec: Any, masks: dict[str, list[int]] | None = None) -> Split:
    """The reported train/test split, never silent: ``Split.info`` says which and why.

    Stored masks (canonical HDF5) win unless ``data.test.use_masks: false``; otherwise
    by demonstration when there are at least ``data.test.min_demos``, else held-out
    contiguous time blocks with guard gaps (:func:`model_selection.holdout_split`).
    """
    test = spec.data.test
    if masks and test.use_masks and "train" in masks:
        train = data.select_demos(masks["train"])
        held = data.select_demos(masks["test"]) if masks.get("test") else None
        held = held if held is not None and held.n_samples else None
        info = {"kind": "masks", "reason": "train/test masks stored in the data file",
                "n_train_demos": train.n_demos, "n_test_demos": held.n_demos if held else 0,
                "n_train_samples": train.n_samples, "n_test_samples": held.n_samples if held else 0}
        return Split(train, held, info)
    if test.fraction <= 0:
        return Split(data, None, {"kind": "none", "reason": "data.test.fraction is 0: no held-out test "
                                  "set, every metric is on training data",
                                  "n_train_samples": data.n_samples, "n_test_samples": 0})
    hold = model_selection.holdout_split(data.demo, float(test.fraction), test.seed, guard_gap(spec, data),
                                         test.min_demos, test.blocks,
                                         keys=model_selection.shape_keys(data.X, data.demo))
    train, held = data.subset(hold.train), data.subset(hold.test)
    return Split(train, held if held.n_samples else None, hold.info)


def _heldout_blocks(model: Any) -> dict[str, Any] | None:
    """The held-out NPOE of a model fitted per stretch (demonstration, window, segment) — blocks
    held out inside the stretches it was fitted on (its ``heldout_``) — as a metric entry; None
    for a global model (its held-out figure is the test split's) or when none was measured."""
    h = model.heldout_ if model.is_local else None
    if not h:
        return None
    return {"name": "NPOE", "value": h["mean"], "error": None, "normaliser": None, "normaliser_of": "u",
            "se": h["se"], "n_groups": len(h["per_fold"]), "note": h["folds"]}


def make_constraint(options: Any, seed: int):
    """The constraint estimator of a learn-a section (its ``method``, its parameters, one per
    demonstration with ``per_demo``: for ``auto`` and ``per_window``, one constant constraint
    per demonstration, :class:`~ccl_cli.learn.constraint.PerWindow` with no window)."""
    if options.per_demo and options.method in ("auto", "per_window"):  # nhat per demonstration
        return PerWindow(**{**options.estimator_params(PerWindow), "window": None})
    cls = constraint_class(options.method)
    params = options.estimator_params(cls)
    if options.method == "lambda" and "features" not in params:
        raise ConfigError("learn-a method lambda needs features (e.g. features: arm2, or "
                          "{arm: arm7, rows: [0, 1, 2]})")
    model = cls(**({"seed": seed} if "seed" in cls._param_names() else {}), **params)
    return PerDemonstration(model) if options.per_demo else model


class StageProgress(Protocol):
    """What shows a run's progress (the CLI's bar): a label as each stage starts, a step as it
    ends."""

    def start(self, label: str) -> None: ...

    def advance(self) -> None: ...


#: ``on: auto`` does not learn from a learnt w̃ whose variance is below this share of u's: a
#: null-space component of nearly nothing is a degenerate input, not evidence of a task part.
DEGENERATE_SHARE = 1e-3
#: ... nor when the task part it leaves, u − w̃, holds less than this share of u's variance on the
#: held-out part: without a task part u and w̃ show the same constraint, and u is the measurement.
TASK_SHARE = 0.05
#: ... and on samples that are not trajectories (no states' geometry, no noise to judge by), only
#: when the model on w̃ explains the held-out w̃ PREFER_W × better than the model on u explains u.
PREFER_W = 2.0


class Pipeline:
    """Holds the data split and what earlier stages learnt."""

    def __init__(self, spec: Any, data: Demonstrations, masks: dict | None = None) -> None:
        self.spec = spec
        self.data = data
        #: coded data warnings ({code, message}); stages and other checks append to it (the data
        #: checks run before the split copies the parts: their temporaries on the data alone)
        self.warnings: list[dict[str, str]] = diagnostics.emit(diagnostics.check_data(data))
        self.split = split_data(data, spec, masks)
        self.split_info = self.split.info
        self.seed = spec.seed
        self.convention = spec.metrics.convention
        self.results: list[StageResult] = []
        self.w: dict[str, np.ndarray] = {}
        #: the observations later stages learn from under ``on: auto``: "u", or "w" (the learnt
        #: w̃) — decided by learn-a on held-out evidence, else w̃ when a learn-v stage generalised
        self.observations: str | None = None
        self.constraint: Any = None

    # -- helpers ------------------------------------------------------------------------
    def parts(self) -> list[tuple[str, Demonstrations]]:
        out = [("train", self.split.train)]
        if self.split.test is not None:
            out.append(("test", self.split.test))
        return out

    def _on(self, on: str) -> str:
        """Which observations ``on`` (auto, u, w) means now: "u" or "w"."""
        if on != "auto":
            return on
        return self.observations or ("w" if self.w else "u")

    def _target(self, on: str, part: str, data: Demonstrations) -> np.ndarray:
        if self._on(on) == "w":
            if part not in self.w:
                raise ConfigError("'on: w' needs a learn-v stage before this one")
            return self.w[part]
        return data.U

    def _judge(self, result: StageResult, checks: list[dict[str, str]]) -> None:
        """Attach the stage's verdict (its checks and status) and report the checks."""
        result.checks = diagnostics.emit(checks)
        result.status = diagnostics.status(checks)
        result.info["status"] = result.status
        self.warnings += result.checks

    def _held_out(self) -> tuple[str, Demonstrations]:
        """The data a verdict is judged on: the held-out part, else (said so) the training part."""
        return self.parts()[-1]

    # -- stages -------------------------------------------------------------------------
    def run(self, stages: list[tuple[str, Any]], progress: StageProgress | None = None,
            on_views: Callable[[list[View]], None] | None = None) -> list[StageResult]:
        """Run ``stages`` — (name, options: the stage's section of the run spec) pairs — in
        order; ``progress.start(label)`` before each and ``progress.advance()`` after it
        (without a progress display, each stage is one INFO log line). ``on_views`` (if given)
        receives each stage's figures as soon as no later stage can change them (a policy's
        depend on the constraint of a learn-a stage, which may come later)."""
        names = [name for name, _ in stages]
        for i, (name, opts) in enumerate(stages):
            t0, c0 = time.perf_counter(), time.process_time()
            label = f"{name} ({self._describe(name, opts)})"
            if progress is None:
                log.info("stage %s", label)
            else:
                progress.start(label)
            result = getattr(self, "_" + name.replace("-", "_"))(opts)
            result.seconds = time.perf_counter() - t0
            result.cpu_seconds = time.process_time() - c0
            self.results.append(result)
            if on_views is not None and not (name == "learn-pi" and "learn-a" in names[i + 1:]):
                on_views(self.stage_views(result))
            if progress is not None:
                progress.advance()
        return self.results

    def _describe(self, name: str, opts: Any) -> str:
        """What a stage runs, for the progress line: its method (or the evaluate convention)."""
        if name == "learn-v":
            return "ncl"
        if name == "evaluate":
            return f"every model under the {opts.convention or self.convention} convention"
        return opts.method or PolicyLearner().method

    def _learn_v(self, opts: Any) -> StageResult:
        tr = self.split.train
        model = NullSpaceComponent(**opts.estimator_params(NullSpaceComponent),
                                   seed=self.seed).fit(tr.X, tr.U, groups=tr.demo)
        result = StageResult("learn-v", "ncl", model, info={"n_iter": model.n_iter_,
                                                            "stop_reason": model.stop_reason_})
        if getattr(model, "tuning_", None):
            result.info["tuning"] = model.tuning_
        ws = {part: model.predict(d.X) for part, d in self.parts()}
        self.w.update(ws)
        result.score = lambda part, d, convention: scoring.nullspace_metrics(ws[part], d, convention)
        self._score_parts(result)
        # "no task part": u regressed on the same features (w̃ = E[u | x], v = 0)
        plain = PolicyLearner(method="dpl", basis=model.basis_, tune=False, seed=self.seed).fit(tr.X, tr.U)
        baseline = {part: {"NPE": scoring.nullspace_metrics(plain.predict(d.X), d, truth=False)["NPE"]}
                    for part, d in self.parts()}
        result.info["baseline"] = {"method": "u regressed on the same features (no task part)", **baseline}
        part, _ = self._held_out()
        self._judge(result, [
            *diagnostics.nullspace_far_from_truth("learn-v", part, result.metrics.get(part)),
            *diagnostics.overfit("learn-v", "NPE", result.metrics["train"]["NPE"],
                                 result.metrics.get("test", {}).get("NPE")),
            *diagnostics.not_better("learn-v", "NPE", result.metrics.get("test", {}).get("NPE"),
                                    baseline.get("test", {}).get("NPE", {}).get("value", np.nan),
                                    "u regressed on the same features with no task part")])
        return result

    def _fit_constraint(self, opts: Any, on: str) -> Any:
        tr = self.split.train
        q = tr.n_action
        if q < 2:  # the learners answer k = 0 there (base.ONE_ACTION): nothing to learn from a recording
            raise ConfigError("learning a constraint needs at least 2 action dimensions (a constraint row "
                              "on one would forbid all motion)")
        if opts.n_constraints is not None and not 1 <= opts.n_constraints <= max(q - 1, 1):
            raise ConfigError(f"learn-a.n_constraints (--n-constraints) is {opts.n_constraints}, but "
                              f"{q}-dimensional actions allow 1 to {max(q - 1, 1)} constraints")
        model = make_constraint(opts, self.seed)
        if tr.rate_assumed and "rate_assumed" in model.get_params():
            model.set_params(rate_assumed=True)  # no cuts in seconds of a rate nobody measured
        target = self._target(on, "train", tr)
        how = tr.derivative if target is tr.U else Derivative(False)  # a learnt w̃ is no derivative
        try:
            model.fit(tr.X, target, groups=tr.demo, t=tr.t, derivative=how,
                      **force_evidence.fit_params(model, tr.force))
        except (np.linalg.LinAlgError, FloatingPointError) as exc:
            raise LearningError(f"learn-a failed: {exc}") from None
        return model

    def _choose_observations(self, opts: Any) -> tuple[Any, str, str]:
        """``on: auto`` after a learn-v stage: u and the learnt w̃ on equal terms; → (model, "u"
        or "w", why). The constraint is learnt from u when it finds rows there that hold on the
        held-out u (no task part is needed for them), when learn-v did not generalise, when w̃ is
        degenerate (variance below DEGENERATE_SHARE of u's) or its task part negligible (below
        TASK_SHARE). Otherwise from w̃ when it shows more: when the actions are the states'
        derivative, the states with the learnt task part integrated out (X − ∫ṽ dt) must show more
        constraints than the states themselves; else the model learnt on w̃ must explain the
        held-out w̃ at least PREFER_W × better (held-out NPOE) than the model on u explains u — a
        task part moves u along the rows, and k = 0 on u is no evidence that nothing holds."""
        model = self._fit_constraint(opts, "u")
        part, d = self._held_out()
        evidence = diagnostics.constraint_evidence(model, d, d.U)
        learn_v = next((r for r in self.results if r.name == "learn-v"), None)
        k_u = int(model.n_constraints_)
        if k_u and evidence is not None and evidence["holds"]:
            why = (f"it holds on the {part} u ({k_u} row(s); "
                   + (f"the positions drift along them by at most {max(evidence['drift']):.3g} of their "
                      "spread" if evidence.get("measure") == "drift" else
                      f"motion along its rows {max(evidence['ratio']):.3g}× their noise")
                   + ("; a model per stretch, fitted again there" if evidence["refitted"] else "") + ")")
            return model, "u", f"learnt from u: {why}, so no task part is needed for it"
        if learn_v is not None and learn_v.status != "ok":
            either = f" (the constraint does not hold on the {part} u either)" if k_u and evidence else ""
            return model, "u", f"learnt from u: learn-v did not generalise, so its w̃ is not used{either}"
        w = self.w["train"]
        u_var = float(self.split.train.U.var(0).sum())
        w_share = float(w.var(0).sum()) / max(u_var, 1e-300)
        if not w_share >= DEGENERATE_SHARE:
            return model, "u", (f"learnt from u: the learnt w̃ is degenerate (its variance {w_share:.2g} of "
                                "u's), so it is not used")
        task = float((d.U - self.w[part]).var(0).sum()) / max(float(d.U.var(0).sum()), 1e-300)
        if not task >= TASK_SHARE:
            return model, "u", (f"learnt from u: the task part learn-v found is {task:.2g} of u's variance "
                                f"on the {part} data, too little to move u off a constraint")
        tr = self.split.train
        if geometry.kinematic(tr.X, tr.U, tr.demo, tr.t, tr.derivative)[0]:
            # equal terms: the states with the learnt task part taken out, X − ∫ṽ dt, must show more
            # constraints than the states themselves (they integrate w̃ as X integrates u)
            shown = geometry.decide(geometry.integrate(w, tr.X, tr.demo, tr.t), tr.demo).k
            if shown <= k_u:
                return model, "u", (f"learnt from u: the states with learn-v's task part taken out show "
                                    f"{shown} constraint(s), no more than the states themselves ({k_u})")
            return self._fit_constraint(opts, "w"), "w", (
                f"learnt from the learnt w̃: the states with learn-v's task part taken out show {shown} "
                f"constraint(s), the states themselves {k_u}, and learn-v generalised")
        on_w = self._fit_constraint(opts, "w")
        k_w = int(on_w.n_constraints_)
        if not k_w:
            return model, "u", "learnt from u: the learnt w̃ shows no constraint either"
        err_u = model.held_out_error(d.X, d.U, groups=d.demo, t=d.t) if k_u else 1.0
        err_w = on_w.held_out_error(d.X, self.w[part], groups=d.demo, t=d.t)
        if k_w <= k_u and not err_w * PREFER_W <= err_u:
            return model, "u", (f"learnt from u: the model on w̃ explains the {part} w̃ (NPOE {err_w:.3g}) no "
                                f"{PREFER_W:g}× better than the model on u explains u ({err_u:.3g})")
        return on_w, "w", (f"learnt from the learnt w̃: its {k_w} row(s) explain the {part} w̃ with NPOE "
                           f"{err_w:.3g} against {err_u:.3g} for {k_u} row(s) on u, and learn-v generalised")

    def _learn_a(self, opts: Any) -> StageResult:
        tr = self.split.train
        if opts.on == "auto" and self.w:
            model, on, why = self._choose_observations(opts)
            self.observations = on
        else:
            on = self._on(opts.on)
            model = self._fit_constraint(opts, on)
            why = ("learnt from the learnt w̃ (on: w)" if on == "w" else
                   "on: u" if self.w else "")  # without learn-v there is nothing else to learn from
        self.constraint = model
        target = self._target(on, "train", tr)
        self.warnings += diagnostics.emit(diagnostics.low_rank_actions(tr, target, int(model.n_constraints_)))
        method = opts.method + (" per demonstration" if opts.per_demo else "")
        result = StageResult("learn-a", method, model,
                             info={"n_constraints": int(model.n_constraints_),
                                   "selection": model.selection_, "on": on, "on_reason": why})
        if getattr(model, "tuning_", None):
            result.info["tuning"] = model.tuning_
        result.info["constraint"] = describe_constraint(model, tr)
        heldout = _heldout_blocks(model)
        result.generalises = model.new_data_rule.carries_over
        if not result.generalises:
            result.info["per_demo_note"] = (
                "One constraint per training demonstration: a held-out demonstration has none, so there "
                "are no test metrics; " + ("the held-out figure is from blocks held out inside each "
                                           "training demonstration." if heldout else
                                           "the demonstrations are too short for held-out blocks inside "
                                           "them, so every figure is a training figure."))
        targets = {part: self._target(on, part, d) for part, d in self.parts()}
        result.score = lambda part, d, convention: scoring.constraint_metrics(
            scoring.applied_on(model, d, targets[part]), d, targets[part], convention,
            of="learnt w" if on == "w" else "u")
        self._score_parts(result)
        if heldout is not None:
            result.metrics["heldout_blocks"] = {"NPOE": heldout}
        part, d = self._held_out()
        checks = diagnostics.overfit("learn-a", "NPOE", result.metrics["train"]["NPOE"],
                                     heldout or result.metrics.get("test", {}).get("NPOE"))
        if on == "u" and result.generalises:
            evidence = diagnostics.constraint_evidence(model, d, d.U)
            result.info["evidence"] = {"part": part, **evidence} if evidence else None
            checks += diagnostics.does_not_hold("learn-a", evidence, f"{part} data")
        checks = self._honest(result, model, on, target, checks)
        rows = constant_rows(model, tr)
        if rows is not None:
            judged = (tr, target)
            inside = model.holds(tr.X, groups=tr.demo, t=tr.t)
            if not inside.all():  # judged where it claims to hold, not in free air
                judged = (tr.subset(inside), target[inside])
            self.warnings += diagnostics.emit(diagnostics.constraint_varies("learn-a", rows, *judged))
        self._judge(result, checks)
        return result

    def _honest(self, result: StageResult, model: Any, on: str, target: np.ndarray,
                checks: list[dict[str, str]]) -> list[dict[str, str]]:
        """learn-a's verdict honest by construction (issue 30 item 5): against the ground truth the
        file carries (on the held-out part, the training part for a model that knows only its own
        demonstrations), held-out support for its rows, and no degenerate input; the truth
        comparison, the support, the cones (``auto``) and the phases go into ``result.info``."""
        tr = self.split.train
        part, d = self._held_out() if result.generalises else ("train", tr)
        Y = self._target(on, part, d)
        hint = truth.task_hint(d, on, any(r.name == "learn-v" for r in self.results))
        comparison = truth.compare(model, d, Y, part, result.metrics.get(part), hint)
        support = diagnostics.heldout_support(model.selection_, result.info.get("evidence"), part)
        found = phases(model, tr)
        result.info.update({k: v for k, v in (("truth", comparison), ("support", support), ("phases", found))
                            if v is not None})
        u_var = float(tr.U.var(0).sum())
        return [*diagnostics.far_from_truth("learn-a", comparison), *checks,
                *diagnostics.no_heldout_support("learn-a", support),
                *diagnostics.degenerate_input("learn-a", tr, target, on, model, u_var, DEGENERATE_SHARE)]

    def _score_parts(self, result: StageResult, convention: str | None = None,
                     into: dict | None = None, prefix: str = "") -> None:
        """Score ``result``'s model on train and test (a per-demonstration constraint only on
        the training demonstrations it knows) into ``into`` (default: its own metrics)."""
        into = result.metrics if into is None else into
        for part, d in self.parts():
            if not result.generalises and part != "train":
                continue  # e.g. a per-demonstration model knows only its own demonstrations
            convention = convention or self.convention
            if convention == self.convention and into is not result.metrics and part in result.metrics:
                scored = dict(result.metrics[part])  # the same numbers: no need to score again
            else:
                scored = result.score(part, d, convention)
            into.setdefault(part, {}).update({prefix + k: {**m, "name": prefix + k}
                                              for k, m in scored.items()})

    def _projections(self, method: str, opts: Any, d: Demonstrations) -> np.ndarray | None:
        if method != "pi-coupled":
            return None
        source = opts.projections
        if source in ("learnt", "auto") and self.constraint is not None:  # per stretch: by its rule on d
            return scoring.projection_on(scoring.applied_on(self.constraint, d, d.U), d)
        if source in ("true", "auto") and (d.has_truth("N") or d.has_truth("A")):
            return d.true_projection()
        raise ConfigError("pi-coupled needs projections: run learn-a first (projections: learnt) or "
                          "use data with ground-truth constraints (projections: true)")

    def _learn_pi(self, opts: Any) -> StageResult:
        tr = self.split.train
        on = opts.on
        kw = opts.estimator_params(PolicyLearner)
        if isinstance(kw.get("cutoff"), str):  # cutoff: absolute | relative (the rule, at 1e-6)
            kw["cutoff_rule"] = kw.pop("cutoff")
        model = PolicyLearner(seed=self.seed, **kw)
        model.fit(tr.X, self._target(on, "train", tr), groups=tr.demo,
                  projections=self._projections(model.method, opts, tr))
        result = StageResult("learn-pi", model.method, model, info={"n_used": model.n_used_})
        if getattr(model, "tuning_", None):
            result.info["tuning"] = model.tuning_
        if opts.baseline and model.method != "dpl":
            base_kw = {k: v for k, v in kw.items() if k != "method"}
            if (model.tuning_ or {}).get("chosen"):  # the baseline regresses on the same basis
                base_kw.update(model.tuning_["chosen"], tune=False)
            result.baseline = PolicyLearner(method="dpl", seed=self.seed, **base_kw).fit(
                tr.X, self._target(on, "train", tr), groups=tr.demo)
        constraint = self.constraint
        targets = {part: self._target(on, part, d) for part, d in self.parts()}
        of = "learnt w" if self._on(on) == "w" else "u"

        def applied(part: str, d: Demonstrations) -> Any:
            """The learnt constraint on ``d`` (None: none, or one that knows only its training data)."""
            if constraint is None or (part != "train" and not constraint.new_data_rule.carries_over):
                return None
            return scoring.applied_on(constraint, d, targets[part])

        result.score = lambda part, d, convention: scoring.policy_metrics(
            model.predict(d.X), d, applied(part, d), targets[part], of)
        self._score_parts(result)
        if result.baseline is not None:  # the dpl baseline is its own model, with its own metrics
            baseline = StageResult("learn-pi", "dpl", result.baseline)
            baseline.score = lambda part, d, convention: scoring.policy_metrics(
                result.baseline.predict(d.X), d, applied(part, d), targets[part], of)
            self._score_parts(baseline)
            result.info["baseline"] = {"method": "dpl", **baseline.metrics}
        self.warnings += diagnostics.emit(diagnostics.not_identifiable(
            "learn-pi", tr, self._target(on, "train", tr)))
        self._judge(result, self._policy_checks(result))
        return result

    def _policy_checks(self, result: StageResult) -> list[dict[str, str]]:
        """A policy is no better than predicting zero when its held-out NCPE_obs (or, with ground
        truth, NUPE) is ≥ 1, no better than the dpl baseline when not below the baseline's, and
        overfit when far above its training value."""
        checks: list[dict[str, str]] = []
        test = result.metrics.get("test", {})
        base = (result.info.get("baseline") or {}).get("test", {})
        if not any(n in result.metrics.get(p, {}) for p in ("train", "test") for n in ("NCPE_obs", "NUPE")):
            return diagnostics.not_judged("learn-pi", diagnostics.NO_POLICY_METRIC)
        for name in ("NCPE_obs", "NUPE"):
            if name not in result.metrics.get("train", {}):
                continue
            checks += diagnostics.overfit("learn-pi", name, result.metrics["train"][name], test.get(name))
            checks += diagnostics.not_better("learn-pi", name, test.get(name), diagnostics.ZERO_LEVEL,
                                             "predicting zero")
            if name in base:
                checks += diagnostics.not_better("learn-pi", name, test.get(name), base[name]["value"],
                                                 "the dpl baseline (u regressed on the features)")
        return checks

    def stage_views(self, result: StageResult) -> list[View]:
        """Compute the figures of one stage (:func:`~ccl_cli.app.views.stage_views`) on the
        held-out data (the training data when there is none) into ``result.views``."""
        part, shown = self.parts()[-1]
        blocks = self.split_info.get("kind") == "blocks"
        result.views = stage_views(result, shown, part, self.split.train, blocks, self.constraint)
        return result.views

    def views(self) -> list[View]:
        """Every stage's figures, those not computed yet computed now."""
        return [v for r in self.results for v in (r.views if r.views is not None else self.stage_views(r))]

    def _evaluate(self, opts: Any) -> StageResult:
        """Every learnt model of the earlier stages on train and test, under this stage's
        ``convention`` (e.g. ``original`` for the original library's normalisers)."""
        convention = opts.convention or self.convention
        result = StageResult("evaluate", f"every learnt model under the {convention} convention", None,
                             info={"convention": convention})
        for r in self.results:
            if r.score is not None:
                self._score_parts(r, convention, result.metrics, f"{r.name}.")
        return result
