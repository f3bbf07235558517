"""The report's figures (plots/*.png), each one saying which model and which data it shows.

* ``<stage>-field.png`` (2-D state and action): the learnt field on a grid over the data
  (streamlines; for a constraint the learnt null-space directions) and, at one state per
  grid cell, true (wide, light) against learnt (thin, dark) arrows, the dpl baseline for
  a policy; legend outside the axes.
* ``<stage>-time.png``: per action dimension against time for up to two held-out
  demonstrations (training ones for a per-demonstration constraint, and the title says
  so), names and units from the data.
* ``learn-a-selection.png``: the criterion per candidate number of constraints k.
* ``learn-a-constraint.png``: the learnt constraint rows by action name (at the mean
  state when A depends on x), against the true ones when known, with the angle between
  the learnt and true row spaces; per demonstration, that angle for every demonstration.

Arrows are subsampled onto a grid and every figure is drawn once (< 0.5 s each).
"""

from __future__ import annotations

import functools
import logging
import os
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations

CELLS = 12  # arrow subsampling: at most one state per cell of a CELLS × CELLS grid
MAX_DEMOS = 2  # demonstrations per time plot
DPI = 90

STYLE = {
    "observed": {"color": "0.7", "lw": 2.2},
    "true": {"color": "tab:green", "alpha": 0.45, "lw": 3.0},
    "learnt": {"color": "tab:red", "lw": 1.1},
    "baseline": {"color": "tab:blue", "lw": 0.9, "ls": ":"},
    "predicted": {"color": "tab:purple", "lw": 1.0, "ls": "--"},
}


def _matplotlib() -> None:
    """matplotlib with its font cache in a per-user cache folder and its INFO logging
    (e.g. "generated new fontManager") kept away from the user."""
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ccl" / "matplotlib"
    try:
        cache.mkdir(parents=True, exist_ok=True)
        os.environ.setdefault("MPLCONFIGDIR", str(cache))
    except OSError:
        pass  # matplotlib then picks a temporary folder itself
    logging.getLogger("matplotlib").setLevel(logging.WARNING)


def _import_matplotlib():
    """(Figure, FigureCanvasAgg), matplotlib set up by :func:`_matplotlib` first."""
    _matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    _freeze_once()
    return Figure, FigureCanvasAgg


@functools.cache
def _freeze_once() -> None:
    """Move every object alive now — above all the ~10⁵ of matplotlib's modules, imported
    just before — out of the cyclic garbage collector's reach (``gc.freeze``): drawing
    allocates many short-lived objects, and each collection would otherwise scan the
    modules again (a small run: 1.01 → 0.89 s). Once per process, so a batch worker
    (which imports matplotlib before its first job) freezes only what it preloaded."""
    import gc

    gc.freeze()


def preload_in_background():
    """Import matplotlib's figure and Agg canvas in a daemon thread, for a process that
    will draw later and waits on something else meanwhile (``ccl batch`` on its workers).
    A failed import is left to the later, foreground import to report."""
    import threading

    _matplotlib()

    def load() -> None:
        import importlib

        for module in ("matplotlib.figure", "matplotlib.backends.backend_agg"):
            try:
                importlib.import_module(module)
            except ImportError:
                return

    thread = threading.Thread(target=load, name="ccl-preload-matplotlib", daemon=True)
    thread.start()
    return thread


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **kw: Any):
    """(figure, axes) as ``pyplot.subplots`` makes them, drawn by the Agg canvas directly:
    no pyplot import, no backend selection, no global figure registry to close."""
    Figure, FigureCanvasAgg = _import_matplotlib()
    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **kw)


def save_figure(fig, path: Path, dpi: float = DPI, fmt: str | None = None) -> None:
    """Write ``fig`` to ``path`` as ``fmt`` (default: the format its suffix names): PNG (zlib
    level 3: the same pixels as 6, ~1 % larger, ~40 % faster to encode), or vector SVG / PDF
    for a paper. A staging path (``x.png.tmp``) passes the final name's format."""
    fmt = fmt or Path(path).suffix.lstrip(".").lower() or "png"
    if fmt == "png":
        fig.savefig(path, format="png", dpi=dpi, pil_kwargs={"compress_level": 3})
    else:
        fig.savefig(path, format=fmt)


