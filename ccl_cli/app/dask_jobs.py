"""Batch jobs on a dask.distributed cluster, watched for lost workers and a lost scheduler.

Jobs are submitted through the cluster's client, one task per job; a supervisor loop waits
for them a poll at a time and asks the scheduler, between polls, which workers are alive
and which jobs each one holds:

* **A lost worker costs its jobs, not the batch.** The scheduler moves the jobs it held to
  another worker; a job whose worker is lost :data:`MAX_LOSSES` times (a job that kills its
  worker, or a flaky node) is cancelled and marked failed, naming the worker and the job.
* **No worker left** (none for ``worker_wait`` seconds, e.g. the only worker was killed and
  nothing restarted it): the wait ends, a :class:`ClusterLost` line names the workers lost
  and the jobs they held; the jobs that finished keep their folders, so a rerun resumes.
* **A lost scheduler**: once the client gives up reconnecting, :class:`ClusterLost` says so
  in one line; the finished jobs resume the same way.

The waits are about liveness only: which jobs run where, and their results, never depend
on them. dask.distributed's own log lines are held back while the batch runs (its messages
are reported here, once, in ccl's words).
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from ccl_cli.errors import LearningError

#: a job whose worker was lost this many times is not retried again
MAX_LOSSES = 2
#: seconds between two looks at the cluster (workers alive, jobs held)
POLL = 0.5
#: default seconds to wait for a worker when none is left
WORKER_WAIT = 30.0
#: seconds to wait for a finished job's result (a few hundred bytes) from its worker: longer,
#: the worker holding it is gone and the scheduler runs the job again
RESULT_WAIT = 10.0

log = logging.getLogger("ccl")


class ClusterLost(LearningError):
    """The batch cannot go on: the scheduler is gone, or no worker is left (exit 1)."""


@dataclass
class _Watch:
    """What the supervisor knows of the cluster: the workers seen alive, the jobs each held
    at the last look, per job the workers lost while holding it, and since when none is alive."""

    workers: set[str] = field(default_factory=set)
    holding: dict[str, set[str]] = field(default_factory=dict)
    losses: dict[str, list[str]] = field(default_factory=dict)
    lost_workers: list[str] = field(default_factory=list)
    empty_since: float | None = None
    #: losses not yet reported (reported once another worker runs the jobs, or in the error)
    unreported: list[tuple[str, list[str]]] = field(default_factory=list)


def _short(items: list[str], n: int = 3) -> str:
    shown = ", ".join(items[:n])
    return shown + (f" and {len(items) - n} more" if len(items) > n else "")


def lost_message(worker: str, job_ids: list[str]) -> str:
    """'worker tcp://… lost while running job X' (jobs X, Y, …)."""
    noun = "job" if len(job_ids) == 1 else "jobs"
    return f"worker {worker} lost while running {noun} {_short(job_ids)}"


#: loggers whose lines are held back while a batch runs on Dask
QUIET = ("distributed", "tornado", "asyncio")


def _foreign(record: logging.LogRecord) -> bool:
    return not record.name.startswith(QUIET)


def quiet_dask() -> Callable[[], None]:
    """Hold dask.distributed's log lines back (and those of tornado and asyncio under it) while
    the batch runs: its reconnect attempts, warnings and tracebacks would print many lines;
    the supervisor reports what matters in one. Returns the function that lets them through
    again (not called when the client could not close: its event loop may still be logging
    the lost connection while the process ends)."""
    loggers = [logging.getLogger(name) for name in QUIET]
    loggers += [logging.getLogger(name) for name in list(logging.root.manager.loggerDict)
                if name.startswith(QUIET)]
    before = [(lg, lg.disabled) for lg in loggers]
    for lg, _ in before:
        lg.disabled = True
    handlers = list(logging.root.handlers)
    for handler in handlers:
        handler.addFilter(_foreign)

    def restore() -> None:
        for handler in handlers:
            handler.removeFilter(_foreign)
        for lg, disabled in before:
            lg.disabled = disabled

    return restore


def connect(address: str) -> Any:
    """A dask.distributed client of the scheduler at ``address`` (ConfigError when it is not
    installed or not reachable); call it under :func:`quiet_dask`."""
    from ccl_cli.errors import ConfigError

    try:
        from distributed import Client
    except ImportError:
        raise ConfigError("--scheduler needs dask.distributed: pip install 'ccl_cli[dask]'") from None
    _check_reachable(address)
    try:
        return Client(address, timeout="10s")
    except Exception as exc:  # noqa: BLE001 - any failure of the connection is one line
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"cannot connect to the Dask scheduler at {address} ({first})") from None


@contextlib.contextmanager
def connected(address: str) -> Iterator[Any]:
    """A client of the scheduler at ``address`` (:func:`connect`) while the block runs, with
    dask.distributed's log lines held back (:func:`quiet_dask`); closed after (a lost scheduler:
    nothing left to close), its log lines let through again once it has closed."""
    restore = quiet_dask()
    client = None
    try:
        client = connect(address)
        yield client
    finally:
        with contextlib.suppress(Exception):
            if client is not None:
                client.close(timeout=5)
        if client is None or str(client.status) == "closed":
            restore()


def _check_reachable(address: str) -> None:
    """A refused or unresolvable ``tcp://host:port`` scheduler address is a ConfigError at once
    (dask.distributed would retry it until its connect timeout)."""
    import socket
    from urllib.parse import urlsplit

    from ccl_cli.errors import ConfigError

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme != "tcp" or not parts.hostname or parts.port is None:
        return  # other transports (tls, inproc, ...): left to dask.distributed
    try:
        with socket.create_connection((parts.hostname, parts.port), timeout=5):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ConfigError(f"cannot connect to the Dask scheduler at {address} ({reason})") from None


def run_jobs(client: Any, tasks: dict[str, tuple[Callable[..., Any], tuple]], on_result: Callable,
             on_failure: Callable[[str, str], Any], worker_wait: float = WORKER_WAIT) -> None:
    """Run ``tasks`` (job id → (function, arguments)) on the cluster of ``client``;
    ``on_result(job_id, value)`` as each ends, ``on_failure(job_id, reason)`` for a job given
    up after :data:`MAX_LOSSES` lost workers (or failed by the cluster itself). Raises
    :class:`ClusterLost` when the scheduler is lost or no worker is left for ``worker_wait``
    seconds; an exception of the callbacks (or Ctrl-C) cancels what is left, then propagates."""
    from distributed import wait

    address = getattr(client, "scheduler", None) and client.scheduler.address
    keys = {f"ccl-job-{job_id}": job_id for job_id in tasks}
    futures = {key: client.submit(fn, *args, key=key, pure=False)
               for key, (fn, args) in ((k, tasks[j]) for k, j in keys.items())}
    watch = _Watch()
    try:
        while futures:
            with contextlib.suppress(Exception):  # a timeout; a closed client shows in its status
                wait(list(futures.values()), timeout=POLL, return_when="FIRST_COMPLETED")
            for key in [k for k, f in futures.items() if f.done()]:
                _ended(client, address, keys, futures, key, watch, on_result, on_failure)
            if futures:
                _look(client, address, keys, futures, watch, on_failure, worker_wait)
    except BaseException:
        with contextlib.suppress(Exception):
            client.cancel(list(futures.values()), force=True)
        raise


def _ended(client: Any, address: str, keys: dict[str, str], futures: dict[str, Any], key: str,
           watch: _Watch, on_result: Callable, on_failure: Callable[[str, str], Any]) -> None:
    """Hand over the outcome of a finished task, and release it at once (a lost worker's
    results are not recomputed). A connection that closes while the outcome is fetched is
    the scheduler lost; a result that does not come (its worker died after finishing it) is
    waited for again, as the scheduler runs the job again."""
    from distributed.comm.core import CommClosedError

    fut = futures[key]
    try:
        if fut.status == "finished":
            value, error = fut.result(timeout=RESULT_WAIT), None
        elif fut.status == "error":
            value, error = None, fut.exception(timeout=RESULT_WAIT)
        else:  # cancelled: by us, or by a client that lost its scheduler
            _check_scheduler(client, address)
            value, error = None, None
    except TimeoutError:  # (an OSError too: before it)
        _check_scheduler(client, address)
        return  # left in ``futures``: the scheduler computes it again (or no worker is left)
    except (CommClosedError, OSError):
        raise ClusterLost(_lost_scheduler(address)) from None
    del futures[key]
    if fut.status == "finished":
        on_result(keys[key], value)
    elif error is not None:
        on_failure(keys[key], _cluster_failure(keys[key], error, watch))
    else:
        on_failure(keys[key], "cancelled by the Dask cluster")
    fut.release()


def _cluster_failure(job_id: str, exc: BaseException, watch: _Watch) -> str:
    """Why the cluster failed a job: its workers died under it (KilledWorker), or another
    error of dask.distributed's."""
    from distributed.scheduler import KilledWorker

    if isinstance(exc, KilledWorker):
        last = getattr(exc, "last_worker", None)
        worker = getattr(last, "address", None) or (str(last) if last else "?")
        return f"{lost_message(worker, [job_id])} (the scheduler gave the job up)"
    first = str(exc).splitlines()[0] if str(exc) else ""
    return f"Dask: {type(exc).__name__}: {first}"[:300]


