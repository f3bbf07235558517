"""summary.png of a ``ccl batch``: one row per job, one panel per metric.

A row per job, named in plain text at the left, so the figure grows with the jobs: 40 jobs are
a page, 400 a long page one scrolls, every name legible (8 pt at 80 dpi) and every job at the same
height in every panel (a table with dots). Each panel's value axis is logarithmic and drawn at
its top as well as at its foot; a value of exactly 0 — a job that reproduces the data exactly,
which a log axis cannot show — is drawn at the panel's left edge as a distinct marker, a job
with no such metric as a light dash, a failed job as a red cross and its name in red.

Drawn from few artists (docs/measurements.md, "ccl batch: the fixed cost"): per panel one
scatter per method and one per kind of mark, the rows' guide lines one collection; the names
are texts on the first panel only; value labels are plain text (``2e-03``, not matplotlib's
TeX-parsed ``2 × 10⁻³``); the layout is set in inches (no ``tight_layout``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

DPI = 80  # summary.png's resolution
#: Inches per job row (13.6 px at 80 dpi: an 8-pt name is 8.9 px tall).
ROW = 0.17
#: Inches above the rows (legend, panel titles, the upper value axis) and below them.
HEAD, FOOT = 1.0, 0.55
#: Inches per panel, and per character of the longest job name.
PANEL, CHAR = 2.5, 0.062
#: Colours of the marks that are not a method's value.
ZERO, MISSING, FAILED = "k", "0.6", "tab:red"


@dataclass
class Job:
    """One row of the figure: the job's shown name, its status (ok, skipped, failed), the
    methods it ran (the colour) and its value per metric (None: it has none)."""

    name: str
    status: str
    method: str
    values: dict[str, float | None]


def jobs_figure(jobs: list[Job], metrics: list[str]):
    """The figure (module docstring) of ``jobs`` over the panels ``metrics``."""
    import matplotlib

    from ccl_cli.render.figures import subplots

    n = len(jobs)
    names = [j.name + (" (failed)" if j.status == "failed" else "") for j in jobs]
    name_w = 0.3 + CHAR * max((len(name) for name in names), default=4)
    width = name_w + PANEL * len(metrics) + 0.25
    height = HEAD + ROW * max(n, 3) + FOOT
    fig, axes = subplots(1, len(metrics), figsize=(width, height), squeeze=False, sharey=True)
    fig.set_dpi(DPI)
    methods = sorted({j.method for j in jobs if j.status != "failed"})
    tab10 = matplotlib.colormaps["tab10"]
    colours = {m: tab10(i % 10) for i, m in enumerate(methods)}
    y = np.arange(n)
    failed = np.array([j.status == "failed" for j in jobs], dtype=bool)
    for ax, col in zip(axes[0], metrics, strict=True):
        _panel(ax, jobs, col, y, failed, methods, colours)
    first = axes[0, 0]
    first.set_ylim(n - 0.5, -0.5)  # job 1 at the top
    first.set_yticks([])
    for i, (j, name) in enumerate(zip(jobs, names, strict=True)):  # the job's name left of its row
        first.text(-0.02, i, name, ha="right",
                   va="center", fontsize=8, transform=first.get_yaxis_transform(), parse_math=False,
                   color=FAILED if j.status == "failed" else "0.45" if j.status == "skipped" else "k")
    _legend(fig, methods, colours, jobs, metrics)
    fig.subplots_adjust(left=name_w / width, right=1 - 0.25 / width, top=1 - HEAD / height,
                        bottom=FOOT / height, wspace=0.08)
    return fig


def _panel(ax: Any, jobs: list[Job], col: str, y: np.ndarray, failed: np.ndarray, methods: list[str],
           colours: dict[str, Any]) -> None:
    """One metric's panel: each job's value on a log axis (module docstring)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator

    v = np.array([np.nan if j.values.get(col) is None else float(j.values[col]) for j in jobs])
    positive = v > 0
    lo = float(v[positive].min()) if positive.any() else 1e-3
    hi = float(v[positive].max()) if positive.any() else 1.0
    left, right = lo / 10 ** 0.6, hi * 10 ** 0.25  # room at the left edge for the zeros
    ax.hlines(y, 0, 1, transform=ax.get_yaxis_transform(), colors="0.9", lw=0.5, zorder=0)
    for m in methods:
        at = positive & np.array([j.method == m for j in jobs]) & ~failed
        if at.any():
            ax.scatter(v[at], y[at], color=colours[m], s=16, zorder=3, label=m)
    edge = lo / 10 ** 0.4
    zero = (v == 0) & ~failed
    if zero.any():  # a log axis has no 0: at the left edge, as a marker of its own
        ax.scatter(np.full(zero.sum(), edge), y[zero], marker="<", s=26, facecolors="none",
                   edgecolors=ZERO, lw=1.0, zorder=3)
    none = np.isnan(v) & ~failed
    if none.any():
        ax.scatter(np.full(none.sum(), edge), y[none], marker="_", s=30, color=MISSING, lw=1.0, zorder=2)
    if failed.any():
        ax.scatter(np.full(failed.sum(), edge), y[failed], marker="x", s=22, color=FAILED, lw=1.0, zorder=3)
    ax.set_xscale("log")
    ax.set_xlim(left, right)
    decades = np.log10(right) - np.log10(left)
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0,) if decades > 2.5 else (1.0, 2.0, 5.0),
                                          numticks=6))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:.0e}" if x < 1e-2 or x >= 1e3 else f"{x:g}"))
    ax.xaxis.set_minor_locator(NullLocator())  # no minor ticks: each is a few artists
    ax.tick_params(axis="x", labelsize=7, top=True, labeltop=True)
    ax.grid(axis="x", color="0.92", lw=0.5, zorder=0)  # the decades, down a long page
    ax.set_title(col, fontsize=8, pad=16, y=1.0)  # at a fixed height: not fitted to the tick labels


def _legend(fig: Any, methods: list[str], colours: dict[str, Any], jobs: list[Job], metrics: list[str]
            ) -> None:
    """One legend over the panels: the methods' colours and the marks the figure uses."""
    from matplotlib.lines import Line2D

    marks = [Line2D([], [], ls="", marker="o", color=colours[m], label=m) for m in methods]
    values = [j.values.get(c) for j in jobs if j.status != "failed" for c in metrics]
    if any(v == 0 for v in values):
        marks.append(Line2D([], [], ls="", marker="<", mfc="none", mec=ZERO, label="exactly 0 (left edge)"))
    if any(v is None for v in values):
        marks.append(Line2D([], [], ls="", marker="_", color=MISSING, label="no value"))
    if any(j.status == "failed" for j in jobs):
        marks.append(Line2D([], [], ls="", marker="x", color=FAILED, label="failed"))
    if any(j.status == "skipped" for j in jobs):
        marks.append(Line2D([], [], ls="", marker="", label="grey name: up to date, kept"))
    fig.legend(handles=marks, loc="upper center", ncol=min(len(marks), 4), fontsize=7, frameon=False,
               bbox_to_anchor=(0.5, 1.0))


def write(path: Path, jobs: list[Job], metrics: list[str]) -> None:
    """summary.png of ``jobs`` at ``path``."""
    from ccl_cli.render.figures import save_figure

    save_figure(jobs_figure(jobs, metrics), path, dpi=DPI, fmt="png")
