"""The constraint-count figure (``learn-a-selection.png``): how the number of constraints k was
chosen — each candidate with the evidence the rule read and the rule's limit, from the learner's
``selection_`` (:mod:`ccl_cli.learn.constraint.rank`), never recomputed here.

* ``auto`` deciding from the states' geometry (``decided_by == "states"``): per rank k, each
  model tried at its worst held-out drift or shape residual against its limit
  (:func:`_geometry_axes`);
* ``auto`` deciding from the velocities: each candidate's held-out motion over its noise and
  share of the motion per row against the noise rule's limits, or — where the noise rule cannot
  judge — the ratio rule's limit on the shares (:func:`_noise_axes`);
* a learner's own rule (``ratio``, ``threshold``, ``cv``, ``noise``, ``eigengap``, ``manifold``):
  its value per candidate row against the rule's limit (``limits``), the rows that count green,
  the chosen k marked (:func:`_rule_axes`; the noise rule as for ``auto``);
* one model per demonstration: how many demonstrations chose each k.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ccl_cli.learn.constraint.noise_rank import MIN_SNR
from ccl_cli.learn.defaults import RATIO_FACTOR
from ccl_cli.render.figures import CHOSEN_COLOUR, HOLDS_COLOUR, MISSES_COLOUR, _colours, bars, subplots, wrap


def selection_figure(selection: dict[str, Any], q: int):
    """How the number of constraints was chosen (module docstring); None when there is nothing
    to draw (k fixed by the user)."""
    chosen = int(selection.get("n_constraints", 0))
    geometry = (selection.get("geometry") or {}).get("models") or []
    noise = [r for r in selection.get("candidates") or [] if r.get("noise_ratio")]
    if selection.get("rule") == "auto" and (geometry or noise):
        return _auto_selection(selection, q, chosen, geometry, noise)
    if "per_demo" in selection:
        return _per_demo(selection, q, chosen)
    if selection.get("rule") == "noise" and selection.get("share") and selection.get("limits"):
        return _own_noise(selection, chosen)
    if selection.get("values"):
        return _rule_figure(selection, chosen)
    return _series_figure(selection, chosen)


def _title(fig: Any, selection: dict[str, Any], head: str, width: float) -> int:
    """The figure's title: ``head`` and the selection's reason, wrapped to the figure's width;
    returns its number of lines."""
    chars = int(12 * width)  # characters of a 9-pt title line across the figure
    title = wrap(head, chars) + "\n" + wrap(str(selection.get("reason", "")), chars)
    fig.suptitle(title, fontsize=9)
    return title.count("\n") + 1


def _top(fig: Any, lines: int, above: float = 0.0) -> float:
    """The top of the axes (a figure fraction) under a title of ``lines`` lines, the axes' own
    titles (8 pt, as many lines as the longest) and ``above`` inches more (labels over an axes)."""
    axes_lines = max((ax.get_title().count("\n") + 1 for ax in fig.axes if ax.get_title()), default=0)
    return 1 - (0.12 + 0.165 * lines + 0.15 * axes_lines + above) / fig.get_figheight()


def _per_demo(selection: dict[str, Any], q: int, chosen: int):
    counts = np.bincount(list(selection["per_demo"].values()), minlength=q)
    k = np.arange(len(counts))
    fig, ax = subplots(figsize=(5, 3.4))
    bars(ax, k, counts, 0.6, [CHOSEN_COLOUR if i == chosen else "0.6" for i in k])
    ax.set_xticks(k)
    ax.set_xlabel("number of constraints k")
    ax.set_ylabel("demonstrations")
    rules = selection.get("inner_rules") or []
    how = ("fixed by the user" if rules == ["fixed"] else
           f"chosen by rule {', '.join(rules)}" if rules else "chosen")
    ax.set_title(wrap(f"Number of constraints {how} in each training demonstration; the most common, "
                      f"{chosen}, is reported"), fontsize=9, y=1.0)
    fig.subplots_adjust(left=0.14, right=0.97, top=0.84, bottom=0.16)
    return fig


#: What a rule's values are called on the value axis, when the selection does not say.
MEANING = {"cv": "cross-validated NPOE", "eigengap": "residual of candidate k",
           "threshold": "residual of candidate k"}


def _rule_figure(selection: dict[str, Any], chosen: int):
    """A learner's own rule: its value per candidate row (log) against the rule's limit."""
    width = 6.8
    fig, ax = subplots(figsize=(width, 4.0))
    handles = _rule_axes(ax, selection, chosen)
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 4), fontsize=7, frameon=False)
    lines = _title(fig, selection, f"How the number of constraints was chosen: k = {chosen} (rule "
                   f"{selection.get('rule')})", width)
    h = fig.get_figheight()
    fig.subplots_adjust(left=1.0 / width, right=0.97, top=_top(fig, lines), bottom=1.0 / h)
    return fig


def _rule_axes(ax: Any, selection: dict[str, Any], chosen: int) -> list[Any]:
    """Per candidate row k its value (``values``): green while it counts (k ≤ chosen), grey after;
    a black dash at the rule's limit for the row (``limits``), the chosen k ringed; for the
    eigengap rule the ratio across each gap. Returns the legend's handles."""
    from matplotlib.lines import Line2D

    v = np.asarray(selection["values"], dtype=float)
    k = np.arange(1, len(v) + 1)
    top = float(np.nanmax(v)) if np.any(v > 0) else 1.0
    shown = np.maximum(v, 1e-12 * top)  # exact zeros (noise-free data) at the foot of the axis
    ax.plot(k, shown, "-", color="0.5", lw=0.8, zorder=2)
    colour = [HOLDS_COLOUR if i <= chosen else MISSES_COLOUR for i in k]
    ax.scatter(k, shown, c=colour, s=28, zorder=3)
    handles = [Line2D([], [], ls="", marker="o", color=HOLDS_COLOUR, label="counts: a constraint"),
               Line2D([], [], ls="", marker="o", color=MISSES_COLOUR, label="does not count")]
    limits = selection.get("limits")
    if limits:
        at = [(i, lim) for i, lim in zip(k, limits, strict=False) if lim is not None]
        if at:
            x, y = np.array(at, dtype=float).T
            ax.hlines(y, x - 0.3, x + 0.3, colors="k", lw=1.6, zorder=4)
            handles.append(Line2D([], [], color="k", lw=1.6, label="the rule's limit for the row"))
    if 1 <= chosen <= len(v):
        ax.plot([chosen], [shown[chosen - 1]], "o", ms=12, mfc="none", mec=CHOSEN_COLOUR, mew=2, zorder=5)
        handles.append(Line2D([], [], ls="", marker="o", ms=9, mfc="none", mec=CHOSEN_COLOUR, mew=2,
                              label=f"chosen k = {chosen}"))
    for i, g in enumerate(selection.get("gaps") or []):  # eigengap: the ratio across each gap
        if g is not None:
            mid = np.sqrt(shown[i] * shown[i + 1])
            ax.text(i + 1.5, mid, f"×{g:.3g}", fontsize=7, ha="center", va="bottom",
                    color=CHOSEN_COLOUR if i + 1 == chosen else "0.3",
                    fontweight="bold" if i + 1 == chosen else "normal")
    _log_axis(ax)
    ax.set_xticks(k)
    ax.set_xlim(0.5, len(v) + 0.5)
    ax.set_xlabel("candidate row k (k constraints: rows 1 … k)", fontsize=8)
    meaning = selection.get("criterion") or MEANING.get(str(selection.get("rule")), "value")
    ax.set_ylabel(wrap(f"{meaning} (log)", 34), fontsize=8)
    ax.set_title(wrap(selection.get("limit_rule") or {
        "eigengap": "the largest gap between consecutive values sets k"}.get(str(selection.get("rule")), ""),
        90), fontsize=8, y=1.0)
    return handles


