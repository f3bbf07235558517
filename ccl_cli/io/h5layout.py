"""HDF5 recordings: the canonical ``ccl-demonstrations`` layout, or any layout the config
describes.

A foreign layout is read through dataset paths in the ``data`` section::

    demos:  {group: "data/demo_*"}        # one demonstration per matching group (natural sort)
    state:  {dataset: obs/joint_pos}       # relative to each group
    action: {dataset: actions}             # or {derive: state}
    time:   {dataset: t}                   # or {rate: 100} (Hz)

or one flat dataset per variable plus ``demos: {dataset: demo_index}`` (a demo id per
sample), or neither (the whole file is one demonstration). Datasets are one sample per
row unless ``samples: columns``; ``columns: [...]`` picks columns (by index, or by name
when the dataset carries a ``names``/``column_names``/``joint_names`` attribute, which
also names the state and action dimensions).

Files are opened through :func:`ccl_cli.io.h5safe.open_hdf5`: external links, external
storage and virtual datasets are refused before anything is read, and a file ccl did not
write is parsed in a time-limited child process first.
"""

from __future__ import annotations

import fnmatch
import re
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.io import h5safe
from ccl_cli.io.arrays import (
    NAME_ATTRS,
    Variable,
    assemble,
    named_parts,
    numeric,
    orient,
    split_by_index,
    wants_derived,
)

LAYOUT_KEYS = (("state", "dataset"), ("action", "dataset"), ("time", "dataset"), ("demos", "group"),
               ("demos", "dataset"))


def uses_layout(data_cfg: dict[str, Any]) -> bool:
    """True when the config names datasets (a foreign layout)."""
    return any(isinstance(data_cfg.get(s), dict) and data_cfg[s].get(k) is not None for s, k in LAYOUT_KEYS)


def is_canonical_input(path: Path, data_cfg: dict[str, Any] | None) -> bool:
    """True when ``path`` is read as a canonical file (HDF5, canonical, no layout keys)."""
    from ccl_cli.io.hdf5 import is_canonical
    from ccl_cli.io.registry import resolve_format

    return resolve_format(Path(path), data_cfg) == "hdf5" and not uses_layout(data_cfg or {}) \
        and is_canonical(Path(path))


def natural_key(text: str) -> list[Any]:
    """'demo_10' after 'demo_9'."""
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", text)]


def match_groups(f, pattern: str) -> list[str]:
    """Paths of the groups matching a glob, component by component (``*`` never crosses
    ``/``), in natural order."""
    import h5py

    current = [("", f)]
    for comp in [c for c in pattern.strip("/").split("/") if c]:
        nxt = []
        for path, group in current:
            for name in group:
                if fnmatch.fnmatchcase(name, comp) and isinstance(group[name], h5py.Group):
                    nxt.append((f"{path}/{name}" if path else name, group[name]))
        current = nxt
    return sorted((p for p, _ in current), key=natural_key)


def _contents(group, limit: int = 6) -> str:
    """'obs/joint_pos (40×7 float64), actions (40×7 float64), … (12 datasets)'."""
    import h5py

    found: list[str] = []

    def visit(name: str, obj) -> None:
        if isinstance(obj, h5py.Dataset):
            found.append(f"{name} ({'×'.join(map(str, obj.shape)) or 'scalar'} {obj.dtype})")

    group.visititems(visit)
    more = f", … ({len(found)} datasets)" if len(found) > limit else ""
    return (", ".join(found[:limit]) or "no datasets") + more


def _dataset(group, rel: str, where: str, spec: dict[str, Any], keep_int: bool = False,
             names: bool = True) -> Variable:
    """One dataset under ``group`` as a checked :class:`Variable` (read through h5py's
    low-level API: the high-level object layer costs more than the read for small datasets)."""
    import h5py

    rel = rel.strip("/")
    here = f"{where}:/{group.name.strip('/') + '/' if group.name != '/' else ''}{rel}"
    try:
        oid = h5py.h5o.open(group.id, rel.encode())
    except KeyError:
        raise InputError(f"{here}: missing, not a dataset (this group has: {_contents(group)})") from None
    if not isinstance(oid, h5py.h5d.DatasetID):
        raise InputError(f"{here}: a group, not a dataset (this group has: {_contents(group)})")
    dtype = oid.dtype
    if dtype.kind not in "biuf":  # text, references, compounds: refused before reading
        raw = np.zeros(0, dtype=dtype if dtype.kind in "SUOc" else "V1")
    else:
        raw = np.empty(oid.shape, dtype=dtype)
        try:
            if raw.size:
                oid.read(h5py.h5s.ALL, h5py.h5s.ALL, raw)
        except (OSError, TypeError, ValueError) as exc:
            raise InputError(f"{here}: cannot read ({exc})") from None
    found = None
    attrs = h5py.Dataset(oid).attrs if names else {}
    for key in NAME_ATTRS if names else ():
        if key in attrs:
            found = [v.decode() if isinstance(v, bytes) else str(v) for v in np.ravel(attrs[key])]
            break
    return Variable(numeric(raw, here, keep_int), here, spec.get("samples"), found)


