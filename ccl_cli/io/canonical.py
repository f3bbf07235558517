"""The canonical ``ccl-demonstrations`` HDF5 layout (read and write).

::

    /                  attrs: format="ccl-demonstrations", format_version, state_names[p],
                              action_names[q], state_units, action_units, time_unit="s",
                              time_origin_ns (int64), frame_id, provenance (JSON string)
    /demos/demo_0000/  attrs: index (demo order), n_samples, t0_ns, source
        t (n,) float64 seconds since time_origin_ns, strictly increasing
        x (n, p)  u (n, q)
        truth/pi (n, q)  truth/w  truth/v  truth/b (n, s)
        truth/A (s, q) constant | (n, s, q);  truth/N (q, q) | (n, q, q)
    /mask/train, /mask/test   names of demo groups (optional)

Groups are ordered by their ``index`` attribute, never by name. Datasets of more than
``CHUNK_ROWS`` rows are chunked and gzip-compressed. Writing is atomic, and the file
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
from ccl_cli.io.h5.seal import create_hdf5

FORMAT = "ccl-demonstrations"
FORMAT_VERSION = 1
CHUNK_ROWS = 100_000


def _strings(values: list[str]) -> np.ndarray:
    return np.array([str(v) for v in values], dtype=object)


def _dataset(group, name: str, data: np.ndarray) -> None:
    data = np.asarray(data)
    if data.ndim >= 1 and data.shape[0] > CHUNK_ROWS:
        group.create_dataset(name, data=data, chunks=(min(CHUNK_ROWS, data.shape[0]), *data.shape[1:]),
                             compression="gzip", compression_opts=4, shuffle=True)
    else:
        group.create_dataset(name, data=data)


def write_demonstrations(path: str | Path, data: Demonstrations, time_origin_ns: int = 0,
                         frame_id: str = "", provenance: dict[str, Any] | None = None,
                         masks: dict[str, list[int]] | None = None, force: bool = False) -> Path:
    """Write ``data`` in the canonical layout, atomically (temp file + rename).

    ``masks`` maps ``train``/``test`` to demo ids (written as group names).
    """
    import h5py

    path = Path(path)
    with create_hdf5(path, force=force) as f:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        str_dt = h5py.string_dtype()
        for key, values in (("state_names", data.state_names), ("action_names", data.action_names),
                            ("state_units", data.state_units), ("action_units", data.action_units)):
            f.attrs.create(key, _strings(values), dtype=str_dt)
        f.attrs["time_unit"] = "s"
        f.attrs["time_origin_ns"] = np.int64(time_origin_ns)
        f.attrs["frame_id"] = frame_id
        f.attrs["provenance"] = json.dumps(provenance or data.metadata or {}, default=str)
        demos = f.create_group("demos")
        names: dict[int, str] = {}
        for order, d in enumerate(data.demo_ids):
            m = data.demo == d
            name = f"demo_{order:04d}"
            names[int(d)] = name
            g = demos.create_group(name)
            g.attrs["index"] = order
            g.attrs["n_samples"] = int(m.sum())
            g.attrs["t0_ns"] = np.int64(time_origin_ns + int(round(data.t[m][0] * 1e9)))
            g.attrs["source"] = str(data.metadata.get("sources", {}).get(str(int(d)), ""))
            _dataset(g, "t", data.t[m])
            _dataset(g, "x", data.X[m])
            _dataset(g, "u", data.U[m])
            if data.truth:
                tg = g.create_group("truth")
                for key, value in data.truth.items():
                    if key in ("A", "N") and value.ndim == 2:
                        tg.create_dataset(key, data=value)
                    elif key in ("A", "N") and (value[m] == value[m][:1]).all():
                        tg.create_dataset(key, data=value[m][0])  # constant within the demo
                    else:
                        _dataset(tg, key, value[m])
        if masks:
            mg = f.create_group("mask")
            for key, ids in masks.items():
                mg.create_dataset(key, data=_strings([names[int(i)] for i in ids]), dtype=str_dt)
    return path


def check_header(attrs, where: str, fmt: str, version_key: str, version: int, what: str) -> None:
    """Refuse a file whose ``format`` attribute is not ``fmt`` or whose ``version_key``
    attribute does not name the version ``version`` (an integer, or "1" / "1.0"; one message
    naming the file and what was found)."""
    found = attr_str(attrs, "format", where, None)
    if found != fmt:
        raise InputError(f"{where}: not a {what} (format attribute {found!r})")
    got = attr_version(attrs, version_key, where)
    if got != version:
        raise InputError(f"{where}: {what} version {got} is not supported (this ccl reads version {version})")


def is_canonical(path: Path) -> bool:
    """True for a ccl-demonstrations file (damaged or unsafe HDF5 raises InputError)."""
    with open_hdf5(path, "file") as f:
        return attr_str(f.attrs, "format", str(path), "") == FORMAT


def _demo_arrays(g, where: str, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    label = f"{where}: /demos/{name}"
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
    if n > 1 and not np.all(np.diff(t) > 0):
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


def read_demonstrations(path: str | Path) -> tuple[Demonstrations, dict[str, Any]]:
    """Read a canonical file → (Demonstrations, info with time_origin_ns, masks, provenance).

    Every structural problem (foreign file, missing dataset, wrong types or shapes,
    unknown version, links or storage outside the file) is an :class:`InputError`
    naming the file and the object at fault.
    """
    path = Path(path)
    where = str(path)
    with open_hdf5(path, f"{FORMAT} file") as f:
        check_header(f.attrs, where, FORMAT, "format_version", FORMAT_VERSION, f"{FORMAT} file")
        demos = group_of(f, "demos", where, required=False)
        names = members(demos, where) if demos is not None else []
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
        names = [name for _, name, _ in groups]
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
            X=np.concatenate(X), U=np.concatenate(U), demo=np.concatenate(demo), t=np.concatenate(T),
            truth=truth,
            state_names=attr_strings(f.attrs, "state_names", where, p),
            action_names=attr_strings(f.attrs, "action_names", where, q),
            state_units=attr_strings(f.attrs, "state_units", where, p),
            action_units=attr_strings(f.attrs, "action_units", where, q),
            metadata={"source": where},
        )
        try:  # provenance is informative only: a damaged one is dropped, not fatal
            provenance = attr_json(f.attrs, "provenance", where, {}, dict)
        except InputError:
            provenance = {}
        info = {"time_origin_ns": attr_int(f.attrs, "time_origin_ns", where, 0), "masks": masks,
                "provenance": provenance, "groups": names}
        return data, info
