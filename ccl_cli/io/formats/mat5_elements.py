"""The element structure of MATLAB v5/v7 files, checked before scipy parses a variable.

* **Sizes.** A v7 file stores each variable as one ``miCOMPRESSED`` element: a zlib stream
  that inflates to the variable's ``miMATRIX`` element. scipy inflates and reads the data
  tags whole, whatever the variable's header declares, so a few megabytes of zeros can
  declare a 10×10 matrix and still make it allocate gigabytes (zeros deflate ~1000:1). The
  stream is inflated once in bounded pieces and counted first.
* **Types.** scipy's compiled reader indexes its type tables by the element types it finds
  and crashes the process (SIGSEGV) on a type that does not exist (one flipped byte). The
  variable's elements are walked first: every element of a known type, inside its parent,
  numeric data of a numeric type, cells and struct fields holding matrices.

Layout (MATLAB 5 MAT-file format): a 128-byte header whose bytes 126–127 read ``IM``
(little-endian) or ``MI`` (big-endian), then elements of an 8-byte tag (type, byte count)
and their data; an element of at most 4 bytes may be packed into its tag ("small data
element": byte count in the upper 16 bits of the first word). A ``miMATRIX`` holds array
flags (class in the low byte, complex bit 0x800), dimensions, a name, then by class: the
real (and imaginary) parts; a sparse matrix's row and column indices first; a cell's
matrices; a struct's field-name length, names and matrices (an object's class name first).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from pathlib import Path

from ccl_cli.errors import InputError
from ccl_cli.io.limits import open_regular

MI_INT8, MI_INT32, MI_UINT32, MI_MATRIX, MI_COMPRESSED = 1, 5, 6, 14, 15
#: element types of numeric data (int8 … uint32, single, double, int64, uint64)
NUMERIC_TYPES = {1, 2, 3, 4, 5, 6, 7, 9, 12, 13}
#: element types of text (numeric, UTF-8/16/32)
TEXT_TYPES = NUMERIC_TYPES | {16, 17, 18}
#: array classes: cell, struct, object, char, sparse, then the numeric ones (double … uint64)
CELL, STRUCT, OBJECT, CHAR, SPARSE = 1, 2, 3, 4, 5
NUMERIC_CLASSES = set(range(6, 16))
#: nesting deeper than this is refused (as the reader does)
MAX_DEPTH = 32
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


def _find(path: str | Path, name: str, limit: int) -> tuple[int, bytes | None, str]:
    """(size of variable ``name``'s ``miMATRIX`` element — inflated, counted up to
    ``limit + 1`` — , the element itself when it is not over ``limit``, the byte order);
    (0, None, "<") when the file holds no such variable."""
    with open_regular(path) as f:
        header = f.read(128)
        if len(header) < 128 or header[126:128] not in (b"IM", b"MI"):
            return 0, None, "<"
        endian = "<" if header[126:128] == b"IM" else ">"
        pos = 128
        while True:
            f.seek(pos)
            tag = f.read(8)
            if len(tag) < 8:
                return 0, None, endian
            mtype, nbytes = struct.unpack(endian + "II", tag)
            if mtype == MI_COMPRESSED:
                pieces = _inflated(f, nbytes)
                held = b""
                for piece in pieces:
                    held += piece
                    if len(held) >= HEAD:
                        break
                if _name(held[:HEAD], endian) == name:
                    total, parts = len(held), [held]
                    for piece in pieces:
                        if total > limit:
                            break
                        total += len(piece)
                        parts.append(piece)
                    return total, (b"".join(parts) if total <= limit else None), endian
            elif _name(tag + f.read(min(nbytes, HEAD)), endian) == name:
                f.seek(pos)
                return 8 + nbytes, (f.read(8 + nbytes) if 8 + nbytes <= limit else None), endian
            pos += 8 + nbytes


def inflated_size(path: str | Path, name: str, limit: int) -> int:
    """Size of variable ``name``'s element in the v5/v7 file ``path`` once inflated, counted
    up to ``limit + 1`` (more means "over"); 0 when there is no such variable."""
    return _find(path, name, limit)[0]


def _walk(buf: bytes, start: int, end: int, endian: str, depth: int) -> str | None:
    """What is wrong with the ``miMATRIX`` data ``buf[start:end]`` (None: nothing)."""
    if depth > MAX_DEPTH:
        return f"nested deeper than {MAX_DEPTH}"
    parts, pos = [], start
    while pos < end:
        if pos + 8 > end:
            return "an element tag runs past its matrix"
        first, count = struct.unpack_from(endian + "II", buf, pos)
        mtype, nxt = (first & 0xFFFF, pos + 8) if first >> 16 else (first, pos + 8 + count)
        if mtype not in TEXT_TYPES | {MI_MATRIX}:
            return f"an element of type {mtype}, which MATLAB files do not have"
        if nxt > end or (first >> 16 > 4):
            return "an element runs past its matrix"
        nxt += (-(nxt - pos)) % 8
        parts.append((mtype, pos, nxt))
        pos = nxt
    if not parts:
        return None  # an empty matrix
    if len(parts) < 3 or parts[0][0] != MI_UINT32 or parts[1][0] != MI_INT32:
        return "a matrix without array flags, dimensions and a name"
    cls = buf[parts[0][1] + 8] if endian == "<" else buf[parts[0][1] + 11]
    rest = [t for t, _, _ in parts[3:]]
    if cls in NUMERIC_CLASSES | {SPARSE}:
        ok = all(t in NUMERIC_TYPES for t in rest)
    elif cls == CHAR:
        ok = all(t in TEXT_TYPES for t in rest)
    elif cls in (CELL, STRUCT, OBJECT):
        lead = {CELL: 0, STRUCT: 2, OBJECT: 3}[cls]
        ok = len(rest) >= lead and all(t == MI_MATRIX for t in rest[lead:])
        for _, pos, _ in parts[3 + lead:] if ok else ():
            count = struct.unpack_from(endian + "I", buf, pos + 4)[0]
            wrong = _walk(buf, pos + 8, pos + 8 + count, endian, depth + 1)
            if wrong:
                return wrong
    else:
        return f"a matrix of class {cls}, which ccl does not read"
    return None if ok else f"a matrix of class {cls} holding elements of types {sorted(set(rest))}"


def check_variable(path: str | Path, name: str, shape: tuple[int, ...], container: bool, cap: int) -> None:
    """Refuse variable ``name`` before scipy parses it: when its element (inflated) is larger
    than its declared ``shape`` can hold — 3 × 8 bytes per element (real and imaginary
    parts, or a sparse matrix's values and row indices) plus its column index and 64 KiB of
    headers; a cell or struct (``container``), whose shape does not bound its contents,
    more than ``cap`` — or when an element of it has a type or place scipy's reader would
    crash on. One :class:`InputError` line naming the variable."""
    elements = 1
    for n in shape:
        elements *= max(int(n), 0)
    bound = cap if container else min(cap, 24 * elements + 8 * (int(shape[-1]) + 1 if shape else 1)
                                      + (64 << 10))
    total, element, endian = _find(path, name, bound)
    if total > bound:
        declared = "×".join(str(int(n)) for n in shape)
        raise InputError(f"{path}: {name}: the compressed variable inflates to more than {bound} bytes, "
                         f"more than its declared {declared} can hold; refused before reading "
                         "(a damaged or hostile file)")
    if element is not None:
        count = struct.unpack_from(endian + "I", element, 4)[0]
        wrong = _walk(element, 8, min(8 + count, len(element)), endian, 0)
        if wrong:
            raise InputError(f"{path}: {name}: {wrong}; refused before reading (a damaged file)")
