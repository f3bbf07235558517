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

The file is read as a stream and only the columns a read asks for are kept (and the time
columns): a table of numbers only (no quotes, no empty cell) through NumPy's text reader,
block by block; anything else by the csv module, row by row, which also explains every
problem (:mod:`.csv_body`). Exact time stamps: :mod:`.csv_time`.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Sequence
from itertools import islice
from pathlib import Path
from typing import IO, Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.faults import repeated_poses
from ccl_cli.io.formats import csv_body
from ccl_cli.io.formats.csv_body import Body, is_number
from ccl_cli.io.formats.csv_time import parse_time_ns
from ccl_cli.io.limits import check_claim, max_line_bytes, open_regular
from ccl_cli.io.options import DataOptions, StreamOptions, TimeOptions
from ccl_cli.io.streams import Stream, StreamReader
from ccl_cli.io.summary import activity

#: time columns tried in order (case-insensitive): rosbag/PlotJuggler/rostopic exports first;
#: a candidate is used only when every value is a number (an empty ``stamp`` column of a
#: flattened header is skipped)
TIME_NAMES = ("rosbagTimestamp", "%time", "__time", "time", "timestamp", "t", "header.stamp",
              "field.header.stamp", "stamp", "time_stamp")
_TIME_KEYS = {n.lower() for n in TIME_NAMES}


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


# -- the table -------------------------------------------------------------------------------------
#: ``ccl inspect`` looks for repeated rows (a sensor logged faster than it updates) in the state's
#: columns, or without a config in the first this many columns of numbers
REPEAT_COLUMNS = 16
#: ``ccl inspect`` samples the first rows of a table this wide or narrower to tell which columns
#: hold text (a wider one — 10⁶ columns — would hold each sampled row as that many strings)
KIND_COLUMNS = 4096

#: a key asking for every column (a text matrix read without ``columns``)
ALL = "*"


