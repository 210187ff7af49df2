"""Adaptive body shaking: the Gauss–Markov body's stationary std matched to the data.

The model's ``NoiseParams.body_std_deg`` is a floor. Over a trailing window the measured body
(a pair's current-frame pitch/roll, minus the mount where a filter has one) has the robust
variance (1.4826 · MAD)² = body variance + measurement variance (covariance matching); where
that body std is larger than the floor, it replaces it (with a shorter time constant, so
the shaking beyond the model is fast and does not pull the mount: ``model.body_transition``).
Used by the EKF (body = pair minus its filtered mount) and both smoothers (body = the
pair's angles; within a window of seconds the mount is constant, and the MAD is about the
window's median).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from numpy.typing import NDArray

from .model import NoiseParams

FloatArray = NDArray[np.float64]


class BodyScale:
    """Trailing-window covariance matching of the body std (pitch, roll), rad.

    ``window_s`` ≤ 0 keeps the model's std; fewer than ``min_pairs`` pairs in the window too.
    """

    def __init__(self, noise: NoiseParams, window_s: float, min_pairs: int) -> None:
        self._floor = np.full(2, math.radians(noise.body_std_deg))
        self._window_s = float(window_s)
        self._min_pairs = int(min_pairs)
        #: (t, body pitch, body roll, their measurement variances), s / rad / rad²
        self._seen: deque[tuple[float, float, float, float, float]] = deque()

    def add(self, t: float, body: FloatArray, var: FloatArray) -> None:
        """One pair's measured body (pitch, roll, rad) and its measurement variances (rad²)
        at time ``t`` (s, increasing); drops what left the window."""
        if self._window_s <= 0:
            return
        self._seen.append((float(t), float(body[0]), float(body[1]),
                           float(var[0]), float(var[1])))
        while self._seen and self._seen[0][0] < t - self._window_s:
            self._seen.popleft()

    def std(self) -> FloatArray:
        """Stationary body std (pitch, roll), rad: the model's, or the robust scale of the
        window's body less its measurement noise where that is larger."""
        if self._window_s <= 0 or len(self._seen) < self._min_pairs:
            return self._floor.copy()
        seen = np.array(self._seen)
        b, r = seen[:, 1:3], seen[:, 3:5]
        mad = np.median(np.abs(b - np.median(b, axis=0)), axis=0)
        var = (1.4826 * mad) ** 2 - np.median(r, axis=0)
        return np.sqrt(np.maximum(self._floor**2, var))
