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
range, time stamps not after the previous frame of the same id, error frames, unreadable
log tails. Frames of other ids (``other_ids``) and ids the DBC lacks (``unknown_ids``) are
counted apart: they are not errors.
"""

from __future__ import annotations

import csv
import io
import math
import re
import statistics
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import cantools
import numpy as np
from numpy.typing import ArrayLike, NDArray

from vipm_track.errors import InputError, printable
from vipm_track.table import LINE_END, read_text

from .can_decode import MessageDecoder, SignalSpec, load_dbc, parse_signal_specs
from .can_logs import LogRecords

#: Rules combining several speed signals into one speed (rows: samples, columns: signals).
COMBINE_RULES: dict[str, Callable[..., NDArray[np.float64]]] = {
    "mean": np.mean, "median": np.median, "min": np.min, "max": np.max,
}
_COMBINE_SCALAR: dict[str, Callable[[list[float]], float]] = {
    "mean": lambda v: sum(v) / len(v),
    "median": statistics.median, "min": min, "max": max,
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
    non_monotonic: int = 0     # wanted id, time not after its previous frame
    bad_rows: int = 0          # CSV rows that are not two finite numbers
    bad_lines: int = 0         # log lines (or records) the reader could not read as a frame
    read_errors: list[str] = field(default_factory=list)
    #: the first few bad lines / frames, "FILE:LINE: why" or "FILE: frame N: why"
    examples: list[str] = field(default_factory=list)
    interrupted: bool = False  # reading stopped by Ctrl-C / SIGTERM
    unknown_id_set: set[int] = field(default_factory=set)
    channels: Counter = field(default_factory=Counter)
    t_first: float = math.nan  # first frame's time in the log's own time base [s]
    t_last: float = math.nan

    @property
    def bad(self) -> int:
        """Frames or rows that were rejected as bad data (not counting other/unknown ids)."""
        return (self.error_frames + self.length_mismatch + self.decode_errors
                + self.non_monotonic + self.bad_rows + self.bad_lines + len(self.read_errors))

    def note(self, where: str, why: str) -> None:
        """Keep ``where: why`` (made printable) among the first :data:`MAX_EXAMPLES`."""
        if len(self.examples) < MAX_EXAMPLES:
            self.examples.append(printable(f"{where}: {why}", 200))

    def lines(self) -> list[str]:
        """Human-readable report, one line per non-zero count."""
        out = [f"{self.source}: {self.frames} frames read, {self.used} decoded, "
               f"{self.samples} speed samples"]
        if math.isfinite(self.t_first):
            out.append(f"  time span {self.t_first:.6f} .. {self.t_last:.6f} s "
                       f"({self.t_last - self.t_first:.3f} s)")
        if self.channels:
            out.append("  channels: " + ", ".join(f"{printable(c, 40)}={n}" for c, n in sorted(
                self.channels.items(), key=lambda kv: str(kv[0]))))
        labels = [
            ("other_ids", "frames of other DBC ids (not errors)"),
            ("unknown_ids", "frames of ids not in the DBC (not errors)"),
            ("other_channel", "frames on other channels (filtered)"),
            ("error_frames", "error/remote frames (skipped)"),
            ("length_mismatch", "wanted frames with a length other than the DBC's (skipped)"),
            ("decode_errors", "wanted frames undecodable or out of the DBC range (skipped)"),
            ("non_monotonic", "wanted frames with time not after the previous (skipped)"),
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
        if self.interrupted:
            out.append(f"  interrupted after {self.frames} frames")
        if self.examples:
            out.append(f"  first {len(self.examples)} bad: " + "; ".join(self.examples))
        return out

    def __str__(self) -> str:
        return "\n".join(self.lines())


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

    def speed_at(self, times: ArrayLike,
                 max_gap: float | None = DEFAULT_MAX_GAP) -> NDArray[np.float64]:
        """Speed [m/s] linearly interpolated at ``times`` [s, this series' clock]; NaN outside
        the samples' span or inside a gap longer than ``max_gap`` (None: no gap check)."""
        times = np.asarray(times, dtype=np.float64)
        out = np.full(times.shape, np.nan)
        if len(self) == 0:
            return out
        inside = (times >= self.t[0]) & (times <= self.t[-1])
        if max_gap is not None and len(self) > 1:
            hi = np.clip(np.searchsorted(self.t, times, side="left"), 1, len(self) - 1)
            exact = self.t[hi] == times
            inside &= exact | (self.t[hi] - self.t[hi - 1] <= max_gap)
        out[inside] = np.interp(times[inside], self.t, self.speed_mps)
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


def _channel_matches(channel: object, want: str) -> bool:
    """``can0`` matches channel index 0 (ASC/BLF number channels) but never ``can1``."""
    have = str(channel)
    if have == want:
        return True
    mh, mw = re.search(r"(\d+)$", have), re.search(r"(\d+)$", want)
    if not mh or not mw or int(mh.group(1)) != int(mw.group(1)):
        return False
    return have.isdigit() or want.isdigit()


@dataclass
class _Wanted:
    """One DBC message carrying wanted signals: its decoder and where its columns go."""

    decoder: MessageDecoder
    columns: NDArray[np.intp]
    t_last: float = -math.inf

    @property
    def column_list(self) -> list[int]:
        return self.columns.tolist()


class SpeedDecoder:
    """Streaming speed decoder: feed python-can messages, get speed samples.

    Parameters
    ----------
    dbc : DBC path or a loaded cantools database.
    signals : ``"MSG.SIG[:UNIT],..."``, a list of such specs, or None for the rear wheels.
    combine : rule combining several signals (``mean``, ``median``, ``min``, ``max``).
    channel : only frames from this channel (``can0`` also matches index 0), or None.
    scale : factor on the speed (tyre-radius correction).
    source : name used in the summary and errors.

    Signals from several messages are combined with each signal's latest value; a sample is
    produced at each wanted frame once every signal has been seen, and only if its time is
    after every earlier wanted frame's, so the output times strictly increase.
    ``feed(msg)`` (live buses) and ``feed_many(msgs)`` (logs, vectorised) give identical
    samples and share state.
    """

    def __init__(self, dbc: str | Path | cantools.database.can.Database,
                 signals: str | list[str] | None = None, combine: str = "mean",
                 channel: str | None = None, scale: float = 1.0, source: str = "CAN"):
        db = dbc if isinstance(dbc, cantools.database.can.Database) else load_dbc(dbc)
        dbc_name = "DBC" if isinstance(dbc, cantools.database.can.Database) else str(dbc)
        if combine not in COMBINE_RULES:
            raise InputError(f"combine rule {combine!r} is not one of {sorted(COMBINE_RULES)}")
        if not (np.isfinite(scale) and scale > 0):
            raise InputError(f"speed scale {scale!r} must be a positive number")
        self.specs: list[SignalSpec] = parse_signal_specs(db, signals, dbc_name)
        self.combine, self.channel, self.scale = combine, channel, float(scale)
        self.summary = DecodeSummary(source=source)
        self._known = {(m.frame_id, bool(m.is_extended_frame)) for m in db.messages}
        by_message: dict[str, list[int]] = {}
        for j, spec in enumerate(self.specs):
            by_message.setdefault(spec.message, []).append(j)
        self._wanted: dict[tuple[int, bool], _Wanted] = {}
        for name, cols in by_message.items():
            msg = db.get_message_by_name(name)
            dec = MessageDecoder(msg, [self.specs[j].signal for j in cols])
            self._wanted[(msg.frame_id, bool(msg.is_extended_frame))] = _Wanted(dec, np.array(cols))
        self._to_mps = np.array([s.to_mps for s in self.specs])
        self._to_mps_list = self._to_mps.tolist()
        self._hold = [math.nan] * len(self.specs)   # latest value of each signal [m/s]
        self._t_max = -math.inf                      # latest accepted wanted-frame time
        self._t: list[NDArray[np.float64]] = []     # emitted samples, in chunks
        self._v: list[NDArray[np.float64]] = []
        self._pending_t: list[float] = []           # samples from feed() not yet chunked
        self._pending_v: list[float] = []
        #: position of the message being screened: its line in a text log (``position_kind``
        #: "line", set by the log reader) or its frame index
        self.position: Callable[[], int] = lambda: self.summary.frames - 1
        self.position_kind = "frame"

    @property
    def signal_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.specs)

    def where(self, position: int | None = None) -> str:
        """``FILE:LINE`` or ``FILE: frame N`` of ``position`` (default: the current message)."""
        position = self.position() if position is None else position
        if self.position_kind == "line":
            return f"{self.summary.source}:{position}"
        return f"{self.summary.source}: frame {position}"

    # -- per-frame screening (shared by feed and feed_many) ---------------------------------
    def _screen(self, msg) -> _Wanted | None:
        s = self.summary
        s.frames += 1
        t = float(msg.timestamp)
        if s.frames == 1:
            s.t_first = t
        s.t_last = t
        s.channels[msg.channel] += 1
        if msg.is_error_frame or msg.is_remote_frame:
            s.error_frames += 1
            return None
        if self.channel is not None and not _channel_matches(msg.channel, self.channel):
            s.other_channel += 1
            return None
        key = (msg.arbitration_id, bool(msg.is_extended_id))
        wanted = self._wanted.get(key)
        if wanted is None:
            if key in self._known:
                s.other_ids += 1
            else:
                s.unknown_ids += 1
                s.unknown_id_set.add(msg.arbitration_id)
            return None
        if len(msg.data) != wanted.decoder.length:
            s.length_mismatch += 1
            s.note(self.where(), f"{len(msg.data)} data bytes, the DBC's "
                   f"{wanted.decoder.message.name} has {wanted.decoder.length}")
            return None
        return wanted

    def feed(self, msg) -> tuple[float, float] | None:
        """Screen and decode one ``can.Message``; the (t [s], speed [m/s]) sample it yields,
        or None (other id, bad frame, or not every signal seen yet). Same rules and results
        as :meth:`feed_many`, in scalar Python for per-frame speed."""
        wanted = self._screen(msg)
        if wanted is None:
            return None
        s = self.summary
        t = float(msg.timestamp)
        if not (math.isfinite(t) and t > wanted.t_last):
            s.non_monotonic += 1
            s.note(self.where(), f"time {t} not after the previous frame's {wanted.t_last}")
            return None
        wanted.t_last = t
        values = wanted.decoder.decode_one(bytes(msg.data))
        if values is None:
            s.decode_errors += 1
            s.note(self.where(), "undecodable or outside the DBC's range")
            return None
        s.used += 1
        hold = self._hold
        for col, value in zip(wanted.column_list, values, strict=True):
            hold[col] = value * self._to_mps_list[col]
        emit = t > self._t_max and not any(math.isnan(h) for h in hold)
        self._t_max = max(self._t_max, t)
        if not emit:
            return None
        speed = float(_COMBINE_SCALAR[self.combine](hold)) * self.scale
        self._pending_t.append(t)
        self._pending_v.append(speed)
        s.samples += 1
        return t, speed

    def feed_many(self, messages: Iterable, progress: bool = False,
                  resume: Callable[[], Iterator] | None = None) -> SpeedSeries:
        """Screen all ``messages``, decode the wanted ones at once; the samples they yield.

        An exception from the iterator (an unreadable record) is recorded in
        ``summary.read_errors``; reading goes on with ``resume()`` (a fresh iterator that
        continues after the bad record) where given, else stops keeping what was read. An
        interrupt (Ctrl-C) stops the reading too: the frames read before it are decoded and
        ``summary.interrupted`` is set."""
        batches: dict[int, tuple[list[float], list[bytes], list[int], list[int]]] = {}
        seq = 0
        iterator = iter(messages)
        bar = _progress(progress, self.summary.source)
        while True:
            try:
                msg = next(iterator)
            except StopIteration:
                break
            except KeyboardInterrupt:
                self.summary.interrupted = True
                break
            except InputError:  # the log cannot be opened at all: nothing to go on with
                raise
            except Exception as exc:  # python-can readers raise assorted types on bad files
                errors = self.summary.read_errors
                go_on = resume is not None and len(errors) < MAX_READ_ERRORS
                errors.append(f"unreadable record after frame {self.summary.frames} "
                              f"({type(exc).__name__}: {exc}); "
                              + ("skipped" if go_on else "reading stopped there"))
                if not go_on:
                    break
                iterator = resume()
                continue
            if bar is not None and seq % 4096 == 0:
                bar.update(self.summary.frames - bar.n)
            seq += 1
            wanted = self._screen(msg)
            if wanted is None:
                continue
            ts, data, order, where = batches.setdefault(id(wanted), ([], [], [], []))
            ts.append(float(msg.timestamp))
            data.append(bytes(msg.data))
            order.append(seq)
            where.append(self.position())
        if bar is not None:
            bar.update(self.summary.frames - bar.n)
            bar.close()
        t, v = self._process(batches)
        return SpeedSeries(t, v, source=self.summary.source, signals=self.signal_names,
                           scale=self.scale, summary=self.summary)

    def _flush(self) -> None:
        if self._pending_t:
            self._t.append(np.array(self._pending_t))
            self._v.append(np.array(self._pending_v))
            self._pending_t, self._pending_v = [], []

    def series(self) -> SpeedSeries:
        """Every sample produced so far (by ``feed`` and ``feed_many``)."""
        self._flush()
        t = np.concatenate(self._t) if self._t else np.zeros(0)
        v = np.concatenate(self._v) if self._v else np.zeros(0)
        return SpeedSeries(t, v, source=self.summary.source, signals=self.signal_names,
                           scale=self.scale, summary=self.summary)

    # -- vectorised decode and combination --------------------------------------------------
    def _process(self, batches: dict[int, tuple[list[float], list[bytes], list[int], list[int]]]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        self._flush()
        by_id = {id(w): w for w in self._wanted.values()}
        ev_t, ev_order, ev_rows, ev_msg = [], [], [], []
        for m_index, (key, (ts, data, order, where)) in enumerate(batches.items()):
            wanted = by_id[key]
            t = np.asarray(ts, dtype=np.float64)
            # Accept a frame only if its time is after every earlier frame of its id.
            prior = np.maximum.accumulate(np.concatenate([[wanted.t_last], t[:-1]]))
            mono = np.isfinite(t) & (t > prior)
            self.summary.non_monotonic += int((~mono).sum())
            for i in np.flatnonzero(~mono)[:MAX_EXAMPLES]:
                self.summary.note(self.where(where[i]),
                                  f"time {t[i]} not after the previous frame's {prior[i]}")
            if mono.any():
                wanted.t_last = max(wanted.t_last, float(t[mono].max()))
            payload = np.frombuffer(b"".join(data), dtype=np.uint8).reshape(len(ts), -1)
            values, ok = wanted.decoder.decode(payload[mono])
            self.summary.decode_errors += int((~ok).sum())
            for i in np.flatnonzero(mono)[~ok][:MAX_EXAMPLES]:
                self.summary.note(self.where(where[i]), "undecodable or outside the DBC's range")
            self.summary.used += int(ok.sum())
            rows = np.full((int(ok.sum()), len(self.specs)), np.nan)
            rows[:, wanted.columns] = values[ok] * self._to_mps[wanted.columns]
            ev_t.append(t[mono][ok])
            ev_order.append(np.asarray(order)[mono][ok])
            ev_rows.append(rows)
            ev_msg.append(np.full(rows.shape[0], m_index))
        if not ev_t or sum(a.size for a in ev_t) == 0:
            return np.zeros(0), np.zeros(0)
        order = np.argsort(np.concatenate(ev_order), kind="stable")
        t = np.concatenate(ev_t)[order]
        rows = np.concatenate(ev_rows)[order]
        n = t.size
        # Sample-and-hold: each signal takes its latest value (or the held one from before).
        hold = np.array(self._hold, dtype=np.float64)
        filled = np.empty_like(rows)
        for j in range(len(self.specs)):
            src = np.where(np.isfinite(rows[:, j]), np.arange(n), -1)
            src = np.maximum.accumulate(src)
            filled[:, j] = np.where(src >= 0, rows[np.maximum(src, 0), j], hold[j])
        prior = np.maximum.accumulate(np.concatenate([[self._t_max], t[:-1]]))
        emit = np.all(np.isfinite(filled), axis=1) & (t > prior)
        self._hold = filled[-1].tolist()
        self._t_max = max(self._t_max, float(t.max()))
        speed = COMBINE_RULES[self.combine](filled[emit], axis=1) * self.scale
        self._t.append(t[emit])
        self._v.append(speed)
        self.summary.samples += int(emit.sum())
        return t[emit], speed


def _progress(enabled: bool, what: str):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(desc=f"decoding {Path(what).name}", unit=" frames", file=sys.stderr,
                mininterval=0.5, leave=False)


def decode_can_log(path: str | Path, dbc: str | Path | cantools.database.can.Database,
                   signals: str | list[str] | None = None, combine: str = "mean",
                   channel: str | None = None, scale: float = 1.0,
                   progress: bool = False) -> tuple[SpeedSeries, DecodeSummary]:
    """Speed series [t s in the log's time base, m/s] decoded from a CAN log, and the summary.

    ``path`` is any log python-can's ``LogReader`` reads (candump .log, Vector .asc/.blf,
    PCAN .trc, .csv, .mf4 with asammdf), read by ``filters.can_logs.LogRecords``: a line or
    record that is not a frame is skipped, counted and (the first few) named by line or frame
    index, and reading goes on. See :class:`SpeedDecoder` for the other parameters. A log
    that yields no speed sample raises :class:`InputError` with the summary.
    """
    path = Path(path)
    decoder = SpeedDecoder(dbc, signals, combine=combine, channel=channel, scale=scale,
                           source=str(path))
    summary = decoder.summary

    def bad(position: int, why: str) -> None:
        summary.bad_lines += 1
        summary.note(decoder.where(position), why)

    records = LogRecords(path, bad)
    decoder.position_kind = records.kind
    decoder.position = lambda: records.position
    series = decoder.feed_many(records, progress=progress)
    if records.stopped:
        summary.read_errors.append(f"{decoder.where(records.position)}: {records.stopped}")
    if summary.interrupted and len(series) == 0:
        raise KeyboardInterrupt
    if len(series) == 0:
        raise InputError(f"{path}: no speed sample decoded for {', '.join(decoder.signal_names)}"
                         "\n" + str(summary))
    return series, summary


def iter_bus(bus, duration: float | None = None, max_messages: int | None = None,
             idle_timeout: float = 1.0) -> Iterator:
    """Messages from a python-can ``bus`` until ``duration`` [s] passes, ``max_messages`` are
    received, or none arrives for ``idle_timeout`` [s]."""
    end = None if duration is None else time.monotonic() + duration
    n = 0
    while max_messages is None or n < max_messages:
        wait = idle_timeout if end is None else min(idle_timeout, end - time.monotonic())
        if wait <= 0:
            return
        msg = bus.recv(timeout=wait)
        if msg is None:
            return
        n += 1
        yield msg


def decode_bus(bus, dbc: str | Path | cantools.database.can.Database,
               signals: str | list[str] | None = None, combine: str = "mean",
               channel: str | None = None, scale: float = 1.0, duration: float | None = None,
               max_messages: int | None = None, idle_timeout: float = 1.0,
               on_sample: Callable[[float, float], None] | None = None
               ) -> tuple[SpeedSeries, DecodeSummary]:
    """Speed series decoded live from a python-can ``bus`` (e.g. ``can.Bus(interface=
    "virtual", channel=...)``), message by message; ``on_sample(t, speed_mps)`` is called for
    each sample as it arrives. Stops as :func:`iter_bus` says."""
    decoder = SpeedDecoder(dbc, signals, combine=combine, channel=channel, scale=scale,
                           source=f"bus {getattr(bus, 'channel_info', bus)}")
    for msg in iter_bus(bus, duration, max_messages, idle_timeout):
        sample = decoder.feed(msg)
        if sample is not None and on_sample is not None:
            on_sample(*sample)
    return decoder.series(), decoder.summary


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

    Rows that are not two finite numbers, and rows whose time is not after the previous
    row's, are skipped and counted in ``series.summary``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: speed CSV not found")
    summary = DecodeSummary(source=str(path))
    ts: list[float] = []
    vs: list[float] = []
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
            if ts and t <= ts[-1]:
                summary.non_monotonic += 1
                summary.note(where, f"t {t} not after the previous row's {ts[-1]}")
                continue
            ts.append(t)
            vs.append(v)
    except csv.Error as exc:
        raise InputError(f"{path}: line {reader.line_num}: not CSV ({exc})") from None
    summary.used = summary.samples = len(ts)
    if ts:
        summary.t_first, summary.t_last = ts[0], ts[-1]
    return SpeedSeries(np.array(ts), np.array(vs), source=str(path), signals=("speed_mps",),
                       summary=summary)


def write_speed_csv(series: SpeedSeries, path: str | Path) -> Path:
    """Write ``t,speed_mps`` (µs and 0.01 mm/s resolution); the path written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # written beside it, then renamed: an interrupted write never leaves half a table
    partial = path.with_name(path.name + ".partial")
    try:
        with partial.open("w", newline="") as fh:
            fh.write("t,speed_mps" + LINE_END)
            np.savetxt(fh, np.column_stack([series.t, series.speed_mps]), fmt=["%.6f", "%.5f"],
                       delimiter=",", newline=LINE_END)
        partial.replace(path)
    finally:
        partial.unlink(missing_ok=True)
    return path


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
