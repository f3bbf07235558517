"""Child processes die with ccl, even when ccl is killed with SIGKILL.

Local ``ccl batch`` workers fork from ccl itself on Linux (while ccl runs no other
thread), else from a fork server that ccl starts. On Linux each link of that chain asks
the kernel for a parent-death signal (``prctl(PR_SET_PDEATHSIG, SIGKILL)``): the workers
die with ccl, or with the fork server, which dies with ccl. The fork server imports this
module (``set_forkserver_preload``) and recognises itself by ``CCL_BATCH_PARENT`` naming
its parent; the workers call :func:`worker_init`. Elsewhere (other systems) this is a
no-op and workers end when their queue closes.
"""

from __future__ import annotations

import os
import signal
import sys

PARENT_ENV = "CCL_BATCH_PARENT"
PR_SET_PDEATHSIG = 1


def die_with_parent() -> bool:
    """Ask the kernel to SIGKILL this process when its parent exits (Linux only)."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    return libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0


def worker_init(parent: int) -> None:
    """Initializer of pool workers: die with the fork server (or with ccl when forked
    directly); exit at once if it is already gone. Ctrl-C is handled by ccl alone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()
    if os.getppid() == 1 or not pid_alive(parent):
        os._exit(1)


def pid_alive(pid: int) -> bool:
    """True while process ``pid`` exists and is not a zombie (signal 0 probes without
    sending anything; a killed process that is not yet reaped still answers it)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except (OSError, IndexError):
        return True  # no /proc: the signal probe is all there is


def _forkserver_hook() -> None:
    if os.environ.get(PARENT_ENV) == str(os.getppid()):
        die_with_parent()
        if not pid_alive(os.getppid()) or os.getppid() == 1:
            os._exit(1)


_forkserver_hook()
