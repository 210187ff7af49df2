"""Per-frame tables in the format of ``CONVENTIONS.md`` (CSV, and Parquet on request).

The first eight columns are fixed (``BASE_COLUMNS``); further columns follow. Rows are
written and flushed one at a time so an interrupted run keeps everything it computed.
Numbers are written as text at 15 significant digits (``format_float``: ``0.3``, not
``0.30000000000000004``); missing numbers are empty; lines end in ``\n``.
"""

from __future__ import annotations

import csv
import io
import math
import os
import sys
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError, interrupts_deferred, printable
from .text_files import read_text

BASE_COLUMNS: tuple[str, ...] = (
    "frame",
    "t",
    "pitch_deg",
    "roll_deg",
    "height_m",
    "tx_m",
    "tz_m",
    "yaw_deg",
    "status",
)

#: Short names of the pair's seven values (``measurement.PARAMETER_NAMES`` order) as the
#: correlation columns spell them.
CORRELATION_NAMES: tuple[str, ...] = ("prev_pitch", "prev_roll", "pitch", "roll", "tx", "tz", "yaw")
#: Correlation coefficients of the pair's values, upper triangle row by row:
#: ``corr_<a>__<b>`` (dimensionless, in [-1, 1]); with the ``*_std`` columns they give the
#: estimator's full 7×7 covariance.
CORRELATION_COLUMNS: tuple[str, ...] = tuple(
    f"corr_{a}__{b}"
    for i, a in enumerate(CORRELATION_NAMES)
    for b in CORRELATION_NAMES[i + 1 :]
)

#: Columns the two-frame estimator adds after the base ones (see ``measurement.py``).
ESTIMATE_COLUMNS: tuple[str, ...] = (
    "prev_pitch_deg",
    "prev_roll_deg",
    "pitch_std_deg",
    "roll_std_deg",
    "prev_pitch_std_deg",
    "prev_roll_std_deg",
    "tx_std_m",
    "tz_std_m",
    "yaw_std_deg",
    "inliers",
    "patches",
    "residual_px",
    *CORRELATION_COLUMNS,
)

#: The estimates table's concise columns: every one but the estimator's diagnostics
#: (``patches``, ``residual_px``). The correlations stay: the filters and the monitor read
#: the pair's full covariance from them, and ``inliers`` gates the monitor.
ESTIMATE_CONCISE: tuple[str, ...] = tuple(
    c for c in ESTIMATE_COLUMNS if c not in ("patches", "residual_px")
)

TEXT_COLUMNS = frozenset(
    {"status", "monitor_state", "reason", "filter_status", "meas_status", "gated", "reset_reason"}
)


class TableError(InputError):
    """A per-frame table is unreadable or lacks a column; the message names file and row."""


#: ``columns`` choices beside an explicit list of names: every column, or the concise set.
ALL = "all"
CONCISE = "concise"
#: Which columns a table writes: :data:`ALL`, :data:`CONCISE`, or the names of columns.
ColumnChoice = str | Sequence[str]


@dataclass(frozen=True)
class TableColumns:
    """The columns a kind of per-frame table may carry after ``BASE_COLUMNS`` (``every``, in
    the order written) and the concise default among them (``concise``: what a reader looks
    at first, and every column another command reads back from the table)."""

    name: str
    every: tuple[str, ...]
    concise: tuple[str, ...]

    def __post_init__(self) -> None:
        stray = [c for c in self.concise if c not in self.every]
        if stray:
            raise ValueError(f"{self.name}: concise column(s) {stray} are not in the table")


ESTIMATE_TABLE = TableColumns("estimates", ESTIMATE_COLUMNS, ESTIMATE_CONCISE)


def choose_columns(table: TableColumns, choice: ColumnChoice = CONCISE,
                   option: str = "--columns") -> tuple[str, ...]:
    """The columns after ``BASE_COLUMNS`` that ``table`` writes for ``choice``, in the table's
    order: ``"all"``, ``"concise"``, or names (a sequence, or one comma-separated string; base
    columns may be named and are always written). An :class:`InputError` naming ``option``
    lists unknown names and the valid ones. A string naming no column is an error; an empty
    sequence (what naming only base columns chooses) writes the base columns only."""
    return choose_columns_each((table,), choice, option)[0]


