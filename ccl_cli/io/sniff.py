"""What a file is, from its first bytes: the magic numbers and content tests of each format.

A leaf (it imports only the errors and :mod:`ccl_cli.io.limits`): no format module is
imported here, so every reader and the registry can use it.
Each ``is_*`` test takes the path and its first :data:`HEAD_BYTES` bytes (empty for a
directory) and answers without parsing the file (HDF5 behind a user block asks h5py).
"""

from __future__ import annotations

from pathlib import Path

from ccl_cli.errors import InputError
from ccl_cli.io.limits import open_regular

HEAD_BYTES = 128
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
MCAP_MAGIC = b"\x89MCAP"
BAG1_MAGIC = b"#ROSBAG V2.0"
SQLITE_MAGIC = b"SQLite format 3"
MAT5_MAGIC = b"MATLAB 5.0 MAT-file"
MAT73_MAGIC = b"MATLAB 7.3 MAT-file"
BAG2_METADATA = "metadata.yaml"


def read_head(path: Path, n: int = HEAD_BYTES) -> bytes:
    """The first ``n`` bytes of the regular file ``path`` (an unreadable file, a FIFO or a
    device is an InputError, found before anything blocks on it)."""
    try:
        with open_regular(path) as f:
            return f.read(n)
    except OSError as exc:
        raise InputError(f"{path}: {exc.strerror}") from None


def is_bag(path: Path, head: bytes) -> bool:
    """A ROS 1 ``.bag``, a ROS 2 bag directory, or a file of one (its metadata.yaml or storage)."""
    if path.is_dir():
        return (path / BAG2_METADATA).exists() or (path / BAG2_METADATA).is_symlink()
    if path.name == BAG2_METADATA or head.startswith(BAG1_MAGIC):
        return True
    beside = (path.parent / BAG2_METADATA).exists()
    return beside and (head.startswith(MCAP_MAGIC) or head.startswith(SQLITE_MAGIC))


def is_mcap(path: Path, head: bytes) -> bool:
    return head.startswith(MCAP_MAGIC)


def is_mat(path: Path, head: bytes) -> bool:
    """MATLAB v5/v7 (its own container) or v7.3 (HDF5 behind a MATLAB text header)."""
    return not path.is_dir() and (head.startswith(MAT5_MAGIC) or head.startswith(MAT73_MAGIC))


def is_hdf5(path: Path, head: bytes) -> bool:
    """HDF5 at the start of the file, or behind a user block (h5py looks for the signature)."""
    if head.startswith(HDF5_MAGIC):
        return True
    if b"\x00" in head and not path.is_dir():
        import h5py

        return bool(h5py.is_hdf5(str(path)))
    return False


def is_text(path: Path, head: bytes) -> bool:
    """No NUL byte in the head: a CSV or text table, as far as the bytes tell."""
    return not path.is_dir() and b"\x00" not in head