def _own_noise(selection: dict[str, Any], chosen: int):
    """A learner's noise rule (lambda's default): its rows' noise ratios and shares against the
    rule's limits, drawn as ``auto``'s velocity candidates are."""
    row = {"class": "the learnt rows", "k": chosen, "chosen": True, "noise_ratio": selection["values"],
           "share": selection["share"], "noise_limit": selection["limits"],
           "share_limit": selection.get("share_limits")}
    width = 10.4
    fig, (ax_ratio, ax_share) = subplots(1, 2, figsize=(width, 4.4))
    handles = _noise_axes(ax_ratio, ax_share, [row], chosen, held_out=False)
    if selection.get("still_rows"):
        rows = selection["still_rows"]
        ax_ratio.text(0.02, 0.02, f"row{'s' if len(rows) > 1 else ''} {', '.join(map(str, rows))}: above the "
                      f"noise, but the positions drift along {'them' if len(rows) > 1 else 'it'} by at most "
                      f"{max(selection['drift'][r - 1] for r in rows):.3g} of their spread (≤ "
                      f"{selection['drift_limit']:g}): counted", transform=ax_ratio.transAxes, fontsize=7,
                      color=CHOSEN_COLOUR)
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 4), fontsize=7, frameon=False)
    lines = _title(fig, selection, f"How the number of constraints was chosen: k = {chosen} (rule noise)",
                   width)
    h = fig.get_figheight()
    fig.subplots_adjust(left=1.0 / width, right=0.98, top=_top(fig, lines), bottom=1.05 / h,
                        wspace=0.35)
    return fig


