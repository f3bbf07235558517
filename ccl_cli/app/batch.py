"""``ccl batch``: one pipeline run per recording (or group of recordings), in parallel.

Manifest (YAML; paths relative to it)::

    out: runs/batch                    # output root (flag -o overrides)
    jobs:                              # rules: which files, which pipeline config
      - files: [logs/kuka/*.bag]       # paths or globs
        config: configs/kuka_bag.yaml
        overrides: {learn-a: {n_constraints: 1}}   # merged into that config
        group: false                   # true: all matched files form one dataset (one job)
    overrides:                         # per file (path or glob) → config overrides
      logs/kuka/run_07.bag: {data: {demos: {split_on_gap: 1.0}}}

Each job writes ``OUT/jobs/<job>/`` exactly as ``ccl run`` would, plus ``job.json`` with its
content key (sha256 of the input files, the resolved config and the ccl version). A job
whose folder holds the same key is skipped unless ``force``; folders are written atomically,
so an interrupted batch resumes where it stopped. Each job is one call of :func:`run_job`: on a
local process pool, or with ``scheduler`` on a dask.distributed cluster whose lost workers and
scheduler are watched for (:mod:`ccl_cli.app.dask_jobs`).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import Executor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ccl_cli import __version__, config
from ccl_cli.errors import CCLError, ConfigError, OutputError
from ccl_cli.learn.blas import THREAD_VARS, affinity_cores

log = logging.getLogger("ccl")
#: writes one job's folder: (RunResult, outdir, *, force, extra_files) → summary
Writer = Callable[..., dict[str, Any]]
MANIFEST_KEYS = {"out", "jobs", "overrides"}
RULE_KEYS = {"files", "config", "overrides", "group"}


@dataclass
class Job:
    job_id: str
    files: list[str]
    config_path: str | None
    config: dict[str, Any]
    key: str = ""
    #: the config's ``output.plots``: the job draws figures
    plots: bool = True


@dataclass
class JobResult:
    job_id: str
    files: list[str]
    status: str  # ok | skipped | failed
    seconds: float = 0.0
    error: str = ""
    exit_code: int = 0
    stages: dict[str, Any] = field(default_factory=dict)
    #: the job's folder could not be written (a full disk, a file-size limit): the batch stops
    output_fault: bool = False


# -- planning ------------------------------------------------------------------------------
def _resolve_config(path: str | None, overrides: list[dict], base: Path,
                    loaded: dict[str | None, config.Config]) -> config.Config:
    """The config file of a rule (relative to the manifest) with the overrides merged in,
    validated (errors name the file and line of a key of the file). ``loaded`` holds the
    files read so far: each is read once per plan."""
    if path not in loaded:
        loaded[path] = config.load(base / path if path and not Path(path).is_absolute() else path)
    cfg = loaded[path]
    if not any(overrides):
        return cfg
    merged = cfg.raw
    for over in overrides:
        merged = config.deep_merge(merged, over or {})
    return config.from_mapping(merged, source=cfg.source, base=cfg.base, lines=cfg.lines)


def job_key(files: list[str], cfg: dict[str, Any]) -> str:
    """sha256 over the inputs' contents, the resolved config and the ccl version."""
    from ccl_cli.io import file_hash

    h = hashlib.sha256()
    for f in files:
        h.update(file_hash(Path(f)).encode())
    h.update(json.dumps(cfg, sort_keys=True, default=str).encode())
    h.update(__version__.encode())
    return h.hexdigest()


def _job_id(files: list[str]) -> str:
    stem = Path(files[0]).name.replace(".", "_") if len(files) == 1 else f"group_{Path(files[0]).parent.name}"
    names = "\n".join(sorted(map(str, files))).encode("utf-8", "surrogateescape")  # any bytes a name holds
    digest = hashlib.sha256(names).hexdigest()[:8]
    return f"{stem}-{digest}"


