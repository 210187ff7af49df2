"""Onboard monitoring at the pace of a camera: ``LiveMonitor`` takes frames and wheel speed
as they arrive (``push_frame``, ``push_speed`` / ``push_can``, from any thread, never
blocking) and runs the two-frame estimator, the EKF and the drift monitor in its own thread
on what it can keep up with.

Never falling behind: the monitor holds only the newest frame and the one before it. When
its thread is free it takes that pair (two consecutive frames, so the estimator's
assumptions hold) and every frame that arrived meanwhile and was not part of a pair is
dropped and counted. Each processed pair gives one row (``on_row``, a :class:`LiveRow`) and
each change of state one event (``on_event``, a JSON-ready dict), both called from the
monitor's thread.

A watchdog puts the monitor on HOLD, with the reason, when no frame arrived for
``camera_timeout_s`` or, where wheel speed is expected, no speed sample for
``speed_timeout_s``; it leaves HOLD when the data returns. Frames further apart than
``max_pair_gap_s`` are not paired (the first frame after an outage starts afresh).

All times pushed are seconds on one clock (frame times and speed times alike); latency
and the watchdog use this machine's monotonic clock. See ``docs/live.md`` for an example
that feeds it from ROS 2.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vipm_track.filters.ekf_state import EkfConfig, FilterState
from vipm_track.filters.monitor import event_dict
from vipm_track.filters.monitor_online import OnlineMonitor, SpeedBuffer
from vipm_track.filters.monitor_table import MONITOR_COLUMNS, MONITOR_TABLE, monitor_row
from vipm_track.filters.monitor_types import MonitorOutput
from vipm_track.filters.nominal import NominalCalibration

from .estimator import TwoFrameEstimator
from .estimator_config import EstimatorConfig
from .measurement import PairMeasurement
from .pair_chain import PairChain
from .pipeline import WRONG_SIZE, prepare_image
from .rig import Rig
from .sources import Frame, _to_grey
from .statuses import NO_ESTIMATE
from .table import TableColumns

#: columns a live row adds after the monitor's: the pair's first frame, frames dropped
#: since the previous row, and the time from the frame's arrival to its row [s]
LIVE_COLUMNS: tuple[str, ...] = (*MONITOR_COLUMNS, "prev_frame", "dropped", "latency_s")
#: The concise live table: the monitor's concise columns and which frames were paired,
#: dropped and how late the row came.
LIVE_TABLE = TableColumns("live", LIVE_COLUMNS,
                          (*MONITOR_TABLE.concise, "prev_frame", "dropped", "latency_s"))

#: a previous result seeds the next pair (tracking) if it is at most this old [s]
_TRACK_WITHIN_S = 1.0


@dataclass(frozen=True)
class LiveRow:
    """One processed pair: its measurement, the EKF state, the monitor's verdict, the
    estimator's result (None where the images could not be used), the current frame's image,
    the table ``row`` (``LIVE_COLUMNS``) and the latency from frame arrival to row [s]."""

    measurement: PairMeasurement
    state: FilterState
    output: MonitorOutput
    result: Any
    image: NDArray[np.uint8] | None
    row: dict[str, Any]
    latency_s: float


@dataclass(frozen=True)
class LiveState:
    """The monitor's state now: ``state`` (one of ``filters.monitor_types.STATES``), its
    ``reason``, the frame and time [s] it was decided at, and the EKF's mount estimate
    (pitch rad, roll rad, height m; None before the filter starts)."""

    state: str
    reason: str
    frame: int | None = None
    t: float | None = None
    mount: NDArray[np.float64] | None = None


@dataclass
class LiveStats:
    """Counts and timing of a live run (:meth:`LiveMonitor.summary`)."""

    seen: int = 0
    processed: int = 0
    used: int = 0
    rejected: int = 0
    latencies: list[float] = field(default_factory=list)
    states: Counter = field(default_factory=Counter)
    #: the processed pairs' statuses (``ok`` or why not)
    statuses: Counter = field(default_factory=Counter)
    wall_s: float = 0.0
    cpu_s: float = 0.0
    #: seconds from the last frame's arrival to the end of the run (the last rows written)
    tail_s: float = float("nan")
    first_recalibrate: dict[str, Any] | None = None

    @property
    def dropped(self) -> int:
        """Frames that arrived but were not part of a processed pair."""
        return self.seen - self.used

    def latency(self, q: float) -> float:
        """The ``q``-quantile of frame arrival → row [s] (NaN without rows)."""
        return float(np.quantile(self.latencies, q)) if self.latencies else float("nan")

    @property
    def cpu_share(self) -> float:
        """Process CPU time over wall time (1 = one core busy throughout)."""
        return self.cpu_s / self.wall_s if self.wall_s > 0 else float("nan")

    def line(self) -> str:
        """One-line summary: frames seen / processed / dropped, latency, CPU share."""
        rate = self.processed / self.wall_s if self.wall_s > 0 else float("nan")
        latency = (f"latency p50 {self.latency(0.5) * 1e3:.0f} ms, p95 "
                   f"{self.latency(0.95) * 1e3:.0f} ms" if self.latencies else "no rows")
        text = (f"{self.seen} frames seen, {self.processed} pairs processed ({rate:.2f}/s), "
                f"{self.dropped} frames dropped; {latency}; CPU {100 * self.cpu_share:.0f} % of "
                f"one core over {self.wall_s:.1f} s; ended {self.tail_s:.2f} s after the last "
                "frame")
        if self.rejected:
            text += f"; {self.rejected} frames rejected"
        return text


@dataclass
class _Arrived:
    """A frame as pushed: index, time [s], grey image, arrival (monotonic s)."""

    index: int
    t: float
    image: NDArray[np.uint8]
    arrived: float


#: a wheel-speed sample further than this from the frames' clock [s] is on another clock
#: (a bus adapter's own time stamps: 1.8·10⁹ s off, the height test off all run, unsaid)
SPEED_CLOCK_TOLERANCE_S = 10.0

#: the monitor's states that call for action: said also while the watchdog holds
ALARMS = frozenset({"DRIFTING", "RECALIBRATE"})


def _held_for_speed(out: MonitorOutput, why: str) -> MonitorOutput:
    """``out`` while the wheel speed the run expects is silent (``why``): no verdict of
    calibration without the height (HOLD, as the watchdog announced), but the pitch and
    roll's alarms stand, their reason saying the height was not tested."""
    if out.state in ALARMS:
        return replace(out, reason=f"{out.reason}; {why}: height not tested")
    return replace(out, state="HOLD", reason=why, estimate=None, interval95=None, event=None)


