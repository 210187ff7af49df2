"""The EKF and the drift monitor run online on pairs that may skip frames (a live camera whose
estimator drops frames when it is busy): ``OnlineMonitor.step(pair, t_prev)`` judges each
pair as soon as it is in, from the wheel-speed samples pushed so far (``SpeedBuffer``).

A processed pair (k−1, k) is two consecutive frames, but the pair before it may end long
before k−1. Both floors below take that as they are:

- the EKF (``filters.ekf``) clones its planar pose at every step, and a pair measures the
  motion since the clone: where frames were dropped, the filter is first stepped to frame
  k−1 without a measurement (a prediction), so the clone sits where the pair begins;
- the monitor inputs (``filters.monitor_inputs``) of frame k are computed from the pair and
  the row before it, which is the pair of frame k−1 where that was processed and otherwise
  a placeholder at frame k−1's time: the wheel distance, the standstill and the body's
  change use the pair's own interval. The neighbour test (``inconsistent_pairs``) compares
  a pair with the one before it only, since a live verdict does not wait for the next.

The monitor's frame rate (false-alarm run length, calibration time in frames) is the rate
of *processed* pairs: given, or measured on the first ``warmup_pairs`` pairs, which are then
judged together.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from .ekf import ExtrinsicsEKF
from .ekf_state import EkfConfig, FilterState
from .monitor import DriftMonitor
from .monitor_inputs import forward_camera_options, inputs_from_measurements, mount_from_state
from .monitor_types import MonitorConfig, MonitorInput, MonitorOutput
from .nominal import NominalCalibration
from .wheel_speed import SpeedSeries, interpolate_speed

FloatArray = NDArray[np.float64]

#: status of the placeholder row standing for a frame k−1 whose own pair was not processed
NOT_PROCESSED = "not processed"


class SpeedBuffer:
    """The latest wheel-speed samples (t [s, camera clock], speed [m/s]), at most
    ``keep_s`` seconds of them; a sample not after the last one is ignored (counted).
    Pushed from one thread (a bus reader) and read from another (the estimator's)."""

    def __init__(self, keep_s: float = 30.0, source: str = "wheel speed") -> None:
        self.keep_s = float(keep_s)
        self.source = source
        self._t: deque[float] = deque()
        self._v: deque[float] = deque()
        self._lock = threading.Lock()
        self.ignored = 0

    def push(self, t: float, speed_mps: float) -> bool:
        """Add one sample; False (and counted) where it is not finite or not after the last."""
        with self._lock:
            if (not (math.isfinite(t) and math.isfinite(speed_mps))
                    or (self._t and t <= self._t[-1])):
                self.ignored += 1
                return False
            self._t.append(float(t))
            self._v.append(float(speed_mps))
            while self._t[0] < t - self.keep_s:
                self._t.popleft()
                self._v.popleft()
            return True

    def __len__(self) -> int:
        return len(self._t)

    @property
    def last_t(self) -> float:
        with self._lock:
            return self._t[-1] if self._t else -math.inf

    def series(self) -> SpeedSeries:
        """The samples held now, as a ``SpeedSeries``."""
        with self._lock:
            t = np.fromiter(self._t, float, len(self._t))
            v = np.fromiter(self._v, float, len(self._v))
        return SpeedSeries(t, v, source=self.source)


@dataclass
class OnlineMonitor:
    """EKF + ``DriftMonitor`` stepped pair by pair (module doc).

    ``nominal``: the calibration judged against; ``ekf_config`` defaults to the nominal
    height's; ``monitor_options``: ``MonitorConfig`` fields (``false_alarms_per_hour``,
    ``road_std_deg``, ...); ``fps``: processed pairs per second, None to measure it on the
    first ``warmup_pairs``; ``speed``: the samples pushed so far (None: no wheel speed).
    """

    nominal: NominalCalibration
    ekf_config: EkfConfig | None = None
    monitor_options: dict[str, Any] = field(default_factory=dict)
    fps: float | None = None
    warmup_pairs: int = 5
    speed: SpeedBuffer | None = None

    def __post_init__(self) -> None:
        self.ekf_config = self.ekf_config or EkfConfig(height_m=self.nominal.height_m)
        self.ekf = ExtrinsicsEKF(self.ekf_config)
        self.monitor: DriftMonitor | None = None
        self._ekf_t = -math.inf  # time of the filter's last step [s]
        self._previous: PairMeasurement | None = None
        self._waiting: list[tuple[PairMeasurement, FilterState, MonitorInput]] = []
        if self.fps is not None:
            self._start_monitor(self.fps)

    def _start_monitor(self, fps: float) -> None:
        config = MonitorConfig.from_noise(self.ekf_config.noise, fps=fps,
                                          **self.monitor_options)
        self.monitor = DriftMonitor(self.nominal, config)
        self.fps = fps

    def step(self, m: PairMeasurement, t_prev: float, hold_reason: str = "",
             ) -> list[tuple[PairMeasurement, FilterState, MonitorOutput]]:
        """Apply the pair ``m`` of frames (m.frame − 1, m.frame), the first at ``t_prev`` [s];
        the frames now decided, each (measurement, EKF state, monitor verdict): this one, or
        none while the frame rate is being measured, then all of those at once.
        ``hold_reason``: a reason to hold the verdict of this frame (a silent wheel speed)."""
        prev = self._previous
        adjacent = prev is not None and prev.frame == m.frame - 1
        speed = None if self.speed is None or len(self.speed) == 0 else self.speed.series()
        if not adjacent and t_prev > self._ekf_t:
            self.ekf.step(None, t_prev, _speed_at(speed, t_prev), m.frame - 1)
        state = self.ekf.step(m, m.t, _speed_at(speed, m.t), m.frame)
        self._ekf_t = max(self._ekf_t, m.t)
        before = prev if adjacent else PairMeasurement(
            m.frame - 1, t_prev, np.full(7, np.nan), np.full((7, 7), np.nan),
            m.height_assumed, NOT_PROCESSED)
        inp = inputs_from_measurements([before, m], speed,
                                       **forward_camera_options(self.nominal))[-1]
        mount, mount_cov, gated = mount_from_state(state)
        inp = replace(inp, mount=mount, mount_cov=mount_cov, gated=gated)
        if hold_reason and inp.usable:
            inp = replace(inp, usable=False, hold_reason=hold_reason)
        self._previous = m
        self._waiting.append((m, state, inp))
        if self.monitor is None:
            if len(self._waiting) < self.warmup_pairs:
                return []
            self._start_monitor(processed_rate([w[0].t for w in self._waiting]))
        assert self.monitor is not None
        decided = [(w_m, w_s, self.monitor.update(w_i)) for w_m, w_s, w_i in self._waiting]
        self._waiting = []
        return decided

    def flush(self) -> list[tuple[PairMeasurement, FilterState, MonitorOutput]]:
        """The frames still waiting for the frame rate, judged at the rate they show (at the
        end of a run shorter than the warm-up)."""
        if not self._waiting:
            return []
        if self.monitor is None:
            self._start_monitor(processed_rate([w[0].t for w in self._waiting]))
        assert self.monitor is not None
        decided = [(w_m, w_s, self.monitor.update(w_i)) for w_m, w_s, w_i in self._waiting]
        self._waiting = []
        return decided


def _speed_at(speed: SpeedSeries | None, t: float) -> float:
    """Speed [m/s] at ``t`` between the samples (NaN outside them or across a gap of more
    than 0.5 s: ``wheel_speed.interpolate_speed``); NaN without samples."""
    if speed is None:
        return float("nan")
    return float(interpolate_speed(speed.t, speed.speed_mps, np.array([t]))[0])


def processed_rate(times: Sequence[float], default: float = 10.0) -> float:
    """Pairs per second [Hz] from the times of processed pairs: the inverse of their median
    spacing (``default`` with fewer than two)."""
    dt = np.diff(np.asarray(times, dtype=float))
    dt = dt[np.isfinite(dt) & (dt > 0)]
    return float(1.0 / np.median(dt)) if dt.size else default


__all__ = ["NOT_PROCESSED", "OnlineMonitor", "SpeedBuffer", "processed_rate"]
