"""The canonical ``ccl-demonstrations`` HDF5 layout (read and write).

Version 2 (written by default) is columnar: one dataset per field across all
demonstrations, cut by sample offsets, so opening a file costs a few datasets whatever
the number of demonstrations::

    /                  attrs: format="ccl-demonstrations", format_version=2, state_names[p],
                              action_names[q], state_units, action_units, time_unit="s",
                              time_origin_ns (int64), frame_id, provenance (JSON string)
    /demos/offsets (D+1,) int64   demonstration k is samples offsets[k]:offsets[k+1]
        name (D,) str (the names masks use), t0_ns (D,) int64, source (D,) str
        t (N,) float64 seconds since time_origin_ns, strictly increasing within a demonstration
        x (N, p)  u (N, q)  force (N, 3) base-frame force (optional)
        truth/pi (N, q)  truth/w  truth/v  truth/b (N, s)
        truth/A (s, q) constant | (N, s, q);  truth/N (q, q) | (N, q, q)
    /mask/train, /mask/test   names of demonstrations (optional)

Version 1 (read, and written with ``format_version=1``) keeps one group per demonstration::

    /demos/demo_0000/  attrs: index (demo order), n_samples, t0_ns, source
        t (n,)  x (n, p)  u (n, q)  force (n, 3) (optional)
        truth/pi (n, q)  truth/w  truth/v  truth/b (n, s)
        truth/A (s, q) constant | (n, s, q);  truth/N (q, q) | (n, q, q)

Its groups are ordered by their ``index`` attribute, never by name. Stamps, states, actions
and truth are stored as they are unless ``COMPRESSION`` names a filter (then datasets of more
than ``CHUNK_ROWS`` samples are chunked and filtered; the size and time of each choice:
docs/readers.md). Writing is atomic, and the file
carries its content hash in the HDF5 user block (:mod:`ccl_cli.io.h5.seal`). Reading goes
through :func:`~ccl_cli.io.h5.probe.open_hdf5` (no links or storage outside the file, no
libhdf5 hang) and checks every attribute and dataset for type, shape and finiteness
(:mod:`ccl_cli.io.h5.access`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import TRUTH_KEYS, Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.io.h5.access import (
    attr_int,
    attr_json,
    attr_str,
    attr_strings,
    attr_version,
    group_of,
    has,
    members,
    numeric,
    strings,
)
from ccl_cli.io.h5.probe import open_hdf5
from ccl_cli.io.h5.seal import create_hdf5, large_dataset

FORMAT = "ccl-demonstrations"
FORMAT_VERSION = 2
#: the versions this ccl reads
READ_VERSIONS = (1, 2)
CHUNK_ROWS = 100_000
#: Filter of the state, action and truth datasets of more than CHUNK_ROWS rows: None, "gzip"
#: (shuffle + deflate level 4: any HDF5 reader) or "lzf" (shuffle + LZF: h5py without plugins,
#: not plain libhdf5 tools). Sensor noise leaves little to deflate in the low bytes of float64
#: samples: None (see docs/readers.md). The stamps too: deflating them cost 0.07–0.2 s of a
#: 10⁶-sample write for 5 MB of a 120 MB file.
COMPRESSION: str | None = None
_FILTERS = {None: {}, "gzip": {"compression": "gzip", "compression_opts": 4, "shuffle": True},
            "lzf": {"compression": "lzf", "shuffle": True}}


def _strings(values: list[str]) -> np.ndarray:
    return np.array([str(v) for v in values], dtype=object)


def _dataset(group, name: str, data: np.ndarray, compression: str | None = None) -> None:
    """``data`` as dataset ``name`` of ``group``: chunked (CHUNK_ROWS rows) and filtered with
    ``compression`` (a key of _FILTERS) when longer than CHUNK_ROWS, contiguous otherwise."""
    data = np.asarray(data)
    if compression is not None and data.ndim >= 1 and data.shape[0] > CHUNK_ROWS:
        group.create_dataset(name, data=data, chunks=(CHUNK_ROWS, *data.shape[1:]), **_FILTERS[compression])
    else:
        large_dataset(group, name, data)


def write_demonstrations(path: str | Path, data: Demonstrations, time_origin_ns: int = 0,
                         frame_id: str = "", provenance: dict[str, Any] | None = None,
                         masks: dict[str, list[int]] | None = None, force: bool = False,
                         format_version: int = FORMAT_VERSION) -> Path:
    """Write ``data`` in the canonical layout, atomically (temp file + rename).

    ``masks`` maps ``train``/``test`` to demo ids (written as demonstration names);
    ``format_version``: 2 (columnar, the default) or 1 (a group per demonstration).
    """
    import h5py

    if format_version not in READ_VERSIONS:
        raise ValueError(f"format_version must be one of {READ_VERSIONS}, got {format_version!r}")
    path = Path(path)
    with create_hdf5(path, force=force) as f:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = format_version
        str_dt = h5py.string_dtype()
        for key, values in (("state_names", data.state_names), ("action_names", data.action_names),
                            ("state_units", data.state_units), ("action_units", data.action_units)):
            f.attrs.create(key, _strings(values), dtype=str_dt)
        f.attrs["time_unit"] = "s"
        f.attrs["time_origin_ns"] = np.int64(time_origin_ns)
        f.attrs["frame_id"] = frame_id
        f.attrs["provenance"] = json.dumps(provenance or data.metadata or {}, default=str)
        write = _write_columns if format_version == 2 else _write_groups
        names = write(f.create_group("demos"), data, time_origin_ns)
        if masks:
            mg = f.create_group("mask")
            for key, ids in masks.items():
                mg.create_dataset(key, data=_strings([names[int(i)] for i in ids]), dtype=str_dt)
    return path


def _sources(data: Demonstrations, ids: np.ndarray | None = None) -> list[str]:
    ids = data.demo_ids if ids is None else ids
    return [str(data.metadata.get("sources", {}).get(str(int(d)), "")) for d in ids]


def _file_order(demo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | slice]:
    """The demonstration ids (D,) in order of first appearance, the offsets (D+1,) of their
    samples once grouped in that order, and the rows that group them (a slice when the
    samples are grouped already)."""
    n = len(demo)
    if n and bool((demo[1:] >= demo[:-1]).all()):  # ids non-decreasing (every reader's): no sort
        starts = np.flatnonzero(np.r_[True, demo[1:] != demo[:-1]])
        return demo[starts], np.r_[starts, n].astype(np.int64), slice(None)
    _, first = np.unique(demo, return_index=True)
    ids = demo[np.sort(first)]  # as Demonstrations.demo_ids
    unique, inverse = np.unique(demo, return_inverse=True)
    rank = np.empty(len(ids), dtype=np.int64)
    rank[np.searchsorted(unique, ids)] = np.arange(len(ids))
    position = rank[inverse]  # each sample's demonstration, numbered in file order
    grouped = bool((position[1:] >= position[:-1]).all())  # already in file order: no copy
    counts = np.bincount(position, minlength=len(ids))
    offsets = np.r_[0, np.cumsum(counts)].astype(np.int64)
    return ids, offsets, slice(None) if grouped else np.argsort(position, kind="stable")


def _write_columns(demos, data: Demonstrations, time_origin_ns: int) -> dict[int, str]:
    """Version 2: the demonstrations in file order, one dataset per field, cut by offsets."""
    import h5py

    ids, offsets, rows = _file_order(data.demo)
    names = [f"demo_{k:04d}" for k in range(len(ids))]
    demos.create_dataset("offsets", data=offsets)
    demos.create_dataset("name", data=_strings(names), dtype=h5py.string_dtype())
    t0 = data.t[rows][offsets[:-1]]
    demos.create_dataset("t0_ns", data=time_origin_ns + np.round(t0 * 1e9).astype(np.int64))
    demos.create_dataset("source", data=_strings(_sources(data, ids)), dtype=h5py.string_dtype())
    _write_samples(demos, data, rows, collapse=False)
    return {int(d): name for d, name in zip(ids, names, strict=True)}


def _write_samples(g, data: Demonstrations, rows: np.ndarray | slice, collapse: bool) -> None:
    """t, x, u and the truth of the samples ``rows`` (indices, a mask or a slice) into group ``g``;
    ``collapse``: A and N constant over these rows are stored once (version 1)."""
    _dataset(g, "t", data.t[rows], COMPRESSION)
    _dataset(g, "x", data.X[rows], COMPRESSION)
    _dataset(g, "u", data.U[rows], COMPRESSION)
    if data.force is not None:
        _dataset(g, "force", data.force[rows], COMPRESSION)
    if not data.truth:
        return
    tg = g.create_group("truth")
    for key, value in data.truth.items():
        if key in ("A", "N") and value.ndim == 2:
            tg.create_dataset(key, data=value)
        elif collapse and key in ("A", "N") and (value[rows] == value[rows][:1]).all():
            tg.create_dataset(key, data=value[rows][0])  # constant within the demonstration
        else:
            _dataset(tg, key, value[rows], COMPRESSION)


def _write_groups(demos, data: Demonstrations, time_origin_ns: int) -> dict[int, str]:
    """Version 1: one group per demonstration."""
    names: dict[int, str] = {}
    sources = _sources(data)
    for order, d in enumerate(data.demo_ids):
        m = data.demo == d
        name = f"demo_{order:04d}"
        names[int(d)] = name
        g = demos.create_group(name)
        g.attrs["index"] = order
        g.attrs["n_samples"] = int(m.sum())
        g.attrs["t0_ns"] = np.int64(time_origin_ns + int(round(data.t[m][0] * 1e9)))
        g.attrs["source"] = sources[order]
        _write_samples(g, data, m, collapse=True)
    return names


def check_header(attrs, where: str, fmt: str, version_key: str, version: int | tuple[int, ...],
                 what: str) -> None:
    """Refuse a file whose ``format`` attribute is not ``fmt`` or whose ``version_key``
    attribute does not name ``version`` (or one of them): an integer, or "1" / "1.0" as other
    writers store it (one message naming the file and what was found)."""
    found = attr_str(attrs, "format", where, None)
    if found != fmt:
        raise InputError(f"{where}: not a {what} (format attribute {found!r})")
    got = attr_version(attrs, version_key, where)
    versions = version if isinstance(version, tuple) else (version,)
    if got not in versions:
        told = " or ".join(map(str, versions))
        raise InputError(f"{where}: {what} version {got} is not supported (this ccl reads version {told})")


def is_canonical(path: Path) -> bool:
    """True for a ccl-demonstrations file (damaged or unsafe HDF5 raises InputError)."""
    with open_hdf5(path, "file") as f:
        return attr_str(f.attrs, "format", str(path), "") == FORMAT


def _demo_arrays(g, where: str, name: str, ordered: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    label = f"{where}: /demos/{name}".rstrip("/")
    t = numeric(g, "t", where, ndim=(1,))
    x = numeric(g, "x", where, ndim=(1, 2), finite=False)
    u = numeric(g, "u", where, ndim=(1, 2), finite=False)
    x = x.reshape(-1, 1) if x.ndim == 1 else x
    u = u.reshape(-1, 1) if u.ndim == 1 else u
    n = t.shape[0]
    if x.shape[0] != n or u.shape[0] != n:
        raise InputError(f"{label}: t, x, u have {t.shape}, {x.shape}, {u.shape}")
    if n == 0 or x.shape[1] == 0 or u.shape[1] == 0:
        raise InputError(f"{label}: empty (t, x, u have {t.shape}, {x.shape}, {u.shape})")
    if ordered and n > 1 and not np.all(np.diff(t) > 0):
        raise InputError(f"{label}/t is not strictly increasing")
    return t, x, u


def _truth(g, where: str, name: str, n: int, q: int) -> dict[str, np.ndarray]:
    tg = group_of(g, "truth", f"{where}: /demos/{name}", required=False)
    if tg is None:
        return {}
    out = {}
    for key in members(tg, where):
        if key not in TRUTH_KEYS:
            continue
        v = numeric(tg, key, where, ndim=(1, 2, 3), finite=False)
        per_sample = v.ndim >= 1 and v.shape[0] == n
        ok = {"pi": v.shape == (n, q), "w": v.shape == (n, q), "v": v.shape == (n, q),
              "b": v.ndim == 2 and per_sample,
              "A": (v.ndim == 2 and v.shape[1] == q) or (v.ndim == 3 and per_sample and v.shape[2] == q),
              "N": v.shape == (q, q) or v.shape == (n, q, q)}[key]
        if not ok:
            raise InputError(f"{where}: /demos/{name}/truth/{key} has shape {v.shape}, which does not "
                             f"fit {n} samples of {q}-D actions")
        out[key] = v
    return out


Arrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray], list[str]]


def _read_groups(demos, where: str) -> Arrays:
    """Version 1: X, U, t, demo ids, truth and names from one group per demonstration."""
    names = members(demos, where)
    if not names:
        raise InputError(f"{where}: no demonstrations under /demos")
    groups = []
    for name in names:
        g = group_of(demos, name, f"{where}: /demos")
        groups.append((attr_int(g.attrs, "index", f"{where}: /demos/{name}"), name, g))
    groups.sort(key=lambda item: item[0])
    X, U, T, demo, truth_parts = [], [], [], [], {}
    p = q = None
    truth_keys = None
    for order, (_, name, g) in enumerate(groups):
        t, x, u = _demo_arrays(g, where, name)
        n = t.shape[0]
        if p is None:
            p, q = x.shape[1], u.shape[1]
        elif (x.shape[1], u.shape[1]) != (p, q):
            raise InputError(f"{where}: /demos/{name} has dimensions ({x.shape[1]}, {u.shape[1]}), "
                             f"other demos ({p}, {q})")
        X.append(x)
        U.append(u)
        T.append(t)
        demo.append(np.full(n, order))
        parts = _truth(g, where, name, n, q)
        truth_keys = set(parts) if truth_keys is None else truth_keys & set(parts)
        for key, value in parts.items():
            truth_parts.setdefault(key, []).append((n, value))
    truth: dict[str, np.ndarray] = {}
    for key in sorted(truth_keys or ()):
        parts = truth_parts[key]
        if key == "b" and len({v.shape[1] for _, v in parts}) > 1:
            raise InputError(f"{where}: truth/b has different widths across demonstrations")
        if key == "A" and len({v.shape[-2] for _, v in parts}) > 1:
            raise InputError(f"{where}: truth/A has different numbers of rows across demonstrations")
        const = key in ("A", "N") and all(v.ndim == 2 for _, v in parts)
        if const and all(np.array_equal(parts[0][1], v) for _, v in parts):
            truth[key] = parts[0][1]
        else:
            truth[key] = np.concatenate([np.broadcast_to(v, (n, *v.shape)) if
                                         (key in ("A", "N") and v.ndim == 2) else v
                                         for n, v in parts])
    return (np.concatenate(X), np.concatenate(U), np.concatenate(T), np.concatenate(demo), truth,
            [name for _, name, _ in groups])


def _read_columns(demos, where: str) -> Arrays:
    """Version 2: the field datasets, cut by ``offsets`` (checked: 0 … N, every
    demonstration non-empty, t strictly increasing within each)."""
    label = f"{where}: /demos"
    offsets = numeric(demos, "offsets", where, ndim=(1,))
    n_demos = offsets.size - 1
    if n_demos < 1:
        raise InputError(f"{where}: no demonstrations under /demos")
    t, x, u = _demo_arrays(demos, where, "", ordered=False)
    n = t.shape[0]
    if offsets[0] != 0 or offsets[-1] != n or not (np.diff(offsets) > 0).all() or \
            not (offsets == np.round(offsets)).all():
        raise InputError(f"{label}/offsets must rise strictly from 0 to the {n} samples, got "
                         f"{offsets[:4].tolist()}{' …' if offsets.size > 4 else ''}")
    counts = np.diff(offsets).astype(np.int64)
    demo = np.repeat(np.arange(n_demos), counts)
    rises = np.diff(t) > 0
    rises[offsets[1:-1].astype(np.int64) - 1] = True  # a new demonstration may start earlier
    if not rises.all():
        k = int(demo[np.argmin(rises)])
        raise InputError(f"{label}/t is not strictly increasing within demonstration {k}")
    names = strings(demos, "name", where)
    if len(names) != n_demos or len(set(names)) != n_demos:
        raise InputError(f"{label}/name must hold {n_demos} distinct names, got {len(names)}")
    truth = _truth(demos, where, "", n, u.shape[1])
    if "b" in truth and truth["b"].ndim != 2:
        raise InputError(f"{label}/truth/b must be (N, s), got {truth['b'].shape}")
    return x, u, t, demo, truth, names


def _force(demos, where: str, version: int, names: list[str], n: int) -> np.ndarray | None:
    """The stored base-frame force (N, 3) — beside every demonstration's ``u`` or none — or None."""
    groups = [demos] if version == 2 else [group_of(demos, name, f"{where}: /demos") for name in names]
    found = [has(g, "force", where) for g in groups]
    if not any(found):
        return None
    if not all(found):
        raise InputError(f"{where}: /demos/{names[found.index(False)]} has no force while others have one")
    force = np.concatenate([numeric(g, "force", where, ndim=(2,)) for g in groups])
    if force.shape != (n, 3):
        raise InputError(f"{where}: force must be one 3-D force per sample, ({n}, 3), got {force.shape}")
    return force