# -- labels ----------------------------------------------------------------------------------
def _units(names: list[str], units: list[str] | None) -> list[str]:
    """The data's units (the readers fill in those the names imply: ``ccl_cli.io.units``)."""
    return list(units or [""] * len(names))


def wrap(text: str, width: int = 70) -> str:
    """``text`` broken into lines of at most ``width`` characters (titles that fit the figure)."""
    import textwrap

    return "\n".join(textwrap.wrap(text, width)) or text


def label(name: str, unit: str) -> str:
    return f"{name} [{unit}]" if unit else name


def state_labels(d: Demonstrations) -> list[str]:
    return [label(n, u) for n, u in zip(d.state_names, _units(d.state_names, d.state_units), strict=True)]


def action_labels(d: Demonstrations) -> list[str]:
    return [label(n, u) for n, u in zip(d.action_names, _units(d.action_names, d.action_units), strict=True)]


def describe_data(part: str, d: Demonstrations, ids: np.ndarray | None = None) -> str:
    """Which demonstrations a figure shows: all of ``d`` (``ids`` None) or the given ones."""
    what = {"test": "held-out (test)", "train": "training", "all": "given",
            "test-blocks": "held-out (test) time blocks of", "train-blocks": "training samples of"}[part]
    if ids is None:
        return f"the {d.n_demos} {what} demonstrations"
    shown = ", ".join(str(int(i)) for i in ids[:MAX_DEMOS]) + (", …" if len(ids) > MAX_DEMOS else "")
    return f"{what} demonstration{'s' if len(ids) > 1 else ''} {shown}"


# -- geometry --------------------------------------------------------------------------------
def grid_subsample(X2: np.ndarray, cells: int = CELLS) -> np.ndarray:
    """Indices of at most one sample per cell of a ``cells × cells`` grid over X2 (N, 2)."""
    lo, hi = X2.min(0), X2.max(0)
    ij = np.floor((X2 - lo) / np.where(hi > lo, hi - lo, 1.0) * (cells - 1e-9)).astype(int)
    _, first = np.unique(ij[:, 0] * cells + ij[:, 1], return_index=True)
    return np.sort(first)


# -- figures ---------------------------------------------------------------------------------
def _quiver(ax, X, V, style: str, label_: str, scale: float) -> None:
    s = STYLE[style]
    kw = {"angles": "xy", "scale_units": "xy", "scale": scale, "color": s["color"], "label": label_}
    if style == "true":
        ax.quiver(X[:, 0], X[:, 1], V[:, 0], V[:, 1], width=0.012, alpha=s["alpha"], zorder=1, **kw)
    elif style == "observed":
        ax.quiver(X[:, 0], X[:, 1], V[:, 0], V[:, 1], width=0.003, zorder=2, **kw)
    else:
        ax.quiver(X[:, 0], X[:, 1], V[:, 0], V[:, 1], width=0.004, zorder=3, **kw)