def plan(manifest: str | Path | None = None, files: list[str] | None = None,
         config: str | None = None, allow_outside: bool = False) -> tuple[list[Job], Path | None]:
    """Jobs from a manifest, or from ``files`` (paths/globs) with one ``config``.

    Returns (jobs, the manifest's ``out`` if it names one). Manifest or config problems
    raise :class:`ConfigError` (exit 2) before anything runs. Every path a manifest names
    (files and globs, configs, per-file overrides, ``out``) must lead inside the manifest's
    folder once ``..`` and symlinks are resolved, unless ``allow_outside``
    (:func:`~ccl_cli.io.limits.inside`).
    """
    from ccl_cli.io import expand_files, read_yaml
    from ccl_cli.io.files import TWICE, given_once

    if manifest is not None:
        mpath = Path(manifest)
        spec, _ = read_yaml(mpath, "manifest")
        spec = {} if spec is None else spec
        if not isinstance(spec, dict) or not isinstance(spec.get("jobs"), list):
            raise ConfigError(f"{mpath}: a manifest needs a jobs: list of rules")
        unknown = set(spec) - MANIFEST_KEYS
        if unknown:
            raise ConfigError(f"{mpath}: unknown manifest key(s) {', '.join(sorted(map(str, unknown)))} "
                              f"(valid: {', '.join(sorted(MANIFEST_KEYS))})")
        base = mpath.resolve().parent
        rules = spec["jobs"]
        per_file = spec.get("overrides") or {}
        if not isinstance(per_file, dict) or not all(isinstance(k, str) and isinstance(v, dict | None)
                                                       for k, v in per_file.items()):
            raise ConfigError(f"{mpath}: overrides must map file paths (or globs) to config mappings")
        out_value = spec.get("out")
        if out_value is not None and not isinstance(out_value, str):
            raise ConfigError(f"{mpath}: out must be a folder path, got {out_value!r}"[:200])
        out = Path(out_value) if out_value else None
        if out is not None and not out.is_absolute():
            out = base / out
        if out is not None:
            _inside(base, out, mpath, allow_outside, "out")
        where = f"{mpath}: "
        named: Path | None = mpath
    else:
        if not files:
            raise ConfigError("give a manifest or --files with --config")
        base = Path.cwd()
        rules = [{"files": files, "config": config}]
        per_file, out, where, named = {}, None, "", None  # paths the user typed: not bounded
    file_over = [(_resolved(expand_files([k], base), base, named, allow_outside), v)
                 for k, v in per_file.items()]
    jobs: list[Job] = []
    seen: set[str] = set()
    loaded: dict[str | None, config.Config] = {}
    #: (config file, overrides) → its validated config: jobs that share both share it
    resolved: dict[str, config.Config] = {}
    for i, rule in enumerate(rules):
        _check_rule(rule, f"{where}jobs[{i}]")
        matched = _resolved(expand_files(rule["files"], base), base, named, allow_outside)
        try:
            given_once([Path(f) for f in matched],
                       why=TWICE if rule.get("group") else "it would be run twice, into one folder")
        except CCLError as exc:
            rule_at = f"jobs[{i}]: " if named is not None else ""
            raise ConfigError(f"{where}{rule_at}{exc.message}") from None
        if named is not None and rule.get("config"):
            _inside(base, Path(rule["config"]), named, allow_outside, f"jobs[{i}].config")
        groups = [matched] if rule.get("group") else [[f] for f in matched]
        for group in groups:
            overrides = [rule.get("overrides") or {}, *(v for paths, v in file_over
                                                          if any(p in group for p in paths))]
            same = json.dumps(_typed_keys([rule.get("config"), overrides]), sort_keys=True, default=str)
            cfg = resolved.get(same)
            if cfg is None:
                try:
                    cfg = _resolve_config(rule.get("config"), overrides, base, loaded)
                except CCLError as exc:
                    raise ConfigError(f"{where}jobs[{i}]: {exc.message}") from None
                try:
                    cfg.stages()
                except ConfigError as exc:
                    raise ConfigError(f"{where}jobs[{i}] ({group[0]}): {exc.message}") from None
                resolved[same] = cfg
            job = Job(_job_id(group), group, str(rule.get("config")), cfg.raw, plots=cfg.spec.output.plots)
            if job.job_id in seen:
                raise ConfigError(f"{group[0]} is matched by more than one rule")
            seen.add(job.job_id)
            jobs.append(job)
    if not jobs:
        raise ConfigError("the manifest matches no files")
    return jobs, out


