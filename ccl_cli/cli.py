"""The ``ccl`` command line: a thin layer over the library.

Parses flags, loads and validates the YAML config (flags override it), calls the
library, writes outputs atomically, and maps errors to exit codes: 0 success,
1 learning/evaluation failure, 2 bad usage or bad input — always with a one-line
message on stderr, never a traceback (``CCL_DEBUG=1`` shows one for internal errors).
"""

from __future__ import annotations

import logging
import os
import sys
import time
from contextlib import contextmanager
from enum import Enum
from pathlib import Path
from typing import Annotated, Any, get_args

import typer
from typer._click.exceptions import NoArgsIsHelpError, UsageError  # typer vendors its click
from typer.core import TyperCommand, TyperGroup

from ccl_cli import choices, progress
from ccl_cli.cli_params import in_words, spread
from ccl_cli.errors import CCLError, ConfigError, InputError, LearningError
from ccl_cli.learn import blas, defaults, params

log = logging.getLogger("ccl")

def _one_line(ctx: Any, exc: Exception) -> InputError:
    """A usage error (bad flag value, unknown option or command) as one line, exit 2."""
    message = exc.format_message().replace("Value error, ", "")
    return InputError(f"{ctx.command_path}: {message} (see {ctx.command_path} --help)")


class _OneLineUsage:
    """Usage errors as one line (``ccl: error: ccl learn-a: Invalid value ...``)."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        try:
            return super().parse_args(ctx, spread(self, args))  # type: ignore[misc]
        except NoArgsIsHelpError:
            raise
        except UsageError as exc:
            raise _one_line(ctx, exc) from None


class _Command(_OneLineUsage, TyperCommand):
    """Commands whose usage errors are one line and whose --help is in words."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        in_words(self.params)


class _Group(_OneLineUsage, TyperGroup):
    """The ``ccl`` group: an unknown command or a bad top-level option is one line too."""

    def resolve_command(self, ctx: Any, args: list[str]) -> Any:
        try:
            return super().resolve_command(ctx, args)
        except UsageError as exc:
            raise _one_line(ctx, exc) from None


def _typer() -> typer.Typer:
    """An empty ``ccl`` app (:data:`app` gets every command; :func:`_app_for` one)."""
    return typer.Typer(
        name="ccl",
        cls=_Group,
        help="Constraint Consistent Learning: learn constraints A(x), null-space components w(x) and "
             "null-space policies π(x) from demonstrations (HDF5, CSV, MCAP, ROS 1/2 bags).",
        no_args_is_help=True,
        context_settings={"help_option_names": ["-h", "--help"]},
        add_completion=True,
        pretty_exceptions_enable=False,
        rich_markup_mode=None,
    )


app = _typer()

# -- shared options -----------------------------------------------------------------------
DataArg = Annotated[list[Path] | None, typer.Argument(
    help="Recordings: files, globs, bag folders or folders of recordings; overrides data.files of the "
         "config.",
    show_default=False)]
ConfigOpt = Annotated[Path | None, typer.Option("--config", "-c", help="YAML config (see README).")]
OutOpt = Annotated[Path | None, typer.Option(
    "--out", "-o", help="Output directory (an existing one is replaced only with --force, and only if ccl "
    "wrote it).", show_default="a new runs/<command>-<input name>, then …-2, …-3: never an existing one")]
