"""Recordings made of time-stamped streams (CSV tables, ROS bags, MCAP) → demonstrations.

A :class:`StreamReader` yields one :class:`Stream` per selection (a topic's field, or
table columns). :meth:`StreamReader.read` reads the state (and action) stream the options
name, drops non-finite samples, aligns the action onto the state's stamps by linear
interpolation (state samples outside the action's span are dropped) or derives it from
the state (:mod:`ccl_cli.io.derivative`), maps joints to the end effector when the state asks
for ``forward_kinematics`` (:mod:`ccl_cli.io.task_space`), and cuts demonstrations and phases
(:mod:`ccl_cli.io.segment`; ``demos.where`` reads its signal as one more stream).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ccl_cli.dataset import Demonstrations, Derivative, Repair, stamps_assumed
from ccl_cli.errors import InputError
from ccl_cli.io import forces
from ccl_cli.io.derivative import derive_actions
from ccl_cli.io.options import DataOptions, DemoOptions, FaultOptions, StreamOptions
from ccl_cli.io.reader import ReaderBase, Recording
from ccl_cli.io.segment import segment_ids
from ccl_cli.io.task_space import log_joint_names, to_task_space, with_joints

log = logging.getLogger("ccl")


@dataclass
class Stream:
    """One selection from one file: ``t_ns`` (n,) int64 nanoseconds, ``values`` (n, d)
    float64, a name per column, the file it came from and what was read (``meta``); for the
    state, what its fault repair did to each sample (``repair``)."""

    t_ns: np.ndarray
    values: np.ndarray
    names: list[str]
    source: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    repair: Repair | None = None


class StreamReader(ReaderBase):
    """A format of time-stamped streams. A subclass gives :meth:`streams` (several in one
    pass where it can) and :meth:`listing` (time span and topics or columns)."""

    #: whether a stream may come from a sibling file (``file``) or lie along ``samples``
    sibling_files: ClassVar[bool] = False

    def __init__(self, path: str | Path, options: DataOptions) -> None:
        super().__init__(path, options)
        for selection in (options.state, options.action, *forces.selections(options).values()):
            if not self.sibling_files and selection is not None and \
                    (selection.file is not None or selection.samples is not None):
                raise InputError(f"{self.path}: file and samples apply to CSV/text input, not {self.format}")

    def streams(self, selections: Sequence[StreamOptions]) -> list[Stream]:
        """One :class:`Stream` per selection, in order."""
        raise NotImplementedError

    def read_streams(self, selections: Sequence[StreamOptions]) -> list[Stream]:
        """:meth:`streams` for :meth:`read`, which asks once: a format that holds what it read
        (a CSV table) may let go of it while the streams are made."""
        return self.streams(selections)

    def listing(self) -> dict[str, Any]:
        """``start_ns``, ``end_ns`` and ``topics`` ({name: {type, count}}) or the table's columns."""
        raise NotImplementedError

    def span(self, listing: dict[str, Any]) -> dict[str, Any]:
        """Start, end and duration (s) of a :meth:`listing`, and the container's storage,
        compression and message encoding where it says them."""
        return {"start_ns": listing["start_ns"], "end_ns": listing["end_ns"],
                "duration_s": (listing["end_ns"] - listing["start_ns"]) / 1e9,
                **{k: listing[k] for k in ("storage", "compression", "encoding") if listing.get(k)}}

    def read(self) -> Recording:
        o = self.options
        if o.state is None:
            raise InputError(f"{self.path}: data.state is required for {self.format} input "
                             "(e.g. state: {topic: /joint_states, field: position})")
        derive = o.derives_action
        fk = o.state.forward_kinematics
        selections = [with_joints(o.state, fk)]
        if not derive:
            selections.append(with_joints(o.action, fk, selections[0].joints))
        signal = o.demos.where
        extra = [forces.plain(s) for s in forces.selections(o).values()]  # data.force: read in the same pass
        raw = self.read_streams(selections + extra + ([signal.selection()] if signal is not None else []))
        state = _repaired(raw[0], selections[0], o)
        rest = [_clean(s, sel, o.nonfinite) for s, sel in zip(raw[1:], selections[1:], strict=False)]
        t_ns, X, repair = state.t_ns, state.values, state.repair
        meta: dict[str, Any] = {"source": str(self.path), "format": self.format, "state": state.meta}
        if state.meta.get("faults"):
            meta["faults"] = state.meta.pop("faults")
        U: np.ndarray | None = None
        if rest:
            (action,), selection = rest, o.action
            paced = stamps_assumed(state.meta.get("time_column"))
            if selection.file and paced and len(action.t_ns) != len(t_ns):
                raise InputError(f"{self.path}: {len(t_ns)} state samples but {len(action.t_ns)} action "
                                 f"samples in {selection.file}; check samples: rows|columns")
            U, inside = align(t_ns, action.t_ns, action.values)
            if not inside.any():
                raise InputError(f"{self.path}: the action stream ({selection.describe()}) does not "
                                 "overlap the state stream in time")
            dropped = int((~inside).sum())
            if dropped:
                t_ns, X, repair = t_ns[inside], X[inside], repair.after(inside, len(inside))
            action_names = action.names
            meta["action"] = {**action.meta, "aligned": "linear interpolation onto state stamps",
                              "dropped_outside_span": dropped}
            how = Derivative(False)  # recorded
        else:
            action_names = [f"d{n}/dt" for n in state.names]
        state_names, units = state.names, None
        if fk is not None:  # joints → end-effector pose (and velocity)
            names = log_joint_names(selections[0], state.names)
            X, U, joints = to_task_space(X, U, fk, names, str(self.path))
            state_names = joints.names
            action_names = [f"v{n}" for n in joints.names] if U is not None else \
                [f"d{n}/dt" for n in joints.names]
            meta["forward_kinematics"], units = joints.describe(), joints.units
        t_s = (t_ns - t_ns[0]) / 1e9
        passes = None
        if signal is not None:  # demos.where: the signal's level at the state stamps
            level = _clean(raw[-1], signal.selection(), "drop")
            values, inside = align(t_ns, level.t_ns, level.values)
            passes = np.zeros(len(t_ns), bool)
            passes[inside] = signal.passes(values)
        demo = segment_ids(t_s, o.demos, str(self.path), passes)
        keep = demo >= 0
        t = t_s  # seconds from the first sample kept
        if not keep.all():  # samples outside every demos.range
            t_ns, t_s, X, demo = t_ns[keep], t_s[keep], X[keep], demo[keep]
            repair = repair.after(keep, len(keep))
            U = U[keep] if U is not None else None
            t = (t_ns - t_ns[0]) / 1e9
        if U is None:
            paced = stamps_assumed(state.meta.get("time_column"))
            U, meta["action"] = derive_actions(t_s, X, demo, o.action, paced=paced)
            how = Derivative.from_record(meta["action"])
        data = Demonstrations(X=X, U=U, demo=demo, t=t,
                              state_names=state_names, action_names=action_names, state_units=units,
                              action_units=[f"{u}/s" for u in units] if units else None, metadata=meta,
                              derivative=how, repair=repair)
        if extra:
            got = [_clean(s, sel, o.nonfinite) for s, sel in zip(raw[len(selections):], extra, strict=False)]
            data = forces.on_stamps(data, t_ns, got, o, str(self.path), align)
        return Recording(data, int(t_ns[0]))

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        raise NotImplementedError