def _typed_keys(value: Any) -> Any:
    """``value`` with every mapping key as text naming its type (``str:a``, ``int:1``): a
    manifest may give keys of several types (YAML ``1:`` is an integer), which json cannot
    sort together; the config check then names the key at fault."""
    if isinstance(value, dict):
        return {f"{type(k).__name__}:{k}": _typed_keys(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_typed_keys(v) for v in value]
    return value


def _resolved(paths: list[Path], base: Path, manifest: Path | None, allow_outside: bool) -> list[str]:
    """Absolute, symlink-free paths: a job is the same however its files were spelled. Those
    a ``manifest`` names stay inside its folder ``base`` (unless ``allow_outside``)."""
    if manifest is not None:
        return [str(_inside(base, p, manifest, allow_outside, "files")) for p in paths]
    return [str(p.resolve()) for p in paths]


def _inside(base: Path, path: Path, manifest: Path, allow_outside: bool, key: str) -> Path:
    """``path`` (named by ``manifest`` under ``key``) resolved, inside ``base`` unless allowed."""
    from ccl_cli.io.limits import inside

    try:
        return inside(base, path, f"{manifest} ({key})", allow_outside, flag="--allow-outside")
    except CCLError as exc:
        raise ConfigError(exc.message) from None


def _check_rule(rule: Any, where: str) -> None:
    """Types of one manifest rule (files, config, overrides, group)."""
    if not isinstance(rule, dict) or "files" not in rule:
        raise ConfigError(f"{where} must be a mapping with files: (and config:)")
    bad = set(rule) - RULE_KEYS
    if bad:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(map(str, bad)))} "
                          f"(valid: {', '.join(sorted(RULE_KEYS))})")
    files = rule["files"]
    if not (isinstance(files, str) or (isinstance(files, list) and files and
                                       all(isinstance(f, str) for f in files))):
        raise ConfigError(f"{where}.files must be a path/glob or a list of them, got {files!r}"[:200])
    if rule.get("config") is not None and not isinstance(rule["config"], str):
        raise ConfigError(f"{where}.config must be a file path, got {rule['config']!r}"[:200])
    if not isinstance(rule.get("overrides") or {}, dict):
        raise ConfigError(f"{where}.overrides must be a mapping, got {rule['overrides']!r}"[:200])
    if not isinstance(rule.get("group", False), bool):
        raise ConfigError(f"{where}.group must be true or false, got {rule['group']!r}"[:200])


# -- running -------------------------------------------------------------------------------
def run_job(job: Job, jobs_dir: str, force: bool, write: Writer) -> JobResult:
    """Run one job into ``jobs_dir/<job_id>`` (in a worker process or on a Dask worker);
    ``write(result, outdir, force=, extra_files=)`` writes its folder (the
    command line passes :func:`ccl_cli.render.outputs.write_run`: a module-level function,
    so it pickles to the workers)."""
    logging.getLogger("ccl").setLevel(logging.WARNING)
    _ignore_file_size_signal()
    with _named(job.job_id):
        return _run_job(job, jobs_dir, force, write)


class _JobLines(logging.Formatter):
    """'ccl: <job>: message' on stderr, a file name that is not UTF-8 shown as ``\\xNN``."""

    def __init__(self, job_id: str) -> None:
        super().__init__("%(message)s")
        self.job_id = job_id

    def format(self, record: logging.LogRecord) -> str:
        line = f"ccl: {self.job_id}: {super().format(record)}"
        return line.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


@contextlib.contextmanager
def _named(job_id: str):
    """While a job runs, its warnings (stderr of a local worker, a Dask worker's log) name it:
    'ccl: <job>: warning: ...'; only the lines of the thread that runs it (a Dask worker runs
    several jobs at once)."""
    import threading

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_JobLines(job_id))
    handler.setLevel(logging.WARNING)
    me = threading.get_ident()
    handler.addFilter(lambda record: record.thread == me)
    logger = logging.getLogger("ccl")
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)


def _run_job(job: Job, jobs_dir: str, force: bool, write: Writer) -> JobResult:
    """:func:`run_job`'s work."""
    t0 = time.perf_counter()
    outdir = Path(jobs_dir) / job.job_id
    try:
        key = job_key(job.files, job.config)
        marker = outdir / "job.json"
        if not force and marker.exists():
            done = _recorded(marker, outdir / "metrics.json", key)
            if done is not None:
                from ccl_cli.app.run import summarise

                return JobResult(job.job_id, job.files, "skipped", 0.0, stages=summarise(done))
        cfg = config.from_mapping(job.config, source=job.config_path or "<batch>")
        from ccl_cli.app.run import execute

        summary = write(execute("run", cfg, job.files), outdir, force=True,
                        extra_files={"job.json": {"key": key, "files": job.files, "config": job.config_path}})
        return JobResult(job.job_id, job.files, "ok", time.perf_counter() - t0, stages=summary["stages"])
    except OutputError as exc:
        return JobResult(job.job_id, job.files, "failed", time.perf_counter() - t0, exc.message,
                         exc.exit_code, output_fault=True)
    except CCLError as exc:
        return JobResult(job.job_id, job.files, "failed", time.perf_counter() - t0, exc.message,
                         exc.exit_code)
    except Exception as exc:  # one bad job must not stop the others
        first = str(exc).splitlines()[0] if str(exc) else ""
        return JobResult(job.job_id, job.files, "failed", time.perf_counter() - t0,
                         f"internal error: {type(exc).__name__}: {first}", 1)


