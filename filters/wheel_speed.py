"""Vehicle speed from CAN (logs or live buses, decoded with a DBC) or a CSV, aligned to camera
frame times. A metric speed is what makes the camera height observable (CONVENTIONS, Scale).

Data flow::

    can.LogReader / can.Bus ──► SpeedDecoder (filter ids, check, decode, combine) ──► SpeedSeries
    SpeedSeries (+ clock offset) ──► align_to_frames(frame_times) ──► AlignedSpeed

Time bases: ``t`` is what python-can's reader gives. candump ``.log`` keeps the absolute
stamps; Vector ``.asc`` (python-can's default) counts from the first frame; ``.blf`` counts
from its header's start time, which python-can truncates to the millisecond and leaves empty
when the stamps are not Unix time (so ``t`` counts from that truncated start). Align clocks
with ``clock_offset`` (seconds added to CAN time to reach camera time);
``DecodeSummary.t_first`` is the log's first frame time in its own base.

Bad data is counted in :class:`DecodeSummary`, never used and never fatal: frames of wanted
ids whose length differs from the DBC's, decode errors and values outside the DBC's stated
range, time stamps out of order with the other frames of the same id (a lone stamp far ahead
or behind; the frames after a clock step back, ``clock_steps``), error frames, unreadable
log tails. Frames of other ids (``other_ids``) and ids the DBC lacks (``unknown_ids``) are
counted apart: they are not errors.
"""

from __future__ import annotations

import csv
import io
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vipm_track.errors import InputError, printable
from vipm_track.increasing import kept_around, left_out_between
from vipm_track.measurement import MAX_SPEED_MPS
from vipm_track.table import read_text, write_columns_csv

#: Rules combining several speed signals into one speed (rows: samples, columns: signals).
COMBINE_RULES: dict[str, Callable[..., NDArray[np.float64]]] = {
    "mean": np.mean, "median": np.median, "min": np.min, "max": np.max,
}
#: Default largest spacing of speed samples [s] across which interpolation is trusted.
DEFAULT_MAX_GAP = 0.5
#: Unreadable records skipped in a binary log before reading gives up.
MAX_READ_ERRORS = 1000
#: Bad lines / frames a summary names (the rest are counted).
MAX_EXAMPLES = 5


