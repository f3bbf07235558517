"""Who draws a run's figures, and when: the process behind ``plots/``.

Drawing is most of a small run's time, and matplotlib's import alone about a sixth of it. So a
learning command starts a **drawer** before it reads any data (:func:`start_drawer`): a
one-worker :class:`~concurrent.futures.ProcessPoolExecutor`, forked from ccl, whose worker
imports matplotlib and Pillow while ccl reads and learns. Each stage's figures are submitted to
it as soon as the stage ends (:func:`submit_views`) and drawn while ccl runs the next stage;
:func:`draw_views` waits for them and writes them into the run's folder. Without a drawer
(``ccl batch`` workers, ``ccl evaluate``, the library, a system without fork) or for the
figures it could not draw (it died, their data are too large to send), ccl draws them itself,
the same way: the files are the same whichever process draws them.
"""

from __future__ import annotations

import os
import time
from functools import partial
from pathlib import Path
from typing import Any

from ccl_cli.render import figures
from ccl_cli.render.count import selection_figure
from ccl_cli.render.figures import _draw, _import_matplotlib

Spec = tuple[str, str, dict[str, Any]]  # a figure as data: (file name, kind of figure, its arguments)
Drawn = dict[str, "tuple[float, bytes] | None"]  # file name -> (seconds, the file's bytes) or None

#: the drawing function of each kind of :class:`~ccl_cli.app.views.View`
DRAW: dict[str, Any] = {"field": figures.field_figure, "time": figures.time_figure,
                        "selection": selection_figure, "constraint": figures.constraint_figure,
                        "trajectory": figures.trajectory_figure, "phases": figures.phases_figure}

#: The largest figure data sent to the drawer (bytes, pickled): a large recording's figures are
#: drawn at the end by ccl itself, from memory it already holds (a copy to another process would
#: cost more time and memory than the drawer saves).
MAX_MESSAGE = 16 * 2**20


def data_bytes(value: Any, seen: set[int] | None = None) -> int:
    """About the bytes a figure's data take in a message: its NumPy arrays' bytes, 8 per other
    item of its dicts, lists and tuples, a string's length — through the fields of objects such as
    :class:`~ccl_cli.dataset.Demonstrations`, each object once."""
    import numpy as np

    seen = set() if seen is None else seen
    if id(value) in seen:
        return 0
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, str | bytes):
        return len(value)
    if isinstance(value, dict):
        return sum(8 + data_bytes(k, seen) + data_bytes(v, seen) for k, v in value.items())
    if isinstance(value, list | tuple):
        return sum(8 + data_bytes(v, seen) for v in value)
    fields = getattr(value, "__dict__", None)
    return data_bytes(fields, seen) if isinstance(fields, dict) else 8


def draw_spec(spec: Spec, fmt: str) -> tuple[float, bytes] | None:
    """One figure drawn as a ``fmt`` file in memory: (seconds, bytes), None: nothing to draw."""
    _, kind, args = spec
    return _draw(partial(DRAW[kind], **args), fmt)


def _warm_up(parent: int) -> float:
    """The drawer's first job: die with ccl, leave Ctrl-C to it, import matplotlib and Pillow;
    the seconds of the import. The objects it inherits from ccl are frozen out of
    its garbage collections first (they are never freed here): its import 0.205 → 0.165 s."""
    import gc

    from ccl_cli.lifeline import worker_init

    gc.freeze()
    worker_init(parent)
    t0 = time.perf_counter()
    _import_matplotlib()
    import PIL.Image  # noqa: F401 - the PNG writer of every figure
    import PIL.PngImagePlugin  # noqa: F401

    return time.perf_counter() - t0


class Drawer:
    """A one-worker process pool started before a command reads its data: it imports
    matplotlib meanwhile, draws the figures it is sent (:meth:`submit`) in order while ccl goes
    on, and hands them over (:meth:`collect`)."""

    def __init__(self, ctx: Any) -> None:
        import multiprocessing
        import warnings
        from concurrent.futures import ProcessPoolExecutor

        self._futures: dict[str, Any] = {}  # file name -> the future of its drawing
        before = set(multiprocessing.active_children())
        try:
            self._pool = ProcessPoolExecutor(1, mp_context=ctx)
            with warnings.catch_warnings():  # 3.12+: fork() beside the BLAS's own (idle) threads
                warnings.simplefilter("ignore", DeprecationWarning)
                self._started = self._pool.submit(_warm_up, os.getpid())  # forks its worker now
            self._workers = [p for p in multiprocessing.active_children() if p not in before]
        except BaseException:  # Ctrl-C half-way: a worker without its pool would be waited for at exit
            for worker in set(multiprocessing.active_children()) - before:
                worker.kill()
                worker.join()
            raise

    def submit(self, specs: list[Spec], fmt: str) -> None:
        """Have the drawer draw these figures, one after another, while ccl goes on (figures
        whose data take over :data:`MAX_MESSAGE` bytes (:func:`data_bytes`) are left to ccl:
        counted, not pickled to be measured — a pickle of a 10⁶-sample recording is a copy)."""
        for spec in specs:
            if spec[0] not in self._futures and data_bytes(spec[2]) <= MAX_MESSAGE:
                self._futures[spec[0]] = self._pool.submit(draw_spec, spec, fmt)

    def collect(self, specs: list[Spec], fmt: str) -> tuple[float, Drawn]:
        """The figures of ``specs`` it drew (those not submitted yet are submitted now):
        (seconds of its matplotlib import, file name → drawn). A figure it failed to draw, or
        all of them when it died, are missing: the caller draws those itself."""
        self.submit(specs, fmt)
        drawn: Drawn = {}
        try:
            imported = self._started.result()
        except Exception:  # noqa: BLE001 - it died (or could not start): ccl draws them all
            return 0.0, drawn
        for name, _, _ in specs:
            try:
                drawn[name] = self._futures[name].result()
            except Exception:  # noqa: BLE001 - a figure that failed there is drawn (and fails) here
                continue
        return imported, drawn

    def close(self) -> None:
        """End the drawer: an idle worker exits when told, one still drawing (ccl stops on an
        error) is killed — it writes no file."""
        if not all(f.done() for f in (self._started, *self._futures.values())):
            for worker in self._workers:
                worker.kill()
        self._pool.shutdown(wait=True, cancel_futures=True)


_drawer: Drawer | None = None


def start_drawer() -> Drawer | None:
    """Start this process's drawer (once) where processes can be forked; None where not."""
    global _drawer
    import multiprocessing

    if _drawer is None and "fork" in multiprocessing.get_all_start_methods():
        _drawer = Drawer(multiprocessing.get_context("fork"))
    return _drawer


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
               fmt: str = "png") -> list[tuple[str, str]]:
    """Draw every figure of a run (:class:`~ccl_cli.app.views.View` data) into
    ``outdir/plots`` as ``fmt`` files (png, svg or pdf) — by the drawer when one runs, else in
    this process; returns (caption, relative path) pairs, captions starting with the stage
    name. ``seconds`` (if given) receives the time of each figure (drawing and encoding; file
    name → s) and of matplotlib's import."""
    specs = specs_of(views, fmt)
    imported, drawn = _drawer.collect(specs, fmt) if _drawer is not None else (0.0, {})
    if len(drawn) < len(specs):  # no drawer, or figures it did not draw
        t0 = time.perf_counter()
        _import_matplotlib()
        imported = time.perf_counter() - t0 if not drawn else imported
        drawn.update({spec[0]: draw_spec(spec, fmt) for spec in specs if spec[0] not in drawn})
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
