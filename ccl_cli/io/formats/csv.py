"""CSV files and text matrices.

A header row names the columns; a file whose first row is all numbers has no header and
its columns are addressed by 0-based index (all of them when ``columns`` is not given).
Whitespace-separated files (any run of spaces or tabs, as the original C library and
MATLAB's ``save -ascii`` write them) are split on whitespace. ``samples: columns`` reads
the table transposed: one sample per column, one variable per row; ``file`` reads a
stream from a sibling file (e.g. ``X.txt`` and ``U.txt``).

Duplicate column names (a rosbag → CSV export repeats ``x,y,z`` for position and
orientation) are kept distinct: the second ``x`` is addressable as ``x.1``, the third
as ``x.2``, or any column by its 0-based index. The time column is parsed exactly:
integer nanoseconds stay int64; decimal seconds are split at the point, never passed
through float64.

A table of numbers only (no quotes, no empty cell) is parsed by NumPy's text reader in
one pass (:class:`_Matrix`); anything else by the csv module, cell by cell (:class:`_Cells`),
which also explains every problem.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.limits import check_claim, max_line_bytes, open_regular
from ccl_cli.io.options import UNIT_NS, DataOptions, StreamOptions, TimeOptions
from ccl_cli.io.streams import Stream, StreamReader
from ccl_cli.io.summary import activity

#: time columns tried in order (case-insensitive): rosbag/PlotJuggler/rostopic exports first;
#: a candidate is used only when every value is a number (an empty ``stamp`` column of a
#: flattened header is skipped)
TIME_NAMES = ("rosbagTimestamp", "%time", "__time", "time", "timestamp", "t", "header.stamp",
              "field.header.stamp", "stamp", "time_stamp")
_TIME_KEYS = {n.lower() for n in TIME_NAMES}
_INT = re.compile(r"^[+-]?\d+$")
_DEC = re.compile(r"^([+-]?)(\d*)\.(\d*)$")
#: a whole time column of integers, or of integers and decimals (one value per line)
_INTS = re.compile(r"(?:[+-]?\d+\n)*")
_DECIMALS = re.compile(r"(?:[+-]?(?:\d*\.\d*|\d+)\n)*")
_I64 = 2**63 - 1
#: line boundaries of str.splitlines that are not line ends to the csv module
_OTHER_LINE_BREAKS = "\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"


def unique_names(header: list[str]) -> list[str]:
    """['x','y','x'] → ['x','y','x.1']."""
    seen: dict[str, int] = {}
    out = []
    for raw in header:
        name = raw.strip()
        n = seen.get(name, 0)
        seen[name] = n + 1
        out.append(name if n == 0 else f"{name}.{n}")
    return out


# -- exact time stamps -----------------------------------------------------------------------
def parse_time_ns(column: Sequence[str], unit: str | None, where: str) -> np.ndarray:
    """Exact int64 nanoseconds from strings (n,) → (n,). ``unit`` None: integers ≥ 1e15 are
    ns, everything else seconds. Values that are not finite or do not fit int64 ns are an
    :class:`InputError` naming the row."""
    fast = _time_ns_vectorised(column, unit)
    return fast if fast is not None else _time_ns_per_value(column, unit, where)


def _time_ns_vectorised(column: Sequence[str], unit: str | None) -> np.ndarray | None:
    """The common cases at array speed: all integers, or integers and plain decimals
    (``[+-]digits.digits``). None when a value is anything else or out of range (then
    :func:`_time_ns_per_value` parses it, and names the row at fault)."""
    text = "\n".join(column) + "\n"
    values = np.array(column, dtype=str)
    try:
        if _INTS.fullmatch(text):
            ints = values.astype(np.int64)
            big = max(abs(int(ints.min())), abs(int(ints.max())))
            unit = unit or ("ns" if big >= 10**15 else "s")
            if big * UNIT_NS[unit] > _I64:
                return None
            return ints * UNIT_NS[unit]
        if not _DECIMALS.fullmatch(text):
            return None
        scale = UNIT_NS[unit or "s"]
        digits = len(str(scale)) - 1
        negative = np.char.startswith(values, "-")
        whole, _, frac = np.char.partition(np.char.lstrip(values, "+-"), ".").T
        whole = np.where(whole == "", "0", whole).astype(np.int64)
        if int(whole.max(initial=0)) >= _I64 // scale:
            return None
        ns = whole * scale
        if digits:
            ns += np.char.ljust(frac, digits, "0").astype(f"U{digits}").astype(np.int64)
        return np.where(negative, -ns, ns)
    except (ValueError, OverflowError):
        return None


def _ns(value: int, v: str, i: int, where: str) -> int:
    if not -_I64 <= value <= _I64:
        raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is out of range "
                         "(beyond ±9.2e18 ns)")
    return value


def _time_ns_per_value(column: Sequence[str], unit: str | None, where: str) -> np.ndarray:
    """:func:`parse_time_ns` one value at a time (any float syntax; exact errors)."""
    if all(_INT.match(v.strip()) for v in column):  # str.strip: any Unicode space around it
        ints = [int(v.strip()) for v in column]
        if unit is None:
            unit = "ns" if max(map(abs, ints), default=0) >= 10**15 else "s"
        scale = UNIT_NS[unit]
        return np.array([_ns(x * scale, v, i, where)
                         for i, (x, v) in enumerate(zip(ints, column, strict=True))], dtype=np.int64)
    scale = UNIT_NS[unit or "s"]
    digits = len(str(scale)) - 1
    out = np.empty(len(column), dtype=np.int64)
    for i, v in enumerate(column):  # exact decimal split; a float would lose ns at epoch scale
        m = _DEC.match(v.strip())
        if m:
            sign = -1 if m.group(1) == "-" else 1
            whole = int(m.group(2) or 0)
            frac = (m.group(3) + "0" * digits)[:digits] if digits else ""
            out[i] = _ns(sign * (whole * scale + (int(frac) if frac else 0)), v, i, where)
        elif _INT.match(v.strip()):
            out[i] = _ns(int(v.strip()) * scale, v, i, where)
        else:
            try:
                value = float(v) * scale
            except ValueError:
                raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is not a number") from None
            if not math.isfinite(value):
                raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is not finite")
            out[i] = _ns(int(round(value)), v, i, where)
    return out


# -- the body of a table: numbers in one pass, or cells ------------------------------------------
class _Matrix:
    """A table of numbers only: every cell parsed by ``np.loadtxt`` at once; the text of a
    column is split out of the lines only when asked (exact time stamps)."""

    def __init__(self, values: np.ndarray, lines: list[str], delimiter: str | None, transposed: bool) -> None:
        self.values = values.T if transposed else values  # (rows, columns), one sample per row
        self.lines = lines
        self.delimiter = delimiter
        self.transposed = transposed

    @property
    def n_rows(self) -> int:
        return self.values.shape[0]

    def text(self, k: int) -> list[str]:
        if self.transposed:  # column k of the table is line k of the file
            return self.lines[k].split(self.delimiter)
        if self.delimiter is None:
            return [ln.split(None, k + 1)[k] for ln in self.lines]
        return [ln.split(self.delimiter, k + 1)[k] for ln in self.lines]

    def numbers(self, k: int, name: str, where: str) -> np.ndarray:
        return self.values[:, k]

    def is_numeric(self, k: int) -> bool:
        return True


class _Cells:
    """A table as rows of cells (strings), as the csv module reads it."""

    def __init__(self, rows: list[list[str]]) -> None:
        self.rows = rows

    @property
    def n_rows(self) -> int:
        return len(self.rows)

    def text(self, k: int) -> list[str]:
        return [r[k] for r in self.rows]

    def numbers(self, k: int, name: str, where: str) -> np.ndarray:
        col = self.text(k)
        try:
            return np.array(col, dtype=float)
        except ValueError:
            bad = next(i for i, v in enumerate(col) if not _is_number(v))
            raise InputError(f"{where}: column {name!r} row {bad + 2} is not numeric "
                             f"({col[bad]!r})") from None

    def is_numeric(self, k: int) -> bool:
        """Every value of column ``k`` parses as a number ('' and text do not)."""
        try:
            np.asarray(self.text(k), dtype=float)
        except ValueError:
            return False
        return True


class CsvTable:
    """One text file read as a table: column names and a body of ``n_rows`` samples."""

    def __init__(self, path: Path, time: TimeOptions, samples: str | None = None) -> None:
        self.path = Path(path)
        self.time = time
        self.samples = samples or "rows"
        self.headerless = False
        self._loaded: tuple[list[str], _Matrix | _Cells] | None = None
        self._time: tuple[np.ndarray, str] | None = None

    # -- parsing ---------------------------------------------------------------------------
    def _read_text(self) -> str:
        """The file's text, once its size and the length of its longest line are known to be
        within the caps (:func:`check_lines`: a scan that never holds a line)."""
        try:
            with open_regular(self.path, "the CSV file") as f:
                check_lines(f, str(self.path))
                raw = f.read()
        except OSError as exc:
            raise InputError(f"{self.path}: {exc.strerror or type(exc).__name__}") from None
        try:
            return raw.decode("utf-8-sig")
        except UnicodeDecodeError:
            raise InputError(f"{self.path}: not a text (CSV) file") from None

    def load(self) -> tuple[list[str], _Matrix | _Cells]:
        """(column names, body), parsed once."""
        if self._loaded is None:
            text = self._read_text()
            delim = self.time.delimiter or _sniff_delimiter(text[:65536])
            self._loaded = self._numbers(text, delim) or self._cells(text, delim)
        return self._loaded

    def _numbers(self, text: str, delim: str) -> tuple[list[str], _Matrix] | None:
        """The whole table through ``np.loadtxt``; None unless it is numbers only (then the
        cell-by-cell reader gives the same table, or says what is wrong)."""
        if '"' in text or any(c in text for c in _OTHER_LINE_BREAKS):
            return None  # quoting, or characters str.splitlines breaks at and the csv module not
        sep = None if delim in (" ", "whitespace") else delim
        lines = text.splitlines()  # at \n, \r\n and \r, as the csv module
        if sep is not None and max(map(len, lines)) > csv.field_size_limit():
            return None  # a line that may hold a field the csv module refuses
        # blank lines (only separators and white space) are skipped; a line of other white
        # space kept here makes np.loadtxt fail, and the cell-by-cell reader decide
        blank = " \t" + (sep or "")
        lines = [ln for ln in lines if ln.strip(blank)]
        header = (lines[0].split(sep) if sep is not None else lines[0].split()) if lines else []
        if not any(c.strip() for c in header):
            return None
        headerless = all(_is_number(c) for c in header)
        if self.samples == "columns" and not headerless:
            return None
        body = lines if headerless else lines[1:]
        if not body:
            return None
        try:
            values = np.loadtxt(body, delimiter=sep, comments=None, dtype=float, ndmin=2)
        except ValueError:
            return None
        if values.shape != (len(body), len(header)):
            return None
        self.headerless = headerless
        transposed = self.samples == "columns"
        n_names = values.shape[0] if transposed else len(header)
        names = [str(j) for j in range(n_names)] if headerless else unique_names(header)
        return names, _Matrix(values, body, sep, transposed)

    def _cells(self, text: str, delim: str) -> tuple[list[str], _Cells]:
        f = io.StringIO(text, newline="")
        if delim in (" ", "whitespace"):
            rows = [line.split() for line in f]
        else:
            reader = csv.reader(f, delimiter=delim)
            try:
                rows = list(reader)
            except csv.Error as exc:  # a field over csv.field_size_limit (128 kB), ...
                raise InputError(f"{self.path}: line {reader.line_num}: not a readable CSV row "
                                 f"({exc})") from None
        rows = [r for r in rows if r and any(c.strip() for c in r)]
        if not rows:
            raise InputError(f"{self.path}: empty CSV file")
        header = rows[0]
        self.headerless = all(_is_number(c) for c in header)
        if self.samples == "columns":
            if not self.headerless:
                raise InputError(f"{self.path}: samples: columns needs a text matrix without a header row")
            width = len(header)
            bad = next((i for i, r in enumerate(rows) if len(r) != width), None)
            if bad is not None:
                raise InputError(f"{self.path}: row {bad + 1} has {len(rows[bad])} fields, row 1 has {width}")
            rows = [list(col) for col in zip(*rows, strict=True)]  # one sample per column → per row
            header = rows[0]
        if self.headerless:
            names = [str(j) for j in range(len(header))]
            body = rows
        else:
            names = unique_names(header)
            body = rows[1:]
        bad = next((i for i, r in enumerate(body) if len(r) != len(names)), None)
        if bad is not None:
            first = "row 1" if self.headerless else "the header"
            raise InputError(f"{self.path}: row {bad + 1 + (not self.headerless)} has {len(body[bad])} "
                             f"fields, {first} has {len(names)}")
        return names, _Cells(body)

    # -- columns and time --------------------------------------------------------------------
    def index(self, names: list[str], key: str | int) -> int:
        """The position of a column given by name or 0-based index."""
        if isinstance(key, int) or (isinstance(key, str) and key.isdigit() and key not in names):
            idx = int(key)
            if not 0 <= idx < len(names):
                raise InputError(f"{self.path}: column index {idx} out of range (0..{len(names) - 1})")
            return idx
        if key in names:
            return names.index(key)
        close = [n for n in names if n.lower() == str(key).lower() or n.endswith("." + str(key))]
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise InputError(f"{self.path}: column {key!r} not found{hint} (columns: {', '.join(names)})")

    def time_ns(self) -> tuple[np.ndarray, str]:
        """Stamps (n,) int64 ns and where they came from (a column name, or the rate)."""
        if self._time is None:
            self._time = self._read_time()
        return self._time

    def _read_time(self) -> tuple[np.ndarray, str]:
        names, body = self.load()
        where = str(self.path)
        if self.time.column is not None:
            idx = self.index(names, self.time.column)
        elif self.time.rate:
            idx = None  # a configured rate is not overridden by a detected column
        else:
            idx = find_time_column(names, body)
        if idx is None:
            if self.time.rate:
                step = int(round(1e9 / self.time.rate))
                return np.arange(body.n_rows, dtype=np.int64) * step, f"rate {self.time.rate} Hz"
            skipped = [n for n in names if n.lower() in _TIME_KEYS]
            why = f"; {', '.join(skipped)} not numeric or empty" if skipped else ""
            raise InputError(f"{where}: no time column (looked for {', '.join(TIME_NAMES)}{why}); "
                             "set data.time.column or data.time.rate")
        return parse_time_ns(body.text(idx), self.time.unit, where), names[idx]

    def listing(self) -> dict[str, Any]:
        names, body = self.load()
        t, col = self.time_ns() if body.n_rows else (np.zeros(0, np.int64), "")
        return {"start_ns": int(t[0]) if len(t) else 0, "end_ns": int(t[-1]) if len(t) else 0,
                "columns": names, "rows": body.n_rows, "time_column": col, "header": not self.headerless,
                "sample_axis": self.samples}

    def stream(self, selection: StreamOptions) -> Stream:
        """The columns of ``selection`` (all but the time column of a text matrix)."""
        names, body = self.load()
        if not selection.columns and not self.headerless:
            raise InputError(f"{self.path}: a CSV stream needs columns: [...] (columns: {', '.join(names)})")
        if not body.n_rows:
            raise InputError(f"{self.path}: CSV has a header but no rows")
        t_ns, tcol = self.time_ns()
        if selection.columns:
            idx = [self.index(names, c) for c in selection.columns]
        else:  # a text matrix: every column but the time column
            idx = [k for k, n in enumerate(names) if n != tcol]
        values = np.empty((body.n_rows, len(idx)))
        for j, k in enumerate(idx):
            values[:, j] = body.numbers(k, names[k], str(self.path))
        labels = [f"{self.path.stem}[{names[k]}]" if self.headerless else names[k] for k in idx]
        return Stream(t_ns, values, labels, str(self.path),
                      {"columns": [names[k] for k in idx], "time_column": tcol, "sample_axis": self.samples})


def check_lines(f: IO[bytes], where: str) -> None:
    """Refuse a text file over the cap (:func:`~ccl_cli.io.limits.check_claim`) or with a line
    longer than :func:`~ccl_cli.io.limits.max_line_bytes`, before it is read: the file is
    mapped, not loaded, and each step looks for the last line end (LF or CR) in the next
    window of that many bytes, so a file of n bytes takes about n / window steps."""
    import mmap

    size = os.fstat(f.fileno()).st_size
    check_claim(where, "the text", size, 1)
    window = max_line_bytes()
    if size <= window:
        return
    with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        start = 0
        while size - start > window:
            end = start + window + 1  # a line of exactly ``window`` bytes ends inside
            last = max(mm.rfind(b"\n", start, end), mm.rfind(b"\r", start, end))
            if last < 0:
                raise InputError(f"{where}: a line longer than {window} bytes starts at byte {start}; "
                                 "not a CSV table (refused before reading it)")
            start = last + 1


def find_time_column(names: list[str], body: _Matrix | _Cells) -> int | None:
    """Index of the first :data:`TIME_NAMES` column (case-insensitive, in that order) whose
    every value is a number; None when there is none."""
    lower = [n.lower() for n in names]
    for cand in TIME_NAMES:
        key = cand.lower()
        for k, name in enumerate(lower):
            if name == key and body.n_rows and body.is_numeric(k):
                return k
    return None


def _sniff_delimiter(sample: str) -> str:
    """``,``, ``;`` or tab as the sample uses them; whitespace (any run of spaces or tabs)
    for text matrices and space-aligned tables."""
    lines = [ln for ln in sample.splitlines() if ln.strip()][:20]
    if lines and not any(c in ln for ln in lines for c in ",;"):
        widths = {len(ln.split()) for ln in lines}
        numeric_first = all(_is_number(tok) for tok in lines[0].split())
        if numeric_first or (len(widths) == 1 and widths.pop() > 1 and "\t" not in sample):
            return " "
    try:
        return csv.Sniffer().sniff(sample, delimiters=",;\t ").delimiter
    except csv.Error:
        return ","


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


# -- the format -------------------------------------------------------------------------------
class CsvReader(StreamReader):
    """A CSV file or text matrix; a stream's ``file`` (relative to the recording's folder) and
    ``samples`` side open a sibling table."""

    format = "csv"
    sibling_files = True

    def __init__(self, path: str | Path, options: DataOptions) -> None:
        super().__init__(path, options)
        self._tables: dict[tuple[Path, str | None], CsvTable] = {}

    def table(self, selection: StreamOptions | None) -> CsvTable:
        """The table of one stream: this file, or its sibling ``file``, read with ``samples``."""
        file = selection.file if selection is not None else None
        samples = selection.samples if selection is not None else None
        path = self.path if file is None else self.path.parent / file  # an absolute file stays itself
        if file is not None and not path.exists():
            raise InputError(f"{path}: no such file (stream file {file!r}, relative to {self.path.parent})")
        key = (path, samples)
        if key not in self._tables:
            self._tables[key] = CsvTable(path, self.options.time, samples)
        return self._tables[key]

    def streams(self, selections: Sequence[StreamOptions]) -> list[Stream]:
        return [self.table(s).stream(s) for s in selections]

    def listing(self) -> dict[str, Any]:
        state = self.options.state
        return self.table(StreamOptions(samples=state.samples) if state is not None else None).listing()

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        """Columns, rows and time column; the names the configured streams would get; the
        rate over the active time and the demonstrations of the (first) state column."""
        info = self.listing()
        out = self.span(info)
        out.update({k: info[k] for k in ("columns", "rows", "time_column", "header", "sample_axis")})
        if info["rows"] > 1 and out["duration_s"] > 0:
            out["rate_hz"] = (info["rows"] - 1) / out["duration_s"]
        o = self.options
        for key, selection in (("state", o.state), ("action", None if o.derives_action else o.action)):
            if selection is not None and (selection.columns or (key == "state" and not info["header"])):
                out[f"{key}_names"] = self.streams([selection])[0].names
        state = o.state.columns if o.state is not None and o.state.columns else \
            [c for c in info["columns"] if c != info["time_column"]][:1]
        if state:
            main = StreamOptions(columns=state[:1], samples=o.state.samples if o.state else None)
            act = activity(self.streams([main])[0].t_ns, gap)
            out.update({"rate_hz": act["rate_hz"], "active_s": act["active_s"], "demos": act["demos"],
                        "demos_from": "rows", "gap_s": act["gap_s"]} | _rule(act))
        return out


def _rule(act: dict[str, Any]) -> dict[str, Any]:
    return {"gap_rule": act["gap_rule"]} if "gap_rule" in act else {}