@dataclass
class DecodeSummary:
    """What happened to every frame (or CSV row) of a speed source; printed by the CLI."""

    source: str
    frames: int = 0            # frames read
    used: int = 0              # frames of the wanted ids decoded into speed
    samples: int = 0           # speed samples produced
    other_ids: int = 0         # ids in the DBC that carry no wanted signal
    unknown_ids: int = 0       # ids the DBC does not define
    other_channel: int = 0     # frames dropped by the channel filter
    error_frames: int = 0      # CAN error frames / remote frames
    length_mismatch: int = 0   # wanted id, payload length != DBC length
    decode_errors: int = 0     # wanted id, undecodable or outside the DBC's [min, max]
    non_monotonic: int = 0     # wanted id, time out of order with its other frames
    bad_rows: int = 0          # CSV rows that are not two finite numbers
    bad_lines: int = 0         # log lines (or records) the reader could not read as a frame
    read_errors: list[str] = field(default_factory=list)
    #: where a wanted id's time steps back and goes on from there (its frames counted in
    #: ``non_monotonic``), "FILE:LINE: what was skipped"
    clock_steps: list[str] = field(default_factory=list)
    #: the first few bad lines / frames, "FILE:LINE: why" or "FILE: frame N: why"
    examples: list[str] = field(default_factory=list)
    interrupted: bool = False  # reading stopped by Ctrl-C / SIGTERM
    unknown_id_set: set[int] = field(default_factory=set)
    channels: Counter = field(default_factory=Counter)
    t_first: float = math.nan  # first frame's time in the log's own time base [s]
    t_last: float = math.nan
    #: what the source holds: CAN "frames", or "rows" of a t,speed_mps CSV
    unit: str = "frames"

    @property
    def bad(self) -> int:
        """Frames or rows that were rejected as bad data (not counting other/unknown ids)."""
        return (self.error_frames + self.length_mismatch + self.decode_errors
                + self.non_monotonic + self.bad_rows + self.bad_lines + len(self.read_errors))

    def note(self, where: str, why: str) -> None:
        """Keep ``where: why`` (made printable) among the first :data:`MAX_EXAMPLES`."""
        if len(self.examples) < MAX_EXAMPLES:
            self.examples.append(printable(f"{where}: {why}", 300))

    def lines(self) -> list[str]:
        """Human-readable report, one line per non-zero count."""
        out = [f"{self.source}: {self.frames} {self.unit} read, {self.used} decoded, "
               f"{self.samples} speed samples"]
        if math.isfinite(self.t_first):
            out.append(f"  time span {self.t_first:.6f} .. {self.t_last:.6f} s "
                       f"({self.t_last - self.t_first:.3f} s)")
        if self.channels:
            # python-can numbers a Vector log's channels from 0 where the file counts from 1:
            # `--can-channel 1` on "channel 1" of an .asc picked the file's channel 2
            suffix = Path(self.source).suffix.lower()
            vector = (" (as python-can numbers them, from 0: the file's channel 1 is 0; "
                      "--can-channel takes these)")
            numbering = {
                ".asc": vector, ".blf": vector,
                # PCAN counts buses from 1 and python-can keeps it: can0 is no channel here
                ".trc": " (as the file numbers them, from 1; --can-channel takes these)",
            }.get(suffix, "")
            out.append("  channels: " + ", ".join(f"{printable(c, 40)}={n}" for c, n in sorted(
                self.channels.items(), key=lambda kv: str(kv[0]))) + numbering)
        labels = [
            ("other_ids", "frames of other DBC ids (not errors)"),
            ("unknown_ids", "frames of ids not in the DBC (not errors)"),
            ("other_channel", "frames on other channels (filtered)"),
            ("error_frames", "error/remote frames (skipped)"),
            ("length_mismatch", "wanted frames with a length other than the DBC's (skipped)"),
            ("decode_errors", "wanted frames undecodable or out of the DBC range (skipped)"),
            ("non_monotonic", "rows with a time out of order with the rows around them (skipped)"
             if self.unit == "rows" else "wanted frames with a time out of order (skipped)"),
            ("bad_rows", "rows that are not two finite numbers (skipped)"),
            ("bad_lines", "lines the log reader could not read as a CAN frame (skipped)"),
        ]
        for name, label in labels:
            n = getattr(self, name)
            if n:
                extra = ""
                if name == "unknown_ids":
                    ids = sorted(self.unknown_id_set)
                    extra = " [" + ", ".join(f"0x{i:X}" for i in ids[:12]) + (
                        ", ..." if len(ids) > 12 else "") + "]"
                out.append(f"  {n} {label}{extra}")
        out.extend(f"  read error: {printable(e, 300)}" for e in self.read_errors)
        out.extend(f"  clock step: {printable(e, 400)}" for e in self.clock_steps)
        if self.interrupted:
            out.append(f"  interrupted after {self.frames} frames")
        if self.examples:
            out.append(f"  first {len(self.examples)} bad: " + "; ".join(self.examples))
        return out

    def __str__(self) -> str:
        return "\n".join(self.lines())


class SpeedSource(Protocol):
    """Anything with sample times ``t`` (s) and ``speed_mps`` arrays."""

    t: NDArray[np.float64]
    speed_mps: NDArray[np.float64]