def _recorded(marker: Path, metrics: Path, key: str) -> dict[str, Any] | None:
    """The metrics of a job folder whose ``job.json`` records ``key`` (it is up to date);
    None when it records another key or either file is unreadable (the job runs again)."""
    from ccl_cli.io.jsonsafe import loads

    try:
        record = loads(marker.read_bytes(), str(marker))
        stages = loads(metrics.read_bytes(), str(metrics)) if isinstance(record, dict) and \
            record.get("key") == key else None
    except (CCLError, OSError):
        return None
    return stages if isinstance(stages, dict) else None


#: what a batch folder of a ccl version before the .ccl-output marker holds
BATCH_FILES = {"jobs", "summary.csv", "summary.md", "summary.json", "summary.png"}


def written_by_earlier_batch(path: Path) -> bool:
    """True for what looks like the batch folder of an earlier ccl (no marker): nothing but
    ``jobs/`` and the summaries, every job folder holding a run.json like ccl's
    (:func:`~ccl_cli.io.atomic.looks_like_an_output`). Only a hint: such a folder is refused
    like any other folder ccl did not mark (any tool may write such files)."""
    from ccl_cli.io.atomic import is_temporary, looks_like_an_output

    try:
        names = {p.name for p in path.iterdir()}
        jobs = [p for p in (path / "jobs").iterdir() if not is_temporary(p.name)] if "jobs" in names else []
    except OSError:
        return False
    return "jobs" in names and names <= BATCH_FILES and bool(jobs) and \
        all(p.is_dir() and not p.is_symlink() and looks_like_an_output(p) for p in jobs)


def _ignore_file_size_signal() -> None:
    """A file-size limit (``ulimit -f``) is a write error (EFBIG) in a worker too, not a kill
    (``ccl`` itself ignores SIGXFSZ, and local workers inherit that; a Dask worker's job runs
    in a thread, where signals cannot be set)."""
    import signal
    import threading

    if hasattr(signal, "SIGXFSZ") and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)


def worker_count(requested: int | None, oversubscribe: bool = False, jobs: int | None = None
                 ) -> tuple[int, str | None]:
    """The local workers of a batch: ``requested`` (default: one per usable core, the cores
    this process may run on: :func:`~ccl_cli.learn.blas.affinity_cores`), at most the usable
    cores unless ``oversubscribe`` (more processes than cores only share them, and each costs
    its memory and start), and no more than the ``jobs``. Returns (workers, the line that says
    why fewer than asked for run, or None)."""
    cores = affinity_cores()
    n = cores if requested is None else requested
    said = None
    if n > cores and not oversubscribe:
        many = "s" if cores != 1 else ""
        said = (f"-j {requested}: {cores} usable core{many}, so {cores} worker{many} (more would only "
                f"share them; --oversubscribe starts {requested})")
        n = cores
    return (max(1, min(n, jobs)) if jobs else n), said


def make_executor(workers: int | None, preload: tuple[str, ...] = ()) -> Executor:
    """The local process pool (workers from the fork server)."""
    from concurrent.futures import ProcessPoolExecutor

    from ccl_cli.lifeline import worker_init

    n = workers or affinity_cores()
    ctx = local_context(n, preload)
    return ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=worker_init,
                               initargs=(os.getpid(),))


#: modules every worker starts with, imported once (by the fork server, or by this process
#: before its workers fork; the command line adds the module of its writer)
PRELOAD = ["ccl_cli.lifeline", "ccl_cli.app.run", "ccl_cli.app.stages", "ccl_cli.models", "ccl_cli.io",
           "ccl_cli.io.canonical", "ccl_cli.learn.blas", "h5py", "numpy.ma", "numpy.random"]