class LiveMonitor:
    """The online chain (module doc): estimator → EKF → drift monitor on a live stream.

    Parameters
    ----------
    rig : the camera of the frames pushed (their size is checked) and the estimator's
        nominal pose, height (its scale) and readout (``NominalCalibration.rig``: the
        nominal's).
    nominal : the calibration judged against.
    config : estimator settings (default: ``EstimatorConfig()``).
    can_decoder : a ``filters.speed_decoder.SpeedDecoder`` for :meth:`push_can`.
    expect_speed : wheel speed will be pushed: its silence puts the monitor on HOLD.
    camera_timeout_s, speed_timeout_s : silence [s] after which the watchdog holds.
    max_pair_gap_s : frames further apart [s] are not paired (default: ``camera_timeout_s``).
    fps : processed pairs per second the monitor assumes (None: measured at the start).
    monitor_options : ``filters.monitor_types.MonitorConfig`` fields (false-alarm rate, road).
    on_row, on_event : called with each :class:`LiveRow` and each event dict.
    watchdog : HOLD where no frame or wheel speed came for the timeouts of wall time (False:
        a recording fed as fast as it is processed, whose silences are not the wall's).
    """

    def __init__(
        self,
        rig: Rig,
        nominal: NominalCalibration,
        config: EstimatorConfig | None = None,
        *,
        can_decoder: Any = None,
        expect_speed: bool = False,
        camera_timeout_s: float = 1.0,
        speed_timeout_s: float = 1.0,
        max_pair_gap_s: float | None = None,
        fps: float | None = None,
        monitor_options: dict[str, Any] | None = None,
        on_row: Callable[[LiveRow], Any] | None = None,
        on_event: Callable[[dict[str, Any]], Any] | None = None,
        watchdog: bool = True,
    ) -> None:
        if not (camera_timeout_s > 0 and speed_timeout_s > 0):
            raise ValueError("the watchdog's timeouts must be > 0 s")
        self.camera, self.nominal = rig.camera, nominal
        self.estimator = TwoFrameEstimator(rig, config)
        # frames may be dropped between pairs: a result seeds one ending within 1 s of it
        self._chain = PairChain(
            self.estimator, track_within_s=_TRACK_WITHIN_S,
            max_acceleration_mps2=self.estimator.config.max_acceleration_mps2)
        self.speed = SpeedBuffer()
        self.online = OnlineMonitor(nominal, EkfConfig(height_m=nominal.height_m),
                                    dict(monitor_options or {}), fps=fps, speed=self.speed)
        self.can_decoder = can_decoder
        self.expect_speed = expect_speed or can_decoder is not None
        self.camera_timeout_s, self.speed_timeout_s = camera_timeout_s, speed_timeout_s
        self.max_pair_gap_s = camera_timeout_s if max_pair_gap_s is None else max_pair_gap_s
        self.on_row, self.on_event = on_row, on_event
        self.watchdog = watchdog
        self.stats = LiveStats()
        self._cond = threading.Condition()
        self._newest: _Arrived | None = None
        self._before: _Arrived | None = None
        self._fresh = False
        self._next_index = 0
        self._last_pair_end: int | None = None
        #: frame → (its pair's frames, estimate, frames dropped before it, the watchdog's
        #: speed HOLD reason when it was processed)
        self._waiting: dict[int, tuple[_Arrived, _Arrived, Any, int, str]] = {}
        self._holds: dict[str, str] = {}
        self._reported: str | None = None
        self._watchdog_held = False  # the last event announced is the watchdog's HOLD
        self._state = LiveState("UNCALIBRATED", "waiting for frames")
        self._last_frame_at: float | None = None
        self._last_speed_at: float | None = None
        #: the last wheel-speed sample's time less the frames' clock [s] where it was beyond
        #: SPEED_CLOCK_TOLERANCE_S (None: the samples are on the frames' clock)
        self._speed_off_clock: float | None = None
        self._started_at = time.monotonic()
        self._stop = threading.Event()
        self._drain = True
        self._thread: threading.Thread | None = None
        self._ended = False  # the thread has left its loop (set under _cond, then notified)
        self.failure: BaseException | None = None
        self._clock: tuple[float, float] = (0.0, 0.0)

    # --- feeding --------------------------------------------------------------------------

    def push_frame(self, image: NDArray, t: float, index: int | None = None) -> None:
        """A frame (grey or BGR array of the camera's size) taken at ``t`` [s]; ``index``: its
        number in the stream (default: one after the last). Returns at once."""
        if image.ndim == 3:
            image = _to_grey(image)
        now = time.monotonic()
        with self._cond:
            if index is None:
                index = self._next_index
            self._next_index = index + 1
            self._before, self._newest = self._newest, _Arrived(int(index), float(t), image, now)
            self._fresh = True
            self._last_frame_at = now
            self.stats.seen += 1
            self._cond.notify_all()

    def wait_taken(self, timeout: float | None = None) -> bool:
        """Block until the newest frame pushed has been taken (or found unpairable) by the
        monitor's thread, or it stopped: a recording read as fast as it is processed drops
        nothing. False on ``timeout``."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._fresh or self._stop.is_set()
                                       or self._thread is None or self._ended, timeout)

    def push_speed(self, t: float, speed_mps: float) -> None:
        """A wheel-speed sample: ``t`` [s, the frames' clock], speed [m/s, a magnitude or
        signed]. Returns at once."""
        now = time.monotonic()
        frames_t = self._now_t(now)
        if frames_t is not None and abs(float(t) - frames_t) > SPEED_CLOCK_TOLERANCE_S:
            # stamped on another clock (an adapter's own): it can never meet a frame, so it
            # does not count as the wheel speed arriving
            self._speed_off_clock = float(t) - frames_t
            return
        if self.speed.push(float(t), float(speed_mps)):
            self._last_speed_at = now
            self._speed_off_clock = None

    def push_can(self, msg: Any) -> None:
        """A ``can.Message`` (timestamp on the frames' clock), decoded by ``can_decoder``."""
        if self.can_decoder is None:
            raise ValueError("push_can needs a can_decoder (filters.speed_decoder.SpeedDecoder)")
        sample = self.can_decoder.feed(msg)
        if sample is not None:
            self.push_speed(*sample)

    # --- reading --------------------------------------------------------------------------

    def state(self) -> LiveState:
        """The state now: HOLD with the watchdog's reason while data is missing, else the
        monitor's latest verdict."""
        holds = dict(self._holds)
        current = self._state
        if current.state in ALARMS and set(holds) == {"speed"}:
            # the pitch and roll's alarm stands through the wheels' silence (_held_for_speed)
            return replace(current, reason=f"{current.reason}; {holds['speed']}")
        if holds:
            return LiveState("HOLD", "; ".join(holds.values()), current.frame, current.t,
                             current.mount)
        return current

    # --- running --------------------------------------------------------------------------

    def start(self) -> LiveMonitor:
        """Start the monitor's thread (frames pushed before are kept)."""
        self._started_at = time.monotonic()
        self._clock = (time.monotonic(), time.process_time())
        self._ended = False
        self._thread = threading.Thread(target=self._run, name="vipm-live-monitor", daemon=True)
        self._thread.start()
        return self

    def stop(self, drain: bool = True, timeout: float | None = None) -> LiveStats:
        """Stop the thread: with ``drain``, after the pair waiting now is processed; the
        statistics of the run. A failure inside the thread is raised here."""
        self._drain = drain
        self._stop.set()
        with self._cond:
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout)
        end = time.monotonic()
        self.stats.wall_s = end - self._clock[0]
        if self._last_frame_at is not None:
            self.stats.tail_s = end - self._last_frame_at
        self.stats.cpu_s = time.process_time() - self._clock[1]
        if self.failure is not None:
            raise self.failure
        return self.stats

    def __enter__(self) -> LiveMonitor:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop(drain=exc[0] is None)

    def _run(self) -> None:
        try:
            while True:
                pair = self._take(0.05)
                if self.watchdog:
                    self._watchdog()
                if pair is not None:
                    self._process(*pair)
                elif self._stop.is_set():
                    break
                if self._stop.is_set() and not self._drain:
                    break
            for decided in self.online.flush():
                self._emit(*decided)
        except BaseException as exc:  # raised again by stop() in the caller's thread
            self.failure = exc
        finally:
            with self._cond:  # a reader waiting in wait_taken() sees the thread has ended
                self._ended = True
                self._cond.notify_all()

    def _take(self, timeout: float) -> tuple[_Arrived, _Arrived] | None:
        """The newest pair of consecutive frames not processed yet, or None."""
        with self._cond:
            if not self._fresh and not self._stop.is_set():
                self._cond.wait(timeout)
            if not self._fresh:
                return None
            self._fresh = False
            self._cond.notify_all()
            a, b = self._before, self._newest
            if (a is None or b is None or b.index != a.index + 1
                    or not 0 < b.t - a.t <= self.max_pair_gap_s):
                return None
            return a, b

    # --- one pair -------------------------------------------------------------------------

    def _process(self, a: _Arrived, b: _Arrived) -> None:
        stats = self.stats
        stats.processed += 1
        stats.used += 1 + (a.index != self._last_pair_end)
        dropped = 0 if self._last_pair_end is None else max(0, a.index - self._last_pair_end - 1)
        self._last_pair_end = b.index
        dt = b.t - a.t
        result: Any = None
        try:
            prev = prepare_image(Frame(a.index, a.t, a.image), self.camera)
            curr = prepare_image(Frame(b.index, b.t, b.image), self.camera)
        except ValueError:
            h, w = b.image.shape[:2]
            status = f"{WRONG_SIZE} {w}×{h} (camera {self.camera.width}×{self.camera.height})"
            stats.rejected += 1
        else:
            result, _ = self._chain.estimate(prev, curr, b.t, dt)
            status = result.status
        stats.statuses[status] += 1
        m = result.to_measurement(b.index, b.t) if status == "ok" else None
        if m is None:
            m = PairMeasurement(b.index, b.t, np.full(7, np.nan), np.full((7, 7), np.nan),
                                self.nominal.height_m,
                                status if status != "ok" else NO_ESTIMATE)
        # the monitor judges the pair's pitch and roll without the wheel speed (its height
        # then goes untested, as `monitor` across a gap); only the verdict is held (_emit)
        self._waiting[b.index] = (a, b, result, dropped, self._holds.get("speed", ""))
        for decided in self.online.step(m, a.t):
            self._emit(*decided)

    def _emit(self, m: PairMeasurement, state: FilterState, out: MonitorOutput) -> None:
        a, b, result, dropped, speed_hold = self._waiting.pop(m.frame)
        if speed_hold:
            out = _held_for_speed(out, speed_hold)
        latency = time.monotonic() - b.arrived
        row = monitor_row(m, state, out)
        row.update(prev_frame=a.index, dropped=dropped, latency_s=latency)
        self.stats.latencies.append(latency)
        self.stats.states[out.state] += 1
        mount = None if out.mount is None else np.asarray(out.mount, dtype=float)
        self._state = LiveState(out.state, out.reason, m.frame, m.t, mount)
        if out.state == "RECALIBRATE" and self.stats.first_recalibrate is None:
            self.stats.first_recalibrate = {"t": m.t, "frame": m.frame, "reason": out.reason}
        if self.on_row is not None:
            self.on_row(LiveRow(m, state, out, result, b.image, row, latency))
        if self._holds:
            # the watchdog's HOLD stands while data is missing (a first pair that finished
            # after the wheel speed fell silent said "data back" for data that never came);
            # an alarm the pitch and roll raise meanwhile is said at once
            if out.state in ALARMS and (out.state != self._reported or out.event is not None):
                self._announce(self._event(m, out, out.reason))
            elif out.state == "HOLD" and self._reported != "HOLD":  # an alarm said meanwhile
                self._announce(self._event(m, out, out.reason))
                self._watchdog_held = True
        elif self._watchdog_held and out.state != "HOLD":
            # the data returned after a watchdog HOLD: say what the monitor says now
            self._announce(self._event(m, out, f"data back; {out.reason}"))
        elif out.event is not None and (out.state != self._reported or out.state != "HOLD"):
            # also an event within a state ("pitch reads off too" while RECALIBRATE); not a
            # second HOLD after the watchdog's
            self._announce(out.event)

    @staticmethod
    def _event(m: PairMeasurement, out: MonitorOutput, reason: str) -> dict[str, Any]:
        """The event of ``out`` (one of its own where its state changed at it) with
        ``reason``."""
        event = dict(out.event) if out.event is not None else event_dict(
            m.t, m.frame, out.state, "", out.estimate, out.interval95, out.mount)
        event["reason"] = reason
        return event

    # --- watchdog -------------------------------------------------------------------------

    def _watchdog(self) -> None:
        now = time.monotonic()
        since_frame = now - (self._last_frame_at or self._started_at)
        camera = ""
        if since_frame > self.camera_timeout_s:
            camera = (f"camera silent for {since_frame:.1f} s" if self._last_frame_at
                      else f"no frame from the camera in {since_frame:.1f} s")
        speed = ""
        if self.expect_speed:
            since_speed = now - (self._last_speed_at or self._started_at)
            if since_speed > self.speed_timeout_s and self._speed_off_clock is not None:
                speed = (f"wheel speed stamped {self._speed_off_clock:+.1f} s from the frames' "
                         "clock: no sample meets a frame")
            elif since_speed > self.speed_timeout_s:
                speed = (f"wheel speed silent for {since_speed:.1f} s" if self._last_speed_at
                         else f"no wheel speed in {since_speed:.1f} s")
        for key, reason in (("camera", camera), ("speed", speed)):
            if reason and key not in self._holds:
                self._holds[key] = reason
                # the wheels' silence holds only the height: an alarm of the pitch and roll
                # stands (its rows say the height went untested), no HOLD said over it
                over_alarm = key == "speed" and self._reported in ALARMS
                if self._reported != "HOLD" and not over_alarm:
                    # the watchdog's own: no estimate behind it
                    self._announce(event_dict(self._now_t(now), self._state.frame, "HOLD",
                                              reason))
                    self._watchdog_held = True
            elif not reason:
                self._holds.pop(key, None)

    def _now_t(self, now: float) -> float | None:
        """Time now on the frames' clock [s]: the newest frame's plus the time since it came
        (None before any frame)."""
        newest = self._newest
        return None if newest is None else round(newest.t + (now - newest.arrived), 6)

    def _announce(self, event: dict[str, Any]) -> None:
        self._reported = event["state"]
        self._watchdog_held = self._watchdog_held and event["state"] == "HOLD"
        if self.on_event is not None:
            self.on_event(event)


__all__ = ["LIVE_COLUMNS", "LiveMonitor", "LiveRow", "LiveState", "LiveStats"]
