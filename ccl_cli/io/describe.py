"""``ccl inspect``: what a recording holds, before writing a config for it.

Per topic (bags, MCAP) the message type, count, the rate over the *active* time (pauses
longer than the gap are left out, so a 500 Hz stream recorded in bursts shows 500 Hz),
the message fields and, for JointState, the joint names; per CSV the columns and the
rate; and the demonstrations a gap split finds. The gap is ``--gap``, else the config's
``data.demos.split_on_gap``, else five times the median sampling interval.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import InputError

#: Default gap: a pause longer than this many median sampling intervals starts a new demonstration.
GAP_INTERVALS = 5.0


def activity(t_ns: np.ndarray, gap_s: float | None = None) -> dict[str, Any]:
    """Rate over the active time and the demonstrations of timestamps ``t_ns`` (n,).

    Intervals longer than ``gap_s`` (default GAP_INTERVALS × the median interval) are
    pauses: rate = (intervals that are not pauses) / (their summed duration);
    demos = pauses + 1."""
    t = np.sort(np.asarray(t_ns, dtype=np.int64))
    if t.size < 2:
        return {"rate_hz": None, "active_s": 0.0, "demos": int(t.size > 0), "gap_s": gap_s}
    dt = np.diff(t) / 1e9
    rule = None
    if gap_s is None:
        med = float(np.median(dt))
        gap_s, rule = GAP_INTERVALS * med, f"{GAP_INTERVALS:g} × median interval"
    pause = dt > gap_s
    active = float(dt[~pause].sum())
    out = {"rate_hz": float((~pause).sum() / active) if active > 0 else None, "active_s": active,
           "demos": int(pause.sum()) + 1, "gap_s": float(gap_s)}
    return out | ({"gap_rule": rule} if rule else {})


def _fields(msg: Any) -> list[str]:
    if isinstance(msg, dict):
        return [k for k in msg if not k.startswith("_")]
    if dataclasses.is_dataclass(msg):
        return [f.name for f in dataclasses.fields(msg) if not f.name.startswith("_")]
    slots = getattr(msg, "__slots__", None)
    if slots:
        return [s for s in slots if not s.startswith("_")]
    return [k for k in vars(msg) if not k.startswith("_")] if hasattr(msg, "__dict__") else []


def _joint_names(msg: Any) -> list[str] | None:
    names = msg.get("name") if isinstance(msg, dict) else getattr(msg, "name", None)
    if isinstance(names, list | tuple) and names and all(isinstance(n, str) for n in names):
        return list(names)
    return None


def _bag_topics(reader) -> dict[str, tuple[np.ndarray, Any]]:
    """Log times (ns) of every message and the first message (decoded) of each topic of a bag."""
    from ccl_cli.io.streams import library_call, library_iter

    bag = reader._open()
    try:
        times: dict[str, list[int]] = {}
        first: dict[str, Any] = {}
        where, what = str(reader.path), "decode the bag's messages"
        for conn, log_ns, raw in library_iter(where, what, bag.messages()):
            times.setdefault(conn.topic, []).append(log_ns)
            if conn.topic not in first:
                first[conn.topic] = library_call(where, what, bag.deserialize, raw, conn.msgtype)
        return {k: (np.asarray(v, dtype=np.int64), first.get(k)) for k, v in times.items()}
    finally:
        bag.close()


def _mcap_topics(reader) -> dict[str, tuple[np.ndarray, Any]]:
    """Log times (ns) and the first decoded message of each topic of an MCAP file."""
    import json

    from ccl_cli.io.streams import library_call, library_iter

    out: dict[str, tuple[np.ndarray, Any]] = {}
    where, what = str(reader.path), "read MCAP messages"
    with reader._open() as f:
        mc, _ = reader._summary(f)
        times: dict[str, list[int]] = {}
        enc: dict[str, str] = {}
        for _, channel, message in library_iter(where, what, mc.iter_messages()):
            times.setdefault(channel.topic, []).append(message.log_time)
            enc[channel.topic] = channel.message_encoding
        for topic in times:
            f.seek(0)
            mc, _ = reader._summary(f)
            if enc[topic] == "json":
                found = next(library_iter(where, what, mc.iter_messages(topics=[topic])), None)
                msg = library_call(where, what, json.loads, found[2].data) if found else None
            else:
                found = next(library_iter(where, what, mc.iter_decoded_messages(topics=[topic])), None)
                msg = found[3] if found else None
            if found is None:
                raise InputError(f"{where}: topic {topic} lost its messages on a second read")
            try:  # a damaged file can claim log times beyond int64
                stamps = np.asarray(times[topic], dtype=np.int64)
            except OverflowError:
                raise InputError(f"{where}: topic {topic} has log times beyond 64-bit nanoseconds "
                                 "(damaged file?)") from None
            out[topic] = (stamps, msg)
    return out


def inspect_recording(path: str | Path, config: dict[str, Any] | None = None,
                      gap: float | None = None) -> dict[str, Any]:
    """Summary of a recording (see the module docstring): the base listing of
    :func:`ccl_cli.io.inspect_path` plus, per topic, ``rate_hz`` over the active time,
    ``active_s``, ``fields`` and ``joint_names``, and ``demos`` (with ``demos_from``,
    ``gap_s`` and ``gap_rule``) for the state topic (the config's, else the busiest)."""
    from ccl_cli.io import detect_format, inspect_path, open_reader
    from ccl_cli.io.streams import StreamSpec

    config = config or {}
    source = "--gap"
    if gap is None:
        gap = (config.get("demos") or {}).get("split_on_gap")
        source = "data.demos.split_on_gap of the config"
    out = inspect_path(path, config, None)
    fmt = out["format"]
    if fmt not in ("bag", "mcap", "csv"):
        return out
    samples = (config.get("state") or {}).get("samples") if fmt == "csv" else None  # text matrices
    reader = open_reader(path, fmt if fmt else detect_format(Path(path)), config, samples)
    if fmt == "csv":
        columns = out.get("columns") or []
        state = (config.get("state") or {}).get("columns") or [c for c in columns
                                                               if c != out.get("time_column")][:1]
        if not state:
            return out
        stream = reader.read(StreamSpec(columns=state[:1]))
        act = activity(stream.t_ns, gap)
        out.update({"rate_hz": act["rate_hz"], "active_s": act["active_s"], "demos": act["demos"],
                    "demos_from": "rows", "gap_s": act["gap_s"], "gap_rule": act.get("gap_rule", source)})
        return out
    topics = _bag_topics(reader) if fmt == "bag" else _mcap_topics(reader)
    listing = out.get("topics") or {}
    for name, (t_ns, msg) in topics.items():
        entry = listing.setdefault(name, {"type": "", "count": int(t_ns.size)})
        act = activity(t_ns, gap)
        entry.update({"rate_hz": act["rate_hz"], "active_s": act["active_s"], "fields": _fields(msg)})
        joints = _joint_names(msg) if "JointState" in str(entry.get("type")) else None
        if joints:
            entry["joint_names"] = joints
    state_topic = (config.get("state") or {}).get("topic")
    if state_topic not in topics:
        state_topic = max(topics, key=lambda k: topics[k][0].size) if topics else None
    if state_topic is not None:
        act = activity(topics[state_topic][0], gap)
        out.update({"demos": act["demos"], "demos_from": state_topic, "gap_s": act["gap_s"],
                    "gap_rule": act.get("gap_rule", source)})
    out["topics"] = listing
    return out