def choose_columns_each(tables: Sequence[TableColumns], choice: ColumnChoice = CONCISE,
                        option: str = "--columns") -> list[tuple[str, ...]]:
    """:func:`choose_columns` for tables written together (a fleet's estimates, smoothed
    and monitor tables): a named column goes to each table that has it, a name none has is
    an :class:`InputError`."""
    # A typed string naming nothing is a mistake; a sequence is a choice already made (an
    # empty one, from names that were all base columns, writes the base columns only).
    typed = isinstance(choice, str)
    if typed:
        key = choice.strip().lower()
        if key in (ALL, CONCISE):
            return [t.every if key == ALL else t.concise for t in tables]
        choice = choice.split(",")
    names = [c for c in (str(c).strip() for c in choice) if c]
    if not names and typed:
        raise InputError(f"{option}: no column named; give '{ALL}', '{CONCISE}' or a "
                         "comma-separated list of columns")
    valid = list(BASE_COLUMNS)
    for t in tables:
        valid += [c for c in t.every if c not in valid]
    unknown = [c for c in names if c not in valid]
    if unknown:
        what = ", ".join(t.name for t in tables) + (" table" if len(tables) == 1 else " tables")
        raise InputError(
            f"{option}: unknown column(s) {printable(', '.join(unknown), 200)} for the "
            f"{what}; valid: '{ALL}', '{CONCISE}' or any of {', '.join(valid)}")
    wanted = set(names)
    return [tuple(c for c in t.every if c in wanted) for t in tables]


#: Significant digits a written number keeps: float64 carries 15.9, and arithmetic noise
#: (``3 * 0.1 = 0.30000000000000004``) sits in the 16th and 17th; numbers of 10^6 and more
#: keep 9 decimal places (a Unix time's nanoseconds) up to float64's 17 digits.
SIGNIFICANT = 15
DECIMALS = 9
#: Line ending of every text file the project writes.
LINE_END = "\n"


def format_float(v: float) -> str:
    """Shortest text of ``v`` at :data:`SIGNIFICANT` significant digits (``0.3``, not
    ``0.30000000000000004``); at least :data:`DECIMALS` decimal places for large numbers."""
    if not math.isfinite(v):
        return "" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if v == 0.0:
        return "0.0"
    digits = min(17, max(SIGNIFICANT, math.floor(math.log10(abs(v))) + 1 + DECIMALS))
    return repr(float(f"{v:.{digits}g}"))


def format_value(value: Any) -> str:
    """Text of one cell: empty for None/NaN, floats by :func:`format_float`."""
    if value is None:
        return ""
    if isinstance(value, (float, np.floating)):
        return format_float(float(value))
    if isinstance(value, (np.integer,)):
        return str(int(value))
    return str(value)


class TableWriter:
    """Stream rows (mappings of column → value) into a CSV, flushing each row.

    With ``parquet_path`` the same rows are also written as Parquet when closed (needs
    pyarrow). ``columns``: the ones among ``extra_columns`` to write (default all; see
    :func:`choose_columns`); a row's values of the others are left out. Use as a context
    manager.
    """

    def __init__(
        self,
        path: str | Path,
        extra_columns: Sequence[str] = (),
        parquet_path: str | Path | None = None,
        columns: Sequence[str] | None = None,
    ) -> None:
        self.path = Path(path)
        self.columns = _written_columns(extra_columns, columns)
        self._known = set(BASE_COLUMNS) | set(extra_columns)
        self.parquet_path = Path(parquet_path) if parquet_path else None
        if self.parquet_path is not None:
            _require_pyarrow()
        # opened with the first row (or at a normal close): a run that fails before its first
        # row (a camera that does not fit the images) leaves a table already there untouched
        self._file: Any = None
        self._written = 0
        self._rows: list[dict[str, Any]] = []
        self._line = io.StringIO()
        self._line_writer = csv.writer(self._line, lineterminator=LINE_END)

    def _open(self) -> None:
        if self._file is not None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # unbuffered: each line goes to the file in the call that writes it, so that a write
        # that fails part-way (disk full) can be cut back to the last complete row
        with self._named_os_errors():
            self._file = self.path.open("wb", buffering=0)
        self._write_line(self.columns)

    def write(self, row: Mapping[str, Any]) -> None:
        unknown = set(row) - self._known
        if unknown:
            raise KeyError(f"{self.path}: row has columns not in the table: {sorted(unknown)}")
        self._open()
        self._write_line([format_value(row.get(c)) for c in self.columns])
        if self.parquet_path is not None:
            self._rows.append({c: row.get(c) for c in self.columns})

    def _write_line(self, cells: Sequence[str]) -> None:
        """One CSV line, all of it on disk when this returns; where the write fails the file
        is cut back to the rows before it (it never ends in half a row) and the error raised."""
        self._line.seek(0)
        self._line.truncate()
        self._line_writer.writerow(cells)
        data = memoryview(self._line.getvalue().encode("utf-8"))
        with self._named_os_errors():
            try:
                while data:
                    data = data[self._file.write(data) or 0:]
            except OSError:
                try:
                    os.ftruncate(self._file.fileno(), self._written)
                except OSError:
                    pass  # (a device such as /dev/full cannot be cut)
                raise
            self._written = self._file.tell()

    @contextmanager
    def _named_os_errors(self) -> Iterator[None]:
        # a write error (disk full) names the file, as the CLI prints it
        try:
            yield
        except OSError as exc:
            if exc.filename is not None:
                raise
            raise OSError(exc.errno, exc.strerror, str(self.path)) from None

    def close(self) -> None:
        """Close the CSV and write the Parquet table; a Ctrl-C meanwhile (pyarrow's import
        alone takes a while) is raised after, not into them (it lost the Parquet file)."""
        self._open()  # a run without rows still leaves its header
        if self._file.closed:
            return
        with interrupts_deferred() as interrupt:
            with self._named_os_errors():
                self._file.close()
            if self.parquet_path is not None:
                write_parquet(self._rows, self.columns, self.parquet_path)
        if interrupt.requested:
            raise KeyboardInterrupt

    def __enter__(self) -> TableWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is not None and self._file is None:
            return  # failed before its first row: nothing to keep, nothing overwritten
        self.close()


