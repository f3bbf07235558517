"""An HDF5 file built in memory, then written out once — without a copy of its large arrays.

libhdf5 writes a file ccl builds through a Python file object (:mod:`ccl_cli.io.h5.seal`
explains why). :class:`Image` is that object: it keeps the stretches of bytes libhdf5 writes
(headers, heaps, small datasets) and nothing for the space it never writes. A large dataset
made with :meth:`Image.dataset` gets its space in the file when it is created and no fill
value, so libhdf5 writes none of its data: the array itself is written into the output file
(and hashed) afterwards, at the dataset's offset, straight from its memory. For 10⁶ samples of
7-D states and actions that spares a 120 MB staging copy of the file.

Offsets are absolute byte offsets of the file, the user block included.
"""

from __future__ import annotations

import bisect
import io
from collections.abc import Iterator
from typing import Any

import numpy as np

#: Datasets of at least this many bytes are written from their arrays (smaller ones: by libhdf5).
DIRECT_BYTES = 1 << 20
#: Zero bytes handed out at a time for unwritten space between stretches.
_ZEROS = bytes(1 << 16)


class Image(io.RawIOBase):
    """A file in memory for ``h5py.File``: the bytes written, as disjoint sorted stretches
    (``starts``, ``parts``), and the arrays of :meth:`dataset` with their offsets."""

    def __init__(self) -> None:
        super().__init__()
        self.starts: list[int] = []
        self.parts: list[bytearray] = []
        self.arrays: list[tuple[int, np.ndarray]] = []
        self.size = 0
        self.pos = 0
        self.last = 0  # the stretch written last

    # -- the file object libhdf5 writes through --------------------------------------------------
    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self.pos, io.SEEK_END: self.size}[whence]
        self.pos = max(base + offset, 0)
        return self.pos

    def tell(self) -> int:
        return self.pos

    def truncate(self, size: int | None = None) -> int:
        """Shorten the file to ``size`` bytes; as ``io.BytesIO``, never lengthen it."""
        size = self.pos if size is None else size
        if size < self.size:
            while self.starts and self.starts[-1] >= size:
                self.starts.pop()
                self.parts.pop()
            if self.parts and self.starts[-1] + len(self.parts[-1]) > size:
                del self.parts[-1][size - self.starts[-1]:]
            self.size = size
        return size

    def write(self, data: Any) -> int:
        view = memoryview(data).cast("B")
        n, at = len(view), self.pos
        k = self.last  # most writes rewrite or extend the stretch written last: no search
        if k < len(self.starts) and self.starts[k] <= at <= self.starts[k] + len(self.parts[k]) and \
                (k + 1 == len(self.starts) or at + n < self.starts[k + 1]):
            self.parts[k][at - self.starts[k]:at - self.starts[k] + n] = view
        elif n:
            self._put(at, view)
        self.pos = at + n
        self.size = max(self.size, self.pos)
        return n

    def readinto(self, buffer: Any) -> int:
        out = memoryview(buffer).cast("B")
        n = max(min(len(out), self.size - self.pos), 0)
        out[:n] = bytes(n)
        lo, hi = self.pos, self.pos + n
        for k in range(max(bisect.bisect_right(self.starts, lo) - 1, 0), len(self.starts)):
            start, part = self.starts[k], self.parts[k]
            if start >= hi:
                break
            a, b = max(start, lo), min(start + len(part), hi)
            if a < b:
                out[a - lo:b - lo] = part[a - start:b - start]
        self.pos += n
        return n

    def _put(self, at: int, view: memoryview) -> None:
        """Bytes ``view`` at offset ``at``: into the stretch they start in or at the end of,
        else a new one, when they reach no further stretch (libhdf5 rewrites a block in place,
        appends, or fills a gap: then the stretches either side join); stretches they overlap
        are merged into one (rare)."""
        end = at + len(view)
        k = bisect.bisect_right(self.starts, at) - 1
        if k + 1 == len(self.starts) or end <= self.starts[k + 1]:  # reaches no later stretch
            if k >= 0 and at <= self.starts[k] + len(self.parts[k]):
                start = self.starts[k]
                self.parts[k][at - start:end - start] = view  # within stretch k, or extending it
            else:
                k += 1
                self.starts.insert(k, at)
                self.parts.insert(k, bytearray(view))
            if k + 1 < len(self.starts) and self.starts[k] + len(self.parts[k]) == self.starts[k + 1]:
                self.parts[k] += self.parts.pop(k + 1)  # a gap filled: one stretch again
                del self.starts[k + 1]
            self.last = k
            return
        first = k if k >= 0 and at < self.starts[k] + len(self.parts[k]) else k + 1
        last = bisect.bisect_left(self.starts, end) - 1  # the last stretch starting before end
        lo = min(at, self.starts[first])
        hi = max(end, self.starts[last] + len(self.parts[last]))
        merged = bytearray(hi - lo)
        for j in range(first, last + 1):
            merged[self.starts[j] - lo:self.starts[j] - lo + len(self.parts[j])] = self.parts[j]
        merged[at - lo:end - lo] = view
        self.starts[first:last + 1] = [lo]
        self.parts[first:last + 1] = [merged]
        self.last = first

    # -- large datasets ---------------------------------------------------------------------------
    def dataset(self, group: Any, name: str, data: np.ndarray) -> None:
        """``data`` as contiguous dataset ``name`` of ``group``: its space allocated at creation,
        no fill value written, and the array kept to be written at the dataset's offset by
        :meth:`pieces`. ``data`` must not change until then."""
        import h5py

        dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
        dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
        dset = group.create_dataset(name, shape=data.shape, dtype=data.dtype, dcpl=dcpl, fill_time="never")
        self.arrays.append((int(dset.id.get_offset()), np.ascontiguousarray(data)))

    def pieces(self, start: int = 0) -> Iterator[memoryview | bytes]:
        """The file's bytes from offset ``start`` to its end, in order: the stretches written,
        the arrays of :meth:`dataset` at their offsets, zeros in between."""
        items = sorted([(s, memoryview(p)) for s, p in zip(self.starts, self.parts, strict=True)] +
                       [(s, memoryview(a).cast("B")) for s, a in self.arrays], key=lambda item: item[0])
        at = start
        for offset, view in items:
            if offset + len(view) <= at:
                continue
            if offset > at:
                yield from _zeros(offset - at)
                at = offset
            yield view[at - offset:]
            at = offset + len(view)
        end = max(self.size, at)
        if end > at:
            yield from _zeros(end - at)


def _zeros(n: int) -> Iterator[bytes]:
    while n > 0:
        yield _ZEROS[:min(n, len(_ZEROS))]
        n -= len(_ZEROS)


def direct(data: np.ndarray) -> bool:
    """Whether ``data`` is written from its array (:meth:`Image.dataset`): an array of native
    integers or floats (whose bytes HDF5 stores as they are) of at least :data:`DIRECT_BYTES`."""
    return data.ndim >= 1 and data.nbytes >= DIRECT_BYTES and data.dtype.kind in "fiu" and \
        data.dtype.isnative