def field_figure(title: str, d: Demonstrations, part: str, arrows: dict[str, tuple[str, np.ndarray]],
                 field: dict[str, np.ndarray] | None = None, field_label: str = "", directions: bool = False):
    """Left: ``field`` ({"G1", "G2": grid (n, n) each, "F": values (n², 2)}) as streamlines
    (or, with ``directions``, headless direction segments); right: ``arrows`` (style →
    (label, (N, 2))) at one state per grid cell. Returns the figure."""
    ncols = 2 if field is not None else 1
    fig, axes = subplots(1, ncols, figsize=(5.2 * ncols, 4.6), squeeze=False)
    names = state_labels(d)
    if field is not None:
        ax = axes[0, 0]
        G1, G2, F = field["G1"], field["G2"], field["F"]
        if directions:
            step = (G1[0, 1] - G1[0, 0]) * 0.8
            norm = np.linalg.norm(F, axis=1, keepdims=True)
            F = F / np.where(norm > 0, norm, 1.0) * step
            ax.quiver(G1.ravel(), G2.ravel(), F[:, 0], F[:, 1], angles="xy", scale_units="xy", scale=1,
                      headwidth=0, headlength=0, headaxislength=0, pivot="middle",
                      color=STYLE["learnt"]["color"], width=0.004)
        else:
            ax.streamplot(G1, G2, F[:, 0].reshape(G1.shape), F[:, 1].reshape(G1.shape), density=0.7,
                          color=STYLE["learnt"]["color"], linewidth=0.8, arrowsize=0.8)
        ax.plot(d.X[:, 0], d.X[:, 1], ".", ms=1, color="0.6", zorder=0)
        ax.set_title(field_label, fontsize=9)
        ax.set_xlabel(names[0])
        ax.set_ylabel(names[1])
    ax = axes[0, -1]
    idx = grid_subsample(d.X)
    Xs = d.X[idx]
    # a typical (90th percentile) arrow spans 1.5 grid cells, whatever a few outliers do
    typical = max(float(np.percentile(np.linalg.norm(V[idx], axis=1), 90)) for _, V in arrows.values())
    lo, hi = d.X.min(0), d.X.max(0)
    cell = float(np.min(np.where(hi > lo, hi - lo, 1.0))) / CELLS
    scale = max(typical, 1e-12) / (1.5 * cell)
    for style in ("true", "observed", "baseline", "learnt"):  # true first and widest: never hidden
        if style in arrows:
            name, V = arrows[style]
            _quiver(ax, Xs, V[idx], style, name, scale)
    ax.set_title(f"{len(idx)} states, one per grid cell", fontsize=9)
    ax.set_xlabel(names[0])
    ax.set_ylabel(names[1])
    ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(f"{title}\non {describe_data(part, d)}", fontsize=10)
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", ncol=len(arrows), fontsize=8,
               frameon=False)
    fig.subplots_adjust(left=0.08, right=0.98, top=0.84, bottom=0.2, wspace=0.25)
    return fig


def with_gaps(t: np.ndarray, factor: float = 3.0) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """Times (n,) with a NaN inserted wherever an interval exceeds ``factor`` × the median one
    (held-out time blocks, pauses), and the function that does the same to a series (n,), so
    a line is never drawn across a gap."""
    dt = np.diff(t)
    step = np.median(dt[dt > 0]) if np.any(dt > 0) else 0.0
    breaks = np.flatnonzero(dt > factor * step) + 1 if step > 0 else np.zeros(0, dtype=int)

    def cut(y: np.ndarray) -> np.ndarray:
        return np.insert(np.asarray(y, dtype=float), breaks, np.nan)

    return cut(t), cut


def time_figure(title: str, part: str, d: Demonstrations, lines: dict[str, tuple[str, np.ndarray]]):
    """One row per action dimension over time for up to MAX_DEMOS demonstrations of ``d``;
    ``lines``: style → (label, (N, q))."""
    ids = d.demo_ids[:MAX_DEMOS]
    q = d.n_action
    fig, axes = subplots(q, len(ids), figsize=(4.2 * len(ids) + 1.5, 1.35 * q + 1.2), squeeze=False,
                             sharex="col")
    names = action_labels(d)
    for c, k in enumerate(ids):
        sel = np.flatnonzero(d.demo == k)
        t, cut = with_gaps(d.t[sel])
        for j in range(q):
            ax = axes[j, c]
            for style in ("true", "observed", "baseline", "learnt", "predicted"):
                if style in lines:
                    name, Y = lines[style]
                    s = STYLE[style]
                    ax.plot(t, cut(Y[sel, j]), label=name, **s)
            ax.text(0.01, 0.96, names[j], transform=ax.transAxes, va="top", fontsize=7,
                    bbox={"facecolor": "white", "alpha": 0.7, "lw": 0, "pad": 1})
            ax.tick_params(labelsize=7)
        axes[0, c].set_title(f"demonstration {int(k)}", fontsize=8)
        axes[-1, c].set_xlabel("time from the start of the recording [s]", fontsize=8)
    fig.suptitle(f"{title}\non {describe_data(part, d, ids)}", fontsize=10)
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="lower center", ncol=len(lines), fontsize=8,
               frameon=False)
    h = fig.get_figheight()
    fig.subplots_adjust(left=0.07, right=0.98, top=1 - 0.95 / h, bottom=1.0 / h, hspace=0.15, wspace=0.18)
    return fig


