"""The body of a CSV table read as a stream, keeping only the columns asked for.

A file is read line by line (its size and longest line were checked first); each line
gives the cells of the kept columns and nothing else is kept, so the memory a read takes
is bounded by the kept columns (a file of 10⁶ columns of which 3 are read holds 3 columns,
not 10⁶). Two ways, as before, and the same table from both:

* :func:`numbers` — a table of numbers only (no quotes, every row as wide as the header):
  blocks of lines through NumPy's text reader with ``usecols`` (the data columns, as
  float64); the time columns are kept as text (exact stamps: :mod:`.csv_time`). ``None``
  when a line is anything else: then
* :func:`cells` — the csv module (quotes, text cells), row by row; a row of another width
  than the header is one line naming it.

Both return a :class:`Body`.
"""

from __future__ import annotations

import contextlib
import csv
import io
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import IO, Any

import numpy as np

from ccl_cli.errors import InputError

#: a block of lines handed to NumPy at once: about this many characters
BLOCK_CHARS = 2 << 20
#: what makes a line one the fast path does not read: quotes, and line boundaries of
#: str.splitlines that are not line ends to the csv module
NOT_PLAIN = re.compile('["\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]')


@dataclass
class Body:
    """The kept columns of a table's ``n_rows`` samples: per column index, its numbers
    (float64) and/or its text (a list of strings, or a NumPy text array)."""

    n_rows: int
    values: dict[int, np.ndarray] = field(default_factory=dict)
    texts: dict[int, Any] = field(default_factory=dict)

    def has(self, k: int) -> bool:
        return k in self.values or k in self.texts

    def text(self, k: int) -> Any:
        return self.texts[k]

    def numbers(self, k: int, name: str, where: str) -> np.ndarray:
        if k in self.values:
            return self.values[k]
        col = self.texts[k]
        try:
            return col.astype(float) if isinstance(col, np.ndarray) else np.array(col, dtype=float)
        except ValueError:
            text = col.tolist() if isinstance(col, np.ndarray) else col
            bad = next(i for i, v in enumerate(text) if not is_number(v))
            shown = text[bad].decode("ascii") if isinstance(text[bad], bytes) else text[bad]
            raise InputError(f"{where}: column {name!r} row {bad + 2} is not numeric ({shown!r})") from None

    def is_numeric(self, k: int) -> bool:
        """Every value of column ``k`` parses as a number ('' and text do not)."""
        if k in self.values:
            return True
        try:
            self.numbers(k, "", "")
        except InputError:
            return False
        return True


def is_number(text: str | bytes) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _as_text_array(texts: list[str]) -> np.ndarray:
    """One byte a character (``S``) when the texts are ASCII without NUL (which ``S`` would
    drop at the end), else ``U``."""
    if all(t.isascii() for t in texts) and not any("\x00" in t for t in texts):
        return np.array(texts, dtype="S")
    return np.array(texts, dtype=str)


def blocks(text: IO[str], first: str | None = None) -> Iterator[str]:
    """The lines of ``text`` (universal newlines: every line end is \\n) in blocks of about
    :data:`BLOCK_CHARS` characters, each whole lines joined by \\n without the last one;
    ``first``: a line read already, put in front."""
    carry = "" if first is None else first + "\n"
    while True:
        chunk = text.read(BLOCK_CHARS)
        if not chunk:
            if carry:
                yield carry[:-1] if carry.endswith("\n") else carry
            return
        chunk = carry + chunk
        cut = chunk.rfind("\n")
        if cut < 0:
            carry = chunk
            continue
        if cut:
            yield chunk[:cut]
        carry = chunk[cut + 1:]


#: a table this wide or wider is read with ``usecols`` and its rows' widths checked line by
#: line (a structured dtype per column is cheaper below)
WIDE = 256
#: the text of a time column is read as this many bytes at most (a longer value is read again
#: from its line: none of that length is a time in range)
TIME_TEXT = 48