def _blas_threads(n: int) -> int | None:
    """BLAS threads of each of ``n`` local workers: cores / n, in the environment of the
    processes started from now on where the user set none (returned; None when the user
    set one: this process's BLAS, and a forked worker's, then already follow it)."""
    threads = max(1, affinity_cores() // n)
    chosen = not any(var in os.environ for var in THREAD_VARS)
    for var in THREAD_VARS:
        os.environ.setdefault(var, str(threads))  # workers share the cores, not oversubscribe them
    return threads if chosen else None


def local_context(n: int, preload: tuple[str, ...] = ()):
    """The multiprocessing context of the local pool of ``n`` workers: BLAS threads per
    worker (cores / n, unless set), the parent's pid for :mod:`ccl_cli.lifeline`, and a
    fork server that has imported :data:`PRELOAD` and ``preload`` (spawn where there is no
    fork server)."""
    from multiprocessing import get_all_start_methods, get_context

    from ccl_cli.lifeline import PARENT_ENV

    _blas_threads(n)
    os.environ[PARENT_ENV] = str(os.getpid())  # the fork server dies with this process
    if "forkserver" not in get_all_start_methods():
        return get_context("spawn")
    # workers fork from a server that has imported the learners once (fast start, and no
    # fork of this process's threads)
    ctx = get_context("forkserver")
    ctx.set_forkserver_preload([*PRELOAD, *preload])
    return ctx


def start_workers(workers: int | None, preload: tuple[str, ...] = ()) -> None:
    """Start the local fork server now: its imports (:data:`PRELOAD` and ``preload``) then
    overlap the planning of the batch instead of delaying the first job."""
    ctx = local_context(workers or affinity_cores(), preload)
    if ctx.get_start_method() == "forkserver":
        from multiprocessing import forkserver

        forkserver.ensure_running()


def can_fork() -> bool:
    """True when local workers may fork from this process (:func:`fork_workers`): on Linux,
    while no other Python thread runs here (a lock another thread holds at the fork stays
    held in the child). The BLAS's own threads are no obstacle: OpenBLAS stops them around
    a fork."""
    import multiprocessing
    import threading

    return sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods() \
        and threading.active_count() == 1


def fork_workers(workers: int | None, preload: tuple[str, ...] = ()) -> Executor:
    """The local pool of ``workers`` processes (default: one per core) forked from this
    process now, once it has imported :data:`PRELOAD` and ``preload``: the workers start
    with everything this process loaded (the fork server would import it all again in a
    new interpreter first: 0.3 s). Call it before any other thread starts
    (:func:`can_fork`); :func:`run_batch` takes the pool as ``pool``."""
    import importlib
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    for module in (*PRELOAD, *preload):
        importlib.import_module(module)
    n = workers or affinity_cores()
    pool = ProcessPoolExecutor(max_workers=n, mp_context=get_context("fork"), initializer=_forked_init,
                               initargs=(os.getpid(), _blas_threads(n)))
    pool.submit(int)  # forks every worker now, before this process starts a thread
    return pool


def _forked_init(parent: int, blas_threads: int | None) -> None:
    """Initializer of a worker forked from ``ccl`` (pid ``parent``): die with it
    (:func:`~ccl_cli.lifeline.worker_init`), the BLAS threads a fork server's worker would
    have (``blas_threads``; None: as inherited), and no progress bar or log handler of the
    command line's (a worker's warnings go to stderr as they do from the fork server's)."""
    from ccl_cli import progress
    from ccl_cli.lifeline import worker_init

    worker_init(parent)
    progress.install(None)
    for handler in logging.root.handlers[:]:
        logging.root.removeHandler(handler)
    logging.root.setLevel(logging.WARNING)
    if blas_threads is not None:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=blas_threads, user_api="blas")  # for the worker's lifetime


