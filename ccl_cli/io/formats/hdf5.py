"""HDF5 recordings: the canonical ``ccl-demonstrations`` layout (:mod:`ccl_cli.io.canonical`),
or any layout the options describe.

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

Files are opened through :func:`ccl_cli.io.h5.probe.open_hdf5`: external links, external
storage and virtual datasets are refused before anything is read, and a file ccl did not
write is parsed in a time-limited child process first.
"""

from __future__ import annotations

import fnmatch
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import Derivative
from ccl_cli.errors import InputError
from ccl_cli.io import forces
from ccl_cli.io.arrays import (
    NAME_ATTRS,
    Variable,
    as_numeric,
    assemble,
    cut_parts,
    named_parts,
    orient,
    split_by_index,
)
from ccl_cli.io.canonical import FORMAT, is_canonical, read_demonstrations
from ccl_cli.io.h5.access import attr_names, attr_str, error_text
from ccl_cli.io.h5.listing import list_hdf5
from ccl_cli.io.h5.probe import open_hdf5
from ccl_cli.io.limits import check_claim
from ccl_cli.io.options import DataOptions, StreamOptions
from ccl_cli.io.reader import ReaderBase, Recording
from ccl_cli.io.segment import CUTS, resegment
from ccl_cli.io.sniff import MAT73_MAGIC, read_head
from ccl_cli.io.stored_faults import repair_dataset
from ccl_cli.io.summary import summary


def uses_layout(options: DataOptions) -> bool:
    """True when the options name datasets (a foreign layout)."""
    demos = options.demos
    named = [s.dataset for s in (options.state, options.action) if s is not None]
    return any(v is not None for v in (*named, options.time.dataset, demos.group, demos.dataset))


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


def _dataset(group, rel: str, where: str, samples: str | None = None, keep_int: bool = False,
             names: bool = True) -> Variable:
    """One dataset under ``group`` as a checked :class:`Variable` (read through h5py's
    low-level API, see docs/readers.md), its names from a ``names``-like attribute."""
    import h5py

    rel = rel.strip("/")
    here = f"{where}:/{group.name.strip('/') + '/' if group.name != '/' else ''}{rel}"
    try:
        oid = h5py.h5o.open(group.id, rel.encode())
    except KeyError:
        raise InputError(f"{here}: missing, not a dataset (this group has: {_contents(group)})") from None
    if not isinstance(oid, h5py.h5d.DatasetID):
        raise InputError(f"{here}: a group, not a dataset (this group has: {_contents(group)})")
    try:
        dtype, shape = oid.dtype, tuple(oid.shape)
    except (OSError, RuntimeError, ValueError, TypeError) as exc:  # a damaged datatype or dataspace
        raise InputError(f"{here}: unreadable type or shape ({error_text(exc)})") from None
    if dtype.kind not in "biuf":  # text, references, compounds: refused before reading
        raw = np.zeros(0, dtype=dtype if dtype.kind in "SUOc" else "V1")
    else:
        # the declared size, before anything is allocated (read as float64 afterwards)
        check_claim(here, "the dataset", shape, 8, os.path.getsize(where))
        raw = np.empty(shape, dtype=dtype)
        try:
            if raw.size:
                oid.read(h5py.h5s.ALL, h5py.h5s.ALL, raw)
        except (OSError, RuntimeError, TypeError, ValueError) as exc:
            raise InputError(f"{here}: cannot read ({error_text(exc)})") from None
    found = None
    attrs = h5py.Dataset(oid).attrs if names else {}
    for key in NAME_ATTRS if names else ():
        found = attr_names(attrs, key, here)
        if found is not None:
            break
    return Variable(as_numeric(raw, here, keep_int), here, samples, found)


def _variable(group, selection: StreamOptions, where: str, names: bool) -> Variable:
    return _dataset(group, selection.dataset, where, selection.samples, names=names)


def _part(group, options: DataOptions, where: str, label: str, names: bool = True
          ) -> tuple[dict[str, np.ndarray], dict[str, Variable]]:
    """The oriented arrays of one group (names attributes read when ``names``)."""
    vars_: dict[str, Variable] = {"state": _variable(group, options.state, where, names)}
    if not options.derives_action:
        if options.action.dataset is None:
            raise InputError(f"{where}: data.action needs dataset: PATH (or derive: state)")
        vars_["action"] = _variable(group, options.action, where, names)
    if options.time.dataset is not None:
        vars_["time"] = _dataset(group, options.time.dataset, where, keep_int=True)
    for key, selection in forces.selections(options).items():  # data.force beside the state
        if selection.dataset is None:
            raise InputError(f"{where}: {forces.option_path(key)} needs dataset: PATH "
                             "for an HDF5 layout")
        vars_[key] = _variable(group, selection, where, False)
    return orient(vars_, "rows", f"{where}: {label}"), vars_


