"""CSV files and text matrices.

A header row names the columns; a file whose first row is all numbers has no header and
its columns are addressed by 0-based index (all of them when ``columns`` is not given).
Whitespace-separated files (any run of spaces or tabs, as the original C library and
MATLAB's ``save -ascii`` write them) are split on whitespace. ``samples: columns`` reads
the table transposed: one sample per column, one variable per row.

Duplicate column names (a rosbag → CSV export repeats ``x,y,z`` for position and
orientation) are kept distinct: the second ``x`` is addressable as ``x.1``, the third
as ``x.2``, or any column by its 0-based index. The time column is parsed exactly:
integer nanoseconds stay int64; decimal seconds are split at the point, never
passed through float64.
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.streams import Stream, StreamSpec

#: time columns tried in order (case-insensitive): rosbag/PlotJuggler/rostopic exports first;
#: a candidate is used only when every value is a number (an empty ``stamp`` column of a
#: flattened header is skipped)
TIME_NAMES = ("rosbagTimestamp", "%time", "__time", "time", "timestamp", "t", "header.stamp",
              "field.header.stamp", "stamp", "time_stamp")
SAMPLES = ("rows", "columns")
UNITS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
_INT = re.compile(r"^[+-]?\d+$")
_DEC = re.compile(r"^([+-]?)(\d*)\.(\d*)$")


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


_I64 = 2**63 - 1


def _ns(value: int, v: str, i: int, where: str) -> int:
    if not -_I64 <= value <= _I64:
        raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is out of range "
                         "(beyond ±9.2e18 ns)")
    return value


def parse_time_ns(column: list[str], unit: str | None, where: str) -> np.ndarray:
    """Exact int64 nanoseconds from strings. ``unit`` None: integers ≥ 1e15 are ns,
    everything else seconds. Values that are not finite or do not fit int64 ns are an
    :class:`InputError` naming the row."""
    if all(_INT.match(v) for v in column):
        ints = [int(v) for v in column]
        if unit is None:
            unit = "ns" if max(map(abs, ints), default=0) >= 10**15 else "s"
        scale = UNITS[unit]
        return np.array([_ns(x * scale, v, i, where)
                         for i, (x, v) in enumerate(zip(ints, column, strict=True))], dtype=np.int64)
    unit = unit or "s"
    scale = UNITS[unit]
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
            out[i] = _ns(int(v) * scale, v, i, where)
        else:
            try:
                value = float(v) * scale
            except ValueError:
                raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is not a number") from None
            if not math.isfinite(value):
                raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is not finite")
            out[i] = _ns(int(round(value)), v, i, where)
    return out


class CsvReader:
    def __init__(self, path: Path, time_column: str | int | None = None, time_unit: str | None = None,
                 rate: float | None = None, delimiter: str | None = None, samples: str | None = None) -> None:
        self.path = Path(path)
        if samples is not None and samples not in SAMPLES:
            raise InputError(f"{path}: samples must be rows or columns, got {samples!r}")
        self.samples = samples or "rows"
        self.headerless = False
        self.time_column = time_column
        self.time_unit = time_unit
        self.rate = rate
        if delimiter is not None and delimiter != "whitespace" and (
                not isinstance(delimiter, str) or len(delimiter) != 1 or delimiter in "\r\n\"" or
                delimiter.isalnum()):
            raise InputError(f"{path}: time.delimiter must be one character (or whitespace), got "
                             f"{delimiter!r}"[:200])
        self.delimiter = delimiter
        if time_unit is not None and time_unit not in UNITS:
            raise InputError(f"time unit must be one of {', '.join(UNITS)}, got {time_unit!r}")
        self._table: tuple[list[str], list[list[str]]] | None = None

    def _load(self) -> tuple[list[str], list[list[str]]]:
        if self._table is not None:
            return self._table
        try:
            with open(self.path, newline="", encoding="utf-8-sig") as f:
                sample = f.read(65536)
                f.seek(0)
                delim = self.delimiter
                if delim is None:
                    delim = _sniff_delimiter(sample)
                if delim in (" ", "whitespace"):
                    rows = [line.split() for line in f]
                else:
                    reader = csv.reader(f, delimiter=delim)
                    try:
                        rows = list(reader)
                    except csv.Error as exc:  # a field over csv.field_size_limit (128 kB), ...
                        raise InputError(f"{self.path}: line {reader.line_num}: not a readable CSV row "
                                         f"({exc})") from None
        except UnicodeDecodeError:
            raise InputError(f"{self.path}: not a text (CSV) file") from None
        except OSError as exc:
            raise InputError(f"{self.path}: {exc.strerror}") from None
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
        self._table = (names, body)
        return self._table

    def _index(self, names: list[str], key: str | int) -> int:
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

    def _time(self, names: list[str], body: list[list[str]]) -> tuple[np.ndarray, str]:
        where = str(self.path)
        if self.time_column is not None:
            idx = self._index(names, self.time_column)
        elif self.rate:
            idx = None  # a configured rate is not overridden by a detected column
        else:
            idx = find_time_column(names, body)
        if idx is None:
            if self.rate:
                step = int(round(1e9 / self.rate))
                return np.arange(len(body), dtype=np.int64) * step, f"rate {self.rate} Hz"
            skipped = [n for n in names if n.lower() in _TIME_KEYS]
            why = f"; {', '.join(skipped)} not numeric or empty" if skipped else ""
            raise InputError(f"{where}: no time column (looked for {', '.join(TIME_NAMES)}{why}); "
                             "set data.time.column or data.time.rate")
        return parse_time_ns([r[idx] for r in body], self.time_unit, where), names[idx]

    def inspect(self) -> dict[str, Any]:
        names, body = self._load()
        t, col = self._time(names, body) if body else (np.zeros(0, np.int64), "")
        return {"start_ns": int(t[0]) if len(t) else 0, "end_ns": int(t[-1]) if len(t) else 0,
                "columns": names, "rows": len(body), "time_column": col, "header": not self.headerless,
                "sample_axis": self.samples}

    def read_many(self, specs: list[StreamSpec]) -> list[Stream]:
        return [self.read(spec) for spec in specs]

    def read(self, spec: StreamSpec) -> Stream:
        names, body = self._load()
        if not spec.columns and not self.headerless:
            raise InputError(f"{self.path}: a CSV stream needs columns: [...] (columns: {', '.join(names)})")
        if not body:
            raise InputError(f"{self.path}: CSV has a header but no rows")
        t_ns, tcol = self._time(names, body)
        if spec.columns:
            idx = [self._index(names, c) for c in spec.columns]
        else:  # a text matrix: every column but the time column
            idx = [k for k, n in enumerate(names) if n != tcol]
        values = np.empty((len(body), len(idx)))
        for j, k in enumerate(idx):
            col = [r[k] for r in body]
            try:
                values[:, j] = np.array(col, dtype=float)
            except ValueError:
                bad = next(i for i, v in enumerate(col) if not _is_number(v))
                raise InputError(f"{self.path}: column {names[k]!r} row {bad + 2} is not numeric "
                                 f"({col[bad]!r})") from None
        labels = [f"{self.path.stem}[{names[k]}]" if self.headerless else names[k] for k in idx]
        return Stream(t_ns, values, labels, str(self.path),
                      {"columns": [names[k] for k in idx], "time_column": tcol, "sample_axis": self.samples})


_TIME_KEYS = {n.lower() for n in TIME_NAMES}


def find_time_column(names: list[str], body: list[list[str]]) -> int | None:
    """Index of the first :data:`TIME_NAMES` column (case-insensitive, in that order) whose
    every value is a number; None when there is none."""
    lower = [n.lower() for n in names]
    for cand in TIME_NAMES:
        key = cand.lower()
        for k, name in enumerate(lower):
            if name == key and body and _numeric_column(body, k):
                return k
    return None


def _numeric_column(body: list[list[str]], k: int) -> bool:
    """Every value of column ``k`` parses as a number (NumPy's C parser; '' and text fail)."""
    try:
        np.asarray([r[k] for r in body], dtype=float)
    except ValueError:
        return False
    return True


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