def _clean(stream: Stream, selection: StreamOptions, nonfinite: str, options: DataOptions | None = None
           ) -> Stream:
    """Non-finite samples dropped (or refused), then — for the state (``options`` given) — its
    sensor faults found and handled as ``options.faults`` says
    (:func:`ccl_cli.io.stored_faults.check_positions`, the findings in ``stream.meta["faults"]``); the
    stamps must then increase strictly."""
    where = f"{stream.source} ({selection.describe()})"
    if not np.isfinite(stream.values).all():  # one pass over the values; rows only when needed
        stream.t_ns, stream.values = drop_nonfinite(stream.t_ns, stream.values, nonfinite, where)
    if len(stream.t_ns) == 0:
        raise InputError(f"{where}: no samples left")
    if options is not None:
        stream = _repair_faults(stream, options.faults, options.demos, where)
    check_increasing(stream.t_ns, where)
    return stream


def _repaired(stream: Stream, selection: StreamOptions, options: DataOptions) -> Stream:
    return _clean(stream, selection, options.nonfinite, options)


def _repair_faults(stream: Stream, options: FaultOptions, demos: DemoOptions, where: str) -> Stream:
    """The state stream with its faults handled: stamps repaired (a re-stamped sample gets the
    repaired time, every other keeps its exact int64 stamp), flips mirrored back or dropped,
    spikes dropped — as ``options`` says; the findings, with counts, sample and time ranges
    (seconds from the first sample), in ``meta["faults"]``. Each demonstration the ``demos``
    options cut (e.g. on pauses) is searched on its own: a cut is never taken for a fault."""
    from ccl_cli.io.stored_faults import check_positions

    t0 = stream.t_ns[0]
    t_s = (stream.t_ns - t0) / 1e9
    phases = {"where": None, "min_duration": None}
    if isinstance(demos.ranges, dict):
        phases["ranges"] = None
    cuts = demos.model_copy(update=phases)  # faults are searched per demonstration, not per phase
    pieces = segment_ids(np.maximum.accumulate(t_s), cuts, where)
    cleaned = check_positions(t_s, stream.values, pieces, options)
    if cleaned is None:
        stream.repair = Repair.untouched(len(t_s))
        return stream
    kept = stream.t_ns[cleaned.keep]
    moved = cleaned.t != t_s[cleaned.keep]
    stream.t_ns = np.where(moved, t0 + np.round(cleaned.t * 1e9).astype(np.int64), kept)
    stream.values = cleaned.X
    stream.meta = {**stream.meta, "faults": cleaned.report(t_s)}
    stream.repair = cleaned.record()
    return stream


