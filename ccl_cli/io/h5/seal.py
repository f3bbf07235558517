"""HDF5 files ccl writes: created atomically and sealed with the sha256 of their content.

The seal sits in the file's user block (:data:`USERBLOCK` bytes that libhdf5 leaves to the
application): ``\\0ccl-sha256:<hex digest of every byte after the block>\\n``. A file whose
seal matches its content is exactly what ccl wrote, so :func:`~ccl_cli.io.h5.probe.open_hdf5`
opens it without the sandboxed probe.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.io.atomic import atomic_path, check_writable
from ccl_cli.io.h5.image import Image, direct

#: user-block size reserved in files ccl writes (HDF5 requires a power of two ≥ 512)
USERBLOCK = 512
SEAL = b"\x00ccl-sha256:"
#: the images of the files :func:`create_hdf5` is building, by the name h5py gives each
_BUILDING: dict[str, Image] = {}


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        f.seek(USERBLOCK)
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@contextlib.contextmanager
def create_hdf5(path: str | Path, force: bool = False, sealed: bool = True) -> Iterator[Any]:
    """An ``h5py.File`` written atomically at ``path`` and (``sealed``) carrying the sha256
    of its content in the user block.

    libhdf5 builds the file in memory (an :class:`~ccl_cli.io.h5.image.Image`; large datasets
    made with :func:`large_dataset` keep only their arrays); Python writes the bytes
    (:func:`ccl_cli.io.atomic.atomic_path`), so a full disk or a file-size limit is one
    ``OSError`` there — one line, nothing left — and never a write failure inside libhdf5,
    which leaves the library unable to close its file (tracebacks at exit, a crash at
    interpreter shutdown).
    """
    import h5py

    path = Path(path)
    check_writable(path, force)
    image = Image()
    with h5py.File(image, "w", userblock_size=USERBLOCK) as f:
        _BUILDING[f.filename] = image
        try:
            yield f
        finally:
            del _BUILDING[f.filename]
    digest: list[str] = []

    def content_hash() -> None:
        h = hashlib.sha256()
        for piece in image.pieces(USERBLOCK):
            h.update(piece)
        digest.append(h.hexdigest())

    hashing = threading.Thread(target=content_hash, name="ccl-seal", daemon=True) if sealed else None
    if hashing is not None:  # hashed while it is written (both release the GIL)
        hashing.start()
    with atomic_path(path, force=force) as tmp, open(tmp, "wb") as out:
        out.write(bytes(USERBLOCK))
        for piece in image.pieces(USERBLOCK):
            out.write(piece)
        if hashing is not None:
            hashing.join()
            out.seek(0)
            out.write(SEAL + digest[0].encode() + b"\n")


def large_dataset(group: Any, name: str, data: np.ndarray) -> None:
    """``data`` as dataset ``name`` of ``group``; in a file :func:`create_hdf5` builds, an array
    of :data:`~ccl_cli.io.h5.image.DIRECT_BYTES` or more is written from its own memory when
    the file is (it must not change until then), not copied into the file's image first."""
    image = _BUILDING.get(group.file.filename) if _BUILDING and direct(data) else None
    if image is not None:
        image.dataset(group, name, data)
    else:
        group.create_dataset(name, data=data)


def sealed(path: str | Path) -> bool:
    """True when ``path`` carries a ccl content hash that matches its content."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(SEAL) + 64)
    except OSError:
        return False
    if not head.startswith(SEAL) or len(head) != len(SEAL) + 64:
        return False
    st = path.stat()
    return _sealed(str(path.resolve()), st.st_size, st.st_mtime_ns, head[len(SEAL):].decode("latin-1"))


@functools.lru_cache(maxsize=256)
def _sealed(path: str, size: int, mtime_ns: int, claimed: str) -> bool:
    """Digest check, remembered per (path, size, mtime): a run opens its inputs more than once."""
    return _digest(Path(path)) == claimed
