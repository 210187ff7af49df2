"""The drift monitor's statistics: CUSUM run lengths and thresholds, the variance of an offset
seen through an AR(1) body plus white noise, the thresholds tabulated over body scales and
interpolated between them, and the heave scale of the measured heights (the maths behind
``filters.monitor_core``)."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq
from scipy.stats import norm

from .body_scale import cautious_std

FloatArray = NDArray[np.float64]

_SIEGMUND_SHIFT = 1.166  # Siegmund's correction of the CUSUM threshold for the overshoot
#: long-run variances over the model's (w/w₀) at which the thresholds are tabulated for a body
#: std and an error correlation adapted to the data; between them the threshold is
#: interpolated in log w
W_SCALES = np.geomspace(1.0, 1e5, 41)


# --- CUSUM thresholds -------------------------------------------------------------------------


def cusum_log_arl(b: float, drift: float) -> float:
    """Natural log of the average run length (samples) of a CUSUM of unit-variance Gaussian
    increments with mean ``drift`` and threshold ``b`` (both in standard deviations),
    Siegmund's approximation ARL = (exp(−2μb') + 2μb' − 1)/(2μ²), b' = b + 1.166."""
    bb = b + _SIEGMUND_SHIFT
    if abs(drift) < 1e-9:
        return 2.0 * math.log(bb)
    x = 2.0 * drift * bb
    if abs(x) < 1e-3:  # the series of exp(−x) + x − 1, which cancels in floating point
        return 2.0 * math.log(bb) + math.log1p(-x / 3.0 + x * x / 12.0)
    if -x > 30.0:  # exp(-x) dominates; stay in log space
        return -x + math.log1p((x - 1.0) * math.exp(x)) - math.log(2.0 * drift * drift)
    return math.log(math.exp(-x) + x - 1.0) - math.log(2.0 * drift * drift)


def cusum_threshold(arl: float, drift: float) -> float:
    """Threshold b (standard deviations of the increment) whose in-control ARL is ``arl``
    samples, for increments of mean ``drift`` < 0 (``cusum_log_arl`` inverted)."""
    if arl <= 1.0:
        raise ValueError(f"ARL must exceed one sample, got {arl}")
    target = math.log(arl)
    if cusum_log_arl(0.0, drift) >= target:
        # A drift this far below zero (a tolerance of many standard deviations: a 5 cm height
        # tolerance on millimetre heights) keeps the ARL beyond the target at any threshold:
        # an alarm then needs one increment beyond it, so the tail of a single sample sets
        # it, with at least one standard deviation so that a statistic of zero is not at it.
        return max(float(norm.isf(1.0 / arl)) + drift, 1.0)
    # without drift the ARL is about b²: the bracket reaches past √ARL
    hi = 1e3 + target + 2.0 * math.sqrt(arl)
    return float(brentq(lambda b: cusum_log_arl(b, drift) - target, 0.0, hi))


def long_run_variance(body_std: float, a: float, meas_var: float) -> float:
    """Variance per frame of the information about a constant offset in AR(1) body
    (stationary std ``body_std``, coefficient ``a``) plus white noise ``meas_var``."""
    return body_std**2 * (1.0 + a) / (1.0 - a) + meas_var


def mean_variance(body_std: float, a: float, meas_var: float, n: int) -> float:
    """Variance of the mean of ``n`` consecutive frames of AR(1) body + white noise."""
    if n <= 0:
        return math.inf
    if a <= 0.0:
        return (body_std**2 + meas_var) / n
    corr = (1.0 + a) / (1.0 - a) - 2.0 * a * (1.0 - a**n) / (n * (1.0 - a) ** 2)
    return body_std**2 * corr / n + meas_var / n


def ar1_coefficient(dt: FloatArray, tau: FloatArray) -> FloatArray:
    """AR(1) coefficient of the body over ``dt`` at time constants ``tau`` (0: white)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
    return a


def interpolate_thresholds(table: FloatArray, scale: FloatArray) -> FloatArray:
    """(B, n, D) thresholds at long-run variance ratios ``scale`` (B, n; the first n axes),
    interpolated log-linearly in ``table`` (S, 3, D), tabulated at ``W_SCALES`` (clamped at
    its ends)."""
    n = scale.shape[1]
    x = np.log(np.clip(scale, W_SCALES[0], W_SCALES[-1]))
    grid = np.log(W_SCALES)
    hi = np.clip(np.searchsorted(grid, x, side="right"), 1, len(grid) - 1)  # (B, n)
    lo = hi - 1
    f = ((x - grid[lo]) / (grid[hi] - grid[lo]))[..., None]  # (B, n, 1)
    out = np.empty((scale.shape[0], n, table.shape[2]))
    for j in range(n):
        out[:, j] = (1 - f[:, j]) * table[lo[:, j], j] + f[:, j] * table[hi[:, j], j]
    return out


# --- heave scale ------------------------------------------------------------------------------


class HeaveScale:
    """Trailing-window robust spread (m) of the measured heights beyond their reported
    variance, for the monitor's height test (``MonitorConfig.heave_std_unknown_frac``); the
    same start rule as ``body_scale.BodyScale``: ``unknown`` below three heights, then the
    spread's upper 95 % bound until ``min_pairs``. ``about_zero``: the spread of the values
    about 0 rather than about their median (residuals, whose steady offset is error too)."""

    def __init__(self, window_s: float, min_pairs: int, unknown: float,
                 about_zero: bool = False) -> None:
        self._window_s, self._min_pairs, self._unknown = window_s, min_pairs, unknown
        self._about_zero = about_zero
        self._seen: deque[tuple[float, float, float]] = deque()

    def add(self, t: float, height: float, var: float) -> None:
        if math.isfinite(height) and math.isfinite(var):
            self._seen.append((t, height, var))
        while self._seen and self._seen[0][0] < t - self._window_s:
            self._seen.popleft()

    @property
    def window_s(self) -> float:
        """The window's length [s]."""
        return self._window_s

    @property
    def known(self) -> bool:
        """The window holds ``min_pairs`` heights: their spread is taken as measured."""
        return len(self._seen) >= self._min_pairs

    def std(self) -> float:
        n = len(self._seen)
        std = 0.0
        if n:
            h = np.array([x[1] for x in self._seen])
            mad = float(np.median(np.abs(h if self._about_zero else h - np.median(h))))
            var = (1.4826 * mad) ** 2 - float(np.median([x[2] for x in self._seen]))
            std = math.sqrt(max(0.0, var))
        return float(cautious_std(std, n, self._min_pairs, self._unknown))


__all__ = [
    "W_SCALES",
    "HeaveScale",
    "ar1_coefficient",
    "cusum_log_arl",
    "cusum_threshold",
    "interpolate_thresholds",
    "long_run_variance",
    "mean_variance",
]