def check_increasing(t_ns: np.ndarray, where: str) -> None:
    """Refuse stamps (n,) that do not strictly increase, naming the first sample at fault."""
    d = np.diff(t_ns)
    if (d <= 0).any():
        k = int(np.argmax(d <= 0)) + 1
        raise InputError(f"{where}: timestamps are not strictly increasing at sample {k} "
                         f"({int(t_ns[k - 1])} ns then {int(t_ns[k])} ns)")


def drop_nonfinite(t_ns: np.ndarray, values: np.ndarray, policy: str, where: str
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Samples whose values hold NaN or inf dropped (``policy`` drop, logged) or refused (fail)."""
    bad = ~np.isfinite(values).all(axis=1)
    if not bad.any():
        return t_ns, values
    if policy == "fail":
        raise InputError(f"{where}: {int(bad.sum())} samples contain NaN or inf "
                         f"(first at sample {int(np.argmax(bad))}); set data.nonfinite: drop to skip them")
    log.warning("%s: dropped %d samples with NaN or inf", where, int(bad.sum()))
    return t_ns[~bad], values[~bad]


def align(t_target: np.ndarray, t_source: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of ``values`` (m, d) at ``t_source`` (m,) onto ``t_target`` (n,),
    both int64 ns. Returns (values at the kept targets, boolean mask (n,) of the targets
    inside the source span)."""
    if len(t_target) == len(t_source) and np.array_equal(t_target, t_source):
        return values, np.ones(len(t_target), bool)  # same stamps (same topic): nothing to do
    inside = (t_target >= t_source[0]) & (t_target <= t_source[-1])
    base = t_source[0]
    ts = (t_source - base).astype(float)
    tt = (t_target[inside] - base).astype(float)
    out = np.empty((int(inside.sum()), values.shape[1]))
    for j in range(values.shape[1]):  # loop over dimensions, not samples
        out[:, j] = np.interp(tt, ts, values[:, j])
    return out, inside