def read_demonstrations(path: str | Path) -> tuple[Demonstrations, dict[str, Any]]:
    """Read a canonical file (version 1 or 2) → (Demonstrations, info with time_origin_ns,
    masks, provenance, the demonstrations' names and the file's ``format_version``).

    Every structural problem (foreign file, missing dataset, wrong types or shapes,
    unknown version, links or storage outside the file) is an :class:`InputError`
    naming the file and the object at fault.
    """
    path = Path(path)
    where = str(path)
    with open_hdf5(path, f"{FORMAT} file") as f:
        check_header(f.attrs, where, FORMAT, "format_version", READ_VERSIONS, f"{FORMAT} file")
        version = attr_version(f.attrs, "format_version", where)
        demos = group_of(f, "demos", where, required=False)
        if demos is None:
            raise InputError(f"{where}: no demonstrations under /demos")
        X, U, T, demo, truth, names = (_read_columns if version == 2 else _read_groups)(demos, where)
        p, q = X.shape[1], U.shape[1]
        force = _force(demos, where, version, names, len(X))
        masks = {}
        mask = group_of(f, "mask", where, required=False)
        if mask is not None:
            for key in ("train", "test"):
                if has(mask, key, where):
                    wanted = strings(mask, key, where)
                    unknown = [w for w in wanted if w not in names]
                    if unknown:
                        raise InputError(f"{where}: /mask/{key} names unknown groups {unknown[:3]}")
                    masks[key] = [names.index(w) for w in wanted]
        data = Demonstrations(
            X=X, U=U, demo=demo, t=T, truth=truth,
            state_names=attr_strings(f.attrs, "state_names", where, p),
            action_names=attr_strings(f.attrs, "action_names", where, q),
            state_units=attr_strings(f.attrs, "state_units", where, p),
            action_units=attr_strings(f.attrs, "action_units", where, q),
            metadata={"source": where}, force=force,
        )
        try:  # provenance is informative only: a damaged one is dropped, not fatal
            provenance = attr_json(f.attrs, "provenance", where, {}, dict)
        except InputError:
            provenance = {}
        info = {"time_origin_ns": attr_int(f.attrs, "time_origin_ns", where, 0), "masks": masks,
                "provenance": provenance, "groups": names, "format_version": version}
        return data, info
