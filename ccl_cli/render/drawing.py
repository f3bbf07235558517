"""Who draws a run's figures, and when: the processes behind ``plots/``.

Drawing is most of a small run's time, and matplotlib's import alone about a sixth of it. So a
learning command starts a **drawer** before it reads any data (:func:`start_drawer`): a process
forked from ccl that imports matplotlib and Pillow while ccl reads and learns. Each stage's
figures are sent to it as soon as the stage ends (:meth:`Drawer.submit`), and it draws them
while ccl runs the next stage; the last ones are drawn when the run is written
(:func:`draw_views`), with a second process forked from the drawer when a core is idle
(:func:`idle_workers`), the two taking figures one at a time from a shared list so that neither
waits on the other's slow figure (:func:`render`). Figures are drawn into memory and written
into the run's folder by ccl itself. Without a drawer (``ccl batch`` workers, the library, or
a drawer that failed) ccl draws them the same way itself: the files are the same whichever
process draws them.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from ccl_cli.learn.blas import affinity_cores
from ccl_cli.render.figures import DRAW, _draw, _import_matplotlib

Job = tuple[str, Callable[[], Any]]  # (file name, make: () -> a figure, or None: nothing to draw)
Spec = tuple[str, str, dict[str, Any]]  # a job as data: (file name, kind of figure, its arguments)
Drawn = dict[str, "tuple[float, bytes] | None"]  # file name -> (seconds, the file's bytes) or None


def idle_workers() -> int:
    """How many processes should draw a run's figures: 2 when this process may use two or
    more cores and the 1-minute load leaves one of them idle, else 1. On a busy machine a
    second process gains no time and costs CPU (forking, its copy-on-write pages, its own
    font set-up; docs/measurements.md, "Small runs"); the files are the same."""
    cores = affinity_cores()
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # no load average (Windows: no fork either)
        load = 0.0
    return 2 if cores >= 2 and load <= cores - 1 else 1


def _fork_context() -> Any | None:
    """``multiprocessing``'s fork context, or None where processes cannot be forked."""
    import multiprocessing

    return multiprocessing.get_context("fork") if "fork" in multiprocessing.get_all_start_methods() else None


def _start(process: Any) -> bool:
    """Start a forked ``process``; False when the system refuses (no memory, a process limit)."""
    import warnings

    try:
        with warnings.catch_warnings():  # 3.12+: fork() beside the BLAS's own (idle) threads
            warnings.simplefilter("ignore", DeprecationWarning)
            process.start()
    except OSError:
        return False
    return True


def jobs_of(specs: list[Spec]) -> list[Job]:
    """The drawing jobs of figure ``specs``: each kind's drawing function with its arguments."""
    return [(name, partial(DRAW[kind], **args)) for name, kind, args in specs]


# -- two processes, one list of figures --------------------------------------------------------
def _queue(n: int) -> int:
    """A pipe holding the job numbers 0 … n−1 (two bytes each), its writing end closed: each
    read of two bytes takes the next job, whichever process reads; end of file when all are
    taken. (Reads from a pipe are atomic, and n ≤ 32,767 fits its buffer.)"""
    r, w = os.pipe()
    try:
        os.write(w, b"".join(k.to_bytes(2, "little") for k in range(n)))
    finally:
        os.close(w)
    return r


def _take(queue: int, jobs: list[Job], fmt: str) -> Drawn:
    """Draw the jobs this process takes from ``queue`` until it is empty."""
    done: Drawn = {}
    while len(got := os.read(queue, 2)) == 2:
        name, make = jobs[int.from_bytes(got, "little")]
        done[name] = _draw(make, fmt)
    return done


def _draw_in_child(jobs: list[Job], fmt: str, queue: int, send: Any) -> None:
    """The second drawing process's work: draw what it takes from ``queue``, send what it drew
    and end. It dies with its parent; any failure ends it without a word (the parent draws
    whatever it did not send)."""
    from ccl_cli.lifeline import die_with_parent

    try:
        die_with_parent()
        send.send(_take(queue, jobs, fmt))
    except BaseException:  # noqa: BLE001 - the parent redraws whatever the child did not
        pass
    finally:
        send.close()


