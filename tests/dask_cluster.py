"""A dask.distributed cluster in processes of its own, for the batch fault tests (and the
bars of benchmarks/hostile_bars.py): its scheduler and workers can be killed by pid
without touching the process that runs the test.

Run as ``python tests/dask_cluster.py N [--no-nanny]``: a LocalCluster (processes,
127.0.0.1) whose scheduler runs in this process, with N workers — nanny processes that
restart a killed worker, or (``--no-nanny``) bare ``dask worker`` processes that nothing
restarts. Prints one JSON line {address, scheduler_pid, workers: {address: pid}}, then
waits to be killed. :func:`start` runs it and returns the line with the process.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path


def start(n_workers: int, nanny: bool = True, timeout: float = 60.0) -> tuple[subprocess.Popen, dict]:
    """The cluster process (its own session: ``os.killpg`` ends it with its workers) and its
    JSON line."""
    proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), str(n_workers),
                             *([] if nanny else ["--no-nanny"])], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, text=True,
                            start_new_session=True)
    import selectors

    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    if not sel.select(timeout):
        stop(proc)
        raise RuntimeError("the Dask cluster did not start")
    return proc, json.loads(proc.stdout.readline())


def stop(proc: subprocess.Popen) -> None:
    """End the cluster process and every worker it started."""
    import signal

    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


def _serve(n: int, nanny: bool) -> None:
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=n if nanny else 0, threads_per_worker=1, processes=True,
                           host="127.0.0.1", dashboard_address=None)
    if not nanny:
        for _ in range(n):
            subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", cluster.scheduler_address,
                              "--no-nanny", "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard"],
                             stdin=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with Client(cluster) as client:
        client.wait_for_workers(n, timeout=60)
        workers = client.run(os.getpid)
    print(json.dumps({"address": cluster.scheduler_address, "scheduler_pid": os.getpid(),
                      "workers": workers}), flush=True)
    while True:
        time.sleep(1)


if __name__ == "__main__":
    _serve(int(sys.argv[1]), "--no-nanny" not in sys.argv[2:])
