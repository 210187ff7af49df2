"""Wheel speed decoded from CAN: ``SpeedDecoder`` turns frames of the wanted messages into a
``wheel_speed.SpeedSeries`` through a DBC (cantools), from a log file (``decode_can_log``,
any format python-can reads) or a live bus (``decode_bus``), counting bad data in a
``DecodeSummary`` instead of failing.

Two things of the log's clock and buses are settled before decoding: a 32-bit microsecond
clock that wraps around (its times step back by exactly 2^32 µs) is unwrapped, and a wanted
message that comes on several channels is decoded from one of them only, and only if the
others carry identical copies of its frames (a gateway mirroring the bus); copies that differ
are two signals, which no decoding may mix: the decoder refuses them until a channel is
chosen."""

from __future__ import annotations

import bisect
import math
import re
import statistics
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cantools
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from vipm_track.errors import InputError, InterruptFlag, interrupts_deferred, printable

from .can_decode import MessageDecoder, SignalSpec, load_dbc, parse_signal_specs
from .can_logs import LogRecords
from .wheel_speed import (
    COMBINE_RULES,
    MAX_EXAMPLES,
    MAX_READ_ERRORS,
    DecodeSummary,
    SpeedSeries,
)

_COMBINE_SCALAR: dict[str, Callable[[list[float]], float]] = {
    "mean": lambda v: sum(v) / len(v),
    "median": statistics.median, "min": min, "max": max,
}
#: Frames of one id a log's decoding looks ahead at to judge a time out of line: up to this
#: many frames in a row stamped after the frames around them, or behind them, are outliers;
#: a longer run is taken as the clock, and a step back to it as a clock step.
LOOKAHEAD = 8
#: Period [s] of a 32-bit microsecond clock: where the time steps back by about this much
#: from one frame of the log to the next, the clock wrapped around.
WRAP_S = 2**32 * 1e-6
#: Most time [s] between the two frames across a wrap-around (a bus quiet there, or a log of
#: one message): a step back up to this much short of :data:`WRAP_S` is unwrapped. A step
#: back farther from it is no wrap-around (a clock reset).
WRAP_GAP_S = 10.0
#: How much [s] a step back may exceed :data:`WRAP_S` and still be unwrapped: the frame
#: after the wrap stamped that much before the one logged before it (out of order).
WRAP_TOLERANCE_S = 0.005
#: How far apart [s] a frame and its copy on another channel (a gateway mirroring the bus)
#: may be stamped: a gateway's forwarding delay, or two channels' time stamps taken apart.
MIRROR_WINDOW_S = 0.05
#: Latest frames of a wanted message kept, on its decoded channel, to match copies against.
_RECENT = 32


@dataclass
class CanDecodeSummary(DecodeSummary):
    """A :class:`DecodeSummary` of CAN frames, with what was done to the log's clock and
    channels (``notes``: a wrap-around unwrapped, a refused channel mix) and, per wanted
    message (``NAME (0xID)``), the channel decoded and the identical copies of its frames
    skipped on each other channel (``copies``)."""

    notes: list[str] = field(default_factory=list)
    copies: dict[str, tuple[object, Counter]] = field(default_factory=dict)

    def lines(self) -> list[str]:
        out = super().lines()
        at = 1
        for i, line in enumerate(out[1:3], start=1):
            if line.startswith("  time span "):
                at = i + 1
                if self.t_last < self.t_first:  # first .. last is no span: the clock stepped
                    out[i] = (f"  time stamps {self.t_first:.6f} .. {self.t_last:.6f} s: the "
                              "clock steps back in between (see the clock steps below)")
            elif line.startswith("  channels:"):
                at = i + 1
        extra = [f"  note: {printable(n, 400)}" for n in self.notes]
        for name, (channel, copies) in self.copies.items():
            extra.append(f"  {name} decoded on channel {_channel_name(channel)} only: its "
                         + ", ".join(f"{n} frames on {_channel_name(c)}"
                                     for c, n in copies.items())
                         + " are identical copies of them (a mirrored bus), skipped; "
                         "--can-channel chooses another")
        out[at:at] = extra
        return out


def _channel_name(channel: object) -> str:
    return printable(str(channel), 40)


