"""What an HDF5 file holds, one entry per group, dataset or link (``ccl inspect``, and
messages that list a file's contents)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ccl_cli.errors import InputError
from ccl_cli.io.h5.access import attr_names, attr_str
from ccl_cli.io.h5.probe import probe
from ccl_cli.io.h5.seal import sealed
from ccl_cli.io.limits import regular_file

LIMIT = 500


def truncate(entries: list[dict[str, Any]], limit: int = LIMIT) -> list[dict[str, Any]]:
    """At most ``limit`` entries; a last entry ``{kind: "truncated", count}`` says how many
    were left out."""
    if len(entries) > limit:
        return [*entries[:limit], {"kind": "truncated", "count": len(entries) - limit}]
    return entries


def list_hdf5(path: str | Path, matlab: bool = False, limit: int = LIMIT) -> list[dict[str, Any]]:
    """Entries ``{path, kind, shape, dtype, names?, class?}`` of an HDF5 file (``kind``: group,
    dataset, soft link, external link), at most ``limit`` (see :func:`truncate`). Links are
    described, not followed, so a file with an external link is listed (its entry says so)
    after the time-limited :func:`~ccl_cli.io.h5.probe.probe`. ``matlab``: a v7.3 .mat file —
    shapes in MATLAB's orientation, its ``#refs#`` storage hidden."""
    import h5py

    path = Path(path)
    regular_file(path, "the HDF5 file")
    if not sealed(path):
        probe(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"{path}: cannot open as HDF5 ({exc})") from None
    out: list[dict[str, Any]] = []
    refused: list[InputError] = []
    with f:
        def visit(name: str, link) -> bool | None:
            """One entry; a refusal stops the visit (returned, not raised: an exception
            raised through libhdf5's callback surfaces as h5py's SystemError)."""
            try:
                add(name, link)
            except InputError as exc:
                refused.append(exc)
                return True
            return None

        def add(name: str, link) -> None:
            if matlab and name.startswith("#"):
                return
            entry: dict[str, Any] = {"path": name}
            if isinstance(link, h5py.ExternalLink):
                entry.update(kind="external link", target=f"{link.filename}:{link.path}")
            elif isinstance(link, h5py.SoftLink):
                entry.update(kind="soft link", target=link.path)
            else:
                obj = f[name]
                if isinstance(obj, h5py.Group):
                    entry["kind"] = "group"
                else:
                    shape = tuple(obj.shape)
                    entry.update(kind="dataset", shape=list(reversed(shape)) if matlab else list(shape),
                                 dtype=str(obj.dtype) if obj.dtype != h5py.ref_dtype else "reference")
                    if obj.is_virtual:
                        entry["virtual"] = True
                at = f"{path}:/{name}"
                names = attr_names(obj.attrs, "names", at) or attr_names(obj.attrs, "column_names", at)
                if names is not None:
                    entry["names"] = names
                cls = attr_str(obj.attrs, "MATLAB_class", at, None)
                if cls is not None:
                    entry["class"] = cls
            out.append(entry)

        try:
            f.visititems_links(visit)
        except (OSError, RuntimeError, KeyError) as exc:
            raise InputError(f"{path}: cannot read the HDF5 structure ({exc})") from None
        except (UnicodeDecodeError, SystemError) as exc:  # h5py wraps an error of its callback
            if not isinstance(exc, UnicodeDecodeError) and not isinstance(exc.__cause__, UnicodeDecodeError):
                raise
            raise InputError(f"{path}: cannot read the HDF5 structure (an object's name is not UTF-8); "
                             "damaged file?") from None
        if refused:
            raise refused[0]
    return truncate(out, limit)