def _series_figure(selection: dict[str, Any], chosen: int):
    """Any per-k lists of a selection without ``values`` (one panel each), the chosen k marked."""
    series = {key: np.asarray(v, dtype=float) for key, v in selection.items()
              if isinstance(v, list) and len(v) > 1 and all(isinstance(x, int | float) for x in v)}
    if not series:
        return None
    width = max(6.4, 4.6 * len(series))
    fig, axes = subplots(1, len(series), figsize=(width, 3.6), squeeze=False)
    for ax, (key, v) in zip(axes[0], series.items(), strict=True):
        _rule_axes(ax, {**selection, "values": list(v), "criterion": key, "limits": None}, chosen)
    lines = _title(fig, selection, f"How the number of constraints was chosen: rule {selection.get('rule')}",
                   width)
    fig.subplots_adjust(left=0.9 / width, right=0.97, top=_top(fig, lines), bottom=0.3, wspace=0.35)
    return fig


def _auto_selection(selection: dict[str, Any], q: int, chosen: int, geometry: list[dict[str, Any]],
                    noise: list[dict[str, Any]]):
    """The constraint-count figure of ``auto``: the states' geometry when it was tried, the
    velocity candidates when they decided."""
    by_states = selection.get("decided_by") == "states"
    shapes = 0.0 if not geometry or q < 2 else max(4.0, 0.5 * len(geometry) + 1.0 * (q - 1))
    curves = 0.0 if not noise or by_states else 8.8
    width = 1.6 + shapes + curves
    ratios = [r for r in (shapes, curves / 2, curves / 2) if r]
    fig, axes = subplots(1, len(ratios), figsize=(width, 4.6), squeeze=False,
                         gridspec_kw={"width_ratios": ratios})
    axes = list(axes[0])
    handles = []
    if geometry and q > 1:
        ax = axes.pop(0)
        handles += _geometry_axes(ax, geometry, chosen, q, by_states)
        said = "" if by_states else ": no shape holds, the velocities decide"
        ax.set_title(f"the states' geometry{said}", fontsize=8, y=1.07)
    if axes:
        handles += _noise_axes(axes[0], axes[1], noise, chosen)
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 4), fontsize=7, frameon=False)
    head = f"How the number of constraints was chosen: k = {chosen}"
    states = selection.get("geometry") or {}
    if states and not states.get("tried"):
        head += f" (the states' geometry not tried: {states.get('reason')})"
    lines = _title(fig, selection, head, width)
    top = _top(fig, lines, above=0.2 if geometry and q > 1 else 0.0)
    fig.subplots_adjust(left=1.2 / width, right=0.98, top=top, bottom=(1.05 + 0.16 * (len(handles) > 4)) /
                        fig.get_figheight(), wspace=0.35)
    return fig


