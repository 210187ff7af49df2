"""The calibration in brief, from a finished per-frame table: what a calibration engineer acts
on (:func:`summarize_drift`).

Per axis (pitch, roll in degrees, height in metres) of the mount (``mount_*`` columns of a
``track`` / ``smooth`` / ``monitor`` table, ``docs/formats.md``): the current extrinsics with a
95 % interval (the filter's ``mount_*_std``, or the monitor's ``new_*_lo`` / ``new_*_hi``
while it reports new extrinsics, or the drift line's end where the axis drifts), the change
since the nominal (or, without one, since the start of the table) with its uncertainty, when
it changed, how sure it is beyond the tolerance, and a drift rate of the frames' own pose
only over a span of at least :data:`MIN_RATE_SPAN_S` seconds since the last change, with its
standard error. Against a ground-truth table with ``mount_*`` columns (``vipm-track
simulate``'s ``gt.csv``) the true mount, the error and when it changed. The
monitor's timeline (states, transitions, first alarm) where the table has ``monitor_state``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from vipm_track.filters.long_run import batch_means
from vipm_track.filters.mount_steps import mount_steps, one_step_squares, untested_drive_note
from vipm_track.filters.row_correlation import correlation_inflation

Z95 = 1.959963984540054
#: shortest span [s] a drift rate is given over: a calibration creeps over minutes, and over
#: seconds the mount's shaking residue and its interval dominate any slope
MIN_RATE_SPAN_S = 60.0
#: a drift this many of its standard deviations from none makes the current extrinsics the
#: drift line's end rather than the filter's mount (where the line fits better than a step)
DRIFT_SIGMAS = 3.0
#: ``interval_from`` where the frames' own pose since their last step is beyond the filter's
#: mount and its interval: the mount never followed the step
FRAMES_SINCE_STEP = "frames since their step"
#: block means a drift rate is fitted to at the least
MIN_RATE_BLOCKS = 4
#: (axis, unit, mount column, its std column, monitor's new column, its 95 % lo / hi columns,
#: nominal attribute, tolerance attribute)
MOUNT_AXES: tuple[tuple[str, str, str, str, str, str, str, str, str], ...] = (
    ("pitch", "deg", "mount_pitch_deg", "mount_pitch_std_deg", "new_pitch_deg",
     "new_pitch_lo_deg", "new_pitch_hi_deg", "pitch_deg", "pitch_tol_deg"),
    ("roll", "deg", "mount_roll_deg", "mount_roll_std_deg", "new_roll_deg",
     "new_roll_lo_deg", "new_roll_hi_deg", "roll_deg", "roll_tol_deg"),
    ("height", "m", "mount_height_m", "mount_height_std_m", "new_height_m",
     "new_height_lo_m", "new_height_hi_m", "height_m", "height_tol_m"),
)
ALARM_STATES: frozenset[str] = frozenset({"DRIFTING", "RECALIBRATE", "INVALID"})
NAN = float("nan")


@dataclass(frozen=True)
class AxisDrift:
    """One axis of the mount, in its unit (``deg`` or ``m``; times in s, rates per minute).

    ``current``: the mount at the table's last frame with a value, ``lo``/``hi`` its 95 %
    interval (NaN where the table gives none; ``interval_from`` says whose: "filter",
    "monitor", "drift fit", :data:`FRAMES_SINCE_STEP` or "none"); ``reference``:
    the nominal, or the first mount value (``reference_from``); ``change`` = current −
    reference with its 1-σ ``change_std``; ``tolerance`` (NaN without a nominal);
    ``p_beyond``: the probability that the true change exceeds the tolerance (normal
    interval; NaN without a tolerance); ``changed_at_s``: when the frames' pose last
    stepped that way (else when the mount crossed halfway from its first level to its
    current one), NaN where the change is within its uncertainty; ``rate``/``rate_std``
    over ``rate_span_s`` since that change (NaN with ``rate_note`` saying why where the span
    is shorter than :data:`MIN_RATE_SPAN_S`); ``true_*`` from ground truth (NaN without;
    the true change when the true mount crossed halfway from its first value to its last)."""

    axis: str
    unit: str
    current: float
    lo: float
    hi: float
    interval_from: str
    reference: float
    reference_from: str
    change: float
    change_std: float
    tolerance: float
    p_beyond: float
    changed_at_s: float
    rate_per_min: float
    rate_std_per_min: float
    rate_span_s: float
    rate_note: str
    true_current: float = NAN
    true_changed_at_s: float = NAN

    @property
    def error(self) -> float:
        """current − true current (NaN without ground truth)."""
        return self.current - self.true_current

    @property
    def off_unfound(self) -> bool:
        """Whether the mount is off the nominal, beyond its 95 % interval and the tolerance,
        with no change found within the table (off before it began, or a creep the filter's
        mount did not follow), which is not "no change"."""
        sure = not math.isfinite(self.change_std) or abs(self.change) > Z95 * self.change_std
        return (self.reference_from == "nominal" and not math.isfinite(self.changed_at_s)
                and sure and abs(self.change) > self.tolerance)

    @property
    def covers_truth(self) -> bool | None:
        """Whether the 95 % interval holds the true mount (None where either is missing)."""
        if not (math.isfinite(self.true_current) and math.isfinite(self.lo)):
            return None
        return self.lo <= self.true_current <= self.hi


@dataclass(frozen=True)
class MonitorTimeline:
    """The monitor's run (a ``monitor`` table): final state, the first alarm (first row in
    DRIFTING / RECALIBRATE / INVALID: frame, t [s]; None without one) and its state, every
    transition ``(frame, t, before, after)`` and the time spent per state [s]."""

    final_state: str
    first_alarm: tuple[int, float] | None
    transitions: tuple[tuple[int, float, str, str], ...]
    seconds: dict[str, float]
    first_alarm_state: str = ""


@dataclass(frozen=True)
class DriftSummary:
    """What :func:`summarize_drift` found: per axis :class:`AxisDrift` (``axes``), the table's
    time span [s], the last frame, and the monitor's timeline where the table has one."""

    axes: dict[str, AxisDrift]
    t0: float
    t1: float
    last_frame: int
    monitor: MonitorTimeline | None