@dataclass(frozen=True)
class SpeedSeries:
    """Vehicle speed samples: ``t`` [s, strictly increasing], ``speed_mps`` [m/s].

    ``clock_offset`` [s] has already been added to ``t``; ``scale`` already multiplies the
    speed. ``source`` and ``signals`` say where the samples came from.
    """

    t: NDArray[np.float64]
    speed_mps: NDArray[np.float64]
    source: str = ""
    signals: tuple[str, ...] = ()
    scale: float = 1.0
    clock_offset: float = 0.0
    summary: DecodeSummary | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64).reshape(-1)
        v = np.asarray(self.speed_mps, dtype=np.float64).reshape(-1)
        if t.shape != v.shape:
            raise ValueError(f"{self.source}: {t.size} times but {v.size} speeds")
        if t.size > 1 and not np.all(np.diff(t) > 0):
            raise ValueError(f"{self.source}: speed times are not strictly increasing")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "speed_mps", v)

    def __len__(self) -> int:
        return int(self.t.size)

    def with_samples(self) -> SpeedSeries:
        """This series; InputError naming its source where it holds no sample (a header-only
        speed CSV, a log without the wanted frames)."""
        if len(self) == 0:
            raise InputError(f"{self.source}: no speed samples")
        return self

    def shifted(self, offset: float) -> SpeedSeries:
        """The same samples with ``offset`` seconds added to the times."""
        return replace(self, t=self.t + offset, clock_offset=self.clock_offset + offset)

    def scaled(self, scale: float) -> SpeedSeries:
        """The same samples with speeds multiplied by ``scale`` (tyre-radius correction)."""
        return replace(self, speed_mps=self.speed_mps * scale, scale=self.scale * scale)

    def gaps(self, max_gap: float = DEFAULT_MAX_GAP) -> NDArray[np.float64]:
        """(G, 2) start/end times [s] of spacings between samples longer than ``max_gap``."""
        if len(self) < 2:
            return np.zeros((0, 2))
        k = np.flatnonzero(np.diff(self.t) > max_gap)
        return np.stack([self.t[k], self.t[k + 1]], axis=1)

    def overlap(self, frame_times: ArrayLike) -> tuple[int, str]:
        """How many of ``frame_times`` [s, this series' clock] have a speed, and the spans of
        both (for a message saying they do not meet)."""
        times = np.asarray(frame_times, dtype=float)
        if times.size == 0:
            return 0, ""
        covered = int(np.isfinite(self.speed_at(times)).sum())
        return covered, (f"speed {self.t[0]:.3f} .. {self.t[-1]:.3f} s (clock offset "
                         f"{self.clock_offset:+.3f} s), camera {times.min():.3f} .. "
                         f"{times.max():.3f} s")

    def none_covered(self, spans: str, hint: str) -> str:
        """What to say where none of the frames has a speed: the source, both spans
        (:meth:`overlap`) and ``hint`` (what to do about it)."""
        return f"{self.source or 'wheel speed'}: no frame has a wheel speed: {spans}; {hint}"

    def speed_at(self, times: ArrayLike,
                 max_gap: float | None = DEFAULT_MAX_GAP) -> NDArray[np.float64]:
        """Speed [m/s] linearly interpolated at ``times`` [s, this series' clock]; NaN outside
        the samples' span or inside a gap longer than ``max_gap`` (None: no gap check)."""
        return interpolate_speed(self.t, self.speed_mps, times, max_gap)