def _geometry_axes(ax: Any, models: list[dict[str, Any]], chosen: int, q: int, decided: bool) -> list[Any]:
    """Per rank k (1 … q − 1) the models of the states' geometry tried (:mod:`ccl_cli.learn.
    constraint.geometry`): a bar per model at its worst held-out drift or shape residual, a black
    dash at its limit, green when within it, the chosen one red; ranks not tried said why (the
    ranks are tried from q − 1 down: one that holds ends the search).
    Returns the legend's handles."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    width = 0.8
    ticks, names = [], []
    for k in range(1, q):
        at = [m for m in models if m["k"] == k]
        if not at:
            why = (f"not tried:\nk = {chosen} holds\n(the largest rank\nis tried first)"
                   if decided and k < chosen else "not tried")
            ax.text(k, 0.5, why, transform=ax.get_xaxis_transform(), ha="center", va="center", fontsize=7,
                    color="0.4")
            continue
        step = width / len(at)
        x = k - width / 2 + step * (np.arange(len(at)) + 0.5)
        worst = np.array([max(m["drift"]) if m["drift"] else np.nan for m in at])
        colour = [CHOSEN_COLOUR if m.get("chosen") and decided else
                  HOLDS_COLOUR if m["holds"] else MISSES_COLOUR for m in at]
        floor = 1e-3 * min(m["limit"] for m in models)  # a bar this short still shows; its value says more
        shown = np.maximum(np.nan_to_num(worst, nan=floor), floor)
        bars(ax, x, shown, step * 0.85, colour)
        ax.hlines([m["limit"] for m in at], x - step * 0.45, x + step * 0.45, colors="k", lw=1.4, zorder=3)
        for xi, h, v in zip(x, shown, worst, strict=True):
            ax.text(xi, h * 1.08, f"{v:.2g}", ha="center", va="bottom", fontsize=6, color="0.25")
        ticks += list(x)
        names += [f"{m['basis']} {m['scope'].replace('_', ' ')}" for m in at]
    _log_axis(ax)
    ax.set_ylim(top=ax.get_ylim()[1] * 1.6)  # room for the values over the bars
    ax.set_xlim(0.4, q - 0.6)
    ax.set_xticks(ticks, names, fontsize=7, rotation=35, ha="right", rotation_mode="anchor")
    for k in range(1, q):
        ax.text(k, 1.01, f"k = {k}", transform=ax.get_xaxis_transform(), ha="center", va="bottom", fontsize=8,
                fontweight="bold" if decided and k == chosen else "normal",
                color=CHOSEN_COLOUR if decided and k == chosen else "k")
    ax.set_ylabel("worst held-out drift or shape residual\n(of the rows' spread, log)", fontsize=8)
    return [Patch(color=HOLDS_COLOUR, label="holds (within its limit)"),
            Patch(color=MISSES_COLOUR, label="does not hold"),
            *([Patch(color=CHOSEN_COLOUR, label="chosen")] if decided else []),
            Line2D([], [], color="k", lw=1.4, label="a model's limit")]


def _log_axis(ax: Any, axis: str = "y") -> None:
    """A log scale with plain numbers at the decades only (no labelled minor ticks)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    (ax.set_yscale if axis == "y" else ax.set_xscale)("log")
    ax.autoscale_view()
    target = ax.yaxis if axis == "y" else ax.xaxis
    low, high = (ax.get_ylim() if axis == "y" else ax.get_xlim())
    decades = np.log10(max(high, 1e-300)) - np.log10(max(low, 1e-300))
    subs = (1.0,) if decades > 2.5 else (1.0, 2.0, 5.0)
    target.set_major_locator(LogLocator(base=10, subs=subs, numticks=8))
    target.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    target.set_minor_formatter(NullFormatter())