def has_mount(table: Mapping[str, NDArray]) -> bool:
    """Whether ``table`` has a mount (calibration) column with a number."""
    return any(has_finite(table, axis[2]) for axis in MOUNT_AXES)


def summarize_drift(table: Mapping[str, NDArray], nominal: object | None = None,
                    truth: Mapping[str, NDArray] | None = None) -> DriftSummary | None:
    """The calibration in brief (module doc) of a per-frame table (``table.read_table``
    columns, ``t`` in s) with mount columns; None where it has none. ``nominal``: a
    ``filters.nominal.NominalCalibration`` (or None); ``truth``: a ground-truth table whose
    ``mount_*`` columns are the true mount (rows matched by frame)."""
    if not has_mount(table):
        return None
    t = np.asarray(table["t"], float)
    frames = np.asarray(table["frame"])
    axes: dict[str, AxisDrift] = {}
    for axis in MOUNT_AXES:
        if has_finite(table, axis[2]):
            axes[axis[0]] = _axis(table, t, frames, axis, nominal, truth)
    finite_t = t[np.isfinite(t)]
    t0, t1 = (float(finite_t[0]), float(finite_t[-1])) if finite_t.size else (NAN, NAN)
    return DriftSummary(axes, t0, t1, int(frames[-1]), monitor_timeline(table))


