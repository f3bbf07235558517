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
``CHUNK_ROWS`` rows are chunked and gzip-compressed. Writing is atomic.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import TRUTH_KEYS, Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.io.atomic import atomic_path

FORMAT = "ccl-demonstrations"
FORMAT_VERSION = 1
CHUNK_ROWS = 100_000


def _strings(values: list[str]) -> np.ndarray:
    return np.array([str(v) for v in values], dtype=object)


def _attr_list(attrs, key: str, n: int) -> list[str]:
    if key not in attrs:
        return [""] * n
    return [v.decode() if isinstance(v, bytes) else str(v) for v in attrs[key]]


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
    with atomic_path(path, force=force) as tmp, h5py.File(tmp, "w") as f:
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
    attribute is not ``version`` (one message naming the file and what was found)."""
    found = attrs.get("format")
    found = found.decode() if isinstance(found, bytes) else found
    if found != fmt:
        raise InputError(f"{where}: not a {what} (format attribute {found!r})")
    got = int(attrs.get(version_key, -1))
    if got != version:
        raise InputError(f"{where}: {what} version {got} is not supported (this ccl reads version {version})")


def is_canonical(path: Path) -> bool:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("format") in (FORMAT, FORMAT.encode())
    except OSError:
        return False


def read_demonstrations(path: str | Path) -> tuple[Demonstrations, dict[str, Any]]:
    """Read a canonical file → (Demonstrations, info with time_origin_ns, masks, provenance).

    Every structural problem (foreign file, missing dataset, wrong shapes, unknown
    version) is an :class:`InputError` naming the file and the object at fault.
    """
    import h5py

    path = Path(path)
    where = str(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"{where}: cannot open as HDF5 ({exc})") from None
    with f:
        check_header(f.attrs, where, FORMAT, "format_version", FORMAT_VERSION, f"{FORMAT} file")
        if "demos" not in f or not len(f["demos"]):
            raise InputError(f"{where}: no demonstrations under /demos")
        groups = []
        for name, g in f["demos"].items():
            if "index" not in g.attrs:
                raise InputError(f"{where}: /demos/{name} has no index attribute")
            groups.append((int(g.attrs["index"]), name, g))
        groups.sort(key=lambda item: item[0])
        X, U, T, demo, truth_parts = [], [], [], [], {}
        p = q = None
        truth_keys = None
        for order, (_, name, g) in enumerate(groups):
            for key in ("t", "x", "u"):
                if key not in g:
                    raise InputError(f"{where}: /demos/{name}/{key} is missing")
            try:
                t, x, u = g["t"][()], g["x"][()], g["u"][()]
            except Exception as exc:
                raise InputError(f"{where}: cannot read /demos/{name} ({exc})") from None
            x = x.reshape(-1, 1) if x.ndim == 1 else x
            u = u.reshape(-1, 1) if u.ndim == 1 else u
            n = t.shape[0]
            if x.shape[0] != n or u.shape[0] != n or t.ndim != 1:
                raise InputError(f"{where}: /demos/{name}: t, x, u have {t.shape}, {x.shape}, {u.shape}")
            if p is None:
                p, q = x.shape[1], u.shape[1]
            elif (x.shape[1], u.shape[1]) != (p, q):
                raise InputError(f"{where}: /demos/{name} has dimensions ({x.shape[1]}, {u.shape[1]}), "
                                 f"other demos ({p}, {q})")
            if n > 1 and not np.all(np.diff(t) > 0):
                raise InputError(f"{where}: /demos/{name}/t is not strictly increasing")
            X.append(x)
            U.append(u)
            T.append(t)
            demo.append(np.full(n, order))
            keys = set(g["truth"].keys()) if "truth" in g else set()
            truth_keys = keys if truth_keys is None else truth_keys & keys
            for key in keys:
                truth_parts.setdefault(key, []).append((n, g["truth"][key][()]))
        truth: dict[str, np.ndarray] = {}
        for key in truth_keys or ():
            if key not in TRUTH_KEYS:
                continue
            parts = truth_parts[key]
            const = key in ("A", "N") and all(v.ndim == 2 for _, v in parts)
            if const and all(np.array_equal(parts[0][1], v) for _, v in parts):
                truth[key] = parts[0][1]
            else:
                truth[key] = np.concatenate([np.broadcast_to(v, (n, *v.shape)) if
                                             (key in ("A", "N") and v.ndim == 2) else v
                                             for n, v in parts])
        names = [name for _, name, _ in groups]
        masks = {}
        if "mask" in f:
            for key in ("train", "test"):
                if key in f["mask"]:
                    wanted = [v.decode() if isinstance(v, bytes) else str(v) for v in f["mask"][key][()]]
                    unknown = [w for w in wanted if w not in names]
                    if unknown:
                        raise InputError(f"{where}: /mask/{key} names unknown groups {unknown[:3]}")
                    masks[key] = [names.index(w) for w in wanted]
        data = Demonstrations(
            X=np.concatenate(X), U=np.concatenate(U), demo=np.concatenate(demo), t=np.concatenate(T),
            truth=truth,
            state_names=_attr_list(f.attrs, "state_names", p),
            action_names=_attr_list(f.attrs, "action_names", q),
            state_units=_attr_list(f.attrs, "state_units", p),
            action_units=_attr_list(f.attrs, "action_units", q),
            metadata={"source": where},
        )
        try:
            provenance = json.loads(f.attrs.get("provenance", "{}"))
        except (TypeError, json.JSONDecodeError):
            provenance = {}
        info = {"time_origin_ns": int(f.attrs.get("time_origin_ns", 0)), "masks": masks,
                "provenance": provenance, "groups": names}
        return data, info