def render(jobs: list[Job], fmt: str = "png", workers: int = 1) -> Drawn:
    """Draw every (file name, make) job as a ``fmt`` file in memory: with ``workers`` ≥ 2 (and
    fork) this process and one forked from it (it starts with the figures' data in memory,
    nothing is pickled) each take the next figure when they are free. A child that fails costs
    only time: this process then draws its figures too, so the result is the same either way."""
    ctx = _fork_context()
    if workers < 2 or len(jobs) < 2 or ctx is None or len(jobs) > 32_767:
        return {name: _draw(make, fmt) for name, make in jobs}
    queue = _queue(len(jobs))
    receive, send = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_draw_in_child, args=(jobs, fmt, queue, send), daemon=True)
    started = _start(child)
    send.close()
    try:
        done = _take(queue, jobs, fmt)
    finally:
        os.close(queue)
    got: Drawn = {}
    if started:
        try:
            got = receive.recv()
        except (EOFError, OSError):
            got = {}  # the child failed: its figures are drawn here
        child.join()
    receive.close()
    for name, make in jobs:
        if name not in done:
            done[name] = got[name] if name in got else _draw(make, fmt)
    return {name: done[name] for name, _ in jobs}


# -- the drawer: figures drawn while ccl learns ----------------------------------------------
class Drawer:
    """A process forked before a command reads its data: it imports matplotlib meanwhile, draws
    the figures it is sent (:meth:`submit`) while ccl goes on, and hands them over
    (:meth:`collect`). It ignores Ctrl-C (ccl handles it and exits), dies with ccl, and ends
    when ccl closes its pipe (:meth:`close`)."""

    def __init__(self, ctx: Any) -> None:
        requests, self._send = ctx.Pipe(duplex=False)  # ccl → drawer
        self._answers, answer = ctx.Pipe(duplex=False)  # drawer → ccl
        _widen(self._send)
        # not a daemon: multiprocessing lets only those fork a second drawing process
        self._process = ctx.Process(target=_serve, args=(requests, answer, (self._send, self._answers)),
                                    name="ccl-drawer")
        self.running = _start(self._process)
        requests.close()
        answer.close()
        self._sent: set[str] = set()

    def submit(self, specs: list[Spec], fmt: str) -> None:
        """Have the drawer draw these figures now, one after another, while ccl goes on."""
        if self.running and specs:
            self._call(("draw", specs, fmt))
            self._sent.update(name for name, _, _ in specs)

    def collect(self, specs: list[Spec], fmt: str, workers: int) -> tuple[float, Drawn] | None:
        """Every figure of ``specs`` (those not submitted yet drawn now, by ``workers``
        processes): (seconds of the drawer's matplotlib import, what it drew), or None when it
        cannot answer (it died, or the figures' data do not pickle): the caller then draws
        them all itself."""
        if not self.running:
            return None
        answer = self._call(("collect", [s for s in specs if s[0] not in self._sent], fmt, workers))
        if answer is None or not all(s[0] in answer[1] for s in specs):
            return None
        return answer

    def _call(self, message: tuple) -> Any:
        """Send ``message``; for a collect, the answer. A drawer that cannot take it — it died,
        the data do not pickle, or they are larger than :data:`MAX_MESSAGE` — is closed."""
        import pickle

        try:
            data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
            if len(data) > MAX_MESSAGE:
                raise ValueError("figures' data too large to send")
            self._send.send_bytes(data)
            return self._answers.recv() if message[0] == "collect" else None
        except Exception:  # noqa: BLE001 - see above: ccl draws instead
            self.close()
            return None

    def close(self) -> None:
        """End the drawer: an idle one sees the closed pipe and exits; one still drawing (ccl
        stops on an error, or draws itself) is killed — it writes no file, and its second
        drawing process dies with it."""
        if self.running:
            self.running = False
            self._send.close()
            self._answers.close()
            self._process.join(timeout=0.05)
            if self._process.is_alive():
                self._process.kill()
                self._process.join()


#: The largest message sent to a drawer (bytes, pickled): a large recording's figures are drawn
#: at the end by ccl itself, from memory it already holds (a copy through a pipe would cost
#: more time and memory than the drawer saves).
MAX_MESSAGE = 16 * 2**20


def _widen(conn: Any) -> None:
    """Let the pipe behind ``conn`` hold :data:`PIPE_BYTES` (Linux): handing a stage's figures
    to a drawer still importing matplotlib then does not wait for it. Elsewhere, or when the
    system refuses, the pipe stays as it is (a larger message waits)."""
    import fcntl

    try:
        fcntl.fcntl(conn.fileno(), fcntl.F_SETPIPE_SZ, PIPE_BYTES)
    except (AttributeError, OSError):
        pass


#: The drawer's request pipe size: the figures' data of a stage of a small run are ~0.1 MiB.
PIPE_BYTES = 2**20