def run_batch(jobs: list[Job], out: Path, write: Writer, workers: int | None = None,
              scheduler: str | None = None, force: bool = False, progress=None,
              pool: Executor | None = None, worker_wait: float | None = None) -> list[JobResult]:
    """Run ``jobs`` into ``out/jobs/`` over ``workers`` local processes (or the Dask cluster at
    ``scheduler``), each job's folder written by ``write`` (see :func:`run_job`); results in
    the jobs' order. ``progress(result)`` is called as each job ends. ``pool``: local workers
    already started (:func:`fork_workers`), shut down here whatever happens.

    ``out`` must be new, empty, or a batch folder ccl marked (:func:`~ccl_cli.io.atomic.claim_folder`):
    a user's folder is refused untouched. A job whose folder cannot be written (a full disk,
    a file-size limit) stops the batch: :class:`OutputError`, and what this run left empty
    is removed (:func:`~ccl_cli.io.atomic.release_folder`). On Dask, a lost worker costs the
    jobs it held (retried elsewhere, then failed), a lost scheduler or no worker left for
    ``worker_wait`` seconds ends the batch with one line (:mod:`ccl_cli.app.dask_jobs`); the
    jobs that finished are kept for a rerun."""
    from ccl_cli.io.atomic import claim_folder, clean_stale, release_folder

    try:
        claim_folder(out, earlier=written_by_earlier_batch)
    except BaseException:
        _idle_pool_down(pool)
        raise
    jobs_dir = out / "jobs"
    try:
        jobs_dir.mkdir(exist_ok=True)
    except OSError as exc:
        _idle_pool_down(pool)
        release_folder(out)
        raise OutputError(f"{jobs_dir}: cannot write the output ({exc.strerror}); nothing was written") \
            from None
    removed = clean_stale(jobs_dir, every=True)
    if removed:
        log.info("removed %d unfinished job folder(s) of an interrupted batch", removed)
    by_id = {job.job_id: job for job in jobs}
    results: list[JobResult] = []

    def ended(res: JobResult) -> None:
        results.append(res)
        if progress is not None:
            progress(res)
        if res.output_fault:  # the disk is full or a size limit hit: every job would fail
            raise OutputError(res.error)

    def failed(job_id: str, reason: str) -> None:
        job = by_id[job_id]
        ended(JobResult(job.job_id, job.files, "failed", 0.0, reason, 1))

    try:
        args = (str(jobs_dir.resolve()), force, write)
        if scheduler:
            _on_dask(scheduler, {j.job_id: (run_job, (j, *args)) for j in jobs}, ended, failed, worker_wait)
        else:
            _on_pool(pool or make_executor(workers, (write.__module__,)), jobs, args, ended, failed)
    except BaseException as exc:  # Ctrl-C or a failure here: do not wait for the running jobs
        _kill_workers()
        clean_stale(jobs_dir, every=True)
        release_folder(out, fault=isinstance(exc, OutputError))
        raise
    clean_stale(jobs_dir, every=True)  # temporaries of processes that were still dying at the start
    order = {j.job_id: i for i, j in enumerate(jobs)}
    return sorted(results, key=lambda r: order[r.job_id])


def _idle_pool_down(pool: Executor | None) -> None:
    """Shut down a pool that ran no job, waiting for its manager thread (its workers are idle:
    at once). Not waiting raced concurrent.futures' exit hook, which wakes the thread through a
    pipe the thread may be closing: 'Exception ignored ... Bad file descriptor' on stderr."""
    if pool is not None:
        pool.shutdown(wait=True, cancel_futures=True)


def _on_pool(executor: Executor, jobs: list[Job], args: tuple, ended: Callable[[JobResult], None],
             failed: Callable[[str, str], None]) -> None:
    """The jobs on a local process pool; ``ended`` / ``failed`` as each one ends."""
    try:
        futures = {executor.submit(run_job, job, *args): job for job in jobs}
        for fut in as_completed(futures):
            job = futures[fut]
            try:
                res = fut.result()
            except Exception as exc:  # a worker died
                failed(job.job_id, f"worker failed: {exc}")
            else:
                ended(res)
    except BaseException:
        executor.shutdown(wait=False, cancel_futures=True)
        raise
    executor.shutdown(wait=True)


def _on_dask(scheduler: str, tasks: dict[str, tuple[Callable, tuple]], ended: Callable[[JobResult], None],
             failed: Callable[[str, str], None], worker_wait: float | None) -> None:
    """The jobs on the Dask cluster at ``scheduler``, watched (:func:`~ccl_cli.app.dask_jobs.run_jobs`)."""
    from ccl_cli.app import dask_jobs

    with dask_jobs.connected(scheduler) as client:
        dask_jobs.run_jobs(client, tasks, lambda _, res: ended(res), failed,
                           dask_jobs.WORKER_WAIT if worker_wait is None else worker_wait)


def _kill_workers() -> None:
    """SIGKILL the local pool's worker processes (their partial job folders are temporaries):
    every live child process of ccl is one of them (``multiprocessing.active_children``).
    Returns once they are gone: a worker still finishing a system call could otherwise
    create a temporary after the caller removed them."""
    import multiprocessing

    workers = multiprocessing.active_children()
    for proc in workers:
        with contextlib.suppress(OSError):
            proc.kill()
    for proc in workers:
        proc.join(timeout=5)