def numbers(blocks_of_lines: Iterable[str], sep: str | None, width: int, keep: list[int], times: list[int],
            most: int) -> Body | None:
    """The body of a table of ``width`` columns separated by ``sep`` (None: runs of white
    space), from blocks of lines (:func:`blocks`; at ``most`` lines in all), through NumPy's
    text reader: columns ``keep`` as float64 (allocated once, for ``most`` rows), the time
    columns ``times`` as int64 where they are integers, else as text. None when a line is not
    ``width`` numbers in the kept columns (quotes, a text cell, a row of another width, a
    cell the csv module would refuse) or holds a character str.splitlines would break at.
    Each column is an array of its own (a reader lets go of a column once it has copied it)
    and owns its memory: a block's parsed table is dropped once its columns are copied out."""
    blank = re.compile("(?m)^[ \t" + re.escape(sep or "") + "]*$")
    limit = csv.field_size_limit()
    wide = width >= WIDE
    data = [k for k in keep if k not in times]  # a kept time column is read from its text
    out = [np.empty(most) for _ in data]  # one array per data column
    texts: dict[int, list[np.ndarray]] = {k: [] for k in times}
    as_int = dict.fromkeys(times, True)
    n = 0
    for block in blocks_of_lines:
        scan = _Scan(block, sep)
        if not scan.plain:
            return None
        lines: Any = None
        if scan.may_be_blank and blank.search(block):  # lines of only separators and spaces: skipped
            lines = [ln for ln in block.split("\n") if not blank.fullmatch(ln)]
            if not lines:
                continue
            block = "\n".join(lines)
            scan = _Scan(block, sep)
        rows = len(lines) if lines is not None else block.count("\n") + 1
        if n + rows > most or (sep is not None and scan.longest_field > limit):
            return None  # a field the csv module refuses: it explains
        if wide and not all(_width(ln, sep) == width for ln in block.split("\n")):
            return None  # (a narrow table's widths are checked by the structured dtype of _parse)
        table = _parse(block, sep, width, data, times, as_int, wide)
        if table is None:
            return None
        for j, k in enumerate(data):
            out[j][n:n + rows] = table[f"c{k}"]
        for k in times:  # a field of ``table`` is a view of all of it: copied
            field_ = table[f"c{k}"]
            texts[k].append(field_.copy() if as_int[k] else _checked_text(field_, block, sep, k))
        n += rows
    # views: the blank lines' room stays allocated (the data columns' share)
    return Body(n, {k: out[j][:n] for j, k in enumerate(data)}, {k: _joined(v) for k, v in texts.items()})


#: ASCII characters that make a line one the fast path does not read (see :data:`NOT_PLAIN`)
_NOT_PLAIN_BYTES = np.zeros(256, dtype=bool)
_NOT_PLAIN_BYTES[[0x22, 0x0B, 0x0C, 0x1C, 0x1D, 0x1E]] = True


class _Scan:
    """One look at a block's bytes: whether it is plain (:data:`NOT_PLAIN`), whether a line
    may be blank (it starts with a separator or white space, or is empty), and the bytes of
    its longest field (≥ its characters; a field ends at ``sep`` or a line end)."""

    def __init__(self, block: str, sep: str | None) -> None:
        raw = np.frombuffer(block.encode("utf-8", "surrogatepass"), dtype=np.uint8)
        ascii_ = raw.size == len(block)
        self.plain = not _NOT_PLAIN_BYTES[raw].any() and (ascii_ or not NOT_PLAIN.search(block))
        line_ends = np.flatnonzero(raw == 10)
        starts = np.r_[0, line_ends + 1]
        first = raw[starts[starts < raw.size]]
        openers = [10, 32, 9] + ([ord(sep)] if sep and len(sep.encode()) == 1 else [])
        self.may_be_blank = not raw.size or starts[-1] >= raw.size or bool(np.isin(first, openers).any()) \
            or (sep is not None and len(sep.encode()) != 1)
        self.longest_field = 0
        if sep is not None and len(sep.encode()) != 1:
            self.longest_field = max((len(f) for ln in block.split("\n") for f in ln.split(sep)), default=0)
        elif sep is not None:
            ends = np.flatnonzero((raw == ord(sep)) | (raw == 10))
            self.longest_field = int(np.diff(ends, prepend=-1, append=raw.size).max()) - 1