def _axis(table: Mapping[str, NDArray], t: NDArray, frames: NDArray, spec: tuple,
          nominal: object | None, truth: Mapping[str, NDArray] | None) -> AxisDrift:
    name, unit, col, std_col, new, new_lo, new_hi, nom_attr, tol_attr = spec
    mount = np.asarray(table[col], float)
    std = np.asarray(table[std_col], float) if std_col in table else np.full(len(t), NAN)
    rows = np.flatnonzero(np.isfinite(mount) & np.isfinite(t))
    last = rows[-1]
    current, sigma, source = float(mount[last]), float(std[last]), "filter"
    lo, hi = current - Z95 * sigma, current + Z95 * sigma
    if has_finite(table, new) and np.isfinite(np.asarray(table[new], float)[last]):
        # the monitor's new extrinsics: its own estimate of where the camera now sits
        current = float(np.asarray(table[new], float)[last])
        lo, hi = (float(np.asarray(table[c], float)[last]) if c in table else NAN
                  for c in (new_lo, new_hi))
        sigma, source = (hi - lo) / (2 * Z95), "monitor"
    if not math.isfinite(sigma):
        lo = hi = NAN
        source = "none"
    level = _level_since_step(table, t, f"{name}_{unit}") if source == "filter" else None
    if level is not None and abs(level[0] - current) > Z95 * math.hypot(sigma, level[1]):
        # a filter whose mount never followed a knock (one early in the drive, before its
        # test was armed: 30.56 ± 0.05° for 31°): where the camera sits is what its frames
        # show since their step
        current, sigma, source = level[0], level[1], FRAMES_SINCE_STEP
        lo, hi = current - Z95 * sigma, current + Z95 * sigma
    head = rows[: max(3, len(rows) // 20)]
    start, start_sigma = float(np.median(mount[head])), float(np.nanmedian(std[head])
                                                              if np.isfinite(std[head]).any()
                                                              else NAN)
    if nominal is not None:
        reference, reference_from = float(getattr(nominal, nom_attr)), "nominal"
        tolerance = float(getattr(nominal, tol_attr))
    else:
        reference, reference_from, tolerance = start, "start", NAN
    step = current - start
    # a monitor's table has no mount σ at its start: its interval of where the camera now
    # sits is then the step's (it said "no change" beside a 1° knock)
    step_sigma = math.hypot(sigma, start_sigma) if math.isfinite(start_sigma) else sigma
    significant = (abs(step) > Z95 * step_sigma if math.isfinite(step_sigma)
                   else math.isfinite(tolerance) and abs(step) > tolerance)
    if math.isfinite(tolerance):
        significant = significant and abs(step) > tolerance
    changed_at = NAN
    if significant:
        changed_at = _step_time(table, t, f"{name}_{unit}", np.sign(step))
        if not math.isfinite(changed_at):  # a drive too short for the step test
            changed_at = _split_time(table, t, f"{name}_{unit}", np.sign(step))
        if not math.isfinite(changed_at):
            changed_at = _halfway_time(t[rows], mount[rows], start, current)
    fit = _drift_fit(table, t, f"{name}_{unit}", (t[rows], mount[rows], std[rows]),
                     changed_at)
    if fit.creeps and abs(fit.rate) > DRIFT_SIGMAS * fit.rate_std:
        # a creeping mount: the filter's mount (a nearly constant state) lags it; the line
        # through the frames ends on it
        current, sigma, source = fit.end, fit.end_std, "drift fit"
        lo, hi = current - Z95 * sigma, current + Z95 * sigma
    change = current - reference
    # against the table's start, that start's own σ too
    change_std = (sigma if nominal is not None or not math.isfinite(start_sigma)
                  else math.hypot(sigma, start_sigma))
    # without a tolerance there is nothing to be beyond (a tolerance of 0 made it 1)
    p_beyond = (_p_beyond(change, change_std, tolerance) if math.isfinite(tolerance)
                else NAN)
    true_current = true_changed = NAN
    if truth is not None and has_finite(truth, col):
        index = {int(f): i for i, f in enumerate(truth["frame"])}
        true = np.asarray(truth[col], float)
        if int(frames[last]) in index:
            true_current = float(true[index[int(frames[last])]])
        tt = np.asarray(truth["t"], float)
        # over the table's frames (a report of a window), a knock's time and a creep's
        # middle: what "changed at" says of each
        here = [index[int(f)] for f in frames[rows] if int(f) in index]
        tt, true = tt[here], true[here]
        known = np.isfinite(true) & np.isfinite(tt)
        tt, true = tt[known], true[known]
        moved = np.flatnonzero(np.abs(true - true[0]) > 1e-9) if true.size else []
        if len(moved) and abs(true[-1] - true[0]) > 1e-9:
            true_changed = _halfway_time(tt, true, float(true[0]), float(true[-1]))
        elif len(moved):  # set back by the end: when it first moved
            true_changed = float(tt[moved[0]])
    return AxisDrift(name, unit, current, lo, hi, source, reference, reference_from, change,
                     change_std, tolerance, p_beyond, changed_at, fit.rate, fit.rate_std,
                     fit.span_s, fit.note,
                     true_current, true_changed)


def _p_beyond(change: float, sigma: float, tolerance: float) -> float:
    """P(|X| > tolerance) for X ~ N(change, sigma²); NaN without a finite sigma."""
    if not (math.isfinite(sigma) and sigma > 0):
        return NAN
    a = (tolerance - change) / (sigma * math.sqrt(2.0))
    b = (-tolerance - change) / (sigma * math.sqrt(2.0))
    return 0.5 * math.erfc(a) + 0.5 * math.erfc(-b)


def _step_time(table: Mapping[str, NDArray], t: NDArray, column: str, direction: float,
               ) -> float:
    """When the frames' own ``column`` (the pairs' or the filter's frame pose, not its mount)
    last stepped in ``direction`` (``filters.mount_steps``) [s]; NaN where it shows no such
    step. A filter's mount follows a knock at its own pace: the halfway rule put a knock at
    8.0 s, flagged at 9.3 s, at 15.6 s."""
    tx, x = _frame_series(table, t, column)
    steps = [s for s in mount_steps(tx, x) if np.sign(s.step) == direction]
    return steps[-1].onset_s if steps else NAN


def _level_since_step(table: Mapping[str, NDArray], t: NDArray, column: str,
                      ) -> tuple[float, float] | None:
    """The mean of the frames' own ``column`` since its last step (``filters.mount_steps``)
    and its standard error (batch means: the frames' errors run on), or None where it shows
    no step (or too few frames since)."""
    tx, x = _frame_series(table, t, column)
    steps = mount_steps(tx, x) if tx.size else []
    if not steps:
        return None
    level = batch_means(x[tx >= steps[-1].onset_s])
    return None if level is None else (float(np.mean(x[tx >= steps[-1].onset_s])), level.std)


def _frame_series(table: Mapping[str, NDArray], t: NDArray, column: str,
                  ) -> tuple[NDArray, NDArray]:
    """The times [s] and values of ``column`` on the rows that have both (and say ``ok``
    where the table has a status); empty where it has no such column."""
    if column not in table:
        return np.zeros(0), np.zeros(0)
    x = np.asarray(table[column], float)
    ok = np.isfinite(x) & np.isfinite(t)
    if "status" in table:
        ok &= np.asarray(table["status"]).astype(str) == "ok"
    return t[ok], x[ok]


def _split_time(table: Mapping[str, NDArray], t: NDArray, column: str, direction: float,
                ) -> float:
    """Where the frames' own ``column`` splits into two runs whose means differ most in
    standard errors (the least-squares place of one step), if the later run's mean is the
    higher in ``direction`` [s, the first frame after it]; NaN otherwise. For drives too short
    for ``filters.mount_steps``' test (8 s): a 3.2-s knock in an 8-s drive was put at 7.8 s,
    where the filter's mount crossed halfway."""
    tx, x = _frame_series(table, t, column)
    n = len(x)
    if n < 6 or not untested_drive_note(tx):  # where the step test ran, its "none" stands
        return NAN
    k = np.arange(3, n - 2)  # three frames on each side: one odd frame is no run
    total = np.cumsum(x)
    diff = (total[-1] - total[k - 1]) / (n - k) - total[k - 1] / k
    score = diff * direction * np.sqrt(k * (n - k) / n)
    best = int(np.argmax(score))
    return float(tx[k[best]]) if score[best] > 0 else NAN


def _halfway_time(t: NDArray, v: NDArray, start: float, current: float) -> float:
    """When ``v`` last left the start's side of the level halfway to ``current`` [s]."""
    half = 0.5 * (start + current)
    start_side = np.sign(v - half) == np.sign(start - half)
    on_start = np.flatnonzero(start_side)
    if on_start.size == 0:
        return float(t[0])
    i = int(on_start[-1]) + 1
    return float(t[min(i, len(t) - 1)])


class DriftFit(NamedTuple):
    """A straight line through an axis since its last change (:func:`_drift_fit`): ``rate``
    and its 1-σ ``rate_std`` [unit per minute], the ``span_s`` [s] it was fitted over, the
    ``note`` (why NaN, or "since the change" / "over the table"), the line's value at the
    span's end with its 1-σ (``end``, ``end_std``), and whether the line fits the frames
    better than one step does (``creeps``)."""

    rate: float
    rate_std: float
    span_s: float
    note: str
    end: float = NAN
    end_std: float = NAN
    creeps: bool = False


def _drift_fit(table: Mapping[str, NDArray], t: NDArray, column: str,
               mount: tuple[NDArray, NDArray, NDArray], changed_at: float) -> DriftFit:
    """The drift since ``changed_at`` (from the start where NaN); NaN with the reason where
    the span is shorter than :data:`MIN_RATE_SPAN_S`. The line is that of the frames' own
    ``column`` (as :func:`_step_time`; the ``mount`` series ``(t, value, std)`` where the
    table has too few of them or they do not vary, a height the pairs were given): a
    filter's mount follows a knock over tens of seconds, and its catch-up is no drift. It is
    fitted to block means (30 blocks: shaking averages out within a block); the rate's σ is
    the larger of the fit's standard error (widened where the blocks' errors run on) and the
    mount's own σ at both ends over the span."""
    tm, vm, std = mount
    tx, x = _frame_series(table, t, column)
    if tx.size < 4 or np.ptp(x) == 0:
        tx, x = tm, vm
    since = "since the change" if math.isfinite(changed_at) else "over the table"
    if math.isfinite(changed_at):
        keep, kept = tx >= changed_at, tm >= changed_at
        tx, x, std = tx[keep], x[keep], std[kept]
    span = float(tx[-1] - tx[0]) if tx.size else 0.0
    if span < MIN_RATE_SPAN_S:
        return DriftFit(NAN, NAN, span, f"not given: {span:.1f} s {since} < "
                        f"{MIN_RATE_SPAN_S:.0f} s")
    blocks = min(30, tx.size // 2)
    if blocks < MIN_RATE_BLOCKS:
        return DriftFit(NAN, NAN, span, f"not given: {tx.size} frames {since}")
    tb = np.array([b.mean() for b in np.array_split(tx, blocks)]) / 60.0
    vb = np.array([b.mean() for b in np.array_split(x, blocks)])
    (slope, intercept), cov = np.polyfit(tb, vb, 1, cov="unscaled")
    residual = vb - (slope * tb + intercept)
    # errors that run on from block to block (a slow wander) say less than their count
    cov = cov * float(residual @ residual) / (blocks - 2) * correlation_inflation(residual)**2
    ends = [s for s in (std[:1], std[-1:]) if s.size and math.isfinite(s[0])]
    model_std = (math.hypot(ends[0][0], ends[1][0]) / (span / 60.0) if len(ends) == 2
                 else 0.0)
    end = np.array([tx[-1] / 60.0, 1.0])
    # a knock (or a creep that stopped) reads better as one step: its line's end is no place
    cuts = np.arange(2, blocks - 1)
    creeps = bool(cuts.size) and float(residual @ residual) < float(
        one_step_squares(vb, cuts).min())
    return DriftFit(float(slope), max(math.sqrt(cov[0, 0]), model_std), span, since,
                    float(slope * end[0] + intercept), math.sqrt(float(end @ cov @ end)),
                    creeps)


def monitor_timeline(table: Mapping[str, NDArray]) -> MonitorTimeline | None:
    """The monitor's timeline of a table with ``monitor_state`` (None without)."""
    if "monitor_state" not in table:
        return None
    states = np.asarray(table["monitor_state"], dtype=object)
    t = np.asarray(table["t"], float)
    frames = np.asarray(table["frame"])
    runs = state_runs(states)
    transitions = tuple((int(frames[b[0]]), float(t[b[0]]), str(a[2]), str(b[2]))
                        for a, b in itertools.pairwise(runs))
    dt = np.diff(t, append=t[-1] + (np.median(np.diff(t)) if len(t) > 1 else 0.0))
    seconds = {str(s): float(np.nansum(dt[states == s])) for s in dict.fromkeys(states)}
    alarm = next((i for i, s in enumerate(states) if s in ALARM_STATES), None)
    first = (int(frames[alarm]), float(t[alarm])) if alarm is not None else None
    return MonitorTimeline(str(states[-1]), first, transitions, seconds,
                           str(states[alarm]) if alarm is not None else "")


def state_runs(values: NDArray) -> list[tuple[int, int, object]]:
    """(start, stop, value) of the runs of equal consecutive values."""
    if len(values) == 0:
        return []
    change = np.flatnonzero(values[1:] != values[:-1]) + 1
    starts = np.concatenate([[0], change])
    stops = np.concatenate([change, [len(values)]])
    return [(int(a), int(b), values[a]) for a, b in zip(starts, stops, strict=True)]


def has_finite(table: Mapping[str, NDArray], column: str) -> bool:
    """Whether ``column`` exists, is numeric and has a finite number somewhere."""
    if column not in table:
        return False
    try:
        return bool(np.isfinite(np.asarray(table[column], float)).any())
    except (TypeError, ValueError):  # a text column
        return False


__all__: Sequence[str] = [
    "MIN_RATE_SPAN_S",
    "AxisDrift",
    "DriftSummary",
    "MonitorTimeline",
    "has_finite",
    "has_mount",
    "monitor_timeline",
    "state_runs",
    "summarize_drift",
]