def read_layout(f, path: Path, options: DataOptions) -> Recording:
    """A foreign layout → its demonstrations; see the module docstring for the options."""
    where = str(path)
    state = options.state
    if state is None or state.dataset is None:
        raise InputError(f"{where}: data.state.dataset is required to read this HDF5 layout "
                         f"(the file has: {_contents(f)})")
    derive = options.derives_action
    demos = options.demos
    cuts = set(CUTS) - {"per_file", "where"}
    unknown = demos.given() - {"group", "dataset"} - cuts
    if unknown:
        raise InputError(f"unknown demos option(s) for an HDF5 layout: {', '.join(sorted(unknown))} "
                         f"(use group or dataset, then {', '.join(sorted(cuts))})")
    if demos.group is not None and demos.dataset is not None:
        raise InputError("data.demos: give group (one demonstration per group) or dataset (a demo id "
                         "per sample), not both")
    chunks: list[tuple[str, dict[str, np.ndarray]]] = []
    variables: dict[str, Variable] = {}
    if demos.group is not None:
        groups = match_groups(f, demos.group)
        if not groups:
            raise InputError(f"{where}: no group matches demos.group {demos.group!r} "
                             f"(the file has: {_contents(f)})")
        for k, name in enumerate(groups):
            arrays, found = _part(f[name], options, where, name, names=k == 0)
            variables = variables or found  # names from the first group's attributes
            chunks.append((name, arrays))
    else:
        arrays, variables = _part(f, options, where, "file")
        if demos.dataset is not None:
            index = _dataset(f, demos.dataset, where)
            n = arrays["state"].shape[0]
            if index.values.size != n:
                raise InputError(f"{index.where}: {index.values.size} demo ids for {n} samples")
            chunks = split_by_index(arrays, index.values, index.where)
        else:
            chunks = [("file", arrays)]
    selections = {"state": state} if derive else {"state": state, "action": options.action}
    parts, state_names, action_names, origin, time_used = named_parts(
        chunks, options, where, {k: s.dataset.strip("/").split("/")[-1] for k, s in selections.items()},
        {k: variables[k].names for k in selections}, derive)
    parts = cut_parts(parts, demos, where)  # phases: gaps, ranges per demonstration, windows
    time = options.time.dataset
    meta = {"source": where, "format": "hdf5", "layout": {
        "state": state.dataset, "action": "derived" if derive else options.action.dataset,
        "time": f"{time}: {time_used}" if time else time_used,
        "demos": demos.group or demos.dataset or "whole file"}}
    return Recording(assemble(parts, options, where, state_names, action_names, meta), origin)


class Hdf5Reader(ReaderBase):
    """An HDF5 recording: a foreign layout when the options name datasets, else the
    canonical ``ccl-demonstrations`` layout (with its train/test masks, re-cut by
    ``demos`` options)."""

    format = "hdf5"

    def read(self) -> Recording:
        with open_hdf5(self.path, "HDF5 recording") as f:
            if uses_layout(self.options):
                return read_layout(f, self.path, self.options)
            if attr_str(f.attrs, "format", str(self.path), "") != FORMAT:
                raise InputError(
                    f"{self.path}: HDF5 not in the {FORMAT} layout; say where the data is with "
                    "data.state.dataset (and action.dataset or action.derive, time.dataset or "
                    f"time.rate, demos.group or demos.dataset); the file has: {_contents(f)}")
        data, info = read_demonstrations(self.path)
        data.metadata["format"] = "hdf5"
        data.derivative = Derivative.from_record(info["provenance"].get("derivative")) or Derivative()
        data = repair_dataset(data, self.options.faults)  # a file another tool wrote may hold them
        data, masks = resegment(data, self.options.demos, str(self.path), info["masks"])
        return Recording(data, info["time_origin_ns"], masks, info["provenance"])

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        """The tree of a foreign file; what the options read from it, or what a canonical
        file holds (counts, names, ground truth, masks)."""
        out: dict[str, Any] = {}
        layout = uses_layout(self.options)
        canonical = not layout and is_canonical(self.path)
        if not canonical:
            matlab = read_head(self.path).startswith(MAT73_MAGIC)  # format: hdf5 given for a v7.3 .mat
            out["tree"] = list_hdf5(self.path, matlab)  # a canonical file is summarised, not listed
        if layout:
            data = self.read().data
            out.update(summary(data))
            out["time"] = data.metadata["layout"]["time"]
        elif canonical:
            data, info = read_demonstrations(self.path)
            out.update(summary(data))
            out.update({"truth": sorted(data.truth), "masks": {k: len(v) for k, v in info["masks"].items()}})
        return out