def _parse(text: str, sep: str | None, width: int, data: list[int], times: list[int], as_int: dict[int, bool],
           wide: bool) -> np.ndarray | None:
    """One block through ``np.loadtxt`` with a structured dtype: data columns float64, time
    columns int64 (text of :data:`TIME_TEXT` bytes once a block had a non-integer one), the
    others (narrow tables: every column is read, so a row of another width fails) one byte;
    None when it does not parse. A block that is not ASCII reads its time columns as text: NumPy's
    integer conversion (2.x) can crash the process on some characters beyond ASCII."""
    used = sorted({*data, *times})
    if not text.isascii():
        for k in times:
            as_int[k] = False
    for _ in range(2):
        fields = {k: "f8" for k in data} | {k: ("i8" if as_int[k] else f"S{TIME_TEXT}") for k in times}
        columns = used if wide else range(width)
        dtype = [(f"c{k}", fields.get(k, "S1")) for k in columns]
        try:
            return np.loadtxt(text.split("\n"), delimiter=sep, comments=None, quotechar=None, ndmin=1,
                              dtype=dtype, usecols=used if wide else None)
        except ValueError:
            if not any(as_int.values()):
                return None
            for k in times:  # a time column of decimals, or text: read again as text
                as_int[k] = False
    return None


def _checked_text(column: np.ndarray, block: str, sep: str | None, k: int) -> np.ndarray:
    """A time column's text as read (``S``, as wide as its longest value: a copy, not a view
    of the block's table), or — a value that may have been cut at :data:`TIME_TEXT` bytes, or
    a block that is not ASCII — split from its lines again."""
    longest = int(np.char.str_len(column).max()) if column.size else 0
    if longest < TIME_TEXT and block.isascii() and "\x00" not in block:
        return column.astype(f"S{max(longest, 1)}")
    return _as_text_array([_field(ln, sep, k) for ln in block.split("\n")])


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    """The blocks of a time column as one array: int64, or text (``U`` unless every block is
    ``S``)."""
    if not parts:
        return np.empty(0, dtype=np.int64)
    if len({p.dtype.kind for p in parts}) > 1:
        parts = [p.astype(str) for p in parts]
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _width(line: str, sep: str | None) -> int:
    return line.count(sep) + 1 if sep is not None else len(line.split())


def _field(line: str, sep: str | None, k: int) -> str:
    return line.split(sep, k + 1)[k]


def cells(rows: Iterable[list[str]], keep: Callable[[list[str], bool], list[int]],
          is_header: Callable[[list[str]], bool], where: str) -> tuple[list[str], bool, Body]:
    """The first row, whether it is data (no header: ``not is_header(row)``), and the kept
    text columns of ``rows`` (lists of cells; blank ones skipped): ``keep(first row,
    headerless)`` says which. A row of another width than the first is one InputError line
    naming it (rows numbered from 1, the header included)."""
    header: list[str] | None = None
    headerless = False
    kept: list[int] = []
    texts: dict[int, list[str]] = {}
    n = 0
    for row in rows:
        if not row or not any(c.strip() for c in row):
            continue
        if header is None:
            header, headerless = row, not is_header(row)
            kept = keep(header, headerless)
            texts = {k: [] for k in kept}
            if not headerless:
                continue
        if len(row) != len(header):
            first = "row 1" if headerless else "the header"
            raise InputError(f"{where}: row {n + 1 + (not headerless)} has {len(row)} fields, {first} has "
                             f"{len(header)}")
        for k in kept:
            texts[k].append(row[k])
        n += 1
    if header is None:
        raise InputError(f"{where}: empty CSV file")
    return header, headerless, Body(n, texts=texts)


def csv_rows(f: IO[str], delim: str, where: str) -> Iterator[list[str]]:
    """Rows of cells of a text stream (opened with ``newline=""``): the csv module's, or
    white-space-split lines (``delim`` " "); a row the csv module refuses is one line."""
    if delim in (" ", "whitespace"):
        yield from (line.split() for line in f)
        return
    reader = csv.reader(f, delimiter=delim)
    try:
        yield from reader
    except csv.Error as exc:  # a field over csv.field_size_limit (128 kB), ...
        raise InputError(f"{where}: line {reader.line_num}: not a readable CSV row ({exc})") from None


@contextlib.contextmanager
def text_stream(raw: IO[bytes], newline: str | None) -> Iterator[io.TextIOWrapper]:
    """``raw`` from its start, decoded as UTF-8 (a BOM dropped) while it is read; ``raw``
    stays open afterwards (for another pass)."""
    raw.seek(0)
    text = io.TextIOWrapper(raw, encoding="utf-8-sig", errors="strict", newline=newline)
    try:
        yield text
    finally:
        text.detach()