def _unmatched(t_copy: NDArray[np.float64], p_copy: NDArray[np.uint8],
               t_main: NDArray[np.float64], p_main: NDArray[np.uint8],
               window: float = MIRROR_WINDOW_S) -> NDArray[np.bool_]:
    """Which frames of one message on another channel (times ``t_copy`` [s], payloads
    ``p_copy`` (n, length)) have no frame with the same payload on the decoded channel
    (``t_main``, ``p_main``) stamped within ``window`` [s] of them."""
    n = t_copy.size
    if n == 0:
        return np.zeros(0, dtype=bool)
    if t_main.size == 0:
        return np.ones(n, dtype=bool)
    order = np.argsort(t_main, kind="stable")
    t_main, p_main = t_main[order], p_main[order]
    lo = np.searchsorted(t_main, t_copy - window, side="left")
    hi = np.searchsorted(t_main, t_copy + window, side="right")
    found = np.zeros(n, dtype=bool)
    for k in range(int((hi - lo).max(initial=0))):
        j = lo + k
        inside = j < hi
        jj = np.minimum(j, t_main.size - 1)
        found |= inside & np.all(p_main[jj] == p_copy, axis=1)
    return ~found


def _payloads(data: list[bytes]) -> NDArray[np.uint8]:
    """Payloads of one message (all of the DBC's length) as an (n, length) array."""
    if not data:
        return np.zeros((0, 0), dtype=np.uint8)
    return np.frombuffer(b"".join(data), dtype=np.uint8).reshape(len(data), -1)


@dataclass(frozen=True)
class _TimeSkip:
    """Frames of one id's stream left out for their time: ``count`` of them from ``index``
    (indices into the stream), the first at time ``t`` [s], the running time then ``t_run``.

    ``kind``: ``nan`` (not a finite time); ``ahead`` (stamped after the frames that follow
    it; ``last`` is the first of those, which goes on from ``t_run``); ``behind`` (a frame
    not after ``t_run``, alone or one of a few); ``step`` (the time steps back and more than
    :data:`LOOKAHEAD` frames go on from there, a clock reset; ``last`` is the last of them,
    ``resumed`` the frame where the stream passes ``t_run`` again and is kept, or -1).
    """

    kind: str
    index: int
    count: int
    t: float
    t_run: float
    last: int = -1
    resumed: int = -1


def _longest_rise(values: list[float]) -> int:
    """Length of the longest strictly increasing subsequence of ``values``."""
    tails: list[float] = []
    for v in values:
        k = bisect.bisect_left(tails, v)
        tails[k:k + 1] = [v]
    return len(tails)


def _farther(ti: float, window: list[float], t_run: float) -> bool:
    """Whether a frame at ``ti`` [s] is farther out of line than the first of the following
    ``window`` times between ``t_run`` and ``ti``: farther from the middle of ``t_run`` and
    the first time after ``ti`` that follows them (the two frames' neighbours), or, with no
    such time, farther from ``t_run``. False where ``t_run`` is not finite (nothing before)."""
    first = next(((k, u) for k, u in enumerate(window) if u < ti), None)
    if first is None or not math.isfinite(t_run):
        return False
    k, u = first
    after = next((v for v in window[k + 1:] if v > ti), None)
    if after is None:
        return u - t_run < ti - t_run
    middle = 0.5 * (t_run + after)
    return abs(u - middle) < abs(ti - middle)