def _status(client: Any) -> str:
    return str(getattr(client, "status", "running"))


def _check_scheduler(client: Any, address: str) -> None:
    """ClusterLost when the client is not connected to its scheduler (a future was cancelled
    meanwhile: the client cancels every future when the connection drops)."""
    if _status(client) != "running":
        raise ClusterLost(_lost_scheduler(address))


def _lost_scheduler(address: str) -> str:
    return (f"lost the Dask scheduler at {address} (its connection closed); the jobs that finished keep "
            "their folders: run the batch again to resume the others")


def _look(client: Any, address: str, keys: dict[str, str], futures: dict[str, Any], watch: _Watch,
          on_failure: Callable[[str, str], Any], worker_wait: float) -> None:
    """One look at the cluster between polls: workers alive, the jobs each holds; losses
    counted per job (a job over :data:`MAX_LOSSES` cancelled and failed); the wait for a
    worker when none is left."""
    _check_scheduler(client, address)  # not connected (reconnecting, or closed)
    try:
        alive = set(client.scheduler_info(n_workers=-1)["workers"])
        processing = client.processing()
    except TypeError:  # an older client: scheduler_info() without n_workers
        alive = set(client.scheduler_info()["workers"])
        processing = client.processing()
    except Exception:  # noqa: BLE001 - the connection dropped meanwhile: looked at again next poll
        return
    for worker in sorted(watch.workers - alive):  # lost since the last look
        held = sorted(keys[k] for k in watch.holding.get(worker, ()) if k in futures)
        watch.lost_workers.append(worker)
        if held:
            watch.unreported.append((worker, held))
        for job_id in held:
            lost = watch.losses.setdefault(job_id, [])
            lost.append(worker)
            if len(lost) >= MAX_LOSSES:
                key = f"ccl-job-{job_id}"
                fut = futures.pop(key, None)
                if fut is not None:
                    with contextlib.suppress(Exception):
                        fut.cancel(force=True)
                    on_failure(job_id, f"{lost_message(worker, [job_id])} ({len(lost)} workers lost "
                               "with it; not retried)")
    watch.workers = alive
    watch.holding = {w: {k for k in ks if k in keys} for w, ks in processing.items()}
    if alive:
        watch.empty_since = None
        for worker, held in watch.unreported:
            log.warning("%s; retried on another worker", lost_message(worker, held))
        watch.unreported.clear()
        return
    now = time.monotonic()
    if watch.empty_since is None:
        watch.empty_since = now
    if now - watch.empty_since >= worker_wait:
        finished = len(keys) - len(futures)
        held = [f"{lost_message(w, jobs)}" for w, jobs in watch.unreported]
        what = "; ".join(held) if held else (f"worker(s) {_short(watch.lost_workers)} lost" if
                                             watch.lost_workers else "the cluster has no worker")
        raise ClusterLost(f"no Dask worker left: {what}, and none joined within {worker_wait:g} s; "
                          f"{finished} of {len(keys)} jobs done, {len(futures)} not: run the batch "
                          "again to resume (finished jobs are kept)")