def interpolate_speed(t: ArrayLike, speed_mps: ArrayLike, times: ArrayLike,
                      max_gap: float | None = DEFAULT_MAX_GAP) -> NDArray[np.float64]:
    """Speed [m/s] of the samples (``t`` [s], ``speed_mps``) linearly interpolated at ``times``
    [s, the samples' clock]; NaN outside their span or inside a gap longer than ``max_gap``
    [s] (None: no gap check). The one interpolation every speed reader uses."""
    t = np.asarray(t, dtype=np.float64)
    v = np.asarray(speed_mps, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    out = np.full(times.shape, np.nan)
    if len(t) == 0:
        return out
    inside = (times >= t[0]) & (times <= t[-1])
    if max_gap is not None and len(t) > 1:
        hi = np.clip(np.searchsorted(t, times, side="left"), 1, len(t) - 1)
        exact = t[hi] == times
        inside &= exact | (t[hi] - t[hi - 1] <= max_gap)
    out[inside] = np.interp(times[inside], t, v)
    return out


@dataclass(frozen=True)
class AlignedSpeed:
    """Speed per camera frame: ``speed_mps`` [m/s] (NaN where not ``valid``) at ``frame_times``
    [s, camera clock]; ``gaps`` (G, 2) [s, camera clock] are the speed gaps that overlap the
    frames' span; ``clock_offset`` [s] was added to the CAN times."""

    frame_times: NDArray[np.float64]
    speed_mps: NDArray[np.float64]
    valid: NDArray[np.bool_]
    gaps: NDArray[np.float64]
    clock_offset: float
    n_before: int = 0   # frames before the first speed sample
    n_after: int = 0    # frames after the last speed sample

    def lines(self) -> list[str]:
        """Human-readable report of coverage and gaps."""
        n = self.frame_times.size
        out = [f"speed for {int(self.valid.sum())} of {n} frames (clock offset "
               f"{self.clock_offset:+.3f} s)"]
        if self.n_before or self.n_after:
            out.append(f"  {self.n_before} frames before the first speed sample, "
                       f"{self.n_after} after the last")
        out.extend(f"  speed gap {a:.3f} .. {b:.3f} s ({b - a:.3f} s)" for a, b in self.gaps)
        return out


def cumulative_distance(t: ArrayLike, speed_mps: ArrayLike) -> NDArray[np.float64]:
    """Distance [m] from the first sample to each sample of a speed series (times ``t`` [s],
    increasing; speeds [m/s], their magnitude taken), by trapezoids."""
    t = np.asarray(t, dtype=np.float64)
    v = np.abs(np.asarray(speed_mps, dtype=np.float64))
    return np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])


def align_to_frames(series: SpeedSeries, frame_times: ArrayLike, clock_offset: float = 0.0,
                    max_gap: float = DEFAULT_MAX_GAP) -> AlignedSpeed:
    """Speed at each camera frame time [s], from ``series`` shifted by ``clock_offset`` [s].

    Frames outside the speed samples' span, or between two samples more than ``max_gap``
    apart, get NaN and ``valid`` False. Clocks that do not overlap at all raise
    :class:`InputError` stating both spans.
    """
    ft = np.asarray(frame_times, dtype=np.float64).reshape(-1)
    if ft.size == 0:
        raise InputError("no frame times to align the speed to")
    if not np.all(np.isfinite(ft)):
        raise InputError(f"frame times: {int((~np.isfinite(ft)).sum())} are not finite numbers")
    if len(series) == 0:
        raise InputError(f"{series.source or 'speed'}: no speed samples to align")
    shifted = series.shifted(clock_offset) if clock_offset else series
    t0, t1 = shifted.t[0], shifted.t[-1]
    if ft.max() < t0 or ft.min() > t1:
        raise InputError(
            f"{series.source or 'speed'}: speed clock [{t0:.3f}, {t1:.3f}] s (offset "
            f"{shifted.clock_offset:+.3f} s) and camera clock [{ft.min():.3f}, {ft.max():.3f}] s "
            "do not overlap; set the clock offset (--clock-offset) to the camera time minus "
            "the CAN time, or to 'auto' to find it from the data")
    speed = shifted.speed_at(ft, max_gap=max_gap)
    gaps = shifted.gaps(max_gap)
    gaps = gaps[(gaps[:, 1] >= ft.min()) & (gaps[:, 0] <= ft.max())]
    return AlignedSpeed(ft, speed, np.isfinite(speed), gaps, float(shifted.clock_offset),
                        n_before=int((ft < t0).sum()), n_after=int((ft > t1).sum()))