def _part(group, data_cfg: dict[str, Any], where: str, label: str, derive: bool, names: bool = True
          ) -> tuple[dict[str, np.ndarray], dict[str, Variable]]:
    """The oriented arrays of one group (names attributes read when ``names``)."""
    vars_: dict[str, Variable] = {"state": _dataset(group, data_cfg["state"]["dataset"], where,
                                                    data_cfg["state"], names=names)}
    if not derive:
        action = data_cfg["action"]
        if action.get("dataset") is None:
            raise InputError(f"{where}: data.action needs dataset: PATH (or derive: state)")
        vars_["action"] = _dataset(group, action["dataset"], where, action, names=names)
    tcfg = data_cfg.get("time") or {}
    if tcfg.get("dataset") is not None:
        vars_["time"] = _dataset(group, tcfg["dataset"], where, {}, keep_int=True)
    return orient(vars_, "rows", f"{where}: {label}"), vars_


def read_layout(f, path: Path, data_cfg: dict[str, Any]) -> tuple[Demonstrations, int]:
    """A foreign layout → (Demonstrations, time origin ns); see the module docstring for the keys."""
    where = str(path)
    state = data_cfg.get("state") or {}
    if state.get("dataset") is None:
        raise InputError(f"{where}: data.state.dataset is required to read this HDF5 layout "
                         f"(the file has: {_contents(f)})")
    derive = wants_derived(data_cfg, where)
    demos = data_cfg.get("demos") or {}
    unknown = set(demos) - {"group", "dataset"}
    if unknown:
        raise InputError(f"unknown demos option(s) for an HDF5 layout: {', '.join(sorted(unknown))} "
                         "(use group or dataset)")
    if demos.get("group") is not None and demos.get("dataset") is not None:
        raise InputError("data.demos: give group (one demonstration per group) or dataset (a demo id "
                         "per sample), not both")
    tcfg = data_cfg.get("time") or {}
    chunks: list[tuple[str, dict[str, np.ndarray]]] = []
    variables: dict[str, Variable] = {}
    if demos.get("group") is not None:
        groups = match_groups(f, demos["group"])
        if not groups:
            raise InputError(f"{where}: no group matches demos.group {demos['group']!r} "
                             f"(the file has: {_contents(f)})")
        for k, name in enumerate(groups):
            arrays, found = _part(f[name], data_cfg, where, name, derive, names=k == 0)
            variables = variables or found  # names from the first group's attributes
            chunks.append((name, arrays))
    else:
        arrays, variables = _part(f, data_cfg, where, "file", derive)
        if demos.get("dataset") is not None:
            index = _dataset(f, demos["dataset"], where, {})
            n = arrays["state"].shape[0]
            if index.values.size != n:
                raise InputError(f"{index.where}: {index.values.size} demo ids for {n} samples")
            chunks = split_by_index(arrays, index.values, index.where)
        else:
            chunks = [("file", arrays)]
    keys = ("state",) if derive else ("state", "action")
    parts, state_names, action_names, origin, time_used = named_parts(
        chunks, data_cfg, where, {k: data_cfg[k]["dataset"].strip("/").split("/")[-1] for k in keys},
        {k: variables[k].names for k in keys}, derive)
    meta = {"source": where, "format": "hdf5", "layout": {
        "state": state["dataset"], "action": "derived" if derive else data_cfg["action"]["dataset"],
        "time": f"{tcfg['dataset']}: {time_used}" if tcfg.get("dataset") else time_used,
        "demos": demos.get("group") or demos.get("dataset") or "whole file"}}
    return assemble(parts, data_cfg, where, state_names, action_names, meta), origin


class Hdf5File:
    """An HDF5 recording read through the ``data`` config section."""

    def __init__(self, path: Path, data_cfg: dict[str, Any]) -> None:
        self.path = Path(path)
        self.data_cfg = data_cfg

    def load(self) -> tuple[Demonstrations, int]:
        from ccl_cli.io.assemble import resegment
        from ccl_cli.io.hdf5 import FORMAT, read_demonstrations

        with h5safe.open_hdf5(self.path, "HDF5 recording") as f:
            if uses_layout(self.data_cfg):
                return read_layout(f, self.path, self.data_cfg)
            found = f.attrs.get("format")
            found = found.decode() if isinstance(found, bytes) else found
            if found != FORMAT:
                raise InputError(
                    f"{self.path}: HDF5 not in the {FORMAT} layout; say where the data is with "
                    "data.state.dataset (and action.dataset or action.derive, time.dataset or "
                    f"time.rate, demos.group or demos.dataset); the file has: {_contents(f)}")
        data, info = read_demonstrations(self.path)
        data, _ = resegment(data, self.data_cfg.get("demos"), str(self.path))
        return data, info["time_origin_ns"]

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        from ccl_cli.io.hdf5 import is_canonical, read_demonstrations
        from ccl_cli.io.tree import describe_tree

        out: dict[str, Any] = {}
        if uses_layout(self.data_cfg) or not is_canonical(self.path):
            out["tree"] = describe_tree(self.path)  # a canonical file is summarised, not listed
        if uses_layout(self.data_cfg):
            data, _ = self.load()
            out.update(summary(data))
            out["time"] = data.metadata["layout"]["time"]
        elif is_canonical(self.path):
            data, info = read_demonstrations(self.path)
            out.update(summary(data))
            out.update({"truth": sorted(data.truth), "masks": {k: len(v) for k, v in info["masks"].items()}})
        return out


def summary(data: Demonstrations) -> dict[str, Any]:
    """Counts and names of what a reader produced (for ``ccl inspect``)."""
    counts = np.bincount(np.unique(data.demo, return_inverse=True)[1])
    return {"samples": data.n_samples, "demos": int(data.n_demos), "state_names": data.state_names,
            "action_names": data.action_names, "samples_per_demo": counts.tolist(),
            "duration_s": float(sum(np.ptp(data.t[data.demo == d]) for d in data.demo_ids))}
