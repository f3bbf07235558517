"""What the figures show, computed once from the learnt models.

A stage result carries :class:`View` objects: plain data (arrays, labels, the
demonstrations shown) that :mod:`ccl_cli.render.figures` draws without calling a model.
Every array here is a prediction of the same fitted model that produced the stage's
metrics, on the same data, so a figure and metrics.json never disagree.

* ``field``: for 2-D states and actions, the learnt field on a ``GRID × GRID`` grid over
  the shown data (or, for a constraint, its null-space direction) and arrows at the
  samples (true, observed, learnt, dpl baseline);
* ``time``: per action dimension over time, the same series;
* ``selection``: the criterion per candidate number of constraints;
* ``constraint``: the learnt constraint rows (:func:`describe_constraint`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, group_rows
from ccl_cli.learn.consistency import apply_projection
from ccl_cli.learn.constraint.base import AS_FITTED, Windows
from ccl_cli.metrics import row_basis, subspace_angle

GRID = 22  # points per axis of the grid a 2-D field is evaluated on
#: in a caption, only where the figure shows the file's ground truth
VS_TRUE = " vs true"


@dataclass
class View:
    """One figure: its file name, caption (starting with the stage name), kind (``field``,
    ``time``, ``selection``, ``constraint``) and the keyword arguments of its drawing
    function in :mod:`ccl_cli.render.figures` (data only)."""

    name: str
    caption: str
    kind: str
    args: dict[str, Any] = field(default_factory=dict)


def grid_over(X2: np.ndarray, n: int = GRID) -> tuple[np.ndarray, np.ndarray]:
    """A regular n × n grid over the bounding box of X2 (N, 2), widened by 5 % per side."""
    lo, hi = X2.min(0), X2.max(0)
    pad = 0.05 * np.where(hi > lo, hi - lo, 1.0)
    return np.meshgrid(np.linspace(lo[0] - pad[0], hi[0] + pad[0], n),
                       np.linspace(lo[1] - pad[1], hi[1] + pad[1], n))


def field_on_grid(d: Demonstrations, fn) -> dict[str, np.ndarray]:
    """``fn`` (M, 2) → (M, 2) on the grid over the shown states: {"G1", "G2", "F"}."""
    G1, G2 = grid_over(d.X)
    return {"G1": G1, "G2": G2, "F": fn(np.column_stack([G1.ravel(), G2.ravel()]))}


def null_direction(model: Any):
    """For a 2-D constraint: the column of Ñ(x) with the largest norm, i.e. the learnt
    null-space direction at each grid state (a function (M, 2) → (M, 2))."""

    def direction(G: np.ndarray) -> np.ndarray:
        P = model.projection(G)
        cols = np.linalg.norm(P, axis=1)
        return P[np.arange(len(G)), :, np.argmax(cols, axis=1)]

    return direction


def constant_rows(model: Any, d: Demonstrations) -> np.ndarray | None:
    """The rows (s, q) of a constant learnt constraint (its ``constant_rows()``; for ``method:
    auto``, of the model it chose), orthonormal; None for state-dependent, per-demonstration
    and per-window models."""
    A = model.constant_rows()
    if A is None:
        return None
    if not model.n_constraints_:
        return np.zeros((0, d.n_action))
    return row_basis(np.asarray(A, dtype=float))


def describe_constraint(model: Any, d: Demonstrations) -> dict[str, Any] | None:
    """The learnt constraint in readable form, for the report and metrics.json.

    One model: its rows (unit length, sign fixed so the largest entry is positive) at the
    mean state of the samples where it holds (exactly the rows when A is constant), the action
    names, and with ground truth the true rows at the sample nearest that state and the largest
    principal angle between the two row spaces (for one row in 3-D: the angle between the plane
    normals).
    Per demonstration: that angle per demonstration (with ground truth)."""
    names = short_names(d.action_names)
    by_demo = model.models_by_demonstration()
    if by_demo is not None:
        if not d.has_truth("A"):
            return None
        angles = {}
        first = dict(zip(*group_rows(d.demo), strict=True))  # one sort, not a mask per demonstration
        for k, m in by_demo.items():
            if k not in first:
                continue
            sel = first[k]
            learnt = m.constraint(d.X[sel[:1]])[0]
            angles[int(k)] = subspace_angle(learnt, d.truth_per_sample("A")[sel[0]])
        if not angles:
            return None
        return {"per_demo_angle_deg": angles, "median_angle_deg": float(np.median(list(angles.values())))}
    on = np.flatnonzero(model.holds(d.X, groups=d.demo, t=d.t))  # where it holds (in stretches)
    pool = on if len(on) else np.arange(d.n_samples)
    i = int(pool[np.argmin(np.sum((d.X[pool] - d.X[pool].mean(0)) ** 2, axis=1))])
    A = model.constant_rows()  # constant rows (also those of a constraint in stretches)
    constant = A is not None
    if not constant:  # the rows at sample i, read with its demonstration (where a model holds may
        own = np.flatnonzero(d.demo == d.demo[i])  # depend on the rest of it: phases, stretches)
        A = model.constraint(d.X[own], groups=d.demo[own], t=d.t[own])[int(np.searchsorted(own, i))]
    learnt = row_basis(A)
    if not len(learnt):
        return None  # no constraint: nothing to draw (the selection says why)
    learnt = learnt * np.sign(learnt[np.arange(len(learnt)), np.argmax(np.abs(learnt), axis=1)])[:, None]
    at = "constant" if constant else f"state of sample {i} (nearest the mean state where it holds)"
    out: dict[str, Any] = {"names": names, "rows": learnt.tolist(), "at": at}
    if d.has_truth("A"):
        true = row_basis(d.truth_per_sample("A")[i])
        true = true * np.sign(true[np.arange(len(true)), np.argmax(np.abs(true), axis=1)])[:, None]
        out["true_rows"] = true.tolist()
        out["angle_deg"] = subspace_angle(learnt, true)
    if d.n_action == 3 and len(learnt) == 1:
        out["plane_normal"] = learnt[0].tolist()
    windows = model.windows()
    if windows is not None:
        out["per"], out["stretches"] = windows.per, stretch_rows(windows, d)
    return out


def phases(model: Any, d: Demonstrations) -> dict[str, Any] | None:
    """Where a constraint that holds in stretches holds on its training data ``d`` (issue 30 item
    3): the share of the samples and per demonstration its span, the seconds held and the
    stretches [start, end] (s from the demonstration's first sample); None when the model holds
    everywhere (or has no rows)."""
    if not model.n_constraints_:
        return None
    on = np.asarray(model.holds(d.X, groups=d.demo, t=d.t), dtype=bool)
    if on.all():
        return None
    step = float(np.median(np.diff(d.t)[d.demo[1:] == d.demo[:-1]])) if d.n_samples > 1 else 0.0
    per_demo = []
    rows = dict(zip(*group_rows(d.demo), strict=True))  # one sort, not a mask per demonstration
    for k in d.demo_ids:  # a loop over demonstrations
        sel = rows[k]
        t, held = d.t[sel] - d.t[sel[0]], on[sel]
        edges = np.flatnonzero(np.diff(np.r_[0, held.astype(np.int8), 0]))
        spans = [[float(t[a]), float(t[b - 1] + step)] for a, b in zip(edges[::2], edges[1::2], strict=True)]
        per_demo.append({"demo": int(k), "duration_s": float(t[-1] + step),
                         "held_s": float(sum(b - a for a, b in spans)), "spans": spans})
    return {"share": float(on.mean()), "demos": per_demo}


def phase_series(model: Any, d: Demonstrations, title: str) -> dict[str, Any]:
    """The data of the phases figure on the training data ``d``, on the rows of its first
    :data:`PHASE_DEMOS` demonstrations (M,): per sample whether the constraint holds (M,), the
    speed ‖u‖ and the speed along the learnt rows ‖Ã u‖ (M,) — with the rows where it holds
    (constant rows elsewhere too, so the motion along them shows); ``n_demos``: d's count."""
    on = np.asarray(model.holds(d.X, groups=d.demo, t=d.t), dtype=bool)
    A = model.constant_rows()
    rows = (np.broadcast_to(A, (d.n_samples, *np.shape(A))) if A is not None else
            model.constraint(d.X, groups=d.demo, t=d.t))
    true = None
    if d.has_truth("N") or d.has_truth("A"):  # where the file's ground truth has a constraint
        off = np.abs(d.true_projection(False) - np.eye(d.n_action)).max(axis=(-2, -1))  # () or (N,)
        true = np.broadcast_to(off > 1e-6, (d.n_samples,))
    shown = first_demos(d, PHASE_DEMOS)  # the rows the figure draws
    return {"title": f"{title}: where the constraint holds", "d": d.without_truth().subset(shown),
            "n_demos": d.n_demos,
            "holds": on[shown], "speed": np.linalg.norm(d.U[shown], axis=1),
            "along": np.linalg.norm(np.einsum("nkq,nq->nk", rows[shown], d.U[shown]), axis=1),
            "true_holds": None if true is None else true[shown]}


#: Stretches of a per-window / per-segment model listed in the report (the first ones).
SHOWN_STRETCHES = 12


def stretch_rows(windows: Windows, d: Demonstrations) -> dict[str, Any]:
    """The first :data:`SHOWN_STRETCHES` windows or segments of a model (its ``windows()``):
    demonstration, start and end (s), their first row (sign fixed as above) and, with ground
    truth, the angle to the true rows at the sample nearest the stretch's middle; and how many
    there are."""
    spans = windows.spans
    rows = []
    for (demo, start, end), A in zip(spans[:SHOWN_STRETCHES], windows.rows[:SHOWN_STRETCHES], strict=False):
        if not len(A):
            continue
        row = A[0] * np.sign(A[0][np.argmax(np.abs(A[0]))])
        item: dict[str, Any] = {"demo": int(demo), "start_s": float(start), "end_s": float(end),
                                "row": row.tolist()}
        mine = np.flatnonzero(d.demo == demo)
        if d.has_truth("A") and len(mine):
            i = mine[np.argmin(np.abs(d.t[mine] - (start + end) / 2))]
            item["angle_deg"] = subspace_angle(A, d.truth_per_sample("A")[i])
        rows.append(item)
    return {"count": int(len(spans)), "shown": rows}


def short_names(names: list[str]) -> list[str]:
    """Joint names without a common ``.field`` suffix (``lwr_arm_0_joint.velocity`` → ``lwr_arm_0_joint``)."""
    suffixes = {n.rsplit(".", 1)[1] for n in names if "." in n}
    if len(suffixes) == 1 and all("." in n for n in names):
        return [n.rsplit(".", 1)[0] for n in names]
    return list(names)


def stage_views(result: Any, shown: Demonstrations, part: str, train: Demonstrations, blocks: bool,
                constraint: Any = None) -> list[View]:
    """The figures of one stage ``result`` (a :class:`~ccl_cli.app.stages.StageResult`) on
    the ``shown`` data (``part``: ``test`` or ``train``; ``blocks``: the split is by time
    blocks, so titles say so; a per-demonstration constraint is shown on its ``train``
    demonstrations), with ``constraint`` the learnt constraint model of an earlier learn-a
    stage (for the predicted u = ṽ + Ñπ̃ of a policy)."""
    from ccl_cli.app.scoring import applied_on, projection_on, task_part

    model = result.model
    if model is None:
        return []
    suffix = "-blocks" if blocks else ""
    d, dpart = shown, part + suffix
    title = f"{result.name} ({result.method})"
    planar = shown.n_state == 2 and shown.n_action == 2
    out: list[View] = []
    if result.name == "learn-v":
        w = model.predict(d.X)
        arrows = {"observed": ("observed u", d.U), "learnt": ("learnt w̃", w)}
        if d.has_truth("w"):
            arrows["true"] = ("true w", d.truth["w"])
        out += _field_and_time("learn-v", f"{title}: null-space component w", d, dpart, arrows, arrows,
                               model.predict if planar else None, "learnt w̃(x) on a grid",
                               (f"learnt{VS_TRUE if 'true' in arrows else ''} null-space component",
                                "learnt w̃ against the observations over time"))
    elif result.name == "learn-a":
        if not model.new_data_rule.carries_over and not dpart.startswith("train"):
            d, dpart = train, "train" + suffix  # e.g. one model per demonstration: its own only
        applied = applied_on(model, d, d.U)
        N, v = projection_on(applied, d, per_sample=False), task_part(applied, d)
        Y = d.U if v is None else d.U - v
        arrows = {"observed": ("observed u" if v is None else "u − its learnt task part Ã⁺b̃", Y),
                  "learnt": ("Ñ(u − Ã⁺b̃)" if v is not None else "Ñ u", apply_projection(N, Y))}
        if d.has_truth("pi") and (d.has_truth("N") or d.has_truth("A")):
            pi = d.truth["pi"]
            arrows = {"observed": arrows["observed"],
                      "true": ("true N π", apply_projection(d.true_projection(False), pi)),
                      "learnt": ("Ñ π", apply_projection(N, pi))}
        title_a = f"{title}: projection onto the learnt null space"
        if planar:
            # a grid is not a recording: only a model whose Ã(x) is fixed by the state alone ("as
            # fitted") has a field there — where a model in phases or stretches holds is found
            # from a recording's own motion, which grid states do not have
            grid = field_on_grid(d, null_direction(model)) \
                if not model.is_local and model.new_data_rule.rule == AS_FITTED.rule else None
            caption = f"learn-a: learnt{VS_TRUE if 'true' in arrows else ''} projections"
            out.append(View("learn-a-field.png", caption, "field",
                            {"title": title_a, "d": d, "part": dpart, "arrows": arrows, "field": grid,
                             "field_label": "learnt null-space direction of Ñ(x) on a grid",
                             "directions": True}))
        else:
            out.append(View("learn-a-time.png",
                            "learn-a: learnt projection against the observations over time",
                            "time", time_view(title_a, dpart, d, arrows)))
        if d.n_state == 3 and d.n_action == 3 and model.n_constraints_:
            out.append(View("learn-a-trajectory.png",
                            "learn-a: the trajectory and the learnt constraint in 3-D", "trajectory",
                            trajectory_normals(model, d, title, dpart)))
        out.append(View("learn-a-selection.png", "learn-a: how the number of constraints was chosen",
                        "selection", {"selection": result.info.get("selection") or {}, "q": d.n_action}))
        if result.info.get("phases"):
            out.append(View("learn-a-phases.png", "learn-a: where the constraint holds over time", "phases",
                            phase_series(model, train, title)))
        info = result.info.get("constraint")
        if info:
            out.append(View("learn-a-constraint.png", "learn-a: the learnt constraint", "constraint",
                            {"info": info, "method": result.method}))
    elif result.name == "learn-pi":
        est = model.predict(d.X)
        arrows = {"observed": ("observed u", d.U), "learnt": (f"learnt π̃ ({result.method})", est)}
        if d.has_truth("pi"):
            arrows["true"] = ("true π", d.truth["pi"])
        if result.baseline is not None:
            arrows["baseline"] = ("dpl baseline", result.baseline.predict(d.X))
        lines = dict(arrows)
        if constraint is not None and constraint.new_data_rule.carries_over:
            applied = applied_on(constraint, d, d.U)
            v, N = task_part(applied, d), projection_on(applied, d, per_sample=False)
            pred = apply_projection(N, est) + (0 if v is None else v)
            lines["predicted"] = ("predicted u = Ñπ̃" if v is None else "predicted u = Ã⁺b̃ + Ñπ̃", pred)
        out += _field_and_time("learn-pi", f"{title}: null-space policy π", d, dpart, arrows, lines,
                               model.predict if planar else None, "learnt π̃(x) on a grid",
                               (f"learnt{VS_TRUE if 'true' in arrows else ''} policy",
                                "learnt policy (and the predicted u) over time"))
    return out


def _field_and_time(stage: str, title: str, d: Demonstrations, part: str, arrows: dict, lines: dict,
                    predict: Any, field_label: str, captions: tuple[str, str]) -> list[View]:
    """A predicting model's figures: its field on a grid (2-D only: ``predict`` given) and its
    series over time."""
    out = []
    if predict is not None:
        out.append(View(f"{stage}-field.png", f"{stage}: {captions[0]}", "field",
                        {"title": title, "d": d, "part": part, "arrows": arrows,
                         "field": field_on_grid(d, predict), "field_label": field_label}))
    out.append(View(f"{stage}-time.png", f"{stage}: {captions[1]}", "time", time_view(title, part, d, lines)))
    return out


#: Arrows of the learnt constraint drawn along a 3-D trajectory.
TRAJECTORY_ARROWS = 40
#: A 3-D trajectory figure draws about this many states at most (every s-th sample of each
#: demonstration, and those the arrows start from).
TRAJECTORY_POINTS = 20_000
#: Demonstrations a figure over time draws (the first ones of its part).
TIME_DEMOS = 2
#: Demonstrations the phases figure draws (the first ones of the training part).
PHASE_DEMOS = 6


def first_demos(d: Demonstrations, count: int) -> np.ndarray:
    """The rows (indices, in order) of the first ``count`` demonstrations of ``d``."""
    return np.flatnonzero(np.isin(d.demo, d.demo_ids[:count]))


#: A line over time is drawn through at most this many of its samples (:func:`envelope`: each run
#: of samples keeps its lowest and highest, about five per pixel of the ~400-pixel-wide panels).
LINE_POINTS = 4000


def time_view(title: str, part: str, d: Demonstrations, lines: dict[str, tuple[str, np.ndarray]]
              ) -> dict[str, Any]:
    """The data of a figure over time (:func:`ccl_cli.render.figures.time_figure`): for each of
    the first :data:`TIME_DEMOS` demonstrations of ``d``, each line's (label, Y (N, q)) samples
    as drawn — cut at the gaps in its times (:func:`with_gaps`), through at most LINE_POINTS
    of them (:func:`envelope`): the same figure at any N, from data small enough for the
    drawer."""
    ids = d.demo_ids[:TIME_DEMOS]
    panels = []
    for k in ids:
        sel = np.flatnonzero(d.demo == k)
        t, cut = with_gaps(d.t[sel])
        panels.append({style: (name, [envelope(t, cut(Y[sel, j])) for j in range(Y.shape[1])])
                       for style, (name, Y) in lines.items()})
    return {"title": title, "part": part, "names": list(d.action_names),
            "units": None if d.action_units is None else list(d.action_units),
            "ids": [int(k) for k in ids], "panels": panels}


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


def envelope(x: np.ndarray, y: np.ndarray, points: int = LINE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """The samples of a line (x, y (n,), NaN where it breaks) that draw it at its width: all of
    them up to ``points``; else, in each of ``points`` / 2 runs of consecutive samples, the lowest
    and the highest, in order, with every break and the samples either side of it — the same
    pixels, at any n."""
    n = len(y)
    if n <= points:
        return x, y
    size = -(-n // (points // 2))
    runs = -(-n // size)
    gap = np.isnan(y)
    low = np.full(runs * size, np.inf)
    low[:n] = np.where(gap, np.inf, y)
    high = np.full(runs * size, -np.inf)
    high[:n] = np.where(gap, -np.inf, y)
    first = np.arange(runs) * size
    breaks = np.flatnonzero(gap)
    lowest, highest = low.reshape(runs, size).argmin(1), high.reshape(runs, size).argmax(1)
    keep = np.unique(np.r_[first + lowest, first + highest, breaks, breaks - 1, breaks + 1])
    keep = keep[(keep >= 0) & (keep < n)]
    return x[keep], y[keep]


def trajectory_normals(model: Any, d: Demonstrations, title: str, part: str) -> dict[str, Any]:
    """The data of a 3-D trajectory figure: the states of ``d`` (N, 3) per demonstration (every
    s-th sample of each, about :data:`TRAJECTORY_POINTS` in all) and, at about
    TRAJECTORY_ARROWS states spread along them, the learnt constraint rows (unit, sign fixed
    towards the mean row) and the true ones where known: {"d" (those states), "at" (M,) (rows
    of "d"), "learnt" (M, s, 3), "true" (M, s', 3) or None, ...}."""
    at = np.unique(np.linspace(0, d.n_samples - 1, TRAJECTORY_ARROWS).astype(int))
    # a model per stretch on demonstrations it did not see: by its rule, as the metrics are
    applied = model.applies_to(d.X, d.U, groups=d.demo, t=d.t, new_recording=False).model
    rows = applied.constraint(d.X[at], groups=d.demo[at], t=d.t[at])[:, : model.n_constraints_]
    rows = rows / np.maximum(np.linalg.norm(rows, axis=-1, keepdims=True), 1e-300)
    ref = rows.mean(0)  # one sign for every arrow of a row: towards the row's mean direction
    rows = rows * np.sign(np.einsum("msq,sq->ms", rows, ref) + 1e-300)[..., None]
    true = None
    if d.has_truth("A"):
        true = d.truth_per_sample("A")[at]
        true = true / np.maximum(np.linalg.norm(true, axis=-1, keepdims=True), 1e-300)
    step = max(1, -(-d.n_samples // TRAJECTORY_POINTS))
    keep = np.union1d(np.concatenate([m[::step] for m in group_rows(d.demo)[1]]), at) if step > 1 else None
    return {"title": f"{title}: the trajectory and the learnt constraint", "part": part,
            "d": d if keep is None else d.without_truth().subset(keep),
            "at": at if keep is None else np.searchsorted(keep, at), "learnt": rows, "true": true}
