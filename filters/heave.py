"""The frame's height σ widened by the body's heave.

The filters' model moves the camera's height with the mount only (``filters.model``:
h_k = h_m), so a frame's height σ is the mount's. A body heaving on its suspension (a cart
on cobbles, a car on a rough road) moves each frame's height about the mount by millimetres
to centimetres, far beyond that σ (rendered shaking drives: z RMS 2.7–6.9 of the frames'
height; ±10 % swings: 20–84; ``scripts/bench_heave.py``). Each pair with a wheel speed
measures the height of its first frame (``pair_height``); over a window, the robust spread
about zero of those heights less the filter's own estimate of that frame, beyond their
stated variance (``monitor_stats.HeaveScale``, the monitor's heave estimate), is the heave,
added to each frame's height variance (and the share it moves the pair's metric translation
by to the translation's); without wheel speed, the 'unknown' heave
(``FilterConfig.heave_std_unknown_frac``). Where the pairs' travel is noisier than they say
(a car in dense traffic), the spread takes that noise for heave: the σ is then wider than it
needs to be. The estimates, the mount and the filter's own covariance are unchanged.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from .filter_common import FilterConfig, FrameEstimate
from .monitor_stats import HeaveScale
from .pair_height import MIN_SPEED_MPS, MIN_TRAVEL_FRAC, pair_heights, point_speed_height
from .wheel_speed import DEFAULT_MAX_GAP, SpeedSource

FloatArray = NDArray[np.float64]
Estimate = TypeVar("Estimate", bound=FrameEstimate)


class HeaveWidening:
    """Each frame's estimate with its height σ widened by the body's heave measured up to it
    (module doc); fed in frame order."""

    def __init__(self, config: FilterConfig, speed_series: SpeedSource | None = None,
                 clock_offset_s: float = 0.0) -> None:
        """``speed_series``: the wheel speed (times + ``clock_offset_s`` on the camera clock)
        whose distance between a pair's frames measures its height, as the monitor does;
        None: the speeds given with each frame (a live stream's)."""
        self._series = None
        if speed_series is not None:
            self._series = (np.asarray(speed_series.t, dtype=float) + clock_offset_s,
                            np.asarray(speed_series.speed_mps, dtype=float))
        noise = config.noise
        self._thresholds = dict(min_speed_mps=MIN_SPEED_MPS, min_travel_frac=MIN_TRAVEL_FRAC,
                                speed_std_rel=noise.speed_meas_std_rel,
                                speed_std_abs_mps=noise.speed_meas_std_abs_mps)
        self._unknown = config.heave_std_unknown_frac * config.height_m
        self._scale = HeaveScale(config.body_window_s, config.body_window_min_pairs,
                                 self._unknown, about_zero=True)
        self._last_known = math.nan  # the heave when the window last held enough heights
        #: the frame before: time s, wheel speed m/s, estimated height m
        self._last = (math.nan, math.nan, math.nan)

    def widened(self, estimate: Estimate, m: PairMeasurement | None,
                speed: float = math.nan) -> Estimate:
        """``estimate`` (with its pair ``m``, None where there is none, and the wheel
        ``speed`` at its time, m/s, NaN where none) with its height σ widened by the heave
        measured up to it."""
        self.observe(estimate, m, speed)
        return widen(estimate, self.std(), m)

    def observe(self, estimate: FrameEstimate, m: PairMeasurement | None,
                speed: float = math.nan) -> None:
        """Take the height ``m`` measures into the window (``residual``; the window is aged
        also without one)."""
        self._scale.add(*self.residual(estimate, m, speed))

    def residual(self, estimate: FrameEstimate, m: PairMeasurement | None,
                 speed: float = math.nan) -> tuple[float, float, float]:
        """(time s, residual m, variance m²) of the height ``m`` measures — that of the frame
        before — against that frame's estimate, which had not seen ``m`` (a filter's
        estimate after ``m`` has moved towards it); NaN without one. Frames in order."""
        t_before, v_before, h_before = self._last
        if estimate.t <= t_before:  # a late pair, which the filter left out
            return t_before, math.nan, math.nan
        v = float(speed) if speed is not None and math.isfinite(speed) else math.nan
        pose = estimate.pose
        self._last = (estimate.t, v, float(pose[2]) if pose is not None else math.nan)
        residual, var = math.nan, math.nan
        if m is not None and m.ok and math.isfinite(h_before):
            h, var = self._pair_height(m, t_before, estimate.t, (v_before, v))
            residual = h - h_before
        return estimate.t, residual, var

    def widened_drive(self, estimates: list[Estimate],
                      measurements: dict[int, PairMeasurement]) -> list[Estimate]:
        """A whole drive's estimates (a batch, on a fresh widening) widened by the heave of
        the window centred on each (a batch may look ahead: a trailing window at the start
        of a drive has seen too little of a slow heave), and the frames before the window
        first held enough heights by the heave at that point; ``measurements`` by frame."""
        seen = [self.residual(e, measurements.get(e.frame)) for e in estimates]
        stds = np.empty(len(estimates))
        first_known, j = None, 0
        for i, e in enumerate(estimates):
            while j < len(seen) and seen[j][0] <= e.t + 0.5 * self._scale.window_s:
                self._scale.add(*seen[j])
                j += 1
            stds[i] = self.std()
            if first_known is None and self.known:
                first_known = i
        if first_known is not None:
            stds[:first_known] = stds[first_known]
        return [widen(e, float(s), measurements.get(e.frame))
                for e, s in zip(estimates, stds, strict=True)]

    def _pair_height(self, m: PairMeasurement, t_before: float, t: float,
                     speeds: tuple[float, float]) -> tuple[float, float]:
        """The height and variance ``m`` measures: with the speed series' distance between
        its frames where there is one (only the samples about them are read), else with the
        two frames' speeds."""
        if self._series is None:
            return point_speed_height(m.z, m.covariance, m.height_assumed, t - t_before,
                                      speeds, **self._thresholds)
        ts, vs = self._series
        lo = max(int(np.searchsorted(ts, t_before)) - 1, 0)
        hi = int(np.searchsorted(ts, t)) + 1
        if hi - lo < 2:
            return math.nan, math.nan
        h, var, _ = pair_heights(
            np.array([t_before, t]), np.array([math.nan, t - t_before]),
            np.stack([np.full(7, np.nan), m.z]), np.stack([np.eye(7), m.covariance]),
            np.full(2, m.height_assumed), ts[lo:hi], vs[lo:hi],
            max_speed_gap_s=DEFAULT_MAX_GAP, **self._thresholds)
        return float(h[1]), float(var[1])

    @property
    def known(self) -> bool:
        """The window holds enough heights to take their spread as measured."""
        return self._scale.known

    def std(self) -> float:
        """The heave's std [m] now. While the window holds too few heights: the heave it
        last measured (a stop or a gap in the speed measures nothing, and a standing body
        does not heave more), else at least the 'unknown' one (a filter's first estimates sit
        on the first heights it measured, so their spread about them says little yet)."""
        std = self._scale.std()
        if self.known:
            self._last_known = std
            return std
        return self._last_known if math.isfinite(self._last_known) else max(std, self._unknown)


def widen(estimate: Estimate, heave_std_m: float, m: PairMeasurement | None = None) -> Estimate:
    """``estimate`` with ``heave_std_m``² added to its height variance, and to its metric
    translation's the share of the heave the filter took from the pair ``m``: a pair measures
    the translation in units of its first frame's height, which the filters scale by the
    mount's (an error t · δh / h), and weigh it against the wheel speed — the filter's travel
    variance over the pair's is the weight its travel gave the pair's (a car's wheel speed
    outweighs its pairs' travel, a cart's pairs the wheel speed); without a pair, all of it."""
    pose = estimate.pose
    if pose is None or heave_std_m <= 0.0:
        return estimate
    pose_cov = estimate.pose_cov.copy()
    pose_cov[2, 2] += heave_std_m**2
    changes: dict[str, FloatArray] = {"pose_cov": pose_cov}
    t = None if estimate.motion is None else estimate.motion[:2]
    if t is not None and np.all(np.isfinite(t)) and pose[2] > 0:
        weight = 1.0
        if m is not None and m.ok:
            pair_var = m.covariance[5, 5] * (pose[2] / m.height_assumed) ** 2
            if pair_var > 0:
                weight = float(np.clip(estimate.motion_cov[1, 1] / pair_var, 0.0, 1.0))
        motion_cov = estimate.motion_cov.copy()
        motion_cov[:2, :2] += (weight * heave_std_m / pose[2]) ** 2 * np.outer(t, t)
        changes["motion_cov"] = motion_cov
    return replace(estimate, **changes)