def read_speed_csv(path: str | Path) -> SpeedSeries:
    """Speed series from a CSV with columns ``t`` [s] and ``speed_mps`` [m/s].

    Rows that are not two finite numbers, and rows out of time order (all but the longest
    run of rows whose time increases), are skipped and counted in ``series.summary``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: speed CSV not found")
    summary = DecodeSummary(source=str(path), unit="rows")
    ts: list[float] = []
    vs: list[float] = []
    lines: list[int] = []
    reader = csv.reader(io.StringIO(read_text(path), newline=""))
    try:
        header = [h.strip() for h in next(reader, [])]
        if "t" not in header or "speed_mps" not in header:
            raise InputError(f"{path}: header {printable(header, 200)} lacks column(s) 't' "
                             "and/or 'speed_mps'")
        it, iv = header.index("t"), header.index("speed_mps")
        for row in reader:
            if not row or all(not c.strip() for c in row):
                continue
            summary.frames += 1
            where = f"{path}:{reader.line_num}"
            try:
                t, v = float(row[it]), float(row[iv])
            except (IndexError, ValueError):
                summary.bad_rows += 1
                summary.note(where, "not two numbers t, speed_mps")
                continue
            if not (math.isfinite(t) and math.isfinite(v)):
                summary.bad_rows += 1
                summary.note(where, "not finite")
                continue
            if abs(v) > MAX_SPEED_MPS:
                summary.bad_rows += 1
                summary.note(where, f"speed {v:g} m/s is no ground vehicle's (beyond "
                                    f"{MAX_SPEED_MPS:g})")
                continue
            ts.append(t)
            vs.append(v)
            lines.append(reader.line_num)
    except csv.Error as exc:
        raise InputError(f"{path}: line {reader.line_num}: not CSV ({exc})") from None
    # the longest run of rows whose time increases: one corrupt time drops only its row
    kept, between = left_out_between(ts) if ts else (np.zeros(0, np.int64), [])
    for i, before, after in between:
        summary.non_monotonic += 1
        around = kept_around(before, after)
        summary.note(f"{path}:{lines[i]}",
                     f"t {ts[i]!r} out of order" + (f" ({around})" if around else ""))
    ts, vs = [ts[i] for i in kept], [vs[i] for i in kept]
    summary.used = summary.samples = len(ts)
    if ts:
        summary.t_first, summary.t_last = ts[0], ts[-1]
    return SpeedSeries(np.array(ts), np.array(vs), source=str(path), signals=("speed_mps",),
                       summary=summary)


def write_speed_csv(series: SpeedSeries, path: str | Path) -> Path:
    """Write ``t,speed_mps`` (see :func:`vipm_track.table.write_columns_csv`); the path
    written."""
    return write_columns_csv(path, {"t": series.t, "speed_mps": series.speed_mps})


def fit_speed_scale(series: SpeedSeries, ref_times: ArrayLike, ref_speed_mps: ArrayLike,
                    min_speed: float = 1.0, max_gap: float = DEFAULT_MAX_GAP) -> float:
    """Tyre-radius scale [-] taking ``series`` to a reference speed (e.g. GNSS): the median of
    reference / wheel speed over the reference samples [s, series clock] where both are above
    ``min_speed`` [m/s]. Use it as ``--speed-scale``."""
    ref_t = np.asarray(ref_times, dtype=np.float64).reshape(-1)
    ref_v = np.asarray(ref_speed_mps, dtype=np.float64).reshape(-1)
    if ref_t.shape != ref_v.shape:
        raise InputError(f"reference speed: {ref_t.size} times but {ref_v.size} speeds")
    wheel = series.speed_at(ref_t, max_gap=max_gap)
    use = np.isfinite(wheel) & np.isfinite(ref_v) & (wheel > min_speed) & (ref_v > min_speed)
    if use.sum() < 10:
        raise InputError(f"{series.source or 'speed'}: only {int(use.sum())} reference samples "
                         f"overlap the speed above {min_speed} m/s; cannot fit a scale")
    return float(np.median(ref_v[use] / wheel[use]))
