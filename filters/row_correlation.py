"""Pairs whose errors run on from frame to frame: the filters' per-frame pose and motion σ
widened by the effective-sample-size factor of the pairs' lag-1 autocorrelation.

A filter takes each pair's pitch and roll as independent evidence. On real frames they are
not: a tracked pair starts from the pose the pair before found, and successive pairs see the
same road through the same patches, so their errors run on for several frames (lag-1
autocorrelation of the pairs' errors 0.75–0.85 on KITTI 07, 0.5–0.9 in rendered dense
traffic, 0–0.4 in light traffic: docs/traffic.md). A frame's pose, in effect an average
over many pairs, is then surer in the filter than in fact (smoothed z RMS 3.7–4.4 on
KITTI 07). The pairs' residuals against the filter's own pose show the correlation without a
truth: over a trailing window, their lag-1 autocorrelation ρ, where it is significant (above
2/√n, which white residuals stay below 95 % of the time), widens the pose σ by
√((1+ρ)/(1−ρ)), the factor by which AR(1) samples inflate the variance of their mean
(Bartlett). The estimates are unchanged. The mount's pitch and roll σ widen by the same
factor: the mount is an average of the same correlated errors (under AR(1) angle noise of
τ 1 s the EKF's mount σ was 3× too narrow, NEES 9–12; on KITTI 07 the batch's mount σ was
0.07° where the data's batch means say 0.2°, and is 0.17–0.19° now).

The frame's motion (tx, tz, yaw) is an average of the pairs' in the same way, with errors
that run on as the pose's do (a pitch error makes the travel long for as long as it lasts):
each component widens by the factor of its own residuals (KITTI 07, batch: the smoothed
travel's 95 % interval held the truth on 83 % of the frames, its errors' lag-1
autocorrelation 0.94; 92 % now).

What it cannot see: an error shared by both poses of a pair and carried on by the next (a
frame's pose that a tracked pair inherits) is taken up by the filter's body state, so the
residuals against the filter's pose stay nearly white (on simulated drives with such AR(1)
errors, ρ 0.7–0.9 in the pairs, 0.05–0.13 in the residuals); only errors the chain of pose
changes contradicts show. KITTI 07's do (docs/traffic.md); a drive whose don't keeps the
filter's σ too narrow.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from .filter_common import NOT_APPLIED, FrameEstimate, motion_residual

FloatArray = NDArray[np.float64]
Estimate = TypeVar("Estimate", bound=FrameEstimate)

#: trailing window of residuals [s], and the fewest lagged pairs of residuals to judge by
WINDOW_S = 6.0
MIN_LAG_PAIRS = 10
#: the largest autocorrelation believed (a factor of √19 ≈ 4.4 on the σ)
MAX_RHO = 0.9
#: successive residuals further apart than this many frames are not taken as lagged (a
#: live run under load skips frames between its pairs)
MAX_LAG_FRAMES = 3
#: normalised residuals are clipped to this, so that one pair stating a far too small σ does
#: not decide the correlation of the whole window
MAX_Z = 5.0


#: the channels of a residual: (pitch, roll) of frame k, then (tx, tz, yaw) of the pair's
#: motion
CHANNELS = 5


class PairErrorCorrelation:
    """Each frame's estimate with its pitch, roll, tx, tz and yaw σ widened by the autocorrelation
    of the pairs' normalised residuals against the estimates so far (module doc); fed in
    frame order, one estimate (and its pair, None where there is none) at a time."""

    def __init__(self, window_s: float = WINDOW_S, min_lag_pairs: int = MIN_LAG_PAIRS):
        self.window_s = window_s
        self.min_lag_pairs = min_lag_pairs
        self._residuals: deque[tuple[int, float, FloatArray]] = deque()

    def widened(self, estimate: Estimate, m: PairMeasurement | None) -> Estimate:
        """``estimate`` with its pose and motion σ widened by the residuals up to it."""
        self.observe(estimate, m)
        while self._residuals and self._residuals[0][1] < estimate.t - self.window_s:
            self._residuals.popleft()  # also through a stretch without usable pairs
        return widen(estimate, self.scale())

    def observe(self, estimate: FrameEstimate, m: PairMeasurement | None) -> None:
        """Take the residuals of ``m``'s pose (frame k) and motion against ``estimate``'s
        (the window is aged by :meth:`widened`); a channel without both is NaN."""
        if m is None or not m.ok or estimate.status in NOT_APPLIED:
            return  # (a late pair's estimate is another frame's)
        z = np.full(CHANNELS, np.nan)
        pose = estimate.pose
        var = np.diag(m.covariance)[2:4]
        if (pose is not None and np.all(np.isfinite(pose[:2])) and np.all(np.isfinite(var))
                and np.all(var > 0)):
            z[:2] = (m.z[2:4] - pose[:2]) / np.sqrt(var)
        residual = motion_residual(estimate, m)
        if residual is not None:
            r, var = residual
            with np.errstate(invalid="ignore", divide="ignore"):
                z[2:] = np.where(var > 0, r / np.sqrt(var), np.nan)
        if np.any(np.isfinite(z)):
            self._residuals.append((m.frame, m.t, np.clip(z, -MAX_Z, MAX_Z)))

    def scale(self) -> FloatArray:
        """Factor on the pitch, roll, tx, tz and yaw σ from the window's residuals (1 where their
        autocorrelation is not significant or a channel has too few lagged pairs)."""
        if len(self._residuals) <= self.min_lag_pairs:
            return np.ones(CHANNELS)
        frames = np.fromiter((f for f, _, _ in self._residuals), float, len(self._residuals))
        r = np.array([v for _, _, v in self._residuals])
        step = np.diff(frames)
        known = np.isfinite(r)
        lagged = ((step > 0) & (step <= MAX_LAG_FRAMES))[:, None] & known[:-1] & known[1:]
        n = np.count_nonzero(lagged, axis=0)
        counts = np.count_nonzero(known, axis=0)
        r0 = np.where(known, r, 0.0)
        mean = r0.sum(axis=0) / np.maximum(counts, 1)
        centred = np.where(known, r - mean, 0.0)
        # each sum over its own count: gaps between the pairs must not dilute the covariance
        variance = np.maximum((centred**2).sum(axis=0) / np.maximum(counts, 1), 1e-12)
        lag_sum = np.where(lagged, centred[:-1] * centred[1:], 0.0).sum(axis=0)
        rho = lag_sum / np.maximum(n, 1) / variance
        judged = n >= self.min_lag_pairs
        rho = np.where(judged & (rho > 2.0 / np.sqrt(np.maximum(n, 1))), rho, 0.0)
        return np.sqrt(ar1_variance_factor(rho))


def ar1_variance_factor(rho: FloatArray) -> FloatArray:
    """(1+ρ)/(1−ρ), ρ capped at ``MAX_RHO``: the factor by which errors of lag-1
    autocorrelation ρ (AR(1)) inflate the variance of their mean (Bartlett)."""
    rho = np.minimum(rho, MAX_RHO)
    return (1.0 + rho) / (1.0 - rho)


def correlation_inflation(residual: FloatArray) -> float:
    """How much wider a fit's σ is where its residuals (in time order; NaN left out) run on:
    √ of :func:`ar1_variance_factor` of their lag-1 correlation ρ (at least 0), 1 with fewer
    than three or no scatter. A fit's σ counts every residual as news (the clock offset's
    parabola, the drift report's line through block means)."""
    r = residual[np.isfinite(residual)]
    if r.size < 3 or not np.std(r) > 0:
        return 1.0
    rho = max(float(np.corrcoef(r[:-1], r[1:])[0, 1]), 0.0)
    return float(np.sqrt(ar1_variance_factor(np.float64(rho))))


def widen(estimate: Estimate, scale: FloatArray) -> Estimate:
    """``estimate`` with its pose and mount covariances' pitch and roll scaled by
    ``scale[:2]`` and its motion's (tx, tz, yaw) by ``scale[2:]`` (on σ). The full state
    ``covariance`` is the filter's own, unwidened."""
    if np.all(scale == 1.0):
        return estimate
    out = {}
    if estimate.pose is not None:
        s = np.outer(*(np.array([scale[0], scale[1], 1.0]),) * 2)
        out.update(pose_cov=estimate.pose_cov * s, mount_cov=estimate.mount_cov * s)
    if estimate.motion is not None:
        out.update(motion_cov=estimate.motion_cov * np.outer(scale[2:], scale[2:]))
    return replace(estimate, **out)


def widened_drive(estimates: list[Estimate], measurements: dict[int, PairMeasurement]
                  ) -> list[Estimate]:
    """A whole drive's estimates (a batch: every frame final at once) widened by the
    residuals of the whole drive; ``measurements`` by frame."""
    correlation = PairErrorCorrelation(window_s=math.inf)
    for e in estimates:
        correlation.observe(e, measurements.get(e.frame))
    scale = correlation.scale()
    return [widen(e, scale) for e in estimates]