def selection_figure(selection: dict[str, Any], q: int):
    """The constraint-count criterion per candidate k (every per-k list in ``selection``),
    the chosen k marked; per demonstration, how many demonstrations chose each k."""
    chosen = int(selection.get("n_constraints", 0))
    if "per_demo" in selection:
        counts = np.bincount(list(selection["per_demo"].values()), minlength=q)
        k = np.arange(len(counts))
        fig, ax = subplots(figsize=(5, 3.4))
        ax.bar(k, counts, width=0.6, color=["tab:red" if i == chosen else "0.6" for i in k])
        ax.set_xticks(k)
        ax.set_xlabel("number of constraints k")
        ax.set_ylabel("demonstrations")
        ax.set_title(wrap(f"Number of constraints chosen in each training demonstration; most common: "
                          f"{chosen}"), fontsize=9)
        fig.subplots_adjust(left=0.14, right=0.97, top=0.84, bottom=0.16)
        return fig
    series = {key: np.asarray(v, dtype=float) for key, v in selection.items()
              if isinstance(v, list) and len(v) > 1 and all(isinstance(x, int | float) for x in v)}
    if not series:
        return None
    width = max(6.4, 4.6 * len(series))
    fig, axes = subplots(1, len(series), figsize=(width, 3.6), squeeze=False)
    for ax, (key, v) in zip(axes[0], series.items(), strict=True):
        k = np.arange(1, len(v) + 1)
        ax.semilogy(k, np.maximum(v, 1e-300), "o-", color="0.3", lw=1)
        if 1 <= chosen <= len(v):
            ax.semilogy([chosen], [max(v[chosen - 1], 1e-300)], "o", ms=10, mfc="none", mec="tab:red", mew=2,
                        label=f"chosen k = {chosen}")
            ax.legend(loc="upper left", bbox_to_anchor=(0, -0.22), fontsize=8, frameon=False)
        ax.set_xticks(k)
        ax.set_xlabel("candidate number of constraints k")
        meaning = selection.get("criterion") or {
            "cv": "cross-validated NPOE", "eigengap": "residual of candidate k",
            "threshold": "residual of candidate k"}.get(str(selection.get("rule")), key)
        ax.set_ylabel(wrap(f"{meaning if key == 'values' else key} (log)", 34), fontsize=8)
    chars = int(12 * width)  # characters of a 9-pt title line across the figure
    title = wrap(f"How the number of constraints was chosen: rule {selection.get('rule')}", chars) + "\n" + \
        wrap(str(selection.get("reason", "")), chars)
    fig.suptitle(title, fontsize=9)
    top = 1 - (0.15 + 0.17 * (title.count("\n") + 1)) / fig.get_figheight()
    fig.subplots_adjust(left=0.9 / width, right=0.97, top=top, bottom=0.3, wspace=0.35)
    return fig