def _time_order(t: NDArray[np.float64], t_run: float = -math.inf,
                lookahead: int = LOOKAHEAD) -> tuple[NDArray[np.bool_], list[_TimeSkip]]:
    """Which frames of one id's stream to keep (``t`` [s] in file order, after a running time
    ``t_run`` [s]) so that the kept times strictly increase, and why the others are left out
    (in stream order).

    A frame is kept if its time is after the running time (the latest kept one), unless more
    of the next ``lookahead`` frames keep their order without it than with it (the longest
    rising run of their times after the running time): a frame stamped ahead of the frames
    that follow it is the outlier, not the rest of the stream, while a lone frame behind
    them does not count against it. Where both keep as many (a swapped pair, or the end of
    the stream), the frame farther from where it belongs is left out (:func:`_farther`).

    A frame at or before the running time is left out. If more than ``lookahead`` frames go
    on from it, behind the running time, and at most ``lookahead`` kept frames lie above its
    time, those kept frames were outliers after all: they are left out and the frames after
    the first of them judged again. Otherwise the time stepped back (a clock reset): its
    frames are left out until the stream passes the running time again, so the kept times
    stay on one clock, the log's first.
    """
    n = t.size
    finite = np.isfinite(t)
    if n == 0 or (finite.all() and t[0] > t_run and bool(np.all(t[1:] > t[:-1]))):
        return np.ones(n, dtype=bool), []
    # earliest of the next `lookahead` times (not finite: +inf): only a frame later than it
    # can be an outlier, so the look-ahead loop runs only there
    padded = np.concatenate([np.where(finite, t, np.inf), np.full(lookahead, np.inf)])
    soonest = sliding_window_view(padded[1:], lookahead).min(axis=1)[:n].tolist()
    times = t.tolist()
    keep = np.zeros(n, dtype=bool)
    kept: list[int] = []     # indices kept, in order
    skips: list[_TimeSkip] = []
    behind: list[int] = []   # the open stretch of frames behind t_run, going on in time
    stretch_run = t_run      # t_run when the stretch began
    t_first = t_run

    def close(resumed: int) -> None:
        if len(behind) > lookahead:
            skips.append(_TimeSkip("step", behind[0], len(behind), times[behind[0]],
                                   stretch_run, behind[-1], resumed))
        else:
            skips.extend(_TimeSkip("behind", j, 1, times[j], stretch_run) for j in behind)
        behind.clear()

    rejected: set[int] = set()  # frames found to be outliers after they were kept
    i = 0
    while i < n:
        ti = times[i]
        if i in rejected:
            pass
        elif not math.isfinite(ti):
            skips.append(_TimeSkip("nan", i, 1, ti, t_run))
        elif ti > t_run:
            back = None
            if soonest[i] < ti:
                window = [u for u in times[i + 1:i + 1 + lookahead]
                          if t_run < u < math.inf]
                without = _longest_rise(window)
                with_it = 1 + _longest_rise([u for u in window if u > ti])
                if without > with_it or (without == with_it and _farther(ti, window, t_run)):
                    back = next(j for j in range(i + 1, n) if t_run < times[j] < ti)
            if back is not None:
                skips.append(_TimeSkip("ahead", i, 1, ti, t_run, back))
            else:
                close(i)
                keep[i] = True
                kept.append(i)
                t_run = ti
        elif behind and ti <= times[behind[-1]]:  # not going on from the stretch: alone
            skips.append(_TimeSkip("behind", i, 1, ti, t_run))
        else:
            if not behind:
                stretch_run = t_run
            behind.append(i)
            if len(behind) == lookahead + 1:
                start = behind[0]
                above = [j for j in kept[-lookahead - 1:] if times[j] >= times[start]]
                if 0 < len(above) <= lookahead:
                    # the few kept frames above the stretch were outliers: left out, and the
                    # frames after the first of them judged again
                    del kept[len(kept) - len(above):]
                    keep[above] = False
                    t_run = times[kept[-1]] if kept else t_first
                    skips = [k for k in skips if k.index < above[0] or k.index in rejected]
                    rejected.update(above)
                    back = next(j for j in range(above[0] + 1, i + 1)
                                if j not in rejected and times[j] > t_run)
                    skips.extend(_TimeSkip("ahead", j, 1, times[j], t_run, back) for j in above)
                    behind.clear()
                    i = above[0] + 1
                    continue
        i += 1
    close(-1)
    skips.sort(key=lambda k: k.index)
    return keep, skips


def _channel_matches(channel: object, want: str) -> bool:
    """``can0`` matches channel index 0 (ASC/BLF number channels) but never ``can1``."""
    have = str(channel)
    if have == want:
        return True
    mh, mw = re.search(r"(\d+)$", have), re.search(r"(\d+)$", want)
    if not mh or not mw or int(mh.group(1)) != int(mw.group(1)):
        return False
    return have.isdigit() or want.isdigit()


_NO_CHANNEL = object()  # a message not seen yet: no channel decoded