def _serve(requests: Any, answer: Any, parents_ends: tuple[Any, ...]) -> None:
    """The drawer's life: die with ccl, import matplotlib, then take ("draw", specs, fmt) —
    figures drawn one at a time, in order, and kept — and ("collect", specs, fmt, workers):
    what is still waiting and these drawn by ``workers`` processes, then the answer
    (import seconds, every figure kept); until ccl closes the pipe. Between two figures a
    waiting request is read first, so the last figures, with ccl waiting, are drawn in
    parallel. (The copies of ccl's ends that the fork left here are closed first, or the pipe
    would never close.) Any failure ends it without a word: ccl then draws the figures itself
    and reports a failure once."""
    import gc
    import signal

    from ccl_cli.lifeline import die_with_parent

    for end in parents_ends:
        end.close()
    gc.freeze()  # ccl's objects, inherited: not traversed (nor copied) by this process's collections
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()
    try:
        t0 = time.perf_counter()
        _import_matplotlib()
        import PIL.Image  # noqa: F401 - the PNG writer of every figure
        import PIL.PngImagePlugin  # noqa: F401

        imported = time.perf_counter() - t0
        kept: Drawn = {}
        waiting: list[tuple[Spec, str]] = []  # (figure, format) in the order sent
        while True:
            if waiting and not requests.poll():
                spec, fmt = waiting.pop(0)
                kept.update(render(jobs_of([spec]), fmt))
                continue
            try:
                message = requests.recv()
            except EOFError:
                return
            kind, specs, fmt, *workers = message
            waiting += [(spec, fmt) for spec in specs]
            if kind == "collect":  # what is still waiting, by `workers` processes
                for each in dict.fromkeys(f for _, f in waiting):
                    kept.update(render(jobs_of([s for s, f in waiting if f == each]), each, *workers))
                answer.send((imported, kept))
                kept, waiting = {}, []
    except BaseException:  # noqa: BLE001 - see above
        pass
    finally:
        answer.close()


_drawer: Drawer | None = None


def start_drawer() -> Drawer | None:
    """Start this process's drawer (once), where processes can be forked and a core is idle
    (:func:`idle_workers`: on a busy machine a second process gains no time and costs CPU);
    None when there is none."""
    global _drawer
    ctx = _fork_context()
    if _drawer is None and ctx is not None and idle_workers() >= 2:
        _drawer = Drawer(ctx)
    return _drawer if _drawer is not None and _drawer.running else None


def stop_drawer() -> None:
    """End this process's drawer, if it runs."""
    global _drawer
    if _drawer is not None:
        _drawer.close()
        _drawer = None


def specs_of(views: list[Any], fmt: str) -> list[Spec]:
    """The figure specs of :class:`~ccl_cli.app.views.View` data: file name ``<name>.<fmt>``."""
    return [(str(Path(v.name).with_suffix(f".{fmt}")), v.kind, v.args) for v in views]


def submit_views(views: list[Any], fmt: str = "png") -> None:
    """Hand these figures to the drawer now, when one runs (it draws them while ccl goes on)."""
    if _drawer is not None:
        _drawer.submit(specs_of(views, fmt), fmt)


def draw_views(outdir: Path, views: list[Any], seconds: dict[str, float] | None = None,
               workers: int = 1, fmt: str = "png") -> list[tuple[str, str]]:
    """Draw every figure of a run (:class:`~ccl_cli.app.views.View` data) into
    ``outdir/plots`` as ``fmt`` files (png, svg or pdf) — by the drawer when one runs, else in
    this process; returns (caption, relative path) pairs, captions starting with the stage
    name. ``seconds`` (if given) receives the time of each figure (drawing and encoding; file
    name → s) and of matplotlib's import."""
    specs = specs_of(views, fmt)
    answer = _drawer.collect(specs, fmt, workers) if _drawer is not None else None
    if answer is not None:
        imported, drawn = answer
    else:
        t0 = time.perf_counter()
        _import_matplotlib()
        imported = time.perf_counter() - t0
        drawn = render(jobs_of(specs), fmt, workers)
    pdir = outdir / "plots"
    pdir.mkdir(exist_ok=True)
    for name, _, _ in specs:
        if drawn[name] is not None:
            (pdir / name).write_bytes(drawn[name][1])
    if seconds is not None:
        seconds["matplotlib import"] = imported
        seconds.update({name: drawn[name][0] for name, _, _ in specs if drawn[name] is not None})
    return [(v.caption, f"plots/{name}") for v, (name, _, _) in zip(views, specs, strict=True)
            if drawn[name] is not None]