ForceOpt = Annotated[bool, typer.Option("--force", help="Overwrite existing outputs.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print a machine-readable summary on stdout.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="Only warnings and errors on stderr.")]
StrictOpt = Annotated[bool, typer.Option("--strict", help="Exit 1 when a stage's verdict is not ok "
                                         "(its held-out evidence does not support it).")]
SeedOpt = Annotated[int | None, typer.Option("--seed", help="Seed of every random choice.",
                                             show_default="config, else 0")]
TestOpt = Annotated[float | None, typer.Option(
    "--test-fraction", help="Fraction of demonstrations held out (0: none).",
    show_default=f"config, else {choices.TEST_FRACTION}")]


def _choices(name: str, literal: Any) -> type[Enum]:
    """An Enum of the values of a ``Literal`` (shown as choices in --help)."""
    return Enum(name, [(v.replace("-", "_"), v) for v in get_args(literal)], type=str)


def _default(value: Any) -> str:
    """A default as --help shows it (flags only override the config)."""
    return f"config, else {value}"


def _value(v: Any) -> Any:
    return v.value if isinstance(v, Enum) else v


Convention = _choices("Convention", choices.Convention)
LearnAMethod = _choices("LearnAMethod", choices.ConstraintMethod)
Selection = _choices("Selection", params.SelectionRule)
PiMethod = _choices("PiMethod", params.PolicyMethod)
Projections = _choices("Projections", choices.Projections)
BasisKind = _choices("BasisKind", params.BasisKind)
Features = _choices("Features", params.ArmName)
Regressors = _choices("Regressors", params.Regressors)

ConvOpt = Annotated[Convention | None, typer.Option("--convention",
                                                    help="Metric normalisers (docs/metrics.md).",
                                                    show_default=_default(choices.CONVENTION))]
CentresOpt = Annotated[int | None, typer.Option("--n-centres", help="Number of RBF centres (also sets "
                                                "basis.n_centres of a basis mapping; no basis search).",
                                                show_default="config, else the stage's default")]
BasisOpt = Annotated[BasisKind | None, typer.Option("--basis", help="Feature map (sets basis.kind of a "
                                                    "basis mapping; no basis search).",
                                                    show_default="config, else rbf")]


def _version(value: bool) -> None:
    if value:
        from ccl_cli import __version__

        typer.echo(f"ccl {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                                help="Print the version and exit.")] = False) -> None:
    """Constraint Consistent Learning: learn constraints A(x), null-space components w(x) and
    null-space policies π(x) from demonstrations (HDF5, CSV, MCAP, ROS 1/2 bags)."""


_QUIET = [False]  # set by every command through _logging: -q silences the summaries too


def shown(text: str) -> str:
    """``text`` as it can be printed: the bytes of a file name that is not UTF-8 (held as
    surrogate escapes, ``os.fsdecode``) shown as ``\\xNN``; any other surrogate as ``\\udNNN``."""
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a surrogate that is no escaped byte (a JSON "\\ud800")
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


class _Shown(logging.Formatter):
    """'ccl: message', with :func:`shown` file names."""

    def format(self, record: logging.LogRecord) -> str:
        return shown(super().format(record))


def _logging(quiet: bool) -> None:
    _QUIET[0] = quiet
    progress.install(progress.terminal_hook(quiet))  # long reads: a bar on a terminal, not with -q
    level = logging.WARNING if quiet else logging.INFO
    logging.basicConfig(level=level, format="ccl: %(message)s", stream=sys.stderr, force=True)
    for handler in logging.root.handlers:
        handler.setFormatter(_Shown("ccl: %(message)s"))


def _common(seed, test_fraction, convention) -> dict[str, Any]:
    return {"seed": seed, "data": {"test": {"fraction": test_fraction}},
            "metrics": {"convention": _value(convention)}}


def _config(path: Path | None, overrides: dict[str, Any]):
    from ccl_cli import config

    return config.load(path, overrides)


def _emit(summary: dict[str, Any], as_json: bool, quiet: bool = False) -> None:
    """The summary: JSON on stdout (``--json``), else one line per stage on stderr (none with -q)."""
    from ccl_cli.render import text

    if as_json:
        sys.stdout.write(text.json_line(summary))
        return
    for line in text.summary_lines(summary, quiet or _QUIET[0]):
        typer.echo(shown(line), err=True)


def _wrote(command: str, out: Path, data, as_json: bool) -> None:
    """Report a written dataset: JSON on stdout, or one line on stderr."""
    if as_json:
        _emit({"status": "ok", "command": command, "out": str(out), "samples": data.n_samples,
               "demos": data.n_demos}, True)
    elif not _QUIET[0]:
        typer.echo(shown(f"wrote {out}: {data.n_samples} samples in {data.n_demos} demonstrations"), err=True)


def _learn(command: str, stages: list[str] | None, cfg, files, out: Path | None,
           force: bool, as_json: bool, quiet: bool, strict: bool = False,
           scheduler: str | None = None) -> None:
    from ccl_cli.app.run import default_outdir, execute
    from ccl_cli.render.outputs import check_output, write_run

    outdir = out or default_outdir(command, cfg, files)
    check_output(outdir, force)  # before any work: a folder ccl did not write is never replaced
    stages = cfg.stages() if stages is None else [(name, cfg.spec.section(name)) for name in stages]
    on_views = None
    try:  # the drawer ends however the run does (an error, Ctrl-C at any moment)
        if cfg.spec.output.plots:  # figures drawn by another process while this one learns
            from ccl_cli.render.drawing import start_drawer, submit_views

            if start_drawer() is not None:
                def on_views(views) -> None:
                    submit_views(views, cfg.spec.output.format)
        bar = _bar("stages", len(stages), quiet)
        try:
            with _cluster(scheduler):  # after the drawer's fork: a client's threads are not forked
                result = execute(command, cfg, files, stages, progress=bar, on_views=on_views)
        finally:
            if bar:
                bar.stop()
        summary = write_run(result, outdir, force)
    finally:
        if cfg.spec.output.plots:
            from ccl_cli.render.drawing import stop_drawer

            stop_drawer()
    _emit(summary, as_json, quiet)
    if strict and summary["status"] != "ok":
        error = LearningError(f"--strict: the run is {summary['verdict']}")
        error.summarised = as_json  # --json printed the run's summary (status poor): one object only
        raise error


@contextmanager
def _cluster(scheduler: str | None):
    """The fits' block sums on the Dask cluster at ``scheduler`` (:mod:`ccl_cli.learn.blocksums`)
    while the block runs; nothing without one."""
    if scheduler is None:
        yield
        return
    from ccl_cli.app import dask_jobs
    from ccl_cli.learn.blocksums import on_cluster

    with dask_jobs.connected(scheduler) as client, on_cluster(client):
        yield


def _bar(label: str, total: int, quiet: bool):
    """A rich progress bar on stderr (TTY only, not with -q): done/total, failures when
    ``advance`` is given results with a ``status``, and elapsed or remaining time."""
    if quiet or not sys.stderr.isatty():
        return None
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from ccl_cli import progress as shown

    counts_failures = label == "jobs"
    columns = [TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}")]
    columns += [TextColumn("failed {task.fields[failed]}"), TimeRemainingColumn()] if counts_failures \
        else [TimeElapsedColumn()]
    progress = Progress(*columns, console=Console(stderr=True), transient=True)
    task = progress.add_task(label, total=total, failed=0)
    progress.start()
    shown.live(+1)  # a long read meanwhile shows no second bar
    failed = [0]
    now = [""]  # what runs now, e.g. 'learn-v (ncl)'

    @contextmanager
    def step(what: str, total: float):
        """A step inside the running stage (a search's candidates, a long read), shown after
        the stage's name: 'learn-v (ncl) · tuning, candidates 3/8'."""
        done = [0.0]

        def advance(units: float) -> None:
            done[0] += units
            count = f"{100 * done[0] / total:.0f} %" if total > 1000 else f"{done[0]:g}/{total:g}"
            progress.update(task, description=f"{label}: {now[0]} · {what} {count}")

        advance(0)
        try:
            yield advance
        finally:
            progress.update(task, description=f"{label}: {now[0]}")

    previous = shown.install(step)

    class Handle:
        def start(self, what: str) -> None:
            """Name what runs now: 'learn-v (ncl)' beside the bar."""
            now[0] = what
            progress.update(task, description=f"{label}: {what}")

        def advance(self, result: Any = None) -> None:
            failed[0] += getattr(result, "status", None) == "failed"
            progress.update(task, advance=1, failed=failed[0])

        def stop(self) -> None:
            shown.install(previous)
            shown.live(-1)
            progress.stop()

    return Handle()


# -- learning commands --------------------------------------------------------------------
#: The options every learning command takes besides its stage's own: (name, annotation, default).
_LEADING = (("data", "DataArg", None), ("config", "ConfigOpt", None), ("out", "OutOpt", None))
_TRAILING = (("seed", "SeedOpt", None), ("test_fraction", "TestOpt", None), ("convention", "ConvOpt", None),
             ("strict", "StrictOpt", False), ("force", "ForceOpt", False), ("json_out", "JsonOpt", False),
             ("quiet", "QuietOpt", False))


def _learning_command(stage: str):
    """A command learning one stage: the decorated function takes the stage's own options
    and returns them as config keys (values None: not given); this adds the options every
    learning command shares (recordings, config, output, seed, test fraction, convention,
    force, --json, -q) and runs the stage."""
    import functools
    import inspect as pyinspect

    def wrap(fn):
        import typing

        hints = typing.get_type_hints(fn, include_extras=True)  # typer reads the Annotated options
        own = [p.replace(annotation=hints[p.name]) for p in pyinspect.signature(fn).parameters.values()]
        kind = pyinspect.Parameter.POSITIONAL_OR_KEYWORD
        shared = [pyinspect.Parameter(n, kind, default=d, annotation=globals()[a])
                  for n, a, d in _LEADING + _TRAILING]
        params = shared[:len(_LEADING)] + own + shared[len(_LEADING):]

        @functools.wraps(fn)
        def command(**kw: Any) -> None:
            common = {name: kw.pop(name) for name, _, _ in _LEADING + _TRAILING}
            _logging(common["quiet"])
            flags = _common(common["seed"], common["test_fraction"], common["convention"]) | {stage: fn(**kw)}
            _learn(stage, [stage], _config(common["config"], flags), common["data"], common["out"],
                   common["force"], common["json_out"], common["quiet"], common["strict"])

        command.__signature__ = pyinspect.Signature(params, return_annotation=None)
        command.__annotations__ = {p.name: p.annotation for p in params}
        return command

    return wrap


@app.command("learn-a")
@_learning_command("learn-a")
def learn_a(
    method: Annotated[LearnAMethod | None, typer.Option(
        help="auto (model class and number of constraints, 0 included, by held-out evidence), nhat "
             "(constant A, closed form), alpha (state-dependent), lambda (known Φ), linear (closed form), "
             "per_window (one constant A per time window), per_segment (one constant A per segment, cut "
             "where it changes), manifold (the level sets the states stay on: lines, circles, surfaces; "
             "docs/methods.md).",
        show_default=_default(choices.DEFAULT_CONSTRAINT_METHOD))] = None,
    selection: Annotated[Selection | None, typer.Option(
        help="How the number of constraints s is chosen (lambda's default: noise).",
        show_default=_default(defaults.DEFAULT_RULE))] = None,
    n_constraints: Annotated[int | None, typer.Option(help="Fix the number of constraints s.",
                                                      show_default="chosen by --selection")] = None,
    features: Annotated[Features | None, typer.Option(help="lambda: built-in Φ.", show_default="config")]
    = None,
    regressors: Annotated[Regressors | None, typer.Option(help="linear: regressors of A(x).",
                                                          show_default="config, else identity")] = None,
    degree: Annotated[int | None, typer.Option(help="linear: polynomial degree.",
                                               show_default="config, else the method's default")] = None,
    per_demo: Annotated[bool | None, typer.Option("--per-demo/--pooled", help="One constraint per "
                                                  "demonstration.", show_default="config, else pooled")]
    = None,
    n_centres: CentresOpt = None, basis: BasisOpt = None,
) -> dict[str, Any]:
    """Learn the constraint A(x) (and its projection N = I − A⁺A) from observed actions."""
    return {"method": _value(method), "selection": _value(selection), "n_constraints": n_constraints,
            "features": _value(features), "regressors": _value(regressors), "degree": degree,
            "per_demo": per_demo, "n_centres": n_centres, "basis": _value(basis)}


@app.command("learn-v")
@_learning_command("learn-v")
def learn_v(n_centres: CentresOpt = None, basis: BasisOpt = None) -> dict[str, Any]:
    """Learn the null-space component w(x) of u = v + w (and so the task part v = u − w)."""
    return {"n_centres": n_centres, "basis": _value(basis)}


@app.command("learn-pi")
@_learning_command("learn-pi")
def learn_pi(
    method: Annotated[PiMethod | None, typer.Option(help="Policy learner (docs/methods.md).",
                                                    show_default=_default(defaults.POLICY_METHOD))] = None,
    projections: Annotated[Projections | None, typer.Option(
        help="pi-coupled: projections from the ground truth (true) or a learn-a stage (learnt).",
        show_default=_default("auto"))] = None,
    n_centres: CentresOpt = None, basis: BasisOpt = None,
) -> dict[str, Any]:
    """Learn the unconstrained null-space policy π(x) from demonstrations under varying constraints."""
    return {"method": _value(method), "projections": _value(projections), "n_centres": n_centres,
            "basis": _value(basis)}


@app.command("run")
def run(
    pipeline: Annotated[Path, typer.Argument(help="Pipeline YAML with data and stages.")],
    data: Annotated[list[Path] | None, typer.Option(
        "--data", help="Recordings overriding data.files: files, globs, folders; every word up to the next "
                       "option.")] = None,
    out: OutOpt = None, seed: SeedOpt = None, test_fraction: TestOpt = None, convention: ConvOpt = None,
    n_centres: Annotated[int | None, typer.Option("--n-centres", help="Number of RBF centres of every stage "
                                                  "of the pipeline that has a basis (learn-v, learn-pi, "
                                                  "learn-a with alpha, lambda or linear; no basis search).",
                                                  show_default="config, else each stage's default")] = None,
    basis: Annotated[BasisKind | None, typer.Option("--basis", help="Feature map of every stage of the "
                                                    "pipeline that has a basis (no basis search).",
                                                    show_default="config, else rbf")] = None,
    scheduler: Annotated[str | None, typer.Option(
        help="Address of a running Dask scheduler (tcp://host:8786): the sums over all rows of the fits "
             "(learn-v's passes, the policies' normal equations) are computed by its workers, which hold "
             "the rows; reading, learn-a, predictions and scores run here.")] = None,
    strict: StrictOpt = False, force: ForceOpt = False, json_out: JsonOpt = False, quiet: QuietOpt = False,
) -> None:
    """Run the stages of a pipeline YAML in order (learn-v, learn-a, learn-pi, evaluate)."""
    _logging(quiet)
    flags = _common(seed, test_fraction, convention)
    if n_centres is not None or basis is not None:
        flags |= _basis_flags(pipeline, {"n_centres": n_centres, "basis": _value(basis)})
    cfg = _config(pipeline, flags)
    _learn("run", None, cfg, data, out, force, json_out, quiet, strict, scheduler=scheduler)


def _basis_flags(pipeline: Path, given: dict[str, Any]) -> dict[str, Any]:
    """``--n-centres`` / ``--basis`` of ``ccl run`` as the flags of each stage of the pipeline
    that has a basis (learn-v, learn-pi, and learn-a when its method has one); none is a
    usage error naming the stages."""
    import inspect as pyinspect

    from ccl_cli import spec

    plain = _config(pipeline, {})
    flags: dict[str, Any] = {}
    for name, opts in plain.stages():
        method = getattr(opts, "method", None)
        if name in ("learn-v", "learn-pi") or (name == "learn-a" and "n_centres" in pyinspect.signature(
                spec.constraint_class(method).__init__).parameters):
            flags[name] = given
    if not flags:
        said = "/".join(f"--{k.replace('_', '-')}" for k, v in given.items() if v is not None)
        stages = ", ".join(f"{n} ({getattr(o, 'method', '')})".replace(" ()", "") for n, o in plain.stages())
        raise InputError(f"{said}: no stage of {pipeline} has a basis ({stages})")
    return flags


# -- using saved models -------------------------------------------------------------------
@app.command("evaluate")
def evaluate(
    model: Annotated[Path, typer.Argument(help="A model.h5 written by ccl.")],
    data: DataArg = None, config: ConfigOpt = None, out: OutOpt = None, convention: ConvOpt = None,
    force: ForceOpt = False, json_out: JsonOpt = False, quiet: QuietOpt = False,
) -> None:
    """Metrics of a saved model on data (every metric its ground truth allows; docs/metrics.md)."""
    from ccl_cli.app.evaluate import evaluate_saved
    from ccl_cli.app.run import read_data
    from ccl_cli.render.outputs import check_output, write_evaluation

    _logging(quiet)
    cfg = _config(config, {"metrics": {"convention": _value(convention)}})
    if out is not None:
        check_output(out, force)
    dataset, _ = read_data(cfg, data)
    figures = out is not None and cfg.spec.output.plots
    summary = evaluate_saved(model, dataset, cfg.spec.metrics.convention, figures)
    if out is not None:
        write_evaluation(summary, out, force, cfg.spec.output.format)
    summary = {k: v for k, v in summary.items() if k not in ("entry", "inputs", "samples", "demos", "views")}
    summary["outdir"] = str(out) if out else None
    if json_out:
        _emit({**summary, "metrics": {k: v["value"] for k, v in summary["metrics"].items()}}, True)
    elif not quiet:
        if not summary["metrics"]:
            typer.echo(f"no metric: the data has no ground truth for this {summary['kind']} model", err=True)
        for k, v in summary["metrics"].items():
            typer.echo(f"{k} = {v['value']:.6e}  (error {v['error']:.3e} / var of {v['normaliser_of']} "
                       f"{v['normaliser']:.3e})")
        if summary.get("rule"):
            typer.echo(f"applied: {summary['rule']['words']}", err=True)
        if summary.get("note"):
            typer.echo(f"note: {summary['note']}", err=True)


@app.command("predict")
def predict(
    model: Annotated[Path, typer.Argument(help="A model.h5 written by ccl.")],
    data: DataArg = None, config: ConfigOpt = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Output file: .h5 or .csv.")]
    = Path("predictions.h5"),
    force: ForceOpt = False, json_out: JsonOpt = False, quiet: QuietOpt = False,
) -> None:
    """Predict on new states: projections N(x) (constraint), w and v (null-space), π (policy)."""
    from ccl_cli.app.evaluate import predict_saved
    from ccl_cli.app.run import read_data

    _logging(quiet)
    cfg = _config(config, {})
    dataset, _ = read_data(cfg, data)
    summary = predict_saved(model, dataset, out, force)
    if json_out:
        _emit(summary, True)
    elif not quiet:
        repaired = sum(n for kinds in summary["repaired"].values() for n in kinds.values())
        typer.echo(shown(f"wrote {out} ({summary['samples']} rows: one per sample read"
                   + (f", {repaired} repaired (columns repair, fault)" if repaired else "")
                   + (f"; {summary['left_out']} outside the configured demonstrations" if summary["left_out"]
                      else "") + ")"), err=True)
        typer.echo(f"applied: {summary['rule']['words']}", err=True)
        if summary.get("note"):
            typer.echo(f"note: {summary['note']}", err=True)


@app.command("export")
def export(
    model: Annotated[Path, typer.Argument(metavar="MODEL", help="A model file (model.h5) written by ccl.",
                                          show_default=False)],
    out: Annotated[Path, typer.Option("--out", "-o", metavar="FILE", show_default=False,
                                      help="The file to write: .yaml or .yml for YAML, .json for JSON.")],
    force: ForceOpt = False, json_out: JsonOpt = False, quiet: QuietOpt = False,
) -> None:
    """Write a saved model as a documented, versioned YAML or JSON file that any language reads: a
    constraint's k and rows (or the parameters of A(x) and its formula, per window, segment, phase
    or demonstration, with the rule for a new recording), a null-space component's or a policy's
    basis and weights, the names, units and frame of the data, and how it was trained
    (docs/export.md, with a reference evaluator in numpy)."""
    from ccl_cli.app.export import export_model

    _logging(quiet)
    summary = export_model(model, out, force)
    if json_out:
        _emit(summary, True)
    elif not quiet:
        what = (f"{summary['method']} constraint, k = {summary['k']} ({summary['form']})"
                if summary["kind"] == "constraint" else f"{summary['method']} {summary['kind']}")
        typer.echo(shown(f"wrote {out}: {what}, schema version {summary['schema_version']}"), err=True)


# -- data commands --------------------------------------------------------------------------
@app.command("simulate")
def simulate(
    problem: Annotated[str, typer.Argument(help="toy2d, two_link, arm7, varying_constraint, tracker_plane, "
                                                "tracker_sphere, arm_at_rest, tracker_flips, tracker_tilt, "
                                                "arm_wipe, arm_wipe_joint, free_reach, flow2d, hinge, slide, "
                                                "contact_phases, reach_goal or handwriting.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Canonical HDF5 file to write.")],
    seed: Annotated[int, typer.Option(help="Seed.")] = 0,
    noise: Annotated[float | None, typer.Option(help="Std of noise on u (tracker_*: on positions, m).")]
    = None,
    snr_db: Annotated[float | None, typer.Option(help="Noise as signal-to-noise ratio in dB.")] = None,
    n_demos: Annotated[int | None, typer.Option(help="Number of demonstrations.")] = None,
    n_steps: Annotated[int | None, typer.Option(help="Steps per demonstration.")] = None,
    constraint: Annotated[str | None, typer.Option(help="toy2d: fixed|parabola; arm7: fixed|jacobian.")]
    = None,
    policy: Annotated[str | None, typer.Option(help="toy2d: attractor, limit_cycle, linear.")] = None,
    task: Annotated[bool | None, typer.Option("--task/--no-task", help="Add a task part b.")] = None,
    vary_constraint: Annotated[bool | None, typer.Option("--vary-constraint/--same-constraint",
                                                         help="toy2d: a constraint per demo.")] = None,
    sampling: Annotated[str | None, typer.Option(help="toy2d: trajectory or uniform.")] = None,
    n_samples: Annotated[int | None, typer.Option(help="toy2d uniform: number of states.")] = None,
    rate: Annotated[float | None, typer.Option(help="tracker_*: sampling rate, Hz (default 50).")] = None,
    duration: Annotated[float | None, typer.Option(help="tracker_*: seconds per recording (default 90).")]
    = None,
    n_recordings: Annotated[int | None, typer.Option(help="tracker_*: continuous recordings (default 1).")]
    = None,
    test_fraction: Annotated[float, typer.Option(help="Demos marked test in /mask (0: no masks).")] = 0.0,
    settings: Annotated[list[str] | None, typer.Option(
        "--set", help="NAME=VALUE: any other keyword of the problem (docs/recordings.md), e.g. "
                      "--set compliance=0.003 --set sweep_deg=[60,120]; repeatable.")] = None,
    force: ForceOpt = False, json_out: JsonOpt = False, quiet: QuietOpt = False,
) -> None:
    """Write a reference problem with ground truth (π, w, v, b, A, N) as canonical HDF5."""
    import inspect as pyinspect

    from ccl_cli import simulate as simulations
    from ccl_cli.io import write_demonstrations

    _logging(quiet)
    if problem not in simulations.PROBLEMS:
        raise InputError(f"unknown problem {problem!r} (use {', '.join(simulations.PROBLEMS)})")
    fn = simulations.PROBLEMS[problem]
    given = {"noise": noise, "snr_db": snr_db, "n_demos": n_demos, "n_steps": n_steps,
             "constraint": constraint, "policy": policy, "task": task, "vary_constraint": vary_constraint,
             "sampling": sampling, "n_samples": n_samples, "rate": rate, "duration": duration,
             "n_recordings": n_recordings}
    accepted = pyinspect.signature(fn).parameters
    kwargs = {k: v for k, v in given.items() if v is not None}
    extra = simulations.parse_settings(settings)
    twice = [k for k in extra if k in kwargs or k == "seed"]
    if twice:
        flag = twice[0].replace("_", "-")
        raise InputError(f"--set {twice[0]} repeats an option of its own (use --{flag})")
    kwargs.update(extra)
    bad = [k for k in kwargs if k not in accepted]
    if bad:
        raise InputError(f"{problem} takes no --{bad[0].replace('_', '-')} "
                         f"(it takes: {', '.join(a for a in accepted if a != 'seed')})")
    data = fn(seed=seed, **kwargs)
    masks = None
    if test_fraction > 0:
        train, test = data.split(test_fraction, seed)
        masks = {"train": list(train.demo_ids), "test": list(test.demo_ids)}
    how = data.derivative  # stored, so that a file says how its actions were made
    derivative = {"derivative": {"window": how.window, "order": how.order}} if how.derived else {}
    write_demonstrations(out, data, provenance={"simulate": problem, "seed": seed, **kwargs, **derivative},
                         masks=masks, force=force)
    _wrote("simulate", out, data, json_out)


@app.command("inspect")
def inspect_cmd(
    data: Annotated[list[Path], typer.Argument(
        help="Recordings (files, bag directories, folders of recordings or globs) or model files: "
             "each is described.", show_default=False)],
    config: ConfigOpt = None,
    gap: Annotated[float | None, typer.Option(metavar="SECONDS", help="Pause (seconds) that splits "
                                              "demonstrations.", show_default="data.demos.split_on_gap, "
                                              "else 5 × the median sampling interval")] = None,
    json_out: JsonOpt = False, quiet: QuietOpt = False,
) -> None:
    """What files hold. A recording: topics (type, count, rate over the active time, fields,
    joint names), CSV columns (those holding text said so), time span and the stretches between
    pauses (default: longer than 5 × the median sampling interval); a headerless table without
    a time column: its columns, rows and what a config must say to read it; with -c, the
    demonstrations learning reads with that config. A model file: its method, constraints, basis
    and what it was trained on (inputs, config, figures). Several files: each in turn (--json:
    one object, "files" holding each one's)."""
    from ccl_cli.app.evaluate import inspect_files

    _logging(quiet)
    cfg = _config(config, {})
    infos = inspect_files(data, cfg.spec.data, gap, cfg.base, configured=config is not None)
    if json_out:
        _emit(infos[0] if len(infos) == 1 else {"status": "ok", "command": "inspect", "files": infos}, True)
        return
    from ccl_cli.render.text import inspect_lines

    for i, info in enumerate(infos):
        if i:
            typer.echo("")
        for line in inspect_lines(info):
            typer.echo(line)


@app.command("convert")
def convert(
    data: Annotated[list[Path], typer.Argument(help="Recordings to convert: files, globs, bag folders or "
                                                    "folders of recordings.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Canonical HDF5 file to write.")],
    config: ConfigOpt = None, force: ForceOpt = False, json_out: JsonOpt = False, quiet: QuietOpt = False,
    format_version: Annotated[int, typer.Option("--format-version", min=1, max=2,
                                                help="2: columnar; 1: a group per demonstration.")] = 2,
) -> None:
    """Convert recordings (CSV, bags, MCAP) into the canonical ccl-demonstrations HDF5."""
    from ccl_cli.io import read_dataset, write_demonstrations
    from ccl_cli.io.files import refuse_configs

    _logging(quiet)
    cfg = _config(config, {})
    refuse_configs(data)  # as the learning commands' read_data, without importing the app layer
    dataset, _ = read_dataset(cfg.spec.data, data, cfg.base)
    write_demonstrations(out, dataset, time_origin_ns=int(dataset.metadata.get("time_origin_ns", 0)),
                         provenance={"converted_from": dataset.metadata.get("files"),
                                     "data_config": cfg.raw.get("data")}, force=force,
                         format_version=format_version)
    _wrote("convert", out, dataset, json_out)


@app.command("batch")
def batch(
    manifest: Annotated[Path | None, typer.Argument(help="Manifest YAML (files → pipeline configs).")] = None,
    files: Annotated[list[str] | None, typer.Option(
        "--files", metavar="PATH", help="Recordings, one job each (without a manifest): files, globs, "
                                        "folders.")] = None,
    config: ConfigOpt = None,
    out: OutOpt = None,
    workers: Annotated[int | None, typer.Option("--workers", "-j", min=1, help="Local processes, at most "
                                                "the usable cores (the CPU affinity's).",
                                                show_default="one per usable core")] = None,
    oversubscribe: Annotated[bool, typer.Option("--oversubscribe", help="Start -j workers even when they "
                                                "are more than the usable cores.")] = False,
    scheduler: Annotated[str | None, typer.Option(help="Address of a running Dask scheduler.")] = None,
    worker_wait: Annotated[float, typer.Option("--worker-wait", min=0, help="With --scheduler: seconds to "
                                               "wait for a Dask worker when none is left (then the batch "
                                               "ends; a rerun resumes it).")] = 30.0,
    force: Annotated[bool, typer.Option("--force", help="Re-run jobs whose outputs are up to date.")] = False,
    allow_outside: Annotated[bool, typer.Option("--allow-outside", help="Let the manifest name paths "
                                                "outside its folder.")] = False,
    json_out: JsonOpt = False, quiet: QuietOpt = False,
) -> int:
    """Run a pipeline per recording (or group) in parallel; resumable; summary.csv/.md/.png."""
    from ccl_cli.app.batch import can_fork, fork_workers, plan, run_batch, start_workers, worker_count
    from ccl_cli.render.outputs import write_run
    from ccl_cli.render.summary import write_summary

    _logging(quiet)
    t0 = time.perf_counter()
    if manifest is None and files and config is None:
        raise ConfigError("batch --files needs --config/-c: a pipeline YAML with a stages: list")
    if scheduler is not None and (workers is not None or oversubscribe):
        log.warning("-j/--oversubscribe do not apply with --scheduler: the Dask workers run the jobs, as "
                    "many at once as they have threads")
    asked = workers
    workers, said = worker_count(workers, oversubscribe)
    if said and scheduler is None:
        log.warning(said)
    fork = scheduler is None and can_fork()
    if scheduler is None and not fork:
        start_workers(workers, (write_run.__module__,))  # the fork server's imports overlap the planning
    jobs, manifest_out = plan(manifest, files, str(config) if config else None, allow_outside)
    outdir = out or manifest_out or Path("runs") / "batch"
    plots = any(job.plots for job in jobs)  # summary.png only when a job draws figures
    if plots:
        from ccl_cli.render.figures import preload_in_background

        loading = preload_in_background()  # matplotlib for summary.png (and the jobs' figures)
        if fork:  # imported once here, not again in each worker
            loading.join()
    workers, _ = worker_count(asked, oversubscribe, len(jobs))  # no more workers than jobs
    # workers forked once the plan holds, before this process starts any other thread
    pool = fork_workers(workers, (write_run.__module__,)) if fork else None
    bar = _bar("jobs", len(jobs), quiet)
    try:
        results = run_batch(jobs, outdir, write_run, workers, scheduler, force,
                            progress=bar.advance if bar else None, pool=pool, worker_wait=worker_wait)
    finally:
        if bar:
            bar.stop()
    summary = write_summary(outdir, results, time.perf_counter() - t0, plots=plots)
    summary["outdir"] = str(outdir)
    if scheduler is None:
        summary["workers"] = workers
    if json_out:
        _emit({k: v for k, v in summary.items() if k != "results"}, True)
    elif not quiet or summary["failed"]:
        typer.echo(shown(f"{summary['jobs']} jobs: {summary['ok']} ran, {summary['skipped']} skipped, "
                         f"{summary['failed']} failed; summary in {outdir / 'summary.md'}"), err=True)
        for f in summary["failures"]:
            typer.echo(shown(f"  failed {f['job']}: {f['error']}"), err=True)
    return 1 if summary["failed"] else 0


for _info in app.registered_commands:  # every command: one-line usage errors
    if _info.cls in (None, TyperCommand):
        _info.cls = _Command


# -- entry point ---------------------------------------------------------------------------
def _app_for(args: list[str]) -> typer.Typer:
    """The app that runs ``args``: for ``ccl COMMAND ...``, one holding the root options and
    that command only — typer builds every registered command's options from its signature
    at each start (25 ms for all of them, a fifth of a small run's start-up); for anything
    else (``--help``, ``--version``, an unknown command) the whole :data:`app`."""
    if args and not args[0].startswith("-"):
        chosen = [info for info in app.registered_commands if info.name == args[0]]
        if chosen:
            one = _typer()
            one.registered_callback = app.registered_callback
            one.registered_commands = chosen
            return one
    return app


#: The cyclic collector's first threshold in a learning command: a run allocates objects by the
#: hundred thousand while it imports its modules and learns, few of them in cycles; at Python's
#: default (700) the collector ran 102 times in the tutorial run (about 3 % of its CPU), now 23.
GC_THRESHOLD = 50_000


def _start_learning() -> None:
    """A learning command's process: NumPy's BLAS started at the run's thread count
    (:func:`ccl_cli.learn.blas.import_numpy_at_run_threads`), the collector run less often."""
    import gc

    blas.import_numpy_at_run_threads()
    gc.set_threshold(GC_THRESHOLD, *gc.get_threshold()[1:])


def main(argv: list[str] | None = None) -> int:
    """Console entry point: run the app and turn every failure into a one-line message."""
    import signal

    import ccl_cli

    reconfigure = getattr(sys.stdout, "reconfigure", None)
    if reconfigure is not None:
        try:  # a file name that is not UTF-8 is printed as its own bytes (as ls prints it)
            reconfigure(errors="surrogateescape")
        except (ValueError, OSError):
            pass
    try:
        if signal.getsignal(signal.SIGINT) is ccl_cli._interrupted_while_starting:
            signal.signal(signal.SIGINT, signal.default_int_handler)  # from here on: KeyboardInterrupt
        args = sys.argv[1:] if argv is None else list(argv)
        if argv is None and args and args[0] in blas.RUN_COMMANDS and "--help" not in args:
            _start_learning()  # the process is ccl's own (its command line), not a caller's
        result = _app_for(args)(args=args, prog_name="ccl", standalone_mode=False)
        if result == 130:  # typer turns Ctrl-C into this return value
            typer.echo("ccl: interrupted; no partial outputs were left", err=True)
        return result if isinstance(result, int) else 0
    except typer.Exit as exc:
        code = int(exc.exit_code or 0)
        if code == 130:  # typer turns Ctrl-C into Exit(130)
            typer.echo("ccl: interrupted; no partial outputs were left", err=True)
        return code
    except typer.Abort:
        typer.echo("ccl: interrupted; no partial outputs were left", err=True)
        return 130
    except CCLError as exc:
        typer.echo(f"ccl: error: {shown(exc.message)}", err=True)
        if not getattr(exc, "summarised", False):
            _json_error(argv, exc.exit_code, type(exc).__name__, exc.message)
        return exc.exit_code
    except KeyboardInterrupt:
        typer.echo("ccl: interrupted; no partial outputs were left", err=True)
        return 130
    except Exception as exc:  # an unexpected failure: still one line, unless debugging
        if _caused_by_interrupt(exc):
            typer.echo("ccl: interrupted; no partial outputs were left", err=True)
            return 130
        if hasattr(exc, "show") and hasattr(exc, "exit_code"):  # typer's usage errors (exit 2)
            exc.show()
            _json_error(argv, int(exc.exit_code), "UsageError", exc.format_message())
            return int(exc.exit_code)
        if os.environ.get("CCL_DEBUG"):
            raise
        first = str(exc).splitlines()[0] if str(exc) else ""
        message = f"internal error: {type(exc).__name__}: {first}"
        typer.echo(f"ccl: {shown(message)} (set CCL_DEBUG=1 for a traceback)", err=True)
        _json_error(argv, 1, "InternalError", message)
        return 1


def _caused_by_interrupt(exc: BaseException) -> bool:
    """A Ctrl-C that Python wrapped in another exception: 3.11 raises RuntimeError("Error calling
    __set_name__ ...") from the KeyboardInterrupt when it lands while a module being imported
    creates a class."""
    seen = 0
    while exc is not None and seen < 20:
        if isinstance(exc, KeyboardInterrupt):
            return True
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return False


def _json_error(argv: list[str] | None, code: int, kind: str, message: str) -> None:
    """With ``--json`` on the command line, an error is one JSON object on stdout too, so a
    script piping into ``jq`` always gets something to parse (the exit code is unchanged)."""
    args = sys.argv[1:] if argv is None else [str(a) for a in argv]
    if "--json" in args:
        import json

        sys.stdout.write(json.dumps({"status": "error", "exit_code": code,
                                     "error": {"type": kind, "message": message}}) + "\n")
        sys.stdout.flush()


def entry() -> None:
    """The ``ccl`` script: exit status of :func:`main`; Ctrl-C at any moment → 130 and one
    line; a file-size limit (``ulimit -f``) is a write error (EFBIG), not a kill."""
    import signal

    if hasattr(signal, "SIGXFSZ"):
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        code = main()
    except KeyboardInterrupt:
        typer.echo("ccl: interrupted; no partial outputs were left", err=True)
        code = 130
    _leave(code)


def _leave(code: int) -> None:
    """End the ``ccl`` process with ``code`` once the command is done and its outputs are
    closed: the exit handlers run (logging, multiprocessing, finalizers) and the standard
    streams are flushed, then the process ends without the interpreter freeing, one by one,
    every object matplotlib, numpy and the data left (5 % of a small run's CPU). With a
    thread still running (a worker pool's), under a profiler or tracer (``python -m cProfile``
    writes its output after the command returns), or outside CPython, the ordinary exit."""
    import atexit
    import threading

    run_handlers = getattr(atexit, "_run_exitfuncs", None)
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon]
    watched = sys.getprofile() is not None or sys.gettrace() is not None
    if run_handlers is None or others or watched:
        sys.exit(code)
    run_handlers()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (ccl ... | head): nothing more to say
            pass
    os._exit(code)


if __name__ == "__main__":
    entry()
