"""Compressed variables of MATLAB v5/v7 files, measured before scipy inflates them.

A v7 file stores each variable as one ``miCOMPRESSED`` element: a zlib stream that
inflates to the variable's ``miMATRIX`` element. scipy inflates and reads the data tags
whole, whatever the variable's header declares, so a few megabytes of zeros can declare a
10×10 matrix and still make it allocate gigabytes (zlib inflates up to ~1000×). Here each
compressed variable's stream is inflated once in bounded pieces and only counted: a
variable whose inflated size exceeds what its declared shape can hold is refused before
scipy reads it.

Layout (MATLAB 5 MAT-file format): a 128-byte header whose bytes 126–127 read ``IM``
(little-endian) or ``MI`` (big-endian), then elements of an 8-byte tag (type, byte count)
and their data; an element of at most 4 bytes may be packed into its tag ("small data
element": byte count in the upper 16 bits of the first word).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from pathlib import Path

from ccl_cli.errors import InputError
from ccl_cli.io.limits import open_regular

MI_INT8, MI_MATRIX, MI_COMPRESSED = 1, 14, 15
#: input read from the file per step, and the most inflated output kept per step
STEP = 1 << 20
#: inflated bytes read to find a variable's name (flags, dims and name elements)
HEAD = 1 << 16


def _element(buf: bytes, pos: int, endian: str) -> tuple[int, bytes, int]:
    """(type, data, position after it) of the element at ``pos`` of an inflated variable."""
    first, count = struct.unpack_from(endian + "II", buf, pos)
    if first >> 16:  # small data element: packed into its 8-byte tag
        return first & 0xFFFF, buf[pos + 4:pos + 4 + (first >> 16)], pos + 8
    return first, buf[pos + 8:pos + 8 + count], pos + 8 + count + (-count) % 8


def _name(head: bytes, endian: str) -> str | None:
    """The array name of an inflated ``miMATRIX`` element (None when it cannot be read)."""
    try:
        mtype, _ = struct.unpack_from(endian + "II", head, 0)
        if mtype != MI_MATRIX:
            return None
        pos = 8
        for _ in range(2):  # array flags, dimensions
            _, _, pos = _element(head, pos, endian)
        mtype, data, _ = _element(head, pos, endian)
    except struct.error:
        return None
    return data.decode("latin-1") if mtype == MI_INT8 else None


def _inflated(f, nbytes: int) -> Iterator[bytes]:
    """The zlib stream of ``nbytes`` at ``f``'s position, inflated in pieces of at most
    :data:`STEP` bytes (a damaged stream ends early: scipy's read reports it)."""
    inflater = zlib.decompressobj()
    pending, left = b"", nbytes
    while not inflater.eof:
        if not pending:
            pending = f.read(min(STEP, left)) if left else b""
            if not pending:
                return
            left -= len(pending)
        try:
            out = inflater.decompress(pending, STEP)
        except zlib.error:
            return
        pending = inflater.unconsumed_tail
        yield out


def inflated_size(path: str | Path, name: str, limit: int) -> int:
    """Inflated size of the compressed variable ``name`` of the v5/v7 file ``path``,
    counted up to ``limit + 1`` (more means "over"); 0 when it is not compressed
    (an uncompressed variable is bounded by the file's own size)."""
    with open_regular(path) as f:
        header = f.read(128)
        if len(header) < 128 or header[126:128] not in (b"IM", b"MI"):
            return 0
        endian = "<" if header[126:128] == b"IM" else ">"
        pos = 128
        while True:
            f.seek(pos)
            tag = f.read(8)
            if len(tag) < 8:
                return 0
            mtype, nbytes = struct.unpack(endian + "II", tag)
            if mtype == MI_COMPRESSED:
                pieces = _inflated(f, nbytes)
                head = b""
                for piece in pieces:
                    head += piece
                    if len(head) >= HEAD:
                        break
                if _name(head[:HEAD], endian) == name:
                    total = len(head)
                    for piece in pieces:
                        if total > limit:
                            break
                        total += len(piece)
                    return total
            pos += 8 + nbytes


def check_inflated(path: str | Path, name: str, shape: tuple[int, ...], container: bool,
                   cap: int) -> None:
    """Refuse variable ``name`` when its compressed stream inflates to more than its
    declared ``shape`` can hold: 3 × 8 bytes per element (real and imaginary parts, or a
    sparse matrix's values and row indices) plus its column index and 64 KiB of headers;
    a cell or struct (``container``), whose shape does not bound its contents, to more
    than ``cap``. One :class:`InputError` line naming the variable."""
    elements = 1
    for n in shape:
        elements *= max(int(n), 0)
    bound = cap if container else min(cap, 24 * elements + 8 * (int(shape[-1]) + 1 if shape else 1)
                                      + (64 << 10))
    total = inflated_size(path, name, bound)
    if total > bound:
        declared = "×".join(str(int(n)) for n in shape)
        raise InputError(f"{path}: {name}: the compressed variable inflates to more than {bound} bytes, "
                         f"more than its declared {declared} can hold; refused before reading "
                         "(a damaged or hostile file)")