def constraint_figure(info: dict[str, Any], method: str):
    if "per_demo_angle_deg" in info:
        ang = info["per_demo_angle_deg"]
        fig, ax = subplots(figsize=(6, 3.2))
        ax.bar([str(k) for k in ang], list(ang.values()), color="tab:red")
        ax.set_xlabel("training demonstration")
        ax.set_ylabel("angle learnt vs true [deg]")
        ax.tick_params(axis="x", labelsize=6, rotation=90)
        ax.set_title(f"Learnt constraint of each training demonstration ({method}) against the true one;\n"
                     f"median angle {info['median_angle_deg']:.2g}°", fontsize=9)
        fig.subplots_adjust(left=0.11, right=0.98, top=0.84, bottom=0.2)
        return fig
    rows = np.asarray(info["rows"])
    s, q = rows.shape
    fig, axes = subplots(s, 1, figsize=(max(7.0, 0.75 * q + 2.5), 1.9 * s + 1.6), squeeze=False)
    x = np.arange(q)
    for r in range(s):
        ax = axes[r, 0]
        width = 0.38 if "true_rows" in info else 0.7
        ax.bar(x - (width / 2 if "true_rows" in info else 0), rows[r], width, color="tab:red", label="learnt")
        if "true_rows" in info and r < len(info["true_rows"]):
            ax.bar(x + width / 2, info["true_rows"][r], width, color="tab:green", alpha=0.6, label="true")
        ax.axhline(0, color="0.3", lw=0.6)
        ax.set_ylabel(f"row {r + 1}", fontsize=8)
        ax.set_xticks(x, info["names"], fontsize=7, rotation=30 if q > 3 else 0,
                      ha="right" if q > 3 else "center")
    where = "constant" if info["at"] == "constant" else f"at the {info['at']}"
    extra = ""
    if "angle_deg" in info:
        extra = f"; angle to the true {'normal' if 'plane_normal' in info else 'row space'} " \
                f"{info['angle_deg']:.2g}°"
    elif "plane_normal" in info:
        kind = "plane normal" if info["at"] == "constant" else "surface normal there"
        extra = f"; {kind} " + ", ".join(f"{v:+.3f}" for v in info["plane_normal"])
    fig.suptitle(f"Learnt constraint rows Ã ({method}, unit length, {where}){extra.replace('; ', chr(10), 1)}"
                 f"\nfitted on the training demonstrations", fontsize=9)
    axes[0, 0].legend(loc="upper left", bbox_to_anchor=(1.01, 1), fontsize=8, frameon=False)
    h = fig.get_figheight()
    fig.subplots_adjust(left=0.12, right=0.86, top=1 - 0.8 / h, bottom=0.75 / h, hspace=0.5)
    return fig


# -- the report's plots --------------------------------------------------------------------
def _draw(make: Callable[[], Any], path: Path) -> float | None:
    """Make one figure and write it to ``path``: its seconds, or None when there is nothing
    to draw (``make`` returned None)."""
    t0 = time.perf_counter()
    fig = make()
    if fig is None:
        return None
    save_figure(fig, path)
    return time.perf_counter() - t0


def _draw_in_child(jobs: list[tuple[str, str, Callable[[], Any]]], pdir: Path, send: Any) -> None:
    """A drawing process's work: draw ``jobs``, send {name: seconds or None} and end. It dies
    with its parent; any failure ends it without a word (the parent redraws what is missing)."""
    from ccl_cli.lifeline import die_with_parent

    try:
        die_with_parent()
        send.send({name: _draw(make, pdir / name) for name, _, make in jobs})
    except BaseException:  # noqa: BLE001 - the parent redraws whatever the child did not
        pass
    finally:
        send.close()


def render(jobs: list[tuple[str, str, Callable[[], Any]]], pdir: Path, workers: int = 1
           ) -> dict[str, float | None]:
    """Draw every (file name, caption, make) job into ``pdir``; with ``workers`` ≥ 2 (and
    fork) every other job is drawn meanwhile by a forked process (``multiprocessing``'s fork
    context: it starts with the figures' data in memory, nothing is pickled) — the figures
    are independent, and drawing them is most of a small run's time. Returns {name: seconds,
    or None for a job with nothing to draw}. A child that fails costs only time: the parent
    then draws its jobs too, so the files are the same either way."""
    import multiprocessing
    import warnings

    theirs = jobs[1::2] if workers > 1 and len(jobs) > 1 and \
        "fork" in multiprocessing.get_all_start_methods() else []
    child = receive = None
    if theirs:
        ctx = multiprocessing.get_context("fork")
        receive, send = ctx.Pipe(duplex=False)
        child = ctx.Process(target=_draw_in_child, args=(theirs, pdir, send), daemon=True)
        try:
            with warnings.catch_warnings():  # 3.12+: fork() beside the BLAS's own (idle) threads
                warnings.simplefilter("ignore", DeprecationWarning)
                child.start()
        except OSError:
            child, theirs = None, []
        send.close()
    mine = jobs[0::2] if theirs else jobs
    done = {name: _draw(make, pdir / name) for name, _, make in mine}
    got: dict[str, float | None] = {}
    if child is not None:
        try:
            got = receive.recv()
        except (EOFError, OSError):
            got = {}  # the child failed: its figures are drawn here
        child.join()
    for name, _, make in theirs:
        done[name] = got[name] if name in got else _draw(make, pdir / name)
    return done


