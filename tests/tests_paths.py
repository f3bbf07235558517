"""What the end-to-end tests share: the ccl executable of this environment, and a way
to know that a started ``ccl`` process runs ccl's code."""

import shutil
import sys
import time
from pathlib import Path

CCL = shutil.which("ccl") or str(Path(sys.executable).parent / "ccl")


def running_ccl_code(pid: int) -> bool:
    """True once process ``pid`` runs ccl's code: numpy (imported by ccl_cli, after its
    Ctrl-C guard) is mapped. Before that only the interpreter's own start-up runs, whose
    Ctrl-C behaviour (a KeyboardInterrupt traceback) ccl cannot change."""
    try:
        return "_multiarray_umath" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return not Path("/proc/self/maps").exists()  # no /proc: cannot tell, assume it does


def wait_for_ccl_code(proc, timeout: float = 60.0) -> None:
    """Wait until the ``subprocess.Popen`` ``proc`` runs ccl's code (or has ended)."""
    deadline = time.monotonic() + timeout
    while not running_ccl_code(proc.pid) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.001)


def cpu_seconds() -> float:
    """CPU seconds used so far by this process and its waited-for children: a measure of
    work that a loaded machine does not inflate (tests never assert wall-clock time)."""
    import resource

    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def as_nobody() -> list[str]:
    """The command prefix that runs a command as the unprivileged user ``nobody`` (setpriv,
    when this runs as root), or [] when this already runs unprivileged; skips the test when
    neither is possible."""
    import os
    import pwd
    import subprocess

    import pytest

    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    try:
        user = pwd.getpwnam("nobody")
    except KeyError:
        user = None
    if setpriv is None or user is None:
        pytest.skip("running as root without setpriv or a nobody user")
    prefix = [setpriv, f"--reuid={user.pw_uid}", f"--regid={user.pw_gid}", "--clear-groups", "--"]
    probe = subprocess.run([*prefix, CCL, "--version"], capture_output=True, timeout=60)
    if probe.returncode != 0:
        pytest.skip("ccl cannot run as nobody here (its environment is not readable)")
    return prefix


def shared_folder() -> Path:
    """A new folder under the system's temporary folder that every user may write into
    (the tests' own tmp_path is private to this user)."""
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix="ccl-shared-"))
    folder.chmod(0o777)
    return folder