def _noise_axes(ax_ratio: Any, ax_share: Any, candidates: list[dict[str, Any]], chosen: int,
                held_out: bool = True) -> list[Any]:
    """The velocity candidates of ``auto`` (:mod:`ccl_cli.learn.constraint.noise_rank`): per
    candidate row k its held-out motion over its noise (left) and its share of the motion
    (right), against the rule's limits (MARGIN; after the first row min(MARGIN, RATIO · r₁); the
    share SHARE for the first row only); rows 1 … k of the chosen model are quiet. Where the
    noise rule cannot judge (not trajectories in time) the ratio rule decided on the shares: its
    limit (RATIO_FACTOR × row 1's share) is drawn on the right. ``held_out``: the evidence was
    read on held-out data (``auto``), else on the training data. Returns the legend's handles."""
    from matplotlib.lines import Line2D

    tried = [r for r in candidates if r.get("noise_ratio")]
    winner = next((r for r in tried if r.get("chosen")), None)
    ref = winner if winner is not None and winner.get("noise_limit") else \
        next((r for r in tried if r.get("noise_limit")), None)
    by_ratio = winner if winner is not None and winner.get("ratio_limit") and ref is None else None
    colours = _colours(len(tried))
    m = max(len(r["noise_ratio"]) for r in tried)
    for ax, key, lim in ((ax_ratio, "noise_ratio", "noise_limit"), (ax_share, "share", "share_limit")):
        for c, r in zip(colours, tried, strict=True):
            v = np.maximum(np.asarray(r[key], dtype=float), 1e-12)
            rows = np.arange(1, len(v) + 1)
            mine = r is winner
            ax.plot(rows, v, "o-", color=CHOSEN_COLOUR if mine else c, lw=2.2 if mine else 0.9,
                    ms=6 if mine else 3.5,
                    label=f"{r['class']} (k = {r.get('k')})" + (" — chosen" if mine else ""),
                    zorder=3 if mine else 2)
        if ref is not None and ref.get(lim):
            limits = np.array([np.nan if v is None else v for v in ref[lim]], dtype=float)
            rows = np.arange(1, len(limits) + 1)
            ax.hlines(limits, rows - 0.35, rows + 0.35, colors="k", lw=1.6, zorder=4,
                      label="the rule's limit for the row")
        if chosen > 0 and (ref is not None or by_ratio is not None):
            ax.axvspan(0.5, chosen + 0.5, color=HOLDS_COLOUR, alpha=0.08, lw=0)
        _log_axis(ax)
        ax.set_xticks(np.arange(1, m + 1))
        ax.set_xlim(0.5, m + 0.5)
        ax.set_xlabel("candidate row k (the rows' order of each model)", fontsize=8)
    handles = ax_ratio.get_legend_handles_labels()[0]
    if by_ratio is not None:
        at = [(i + 1, v) for i, v in enumerate(by_ratio["ratio_limit"]) if v is not None]
        if at:
            x, y = np.array(at, dtype=float).T
            ax_share.hlines(y, x - 0.35, x + 0.35, colors="k", lw=1.6, linestyles="dashed", zorder=4)
            handles.append(Line2D([], [], color="k", lw=1.6, ls="--",
                                  label=f"the ratio rule's limit ({RATIO_FACTOR:g} × row 1's share)"))
    data = "held-out" if held_out else "training"
    ax_ratio.set_ylabel(f"motion along row k ({data})\n/ its noise variance (log)", fontsize=8)
    ax_share.set_ylabel(f"share of all the motion\nalong row k ({data}, log)", fontsize=8)
    for c, r in zip(colours, tried, strict=True):
        if r.get("time_share") is not None:  # in stretches: its row must hold in enough of the time too
            ax_ratio.annotate(f"{r['class']}: holds in {100 * r['time_share']:.0f} % of the held-out\n"
                              f"moving time (≥ {100 * r['min_time_share']:.0f} % needed)",
                              (1, max(r["noise_ratio"][0], 1e-12)), xytext=(8, 2), textcoords="offset points",
                              fontsize=6, color=CHOSEN_COLOUR if r is winner else c, va="bottom")
    if ref is None:  # the noise rule could not judge: the ratio rule on held-out energies decided
        said = (f"the samples are not trajectories the noise rule can judge (total variance < {MIN_SNR:g} × "
                "noise): the ratio rule on the held-out shares decided (right); row 1 always counts")
        share_said = f"the ratio rule: row k counts while its share ≤ {RATIO_FACTOR:g} × row 1's"
    elif chosen:
        said = f"a row is a constraint at or below its limit; shaded: the {chosen} chosen"
        share_said = "... or when it carries no more than this share"
    else:
        said = "no candidate's row 1 holds: k = 0"
        share_said = "... or when it carries no more than this share"
    ax_ratio.set_title(wrap(said, 60), fontsize=8, y=1.0)
    ax_share.set_title(wrap(share_said, 60), fontsize=8, y=1.0)
    return handles