def write_table(
    path: str | Path, rows: Iterable[Mapping[str, Any]], extra_columns: Sequence[str] = (),
    columns: Sequence[str] | None = None,
) -> None:
    """Write all ``rows`` to ``path`` (CSV, or Parquet if the suffix is ``.parquet``);
    ``columns`` as :class:`TableWriter`'s."""
    rows = list(rows)
    path = Path(path)
    if path.suffix == ".parquet":
        write_parquet(rows, _written_columns(extra_columns, columns), path)
        return
    with TableWriter(path, extra_columns, columns=columns) as writer:
        for row in rows:
            writer.write(row)


def write_columns_csv(path: str | Path, columns: Mapping[str, ArrayLike]) -> Path:
    """Write equal-length numeric ``columns`` (name → values) as a CSV at
    :func:`format_float`'s precision, through a ``.partial`` file renamed when complete (an
    interrupted write never leaves half a table); the path written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    values = [np.asarray(v, np.float64) for v in columns.values()]
    partial = path.with_name(path.name + ".partial")
    try:
        with partial.open("w", newline="") as fh:
            fh.write(",".join(columns) + LINE_END)
            fh.writelines(",".join(map(format_float, row)) + LINE_END
                          for row in zip(*(v.tolist() for v in values), strict=True))
        partial.replace(path)
    finally:
        partial.unlink(missing_ok=True)
    return path


def _written_columns(extra_columns: Sequence[str], columns: Sequence[str] | None) -> list[str]:
    """Base columns, then those of ``extra_columns`` in ``columns`` (all where None)."""
    extra = [c for c in extra_columns if c not in BASE_COLUMNS]
    if columns is None:
        return list(BASE_COLUMNS) + extra
    stray = sorted(set(columns) - set(extra) - set(BASE_COLUMNS))
    if stray:
        raise ValueError(f"columns {stray} are not among the table's {extra}")
    keep = set(columns)
    return list(BASE_COLUMNS) + [c for c in extra if c in keep]


def write_parquet(
    rows: Sequence[Mapping[str, Any]], columns: Sequence[str], path: str | Path
) -> None:
    """Write rows as Parquet with the given column order (text columns as strings)."""
    pa = _require_pyarrow()
    import pyarrow.parquet as pq

    arrays = {}
    for c in columns:
        values = [r.get(c) for r in rows]
        if c in TEXT_COLUMNS:
            arrays[c] = pa.array([None if v is None else str(v) for v in values], pa.string())
        elif c == "frame":
            arrays[c] = pa.array([int(v) for v in values], pa.int64())
        else:
            # a cell without a number is null, as Parquet says "no value" (not NaN)
            arrays[c] = pa.array([_to_float(v) for v in values], pa.float64(), from_pandas=True)
    pq.write_table(pa.table(arrays), str(path))


def _check_header(path: Path, header: list, required: Sequence[str]) -> None:
    """:class:`TableError` naming the required columns the header lacks."""
    missing = [c for c in required if c not in header]
    if missing:
        raise TableError(f"{path}: missing column(s) {missing}; header is "
                         f"{printable(header, 160)}")


def first_data_row(path: str | Path) -> int:
    """Number of a table file's first data row, as messages about its rows count them: 2 in a
    CSV (the header is row 1), 1 in a Parquet file."""
    return 1 if Path(path).suffix.lower() == ".parquet" else 2


def read_table(path: str | Path, required: Sequence[str] = BASE_COLUMNS[:2], *,
               quiet: bool = False) -> dict[str, NDArray]:
    """Columns of a per-frame CSV or Parquet file: floats (NaN where empty), ``frame`` as int,
    text columns as ``str`` arrays. Raises :class:`TableError` naming file, row and column.
    ``quiet``: a cut last row is left out without a warning (for a reading whose caller
    reads the table again, which names it)."""
    path = Path(path)
    if path.is_dir():
        raise TableError(f"{path}: a folder, not a table; give a CSV or Parquet file")
    if not path.is_file():
        raise TableError(f"{path}: file not found")
    if path.suffix == ".parquet":
        pa = _require_pyarrow()
        import pyarrow.parquet as pq

        try:
            table = pq.read_table(str(path))
            raw = {name: table.column(name).to_pylist() for name in table.column_names}
        except (OSError, ValueError, TypeError, pa.ArrowException) as exc:
            raise TableError(f"{path}: not a readable Parquet table "
                             f"({printable(exc, 160)})") from None
        header = list(raw)
        _check_header(path, header, required)
        records = [[raw[c][i] for c in header] for i in range(table.num_rows)]
    else:
        text = read_text(path)
        reader = csv.reader(io.StringIO(text, newline=""))
        try:
            header = [h.strip() for h in next(reader)]
            # a file that is not such a table (a README, a log) says so, not that its
            # second line has the wrong number of cells
            _check_header(path, header, required)
            records = []
            for r in reader:
                if not r:
                    continue
                if len(r) != len(header):
                    line = reader.line_num  # (_cut_last_row reads on)
                    if _cut_last_row(text, reader, r, header):
                        # a run that ended mid-write: the rows before it are kept
                        if not quiet:
                            print(f"vipm-track: warning: {path}: line {line}: the last "
                                  f"row is cut short ({len(r)} of {len(header)} cells); "
                                  "left out", file=sys.stderr)
                        break
                    raise TableError(f"{path}: line {line}: {len(r)} cells but the "
                                     f"header has {len(header)} (a cut or damaged row)")
                records.append(r)
        except StopIteration:
            raise TableError(f"{path}: empty file, expected a header row") from None
        except csv.Error as exc:
            raise TableError(f"{path}: line {reader.line_num}: not CSV ({exc})") from None
    repeated = sorted({h for h in header if header.count(h) > 1})
    if repeated:
        raise TableError(f"{path}: column(s) {printable(repeated, 200)} appear more than once "
                         "in the header")
    out: dict[str, NDArray] = {}
    for j, name in enumerate(header):
        cells = [r[j] if j < len(r) else "" for r in records]
        if name in TEXT_COLUMNS:
            out[name] = np.array(["" if v is None else str(v) for v in cells], dtype=object)
            continue
        values = np.empty(len(cells))
        for i, v in enumerate(cells):
            try:
                values[i] = _to_float(v)
            except (ValueError, TypeError, OverflowError):
                raise TableError(
                    f"{path}: row {i + 2}, column '{printable(name, 60)}': not a number: "
                    f"{printable(repr(v), 60)}"
                ) from None
        if name == "frame":
            # a frame number is an index: 7.5 is a damaged cell, not frame 7
            bad = np.isfinite(values) & ((values != np.round(values)) | (values < 0))
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise TableError(f"{path}: row {i + first_data_row(path)}, column 'frame': "
                                 f"{printable(repr(cells[i]), 60)} is not a frame index (an "
                                 "integer >= 0)")
            if np.all(np.isfinite(values)):
                values = values.astype(np.int64)
        out[name] = values
    return out


def rows_to_columns(rows: Sequence[Mapping[str, Any]]) -> dict[str, NDArray]:
    """Columns of table rows (dicts, as written), in :func:`read_table`'s layout: floats with
    NaN where a row lacks a number, text columns (``TEXT_COLUMNS``) as object arrays."""
    names = list(dict.fromkeys(k for row in rows for k in row))
    out: dict[str, NDArray] = {}
    for name in names:
        values = [row.get(name) for row in rows]
        if name in TEXT_COLUMNS:
            out[name] = np.array(["" if v is None else str(v) for v in values], dtype=object)
        else:
            out[name] = np.array([float_or_nan(v) for v in values], dtype=float)
    return out


def _cut_last_row(text: str, reader: Any, row: list[str], header: list[str]) -> bool:
    """Whether ``row``, the one ``reader`` just read from ``text``, is its last and was cut
    short: fewer cells than the header and no line end after it."""
    return (len(row) < len(header) and not text.endswith(("\n", "\r"))
            and next(reader, None) is None)


def _to_float(v: Any) -> float:
    if v is None:
        return math.nan
    if isinstance(v, str):
        v = v.strip()
        return math.nan if v == "" else float(v)
    return float(v)


def float_or_nan(v: Any) -> float:
    """``v`` as a float; NaN for None, empty or unreadable values."""
    try:
        return _to_float(v)
    except (TypeError, ValueError, OverflowError):
        return math.nan


def _require_pyarrow():
    try:
        import pyarrow
    except ImportError as exc:
        raise InputError(
            "Parquet output needs pyarrow: pip install 'vipm-track[parquet]'"
        ) from exc
    return pyarrow
