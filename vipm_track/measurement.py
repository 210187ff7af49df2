"""The two-frame measurement: what the front end hands the filters and the monitor.

One :class:`PairMeasurement` per processed frame k (its motion is from frame k-1). The
7-vector ``z`` is ordered as the estimator's parameters:

    (pitch_prev, roll_prev, pitch_curr, roll_curr, tx, tz, yaw)   [rad, rad, rad, rad, m, m, rad]

``tx``/``tz`` are metric *at the assumed height* ``height_assumed`` (CONVENTIONS.md, Scale):
the true translation is ``t · h_true / height_assumed``. ``covariance`` is 7×7 in the same
order and units. A frame whose ``status`` is not ``ok`` carries NaNs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .errors import InputError
from .frame_rates import interval_problem
from .increasing import kept_around, left_out_between
from .statuses import MISSING_NUMBERS, is_known
from .table import CORRELATION_COLUMNS, first_data_row, read_table

PARAMETER_NAMES: tuple[str, ...] = ("pitch_prev", "roll_prev", "pitch", "roll", "tx", "tz", "yaw")
_ANGLE = np.array([True, True, True, True, False, False, True])
#: Estimates-table columns of ``z`` and of its standard deviations, in ``PARAMETER_NAMES`` order.
_Z_COLUMNS = ("prev_pitch_deg", "prev_roll_deg", "pitch_deg", "roll_deg", "tx_m", "tz_m", "yaw_deg")
_STD_COLUMNS = tuple(c.replace("_deg", "_std_deg").replace("_m", "_std_m") for c in _Z_COLUMNS)
#: (row, column) of ``covariance`` behind each of ``table.CORRELATION_COLUMNS``
_UPPER = np.triu_indices(7, 1)


@dataclass(frozen=True)
class PairMeasurement:
    """Pose of both frames and motion between them, with covariance (see module doc)."""

    frame: int
    t: float
    z: NDArray[np.float64]
    covariance: NDArray[np.float64]
    height_assumed: float
    status: str = "ok"
    inliers: int = 0

    @cached_property
    def ok(self) -> bool:
        """Usable: status ``ok`` and all its numbers there (read once, then kept)."""
        return self.status == "ok" and self.has_numbers

    @cached_property
    def has_numbers(self) -> bool:
        """Every value of ``z``, its variances and the assumed height are finite (a table's
        empty cells are NaN): without the height the travel has no scale."""
        return bool(np.isfinite(self.z).all() and np.isfinite(np.diag(self.covariance)).all()
                    and math.isfinite(self.height_assumed))

    @property
    def std(self) -> NDArray[np.float64]:
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def correlation(self) -> NDArray[np.float64]:
        """7×7 correlation matrix of ``z`` (identity where a value's variance is 0)."""
        std = self.std
        scale = np.where(std > 0, std, 1.0)
        corr = self.covariance / np.outer(scale, scale)
        np.fill_diagonal(corr, 1.0)
        return corr


def measurements_from_table(
    columns: dict[str, NDArray], source: str = "table"
) -> list[PairMeasurement]:
    """Measurements from the columns of an estimates table (``read_table``).

    Needs the base columns plus ``prev_pitch_deg``/``prev_roll_deg`` and the ``*_std``
    columns; a missing column is an :class:`InputError` naming ``source``. With the
    ``corr_*`` columns (tables written since they were added) the covariance is the
    estimator's full one; without them, or where a row's are empty, it is diagonal."""
    missing = [c for c in (*_Z_COLUMNS, *_STD_COLUMNS, "height_m") if c not in columns]
    if missing:
        raise InputError(f"{source}: estimates table lacks column(s) {missing}")
    n = len(columns["frame"])
    frames = np.asarray(columns["frame"], dtype=float)
    bad = ~np.isfinite(frames) | (frames != np.round(frames)) | (frames < 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{source}: row {i + first_data_row(source)}: frame {frames[i]} is "
                         "not a frame index (an integer >= 0)")
    corr_all = _correlations(columns, n, source)
    z_all = _stack_in_radians(columns, _Z_COLUMNS)
    std_all = _stack_in_radians(columns, _STD_COLUMNS)
    # without a status column a row is a measurement where it has all its numbers (a first
    # frame has none: it is not an "ok" row missing them)
    complete = (np.isfinite(z_all).all(axis=1) & np.isfinite(std_all).all(axis=1)
                & np.isfinite(np.asarray(columns["height_m"], dtype=float)))
    status = columns.get("status", np.where(complete, "ok", MISSING_NUMBERS).astype(object))
    # a standard deviation of zero makes a filter's measurement exact (a singular system in
    # the smoother); a negative one is no standard deviation
    bad = std_all <= 0.0
    if bad.any():
        row, col = np.argwhere(bad)[0]
        name = _STD_COLUMNS[col]
        raise InputError(f"{source}: row {row + first_data_row(source)} (frame "
                         f"{int(frames[row])}): {name} = {columns[name][row]} is not a "
                         "standard deviation (must be > 0)")
    _check_ranges(columns, frames, source)
    _check_units(frames, np.asarray(columns["t"], dtype=float), z_all,
                 (np.asarray(status) == "ok") & complete, source)
    inliers = columns.get("inliers", np.zeros(n))
    out = []
    for i in range(n):
        st = str(status[i]) or "ok"
        out.append(
            PairMeasurement(
                frame=int(columns["frame"][i]),
                t=float(columns["t"][i]),
                z=z_all[i],
                covariance=corr_all[i] * np.outer(std_all[i], std_all[i]),
                height_assumed=float(columns["height_m"][i]),
                status=st,
                inliers=int(inliers[i]) if np.isfinite(inliers[i]) else 0,
            )
        )
    return out


#: largest magnitude an angle column can have [deg]: a pitch beyond ±90° or a roll or yaw
#: beyond ±180° is no angle of these conventions (a corrupt number: one row's 1e300 wrecked
#: the smoother's summary; 4500° widened its interval a hundredfold)
_ANGLE_LIMITS_DEG = {"prev_pitch_deg": 90.0, "pitch_deg": 90.0, "prev_roll_deg": 180.0,
                     "roll_deg": 180.0, "yaw_deg": 180.0}


#: no pair travels further: its two views of the ground would not overlap [m]
_MAX_TRAVEL_M = 1000.0
#: no vehicle's speed (360 km/h) [m/s]: beyond it a table's travel or times are in other
#: units (millimetres, nanoseconds), a speed sample is a corrupt row
MAX_SPEED_MPS = 100.0


def _check_units(frames: NDArray, t: NDArray, z: NDArray, usable: NDArray,
                 source: str) -> None:
    """An :class:`InputError` where the table's times or travel are plainly not in seconds and
    metres: consecutive frames further apart or closer than the frame rates ``--fps`` takes
    (``frame_rates.interval_problem``), or usable pairs faster than ``MAX_SPEED_MPS``
    (medians, so one odd row does not decide)."""
    with np.errstate(invalid="ignore"):
        step = np.diff(t)
        consecutive = (np.diff(frames) == 1) & (step > 0)
    if not consecutive.any():
        return
    problem = interval_problem(step[consecutive])
    if problem is not None:
        raise InputError(f"{source}: t: {problem}")
    moving = consecutive & usable[1:]
    if not moving.any():
        return
    travel = np.hypot(z[1:, 4], z[1:, 5])[moving]
    speed = float(np.median(travel / step[moving]))
    if speed > MAX_SPEED_MPS:
        raise InputError(
            f"{source}: tx_m, tz_m: the usable pairs travel {float(np.median(travel)):.4g} m "
            f"per frame {float(np.median(step[moving])):.4g} s apart, {speed:.4g} m/s "
            f"(medians) at the table's height_m; travel must be in metres and t in seconds")


def _check_ranges(columns: dict[str, NDArray], frames: NDArray, source: str) -> None:
    """An :class:`InputError` naming row, frame and column for a number no estimate can have:
    an infinite value, an angle beyond ``_ANGLE_LIMITS_DEG``, a height that is not > 0 (empty
    cells, NaN, are missing numbers and pass)."""
    for name in (*_Z_COLUMNS, "height_m"):
        values = np.asarray(columns[name], dtype=float)
        with np.errstate(invalid="ignore"):
            bad = np.isinf(values)
            if name in _ANGLE_LIMITS_DEG:
                bad |= np.abs(values) > _ANGLE_LIMITS_DEG[name]
                rule = f"an angle within ±{_ANGLE_LIMITS_DEG[name]:g}°"
            elif name == "height_m":
                bad |= values <= 0.0
                rule = "a height > 0"
            else:
                bad |= np.abs(values) > _MAX_TRAVEL_M
                rule = f"a travel within ±{_MAX_TRAVEL_M:g} m"
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise InputError(f"{source}: row {row + first_data_row(source)} (frame "
                             f"{int(frames[row])}): {name} = {columns[name][row]} is not {rule}")


def _correlations(columns: dict[str, NDArray], n: int, source: str) -> NDArray:
    """(n, 7, 7) correlation matrices from the ``corr_*`` columns (identity without them);
    a coefficient outside [-1, 1] is an :class:`InputError` naming row and column."""
    corr = np.broadcast_to(np.eye(7), (n, 7, 7)).copy()
    lacking = [c for c in CORRELATION_COLUMNS if c not in columns]
    if len(lacking) == len(CORRELATION_COLUMNS):
        return corr
    if lacking:
        raise InputError(f"{source}: estimates table has some correlation columns but lacks "
                         f"{lacking}")
    values = np.stack([np.asarray(columns[c], dtype=float) for c in CORRELATION_COLUMNS], axis=1)
    bad = np.abs(values) > 1.0 + 1e-9
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise InputError(f"{source}: row {row + first_data_row(source)} (frame "
                         f"{int(columns['frame'][row])}): {CORRELATION_COLUMNS[col]} = "
                         f"{values[row, col]} is not in [-1, 1]")
    values = np.where(np.isfinite(values), values, 0.0)
    corr[:, _UPPER[0], _UPPER[1]] = values
    corr[:, _UPPER[1], _UPPER[0]] = values
    return corr


def _stack_in_radians(columns: dict[str, NDArray], names: tuple[str, ...]) -> NDArray:
    """(n, 7) array of the named columns, degrees converted to radians."""
    return np.stack(
        [np.radians(columns[c]) if a else columns[c] for c, a in zip(names, _ANGLE, strict=True)],
        axis=1,
    )


def read_measurements(path: str | Path) -> list[PairMeasurement]:
    """Measurements from an estimates CSV/Parquet written by ``vipm-track estimate``."""
    return measurements_from_table(read_table(path), str(path))




@dataclass(frozen=True)
class SequenceIssues:
    """Rows of an estimates table that do not form a sequence, by their row number in the
    file (a CSV's header is row 1): ``duplicated`` (row, frame, the row kept for it),
    ``out_of_order`` (row, frame, the kept frames before and after it), ``backwards`` (row,
    t, the kept times before and after it; NaN where there is none),
    ``missing`` (row, frame) of rows saying ``ok`` with numbers missing, ``unknown`` (row,
    frame, status) of rows with a status vipm-track does not write (read as not usable)."""

    duplicated: tuple[tuple[int, int, int], ...] = ()
    out_of_order: tuple[tuple[int, float, float, float], ...] = ()
    backwards: tuple[tuple[int, float, float, float], ...] = ()
    missing: tuple[tuple[int, int], ...] = ()
    unknown: tuple[tuple[int, int, str], ...] = ()

    def __bool__(self) -> bool:
        return bool(self.duplicated or self.out_of_order or self.backwards or self.missing
                    or self.unknown)

    @property
    def left_out(self) -> int:
        """Rows left out of the sequence (repeats, frames or times out of order)."""
        return len(self.duplicated) + len(self.out_of_order) + len(self.backwards)

    def check_a_sequence(self, source: str, rows: int) -> None:
        """InputError where most of a table's ``rows`` were left out: it is no sequence of
        frames (every time equal said "no frame has a usable pair estimate ... give --pitch",
        exit 1)."""
        if rows >= 4 and 2 * self.left_out > rows:
            raise InputError(f"{source}: {self.left_out} of {rows} rows repeat a frame or have "
                             "a frame or time out of order with the rest: not a sequence of "
                             "frames (their numbers and times must increase): "
                             + "; ".join(line.split(": ", 1)[1]
                                         for line in self.lines(source, first=3)))

    def lines(self, source: str, first: int = 5) -> list[str]:
        """One line per kind of issue, naming the first ``first`` rows."""
        def rows(items: tuple, text) -> str:
            shown = "; ".join(text(*item) for item in items[:first])
            return shown + ("; ..." if len(items) > first else "")

        out = []
        if self.duplicated:
            out.append(f"{source}: {len(self.duplicated)} rows repeat an earlier frame, left "
                       "out (the first row of each frame is used): " + rows(
                           self.duplicated, lambda r, f, r0: f"row {r} frame {f} (first row {r0})"))
        def between(r: int, name: str, value: float, before: float, after: float) -> str:
            # a missing number is not out of order: say what it is
            if not math.isfinite(value):
                return f"row {r} {name} not a number"
            kept = kept_around(before, after)
            return f"row {r} {name} {value!r}" + (f" ({kept})" if kept else "")

        if self.out_of_order:
            out.append(f"{source}: {len(self.out_of_order)} rows have a frame out of order "
                       "with the rows around it (or none), left out: " + rows(
                           self.out_of_order, lambda r, f, f0, f1: between(r, "frame", f, f0,
                                                                           f1)))
        if self.backwards:
            out.append(f"{source}: {len(self.backwards)} rows have a time out of order with "
                       "the rows around it (or none), left out: " + rows(
                           self.backwards, lambda r, t, t0, t1: between(r, "t", t, t0, t1)))
        if self.missing:
            out.append(f"{source}: {len(self.missing)} rows say ok but lack numbers, read as "
                       f"'{MISSING_NUMBERS}': " + rows(
                           self.missing, lambda r, f: f"row {r} frame {f}"))
        if self.unknown:
            out.append(f"{source}: {len(self.unknown)} rows have a status vipm-track does not "
                       "write, read as not usable: " + rows(
                           self.unknown, lambda r, f, s: f"row {r} frame {f} {s!r}"))
        return out


def sequence_rows(
    frames: NDArray, times: NDArray | None = None, first_row: int = 2
) -> tuple[list[int], SequenceIssues]:
    """Indices of the rows that form a sequence and the rows left out, numbered from
    ``first_row`` (2: a CSV's first data row). The sequence: the longest run of rows whose
    frames (then, where given, times) strictly increase (``increasing``), so one corrupt row
    is the only one left out; of a repeated frame, its first row where that fits the run.
    A row left out whose frame a kept earlier row has is a repeat; the others are out of
    order, named with the kept values on either side of them."""
    frames = np.asarray(frames, dtype=float)
    duplicated: list[tuple[int, int, int]] = []
    out_of_order: list[tuple] = []
    backwards: list[tuple] = []
    finite = [i for i in range(frames.size) if np.isfinite(frames[i])]
    out_of_order += [(i + first_row, float(frames[i]), math.nan, math.nan)
                     for i in range(frames.size) if not np.isfinite(frames[i])]
    keep = _increasing_rows(finite, frames, first_row, out_of_order, int)
    kept_row = {frames[i]: i for i in keep}
    for item in list(out_of_order):
        i = item[0] - first_row
        if np.isfinite(frames[i]) and kept_row.get(frames[i], i) < i:
            out_of_order.remove(item)
            duplicated.append((i + first_row, int(frames[i]), kept_row[frames[i]] + first_row))
    if times is not None:
        times = np.asarray(times, dtype=float)
        backwards += [(i + first_row, float(times[i]), math.nan, math.nan)
                      for i in keep if not np.isfinite(times[i])]
        keep = _increasing_rows([i for i in keep if np.isfinite(times[i])], times, first_row,
                                backwards, float)
    return keep, SequenceIssues(tuple(sorted(duplicated)), tuple(sorted(out_of_order)),
                                tuple(sorted(backwards)))


def _increasing_rows(rows: list[int], values: NDArray, first_row: int, left_out: list,
                     kind: type) -> list[int]:
    """Of ``rows``, those whose ``values`` form the longest increasing run; each other one
    is appended to ``left_out`` as (row number, its value, the kept values before and after
    it, NaN where there is none)."""
    if not rows:
        return []
    kept, between = left_out_between(values[rows])
    for j, before, after in between:
        i = rows[j]
        left_out.append((i + first_row, kind(values[i]),
                         kind(before) if math.isfinite(before) else before,
                         kind(after) if math.isfinite(after) else after))
    return [rows[j] for j in kept]


def in_sequence(
    measurements: list[PairMeasurement], first_row: int = 2
) -> tuple[list[PairMeasurement], SequenceIssues]:
    """The measurements that form a sequence (:func:`sequence_rows`; a row saying ``ok``
    without all its numbers gets :data:`MISSING_NUMBERS`), and what was done to the others.
    Row numbers count from ``first_row`` (2: a CSV's first data row)."""
    keep, issues = sequence_rows(np.array([m.frame for m in measurements], dtype=float),
                                 np.array([m.t for m in measurements], dtype=float), first_row)
    kept: list[PairMeasurement] = []
    missing, unknown = [], []
    for i in keep:
        m = measurements[i]
        if m.status == "ok" and not m.has_numbers:
            missing.append((i + first_row, m.frame))
            m = replace(m, status=MISSING_NUMBERS)
        elif not is_known(m.status):
            unknown.append((i + first_row, m.frame, m.status))
        kept.append(m)
    return kept, replace(issues, missing=tuple(missing), unknown=tuple(unknown))


def table_in_sequence(
    table: dict[str, NDArray], first_row: int = 2
) -> tuple[dict[str, NDArray], SequenceIssues]:
    """The rows of any per-frame table (``frame`` and, where it has one, ``t``) that form a
    sequence (:func:`sequence_rows`), and what was left out."""
    times = np.asarray(table["t"], dtype=float) if "t" in table else None
    keep, issues = sequence_rows(table["frame"], times, first_row)
    if not issues:
        return table, issues
    rows = np.asarray(keep, dtype=int)
    return {name: np.asarray(values)[rows] for name, values in table.items()}, issues


def measurement_row(m: PairMeasurement) -> dict[str, object]:
    """The estimates-table row (base + ``ESTIMATE_COLUMNS``) of a measurement."""
    z = np.where(_ANGLE, np.degrees(m.z), m.z)
    s = np.where(_ANGLE, np.degrees(m.std), m.std)
    ok = m.ok
    val = (lambda x: float(x)) if ok else (lambda x: None)
    return {
        "frame": m.frame,
        "t": m.t,
        "pitch_deg": val(z[2]),
        "roll_deg": val(z[3]),
        "height_m": m.height_assumed,
        "tx_m": val(z[4]),
        "tz_m": val(z[5]),
        "yaw_deg": val(z[6]),
        "status": m.status,
        "prev_pitch_deg": val(z[0]),
        "prev_roll_deg": val(z[1]),
        "pitch_std_deg": val(s[2]),
        "roll_std_deg": val(s[3]),
        "prev_pitch_std_deg": val(s[0]),
        "prev_roll_std_deg": val(s[1]),
        "tx_std_m": val(s[4]),
        "tz_std_m": val(s[5]),
        "yaw_std_deg": val(s[6]),
        "inliers": m.inliers,
        **dict(zip(CORRELATION_COLUMNS, (val(c) for c in m.correlation[_UPPER]), strict=True)),
    }