class CsvTable:
    """One text file read as a table: column names and a body of ``n_rows`` samples holding
    the columns asked for (:meth:`want`) and the time columns, read as a stream
    (:mod:`.csv_body`): the other columns are skipped while reading."""

    def __init__(self, path: Path, time: TimeOptions, samples: str | None = None) -> None:
        self.path = Path(path)
        self.time = time
        self.samples = samples or "rows"
        self.headerless = False
        self._wanted: set[str | int] = set()
        self._loaded: tuple[list[str], Body] | None = None
        self._time: tuple[np.ndarray, str] | None = None
        self._delim = ","

    # -- parsing ---------------------------------------------------------------------------
    def want(self, keys: list[str | int] | tuple) -> None:
        """Ask for columns (names, indices, or :data:`ALL`) before or after loading: a column
        not read yet makes the next :meth:`load` read the file again."""
        new = set(keys) - self._wanted
        if not new:
            return
        self._wanted |= new
        if self._loaded is not None:
            names, body = self._loaded
            if not all(body.has(k) for k in self._kept(names)):
                self._loaded = None

    def load(self) -> tuple[list[str], Body]:
        """(column names, body), read once per set of columns asked for."""
        if self._loaded is None:
            self._loaded = self._read()
        return self._loaded

    def _kept(self, names: list[str]) -> set[int]:
        """The columns to keep: those asked for that exist (a missing one is named by
        :meth:`stream`)."""
        if ALL in self._wanted:
            return set(range(len(names)))
        kept = set()
        for key in self._wanted:
            try:
                kept.add(self.index(names, key))
            except InputError:
                pass
        return kept

    def _time_columns(self, names: list[str]) -> set[int]:
        """The columns a time may come from: the configured one, or (without a rate) those named
        like one (:data:`TIME_NAMES`)."""
        if self.time.column is not None:
            try:
                return {self.index(names, self.time.column)}
            except InputError:
                return set()
        if self.time.rate:
            return set()
        return {k for k, n in enumerate(names) if n.lower() in _TIME_KEYS}

    def _read(self) -> tuple[list[str], Body]:
        """The table, once the file's size and the length of its longest line are known to be
        within the caps (:func:`check_lines`: a scan that never holds a line)."""
        where = str(self.path)
        try:
            with open_regular(self.path, "the CSV file") as f:
                n_lines = check_lines(f, where)
                f.seek(0)
                delim = self.time.delimiter or _sniff_delimiter(f.read(65536).decode("utf-8-sig", "replace"))
                self._delim = delim
                if self.samples == "columns":
                    with csv_body.text_stream(f, "") as text:
                        return self._transposed(text.read(), delim)
                with csv_body.text_stream(f, None) as text:
                    found = self._numbers(text, delim, n_lines)
                if found is None:
                    with csv_body.text_stream(f, "") as text:
                        found = self._cells(text, delim)
                return found
        except UnicodeDecodeError:
            raise InputError(f"{self.path}: not a text (CSV) file") from None
        except OSError as exc:
            raise InputError(f"{self.path}: {exc.strerror or type(exc).__name__}") from None

    def _names(self, header: list[str], headerless: bool) -> list[str]:
        self.headerless = headerless
        return [str(j) for j in range(len(header))] if headerless else unique_names(header)

    def _numbers(self, text, delim: str, n_lines: int) -> tuple[list[str], Body] | None:
        """The table through NumPy's text reader, block by block, keeping the asked columns;
        None unless it is numbers only (then the cell-by-cell reader gives the same table, or
        says what is wrong)."""
        sep = None if delim in (" ", "whitespace") else delim
        blank = " \t" + (sep or "")
        while (first := text.readline()) and not first.strip(blank + "\n"):
            pass  # blank lines before the header
        first = first[:-1] if first.endswith("\n") else first
        if not first or csv_body.NOT_PLAIN.search(first):
            return None
        header = first.split(sep)
        if not any(c.strip() for c in header):
            return None
        headerless = all(is_number(c) for c in header)
        names = self._names(header, headerless)
        kept, times = self._kept(names), self._time_columns(names)
        body = csv_body.numbers(csv_body.blocks(text, first if headerless else None), sep, len(header),
                                sorted(kept), sorted(times), n_lines)
        if body is None or (not body.n_rows and not headerless):
            return None
        return names, body

    def _cells(self, text, delim: str) -> tuple[list[str], Body]:
        """The table through the csv module, row by row, keeping the asked columns."""
        rows = csv_body.csv_rows(text, delim, str(self.path))

        def keep(header: list[str], headerless: bool) -> list[int]:
            names = self._names(header, headerless)
            return sorted(self._kept(names) | self._time_columns(names))

        header, headerless, body = csv_body.cells(rows, keep, lambda row: not all(map(is_number, row)),
                                                  str(self.path))
        return self._names(header, headerless), body

    def _transposed(self, text: str, delim: str) -> tuple[list[str], Body]:
        """``samples: columns``: a headerless matrix with one sample per column, read whole
        (it is transposed) and checked as before."""
        rows = [r for r in csv_body.csv_rows(io.StringIO(text, newline=""), delim, str(self.path))
                if r and any(c.strip() for c in r)]
        if not rows:
            raise InputError(f"{self.path}: empty CSV file")
        if not all(is_number(c) for c in rows[0]):
            raise InputError(f"{self.path}: samples: columns needs a text matrix without a header row")
        width = len(rows[0])
        bad = next((i for i, r in enumerate(rows) if len(r) != width), None)
        if bad is not None:
            raise InputError(f"{self.path}: row {bad + 1} has {len(rows[bad])} fields, row 1 has {width}")
        self.headerless = True
        names = [str(j) for j in range(len(rows))]  # one variable per line of the file
        return names, Body(width, texts=dict(enumerate(rows)))

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
        """Columns, rows, time column and span; a table with no time column and none configured
        is listed too (``time_column`` None: a config must say the rate or the column)."""
        names, body = self.load()
        t, col = np.zeros(0, np.int64), ""
        if body.n_rows and (self.time.column is not None or self.time.rate or find_time_column(names, body)
                            is not None):
            t, col = self.time_ns()
        elif body.n_rows:
            col = None
        return {"start_ns": int(t[0]) if len(t) else 0, "end_ns": int(t[-1]) if len(t) else 0,
                "columns": names, "rows": body.n_rows, "time_column": col, "header": not self.headerless,
                "sample_axis": self.samples}

    def kinds(self, names: list[str], cells: int = 200_000) -> list[str]:
        """What each column holds in the first rows of the file (as many as hold about ``cells``
        cells, at most 50): ``number``, ``text`` (a cell that is not a number: a frame_id, a
        flattened header) or ``empty``. Called after :meth:`load` (the file's lines are checked).
        A table wider than :data:`KIND_COLUMNS` is not sampled (a row would be as many strings):
        its columns read so far say what they hold, the others count as numbers."""
        if len(names) > KIND_COLUMNS:
            _, body = self.load()
            return ["number" if not body.has(k) or body.is_numeric(k) else "text" for k in range(len(names))]
        limit = max(2, min(50, cells // max(len(names), 1)))
        rows: list[list[str]] = []
        with open_regular(self.path, "the CSV file") as f, csv_body.text_stream(f, "") as text:
            for row in csv_body.csv_rows(text, self._delim, str(self.path)):
                if row and any(c.strip() for c in row):
                    rows.append(row)
                if len(rows) >= limit:
                    break
        rows = [r for r in rows[(0 if self.headerless else 1):] if len(r) == len(names)]
        out = []
        for k in range(len(names)):
            cells_k = [r[k].strip() for r in rows if r[k].strip()]
            out.append("empty" if not cells_k else "number" if all(map(is_number, cells_k)) else "text")
        return out

    def let_go(self, still: Sequence[StreamOptions]) -> None:
        """Drop the columns of the table read that none of the selections ``still`` reads (its
        stamps stay, parsed: :meth:`time_ns`); a column asked for again reads the file again."""
        if self._loaded is None or any(not s.columns for s in still):
            return  # nothing read, or a text matrix's stream: every column
        names, body = self._loaded
        try:
            needed = {self.index(names, c) for s in still for c in s.columns}
        except InputError:  # a column not in the table: its stream says so
            return
        for columns in (body.values, body.texts):
            for k in set(columns) - needed:
                del columns[k]

    def stream(self, selection: StreamOptions) -> Stream:
        """The columns of ``selection`` (all but the time column of a text matrix)."""
        self.want(selection.columns or [ALL])
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


def check_lines(f: IO[bytes], where: str) -> int:
    """Refuse a text file over the cap (:func:`~ccl_cli.io.limits.check_claim`) or with a line
    longer than :func:`~ccl_cli.io.limits.max_line_bytes`, before it is read: the file is
    mapped, not loaded, and each step looks for the last line end (LF or CR) in the next
    window of that many bytes, so a file of n bytes takes about n / window steps. Returns
    how many lines it holds at most (line ends, + 1)."""
    import mmap

    size = os.fstat(f.fileno()).st_size
    check_claim(where, "the text", size, 1)
    window = max_line_bytes()
    if size > window:
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            start = 0
            while size - start > window:
                end = start + window + 1  # a line of exactly ``window`` bytes ends inside
                last = max(mm.rfind(b"\n", start, end), mm.rfind(b"\r", start, end))
                if last < 0:
                    raise InputError(f"{where}: a line longer than {window} bytes starts at byte {start}; "
                                     "not a CSV table (refused before reading it)")
                start = last + 1
    f.seek(0)
    lines = 1
    while block := f.read(1 << 20):  # \n, \r and \r\n end lines (a pair split by a block counts twice)
        lines += block.count(b"\n") + block.count(b"\r") - block.count(b"\r\n")
    return lines


def find_time_column(names: list[str], body: Body) -> int | None:
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
        numeric_first = all(is_number(tok) for tok in lines[0].split())
        if numeric_first or (len(widths) == 1 and widths.pop() > 1 and "\t" not in sample):
            return " "
    try:
        return csv.Sniffer().sniff(sample, delimiters=",;\t ").delimiter
    except csv.Error:
        return ","


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
        return self._streams(selections, once=False)

    def read_streams(self, selections: Sequence[StreamOptions]) -> list[Stream]:
        """:meth:`streams`, each table's columns let go of as soon as the last stream that reads
        them has its copy, and the tables at the end (:meth:`~StreamReader.read` reads each
        once): the memory holds a column as read or as copied into a stream, not both."""
        return self._streams(selections, once=True)

    def _streams(self, selections: Sequence[StreamOptions], once: bool) -> list[Stream]:
        for s in selections:  # every column of a table asked for before it is read: one pass
            self.table(s).want(s.columns or [ALL])
        out = []
        for i, s in enumerate(selections):
            table = self.table(s)
            out.append(table.stream(s))
            if once:
                table.let_go([later for later in selections[i + 1:] if self.table(later) is table])
        if once:
            self._tables.clear()
        return out

    def listing(self) -> dict[str, Any]:
        state = self.options.state
        return self.table(StreamOptions(samples=state.samples) if state is not None else None).listing()

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        """Columns, rows and time column; the names the configured streams would get; the
        rate over the active time and the demonstrations of the (first) state column."""
        o = self.options
        for selection in (o.state, None if o.derives_action else o.action):
            if selection is not None and selection.columns:
                self.table(selection).want(selection.columns)
        table = self.table(StreamOptions(samples=o.state.samples) if o.state is not None else None)
        table.want(list(range(REPEAT_COLUMNS + 1)))  # those :data:`REPEAT_COLUMNS` looks at, in one pass
        info = self.listing()
        kinds = table.kinds(info["columns"]) if info["sample_axis"] == "rows" and info["rows"] else \
            ["number"] * len(info["columns"])
        out = self.span(info)
        out.update({k: info[k] for k in ("columns", "rows", "time_column", "header", "sample_axis")})
        for kind in ("text", "empty"):
            listed = [c for c, k in zip(info["columns"], kinds, strict=True) if k == kind]
            if listed:
                out[f"{kind}_columns"] = listed
        if info["time_column"] is None:  # nothing to time the rows by: say what a config needs
            return {k: v for k, v in out.items() if k not in ("start_ns", "end_ns", "duration_s")} \
                | {"needs": _needs(table, info, kinds)}
        if info["rows"] > 1 and out["duration_s"] > 0:
            out["rate_hz"] = (info["rows"] - 1) / out["duration_s"]
        for key, selection in (("state", o.state), ("action", None if o.derives_action else o.action)):
            if selection is not None and (selection.columns or (key == "state" and not info["header"])):
                out[f"{key}_names"] = self.streams([selection])[0].names
        numbers = list(islice((c for c, k in zip(info["columns"], kinds, strict=True)
                               if k == "number" and c != info["time_column"] and not _bookkeeping(c)),
                              REPEAT_COLUMNS))
        state = o.state.columns if o.state is not None and o.state.columns else numbers
        if state:
            main = StreamOptions(columns=state, samples=o.state.samples if o.state else None)
            stream = self.streams([main])[0]
            act = activity(stream.t_ns, gap)
            out.update({"rate_hz": act["rate_hz"], "active_s": act["active_s"], "demos": act["demos"],
                        "demos_from": "rows", "gap_s": act["gap_s"]} | _rule(act))
            held = repeated_poses((stream.t_ns - stream.t_ns[0]) / 1e9, stream.values,
                                  np.zeros(len(stream.t_ns), dtype=np.int64))
            if held:
                out["repeats"] = {"columns": list(state), **held.detail, "rows": int(held.count)}
        return out


def _bookkeeping(name: str) -> bool:
    """A column that counts or stamps messages rather than measuring (a ROS header's seq and
    stamp, another time column): new in every row, so no sign of a sensor's updates."""
    low = str(name).lower()
    return low in _TIME_KEYS or low.endswith(("seq", "stamp", ".secs", ".nsecs", "time"))


def _needs(table: CsvTable, info: dict[str, Any], kinds: list[str]) -> list[str]:
    """What a config must say to read a table that has no time column (for ``ccl inspect``):
    the rate or the time column (a first column that increases throughout is named), the state
    columns, and the samples' side of a matrix wider than tall."""
    names, body = table.load()
    numbers = [c for c, k in zip(names, kinds, strict=True) if k == "number"]
    out = ["data.time: {rate: HZ} (the rows carry no time: say how many were recorded per second)"]
    if numbers and numbers[0] == names[0] and body.n_rows > 2 and \
            bool(np.all(np.diff(body.numbers(0, names[0], str(table.path))) > 0)):
        out[0] += f", or data.time: {{column: {names[0]}}} (column {names[0]} increases throughout: a time?)"
        numbers = numbers[1:]
    if info["sample_axis"] == "rows" and table.headerless and len(names) > info["rows"]:
        out.append(f"data.state: {{samples: columns}} if each of the {len(names)} columns is a sample (the "
                   f"original library's layout: {info['rows']} rows, one per dimension)")
    shown = ", ".join(map(str, numbers[:8])) + (", …" if len(numbers) > 8 else "")
    out.append(f"data.state: {{columns: [{shown}]}} (the state's columns)")
    out.append("data.action: {derive: state} (velocities from the states), or {columns: [...]}")
    return out


def _rule(act: dict[str, Any]) -> dict[str, Any]:
    return {"gap_rule": act["gap_rule"]} if "gap_rule" in act else {}
