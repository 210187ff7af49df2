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

import numpy as np
from numpy.typing import NDArray

from vipm_track.compiled import kernel

from .model import NoiseParams

FloatArray = NDArray[np.float64]


#: fewer pairs than this in the window tell nothing of the shaking: the 'unknown' std
_FEWEST_PAIRS = 3


def pairs_to_start(init_pairs: int, window_s: float, min_pairs: int) -> int:
    """Good pairs a filter collects before it starts: its ``init_pairs``, and enough for the
    body std to be measured (``min_pairs``) where it is adaptive (``window_s`` > 0); the
    collected pairs are then filtered with that std."""
    return max(init_pairs, min_pairs if window_s > 0 else 0)


class BodyScale:
    """Trailing-window covariance matching of the body std (pitch, roll), rad.

    ``window_s`` ≤ 0 keeps the model's std. With fewer than ``min_pairs`` pairs in the window
    the shaking is not known well yet: the std is ``NoiseParams.initial_body_std_deg`` below
    three pairs, then the upper bound of the spread measured so far. A start that assumed the
    calm floor would weigh a shaking vehicle's first frames as exact and bias the mount
    towards them.
    """

    def __init__(self, noise: NoiseParams, window_s: float, min_pairs: int) -> None:
        self._floor = np.full(2, math.radians(noise.body_std_deg))
        self._unknown = np.full(2, math.radians(noise.initial_body_std_deg))
        self._window_s = float(window_s)
        self._min_pairs = int(min_pairs)
        #: rows (t, body pitch, body roll, their measurement variances), s / rad / rad²,
        #: of the window: self._seen[self._start:self._end]
        self._seen = np.empty((64, 5))
        self._start = self._end = 0

    def add(self, t: float, body: FloatArray, var: FloatArray) -> None:
        """One pair's measured body (pitch, roll, rad) and its measurement variances (rad²)
        at time ``t`` (s, increasing); drops what left the window."""
        if self._window_s <= 0:
            return
        if self._end == len(self._seen):  # full: move the window to the front, or grow
            n = self._end - self._start
            if n > len(self._seen) // 2:
                self._seen = np.concatenate([self._seen, np.empty_like(self._seen)])
            self._seen[:n] = self._seen[self._start:self._end]
            self._start, self._end = 0, n
        self._seen[self._end] = (t, body[0], body[1], var[0], var[1])
        self._end += 1
        self._start += int(np.searchsorted(self._seen[self._start:self._end, 0],
                                           t - self._window_s))

    @property
    def pairs(self) -> int:
        """Pairs in the window now."""
        return self._end - self._start

    def std(self) -> FloatArray:
        """Stationary body std (pitch, roll), rad: the model's, or the robust scale of the
        window's body less its measurement noise where that is larger."""
        if self._window_s <= 0:
            return self._floor.copy()
        n = self._end - self._start
        if n < self._min_pairs:
            if n < _FEWEST_PAIRS:
                return self._unknown.copy()
            # few pairs: the spread's upper 95 % bound (a MAD's relative standard error is
            # about 1.17/√n), so that a few calm-looking pairs of a shaking vehicle are not
            # taken as exact
            out = np.empty(2)
            _matched_std(self._seen[self._start:self._end], self._floor, out)
            return np.maximum(self._floor, out * (1.0 + 2.0 * 1.17 / math.sqrt(n)))
        out = np.empty(2)
        _matched_std(self._seen[self._start:self._end], self._floor, out)
        return out


@kernel
def _matched_std(seen: FloatArray, floor: FloatArray, out: FloatArray) -> None:
    """out = max(floor, √((1.4826·MAD)² − median variance)) per axis of the window ``seen``
    (rows t, body pitch, roll, their variances)."""
    for axis in range(2):
        b = seen[:, 1 + axis]
        mad = np.median(np.abs(b - np.median(b)))
        var = (1.4826 * mad) ** 2 - np.median(seen[:, 3 + axis])
        out[axis] = math.sqrt(max(floor[axis] ** 2, var))