@dataclass
class _Wanted:
    """One DBC message carrying wanted signals: its decoder and where its columns go; with no
    channel chosen, the channel it is decoded on (the first it came on), its frames on each
    channel, its latest frames there (``recent``: time [s], payload) and its frames on others
    still waiting for a copy there (``pending``: time, payload, channel)."""

    decoder: MessageDecoder
    columns: NDArray[np.intp]
    t_last: float = -math.inf
    channel: object = _NO_CHANNEL
    counts: Counter = field(default_factory=Counter)
    recent: deque = field(default_factory=lambda: deque(maxlen=_RECENT))
    pending: deque = field(default_factory=deque)
    refused: str | None = None

    @property
    def column_list(self) -> list[int]:
        return self.columns.tolist()


def _message_name(wanted: _Wanted) -> str:
    """``NAME (0xID)`` of a wanted message, as a log line shows its id."""
    return f"{wanted.decoder.message.name} (0x{wanted.decoder.message.frame_id:X})"


def _mix_error(source: str, wanted: _Wanted, channel: object, bad: int, copies: int) -> str:
    """Why ``wanted`` cannot be decoded with no channel chosen: ``bad`` of its ``copies``
    frames on ``channel`` are no copy of a frame on the channel it is decoded on."""
    name = _message_name(wanted)
    main = _channel_name(wanted.channel)
    counts = ", ".join(f"{_channel_name(c)} ({n} frames)" for c, n in wanted.counts.items())
    return (f"{source}: {name}, the message the speed is decoded from, comes on "
            f"{len(wanted.counts)} channels: {counts}, which are not copies of each other "
            f"({bad} of its {copies} frames on {_channel_name(channel)} have no frame with the "
            f"same payload on {main} within {MIRROR_WINDOW_S * 1e3:g} ms): decoding them "
            "together would mix two signals. "
            f"Choose one with --can-channel (e.g. --can-channel {main})")


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

    A log whose times step back by 2^32 µs (:data:`WRAP_S`) from one frame to the next, less
    the time between the two (up to :data:`WRAP_GAP_S`), has a 32-bit microsecond clock that
    wrapped around: the times from there on are unwrapped (``summary.notes`` says where).

    With no ``channel``, a wanted message is decoded on the first channel it comes on. Its
    frames on other channels are skipped if each is a copy (the same payload stamped within
    :data:`MIRROR_WINDOW_S`) of a frame there (a mirrored bus; ``summary.copies``); if one is
    not, the decoder raises :class:`InputError` naming the channels (two signals that
    decoding must not mix: ``channel`` chooses one), and decodes that message no more.

    A frame whose time is not after its id's running time (the latest kept) is skipped. A
    log's frames are judged with the frames that follow them too (:func:`_time_order`): a
    frame stamped ahead of the next :data:`LOOKAHEAD` frames of its id, which go on at the
    old clock, is the outlier and is skipped, not the rest of the log; where the time steps
    back and goes on from there (a clock reset), the frames before the old clock's time are
    skipped and the step is named in ``summary.clock_steps``.

    ``feed(msg)`` (live buses) and ``feed_many(msgs)`` (logs, vectorised) give identical
    samples and share state, except where a frame is stamped ahead of the frames after it:
    ``feed`` cannot look ahead, so it keeps that frame and skips the ones behind it.
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
        self.summary = CanDecodeSummary(source=source)
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
        self._wraps = 0                              # wrap-arounds of the clock so far
        self._t_prev = math.nan                      # the previous frame's unwrapped time
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

    def _at(self, position: int) -> str:
        """``line N`` or ``frame N`` of ``position``."""
        return f"{self.position_kind} {position}"

    def _time_note(self, wanted: _Wanted, skip: _TimeSkip, t_after: float = math.nan,
                   after: str = "") -> str:
        """Why the frame of ``skip`` (kind ``nan``, ``behind`` or ``ahead``) is left out."""
        name = _message_name(wanted)
        if skip.kind == "nan":
            return f"{name} time {skip.t} is not a finite number: skipped"
        if skip.kind == "ahead":
            before = f"{skip.t_run:.6f} s before, " if math.isfinite(skip.t_run) else ""
            return (f"{name} time {skip.t:.6f} s jumps ahead of its frames around it ({before}"
                    f"{t_after:.6f} s after, at {after}): an outlier, skipped")
        return (f"{name} time {skip.t:.6f} s is not after its frames before it "
                f"({skip.t_run:.6f} s): out of order, skipped")

    def _report_time_skips(self, wanted: _Wanted, skips: list[_TimeSkip],
                           t: NDArray[np.float64], where: list[int]) -> None:
        """Count the frames ``skips`` leaves out (``t``, ``where``: times and positions of the
        stream) and say why: a frame in the examples, a clock step in ``clock_steps``."""
        s = self.summary
        name = _message_name(wanted)
        for skip in skips:
            s.non_monotonic += skip.count
            at = self.where(where[skip.index])
            if skip.kind != "step":
                after = self._at(where[skip.last]) if skip.kind == "ahead" else ""
                s.note(at, self._time_note(wanted, skip, float(t[skip.last]), after))
                continue
            if len(s.clock_steps) >= MAX_EXAMPLES:
                continue
            back = skip.t_run - skip.t
            wrap = ""
            gap = WRAP_S - back  # the time between the frames, were it a wrap-around
            if abs(gap) < 10 * WRAP_GAP_S:  # near 2^32 µs: say why it is no wrap-around
                wrap = (f"; not unwrapped: as a 32-bit microsecond clock wrapping around "
                        f"(2^32 µs = {WRAP_S:.6f} s) it would put {gap:.3f} s between two "
                        f"frames of the log, not within -{WRAP_TOLERANCE_S:g} .. "
                        f"{WRAP_GAP_S:g} s")
            text = (f"{at}: {name} time steps back {back:.6f} s (from {skip.t_run:.6f} to "
                    f"{skip.t:.6f} s) and goes on from there (a clock reset{wrap}): its "
                    f"{skip.count} frames up to {self._at(where[skip.last])} "
                    f"({100 * skip.count / t.size:.0f} % of its {t.size} frames) are before "
                    "the time already decoded and skipped")
            if skip.resumed >= 0:
                text += (f"; decoding goes on at {self._at(where[skip.resumed])}, where its "
                         "time passes the old clock again")
            else:
                text += (f", to the end of its frames: the speed samples of all {skip.count} "
                         "are left out; split the log here to decode them")
            s.clock_steps.append(text)

    # -- per-frame screening (shared by feed and feed_many) ---------------------------------
    def _unwrap(self, t: float) -> float:
        """The time ``t`` [s] of the frame being screened on the log's clock unwrapped: with
        :data:`WRAP_S` added for each wrap-around of a 32-bit microsecond clock before it."""
        if not math.isfinite(t):
            return t
        raw = t
        t += self._wraps * WRAP_S
        back = self._t_prev - t  # NaN for the first frame: no step
        if -WRAP_TOLERANCE_S <= WRAP_S - back <= WRAP_GAP_S:
            self._wraps += 1
            if len(self.summary.notes) < MAX_EXAMPLES:
                self.summary.notes.append(
                    f"{self.where()}: the time steps back {back:.6f} s, to {raw:.6f} s: a "
                    f"32-bit microsecond clock wrapping around (2^32 µs = {WRAP_S:.6f} s) "
                    f"{(WRAP_S - back) * 1e3:.1f} ms after the frame before; "
                    f"{WRAP_S:.6f} s added to the times from here on")
            t += WRAP_S
        elif self._wraps and abs(back + WRAP_S) <= WRAP_TOLERANCE_S:
            return t - WRAP_S  # stamped before the latest wrap-around, logged after it
        self._t_prev = t
        return t

    def _screen(self, msg) -> tuple[_Wanted, float] | None:
        """The wanted message of ``msg`` and its time [s] unwrapped, or None (counted)."""
        s = self.summary
        s.frames += 1
        t = self._unwrap(float(msg.timestamp))
        if math.isfinite(t):
            if not math.isfinite(s.t_first):
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
        return wanted, t

    def _copy(self, wanted: _Wanted, channel: object, n: int = 1) -> None:
        """Count ``n`` frames of ``wanted`` on ``channel`` as copies of its decoded ones."""
        name = _message_name(wanted)
        copies = self.summary.copies.setdefault(name, (wanted.channel, Counter()))[1]
        copies[channel] += n

    def _refuse(self, wanted: _Wanted, channel: object, bad: int, copies: int) -> None:
        text = _mix_error(self.summary.source, wanted, channel, bad, copies)
        wanted.refused = text
        self.summary.notes.append(text)
        raise InputError(text)

    def _on_channel(self, wanted: _Wanted, channel: object, t: float, data: bytes) -> bool:
        """Whether a frame of ``wanted`` (time ``t`` [s], payload ``data``) on ``channel``
        is decoded: with no channel chosen, only on the first the message came on. A frame
        on another is skipped as a copy once one is found there; InputError where none is
        found within :data:`MIRROR_WINDOW_S` (see :class:`SpeedDecoder`)."""
        if self.channel is not None:
            return True
        if wanted.refused is not None:
            return False
        wanted.counts[channel] += 1
        if wanted.channel is _NO_CHANNEL:
            wanted.channel = channel
        main = channel == wanted.channel
        waiting: deque = deque()
        for tc, pc, cc in wanted.pending:
            if main and pc == data and abs(tc - t) <= MIRROR_WINDOW_S:
                self._copy(wanted, cc)
            elif tc < t - MIRROR_WINDOW_S:  # its copy would have come by now
                self._refuse(wanted, cc, 1, wanted.counts[cc])
            else:
                waiting.append((tc, pc, cc))
        wanted.pending = waiting
        if main:
            wanted.recent.append((t, data))
            return True
        self.summary.other_channel += 1
        if any(pm == data and abs(tm - t) <= MIRROR_WINDOW_S for tm, pm in wanted.recent):
            self._copy(wanted, channel)
        else:
            wanted.pending.append((t, data, channel))
        return False

    def _on_channel_many(self, wanted: _Wanted, t: NDArray[np.float64],
                         payload: NDArray[np.uint8], channels: list) -> NDArray[np.bool_] | None:
        """Which frames of ``wanted`` (times ``t`` [s], payloads, channels, in log order) are
        decoded, as :meth:`_on_channel` says frame by frame; None: all of them."""
        if self.channel is not None or not channels:
            return None
        if wanted.refused is not None:
            return np.zeros(len(channels), dtype=bool)
        wanted.counts.update(channels)
        if wanted.channel is _NO_CHANNEL:
            wanted.channel = channels[0]
        if len(wanted.counts) == 1:
            wanted.recent.extend(zip(t[-_RECENT:].tolist(), map(bytes, payload[-_RECENT:]),
                                     strict=True))
            return None
        main = np.fromiter((c == wanted.channel for c in channels), dtype=bool,
                           count=len(channels))
        t_main = np.concatenate([[tm for tm, _ in wanted.recent], t[main]])
        p_main = np.concatenate([_payloads([pm for _, pm in wanted.recent]).reshape(
            -1, payload.shape[1]), payload[main]])
        others = [*wanted.pending, *((t[i], bytes(payload[i]), channels[i])
                                     for i in np.flatnonzero(~main))]
        wanted.pending.clear()
        by_channel: dict[object, list[int]] = {}
        for k, (_, _, c) in enumerate(others):
            by_channel.setdefault(c, []).append(k)
        for c, ks in by_channel.items():
            t_copy = np.array([others[k][0] for k in ks], dtype=np.float64)
            bad = _unmatched(t_copy, _payloads([others[k][1] for k in ks]), t_main, p_main)
            if bad.any():
                self._refuse(wanted, c, int(bad.sum()), wanted.counts[c])
            self._copy(wanted, c, len(ks))
        self.summary.other_channel += int((~main).sum())
        wanted.recent.extend(zip(t_main[-_RECENT:].tolist(), map(bytes, p_main[-_RECENT:]),
                                 strict=True))
        return main

    def feed(self, msg) -> tuple[float, float] | None:
        """Screen and decode one ``can.Message``; the (t [s], speed [m/s]) sample it yields,
        or None (other id, bad frame, or not every signal seen yet). Same rules and results
        as :meth:`feed_many`, in scalar Python for per-frame speed."""
        screened = self._screen(msg)
        if screened is None:
            return None
        wanted, t = screened
        data = bytes(msg.data)
        if not self._on_channel(wanted, msg.channel, t, data):
            return None
        s = self.summary
        if not (math.isfinite(t) and t > wanted.t_last):
            s.non_monotonic += 1
            kind = "behind" if math.isfinite(t) else "nan"
            s.note(self.where(), self._time_note(wanted, _TimeSkip(kind, 0, 1, t, wanted.t_last)))
            return None
        wanted.t_last = t
        values = wanted.decoder.decode_one(data)
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
        batches: dict[int, tuple[list[float], list[bytes], list[int], list[int], list]] = {}
        # an interrupt raised between next() and the appends, or in the decode at the end,
        # lost every frame read (a partial batch); noted instead, it ends the loop cleanly
        with interrupts_deferred() as interrupt:
            self._read(iter(messages), batches, interrupt, progress, resume)
            t, v = self._process(batches)
        if interrupt.requested:  # in the read, or during the decode at its end
            self.summary.interrupted = True
        return SpeedSeries(t, v, source=self.summary.source, signals=self.signal_names,
                           scale=self.scale, summary=self.summary)

    def _read(self, iterator: Iterator, batches: dict, interrupt: InterruptFlag,
              progress: bool, resume: Callable[[], Iterator] | None) -> None:
        """Screen messages into ``batches`` until the end, an unreadable record without
        ``resume``, or an interrupt (``interrupt`` noted, or raised by the iterator itself:
        ``summary.interrupted``)."""
        seq = 0
        bar = _progress(progress, self.summary.source)
        while True:
            if interrupt.requested:
                break
            try:
                msg = next(iterator)
            except StopIteration:
                break
            except KeyboardInterrupt:  # raised by the iterator itself (a reader of its own)
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
            screened = self._screen(msg)
            if screened is None:
                continue
            wanted, t = screened
            ts, data, order, where, channels = batches.setdefault(id(wanted),
                                                                  ([], [], [], [], []))
            ts.append(t)
            data.append(bytes(msg.data))
            order.append(seq)
            where.append(self.position())
            channels.append(msg.channel)
        if bar is not None:
            bar.update(self.summary.frames - bar.n)
            bar.close()

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
    def _process(self, batches: dict[int, tuple[list[float], list[bytes], list[int], list[int],
                                                  list]]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        self._flush()
        by_id = {id(w): w for w in self._wanted.values()}
        ev_t, ev_order, ev_rows, ev_msg = [], [], [], []
        for m_index, (key, (ts, data, order, where, channels)) in enumerate(batches.items()):
            wanted = by_id[key]
            t = np.asarray(ts, dtype=np.float64)
            payload = _payloads(data)
            on = self._on_channel_many(wanted, t, payload, channels)
            if on is not None:
                t, payload = t[on], payload[on]
                order = np.asarray(order)[on]
                where = np.asarray(where)[on].tolist()
            mono, skips = _time_order(t, wanted.t_last)
            self._report_time_skips(wanted, skips, t, where)
            if mono.any():
                wanted.t_last = float(t[mono][-1])
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
    from vipm_track.progress import progress_bar

    return progress_bar(desc=f"decoding {Path(what).name}", unit=" frames",
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
               on_sample: Callable[[float, float], None] | None = None,
               source: str | None = None) -> tuple[SpeedSeries, DecodeSummary]:
    """Speed series decoded live from a python-can ``bus`` (e.g. ``can.Bus(interface=
    "virtual", channel=...)``), message by message; ``on_sample(t, speed_mps)`` is called for
    each sample as it arrives. Stops as :func:`iter_bus` says, or at an interrupt (Ctrl-C),
    keeping the samples decoded before it (``summary.interrupted`` set; the interrupt goes
    on where there are none, as :func:`decode_can_log`'s). ``source`` names the bus in the
    summary (default: python-can's ``channel_info``, "unknown" for some interfaces)."""
    decoder = SpeedDecoder(dbc, signals, combine=combine, channel=channel, scale=scale,
                           source=source or f"bus {getattr(bus, 'channel_info', bus)}")
    try:
        for msg in iter_bus(bus, duration, max_messages, idle_timeout):
            sample = decoder.feed(msg)
            if sample is not None and on_sample is not None:
                on_sample(*sample)
    except KeyboardInterrupt:
        decoder.summary.interrupted = True
    series = decoder.series()
    if decoder.summary.interrupted and len(series) == 0:
        raise KeyboardInterrupt
    return series, decoder.summary