#: the drawing function of each kind of :class:`~ccl_cli.app.views.View`
DRAW: dict[str, Callable[..., Any]] = {}


def draw_views(outdir: Path, views: list[Any], seconds: dict[str, float] | None = None,
               workers: int = 1, fmt: str = "png") -> list[tuple[str, str]]:
    """Draw every figure of a run (:class:`~ccl_cli.app.views.View` data) into
    ``outdir/plots`` as ``fmt`` files (png, svg or pdf); returns (caption, relative path)
    pairs, captions starting with the stage name. ``seconds`` (if given) receives the time of
    each figure (drawing and writing; file name → s) and of matplotlib's import."""
    pdir = outdir / "plots"
    pdir.mkdir(exist_ok=True)
    t0 = time.perf_counter()
    _import_matplotlib()
    if seconds is not None:
        seconds["matplotlib import"] = time.perf_counter() - t0
    jobs = [(str(Path(v.name).with_suffix(f".{fmt}")), v.caption, partial(DRAW[v.kind], **v.args))
            for v in views]
    drawn = render(jobs, pdir, workers)
    if seconds is not None:
        seconds.update({name: s for name, s in drawn.items() if s is not None})
    return [(caption, f"plots/{name}") for name, caption, _ in jobs if drawn.get(name) is not None]


def trajectory_figure(title: str, d: Demonstrations, part: str, at: np.ndarray, learnt: np.ndarray,
                      true: np.ndarray | None):
    """A 3-D view of the states X (N, 3) of ``d``, one colour per demonstration (phases cut
    into demonstrations show as colours), with the learnt constraint rows (M, s, 3) drawn as
    arrows at the states ``at`` (M,) and the true ones (wide, light) where known."""
    Figure, _ = _import_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=(6.4, 5.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d")
    names = state_labels(d)
    extent = float(np.max(d.X.max(0) - d.X.min(0))) or 1.0
    length = 0.08 * extent
    colours = _colours(len(d.demo_ids))
    for c, k in zip(colours, d.demo_ids, strict=True):
        sel = np.flatnonzero(d.demo == k)
        ax.plot(*d.X[sel].T, color=c, lw=0.8, alpha=0.8)
    P = d.X[at]
    if true is not None:
        for r in range(true.shape[1]):
            ax.quiver(*P.T, *(length * true[:, r]).T, color=STYLE["true"]["color"], alpha=0.45, lw=3,
                      arrow_length_ratio=0.2, label="true constraint row" if r == 0 else None)
    for r in range(learnt.shape[1]):
        ax.quiver(*P.T, *(length * learnt[:, r]).T, color=STYLE["learnt"]["color"], lw=1.1,
                  arrow_length_ratio=0.25, label=f"learnt constraint row{'s' if learnt.shape[1] > 1 else ''}"
                  if r == 0 else None)
    ax.set_xlabel(names[0], fontsize=8)
    ax.set_ylabel(names[1], fontsize=8)
    ax.set_zlabel(names[2], fontsize=8)
    ax.tick_params(labelsize=7)
    _equal_3d(ax, d.X)
    fig.suptitle(wrap(f"{title} (one colour per demonstration)") + f"\non {describe_data(part, d)}",
                 fontsize=10)
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.subplots_adjust(left=0.02, right=0.98, top=0.88, bottom=0.08)
    return fig


def _colours(n: int) -> list[Any]:
    import matplotlib

    cmap = matplotlib.colormaps["tab10" if n <= 10 else "viridis"]
    return [cmap(i % 10) if n <= 10 else cmap(i / max(n - 1, 1)) for i in range(n)]


def _equal_3d(ax: Any, X: np.ndarray) -> None:
    """Equal scale on the three axes, so a normal looks normal."""
    mid = (X.max(0) + X.min(0)) / 2
    half = float(np.max(X.max(0) - X.min(0))) / 2 or 1.0
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)


DRAW.update(field=field_figure, time=time_figure, selection=selection_figure, constraint=constraint_figure,
            trajectory=trajectory_figure)
