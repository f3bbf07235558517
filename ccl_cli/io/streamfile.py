"""Recordings made of time-stamped streams (CSV, ROS bags, MCAP) as one :class:`Reader`.

A stream source (:class:`StreamSource`: the CSV, bag and MCAP readers) yields one
:class:`~ccl_cli.io.streams.Stream` per :class:`~ccl_cli.io.streams.StreamSpec`.
:class:`StreamFile` reads the state (and action) streams the config names, drops
non-finite samples, aligns the action onto the state's stamps or derives it, and
splits demonstrations (see :mod:`ccl_cli.io.assemble`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.io.assemble import (
    align,
    check_increasing,
    derive_actions,
    drop_nonfinite,
    segment_ids,
)
from ccl_cli.io.streams import Stream, StreamSpec


class StreamSource(Protocol):
    """A file of named numeric streams."""

    path: Path

    def inspect(self) -> dict[str, Any]: ...

    def read(self, spec: StreamSpec) -> Stream: ...

    def read_many(self, specs: list[StreamSpec]) -> list[Stream]: ...


def open_reader(path: str | Path, fmt: str | None = None, config: dict[str, Any] | None = None,
                samples: str | None = None) -> StreamSource:
    """The stream source of ``path`` (CSV, bag or MCAP); ``samples`` (CSV only): rows or columns."""
    from ccl_cli.io.registry import detect_format

    config = config or {}
    path = Path(path)
    fmt = fmt if fmt and fmt != "auto" else detect_format(path)
    if fmt == "csv":
        from ccl_cli.io.csvfile import CsvReader

        tcfg = config.get("time") or {}
        return CsvReader(path, tcfg.get("column"), tcfg.get("unit"), tcfg.get("rate"),
                         tcfg.get("delimiter"), samples)
    if fmt == "bag":
        from ccl_cli.io.bag import BagReader

        return BagReader(path, config.get("typestore"))
    if fmt == "mcap":
        from ccl_cli.io.mcapfile import McapReader

        return McapReader(path)
    raise InputError(f"{path}: format {fmt!r} has no stream reader")


def _clean(stream: Stream, spec: StreamSpec, nonfinite: str) -> Stream:
    where = f"{stream.source} ({spec.describe()})"
    stream.t_ns, stream.values = drop_nonfinite(stream.t_ns, stream.values, nonfinite, where)
    if len(stream.t_ns) == 0:
        raise InputError(f"{where}: no samples left")
    check_increasing(stream.t_ns, where)
    return stream


class StreamFile:
    """A CSV, bag or MCAP recording read through the ``data`` config section."""

    def __init__(self, path: Path, fmt: str, data_cfg: dict[str, Any]) -> None:
        self.path = Path(path)
        self.format = fmt
        self.data_cfg = data_cfg
        state = data_cfg.get("state") if isinstance(data_cfg.get("state"), dict) else {}
        self._sources: dict[tuple[Path, str | None], StreamSource] = {}
        self.source = self.source_for({"samples": state.get("samples")})

    def source_for(self, stream_cfg: dict[str, Any]) -> StreamSource:
        """The source of one stream: the recording itself, or (text files) a sibling
        ``file`` (relative to the recording's folder), read with its ``samples`` side."""
        file, samples = stream_cfg.get("file"), stream_cfg.get("samples")
        if (file is not None or samples is not None) and self.format != "csv":
            raise InputError(f"{self.path}: file and samples apply to CSV/text input, not {self.format}")
        path = self.path if file is None else (Path(file) if Path(file).is_absolute()
                                               else self.path.parent / file)
        if file is not None and not path.exists():
            raise InputError(f"{path}: no such file (stream file {file!r}, relative to {self.path.parent})")
        key = (path, samples)
        if key not in self._sources:
            self._sources[key] = open_reader(path, self.format, self.data_cfg, samples)
        return self._sources[key]

    def _read(self, specs: list[StreamSpec], cfgs: list[dict[str, Any]]) -> list[Stream]:
        if all(not c.get("file") and not c.get("samples") for c in cfgs):
            return self.source.read_many(specs)  # one pass over the recording
        return [self.source_for(c).read(s) for s, c in zip(specs, cfgs, strict=True)]

    def load(self) -> tuple[Demonstrations, int]:
        path, fmt, data_cfg = self.path, self.format, self.data_cfg
        state_spec = StreamSpec.from_config(data_cfg.get("state"))
        if state_spec is None:
            raise InputError(f"{path}: data.state is required for {fmt} input "
                             "(e.g. state: {topic: /joint_states, field: position})")
        nonfinite = data_cfg.get("nonfinite", "drop")
        action_cfg = data_cfg.get("action") or {"derive": "state"}
        derive = action_cfg.get("derive") if isinstance(action_cfg, dict) else None
        specs = [state_spec] if derive is not None else [state_spec, StreamSpec.from_config(action_cfg)]
        cfgs = [data_cfg["state"]] + ([] if derive is not None else [action_cfg])
        streams = [_clean(s, sp, nonfinite)
                   for s, sp in zip(self._read(specs, cfgs), specs, strict=True)]
        state = streams[0]
        t_ns = state.t_ns
        X = state.values
        meta: dict[str, Any] = {"source": str(path), "format": fmt, "state": state.meta}
        if derive is None:
            action_spec = specs[1]
            action = streams[1]
            paced = str(state.meta.get("time_column", "")).startswith("rate")
            if action_cfg.get("file") and paced and len(action.t_ns) != len(t_ns):
                raise InputError(f"{path}: {len(t_ns)} state samples but {len(action.t_ns)} action samples "
                                 f"in {action_cfg['file']}; check samples: rows|columns")
            U, inside = align(t_ns, action.t_ns, action.values)
            if not inside.any():
                raise InputError(f"{path}: the action stream ({action_spec.describe()}) does not "
                                 "overlap the state stream in time")
            dropped = int((~inside).sum())
            if dropped:
                t_ns, X = t_ns[inside], X[inside]
            action_names = action.names
            meta["action"] = {**action.meta, "aligned": "linear interpolation onto state stamps",
                              "dropped_outside_span": dropped}
        else:
            if derive != "state":
                raise InputError(f"data.action.derive must be 'state', got {derive!r}")
            U = None
            action_names = [f"d{n}/dt" for n in state.names]
        t_s = (t_ns - t_ns[0]) / 1e9
        demo = segment_ids(t_s, data_cfg.get("demos"), str(path))
        keep = demo >= 0
        if not keep.all():  # samples outside every demos.range
            t_ns, t_s, X, demo = t_ns[keep], t_s[keep], X[keep], demo[keep]
        if U is None:
            U, meta["action"] = derive_actions(t_s, X, demo, action_cfg)
        elif not keep.all():
            U = U[keep]
        data = Demonstrations(X=X, U=U, demo=demo, t=(t_ns - t_ns[0]) / 1e9,
                              state_names=state.names, action_names=action_names, metadata=meta)
        return data, int(t_ns[0])

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        info = self.source.inspect()
        span = (info["end_ns"] - info["start_ns"]) / 1e9
        out: dict[str, Any] = {"start_ns": info["start_ns"], "end_ns": info["end_ns"], "duration_s": span}
        if "topics" in info:
            for topic in info["topics"].values():
                topic["rate_hz"] = (topic["count"] - 1) / span if span > 0 and topic["count"] > 1 else None
            out["topics"] = info["topics"]
        else:
            out.update({k: info[k] for k in ("columns", "rows", "time_column", "header", "sample_axis")})
            if info["rows"] > 1 and span > 0:
                out["rate_hz"] = (info["rows"] - 1) / span
        if self.format == "csv":  # the columns a config would read (or all, for a text matrix)
            for key in ("state", "action"):
                cfg = self.data_cfg.get(key)
                if isinstance(cfg, dict) and cfg.get("derive") is None and \
                        (cfg.get("columns") or (key == "state" and not info.get("header", True))):
                    out[f"{key}_names"] = self.source_for(cfg).read(StreamSpec.from_config(cfg)).names
        if gap is not None and self.data_cfg.get("state"):
            state = self.data_cfg["state"]
            stream = self.source_for(state).read(StreamSpec.from_config(state))
            ids = segment_ids((stream.t_ns - stream.t_ns[0]) / 1e9, {"split_on_gap": gap}, str(self.path))
            out["demos"] = int(ids.max()) + 1
        return out
