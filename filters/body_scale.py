"""Adaptive body shaking: the Gauss–Markov body's stationary std matched to the data.

The model's ``NoiseParams.body_std_deg`` is a floor. Over a trailing window, two robust
readings of the shaking (covariance matching), the larger taken:

- the spread of the frames' pitch/roll *levels*: (1.4826 · MAD)² about the window's median,
  less the median measurement variance, is σ² — it sees slow sway too, but a mount change
  inside the window widens it until the window has passed;
- the spread of the pairs' *changes* of pitch/roll between their two frames (``pair_change``),
  in which the mount cancels: under the model's body (Gauss–Markov, std σ, time constant
  τ = τ₀(σ₀/σ)², ``model.body_transition``: shaking beyond the model is fast, so it does not
  pull the mount) a change over Δt has the variance 2σ²(1 − exp(−Δt σ²/(τ₀σ₀²))) + r,
  increasing in σ and solved for it — it sees fast shaking at once, whatever the mount does.

Where the larger is above the floor it replaces it. Used by the EKF, both smoothers and the
monitor.
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


def cautious_std(measured, n: int, min_pairs: int, unknown, floor=0.0):
    """A std measured on ``n`` pairs as far as they can be trusted: ``unknown`` below three,
    the spread's upper 95 % bound below ``min_pairs`` (a MAD's relative standard error is
    about 1.17/√n: a few calm-looking pairs of a shaking vehicle are not taken as exact),
    else ``measured``; never below ``floor``. Scalars or arrays alike."""
    if n < _FEWEST_PAIRS:
        return np.maximum(unknown, floor)
    if n < min_pairs:
        return np.maximum(floor, measured * (1.0 + 2.0 * 1.17 / math.sqrt(n)))
    return np.maximum(floor, measured)


def pairs_to_start(init_pairs: int, window_s: float, min_pairs: int) -> int:
    """Good pairs a filter collects before it starts: its ``init_pairs``, and enough for the
    body std to be measured (``min_pairs``) where it is adaptive (``window_s`` > 0); the
    collected pairs are then filtered with that std."""
    return max(init_pairs, min_pairs if window_s > 0 else 0)


def pair_change(z: FloatArray, covariance: FloatArray) -> tuple[FloatArray, FloatArray]:
    """A pair's measured change of (pitch, roll) from its previous to its current frame, rad,
    and the variances of those changes, rad², from its 7-vector ``z`` and covariance (the
    order of ``vipm_track.measurement``); ``z`` (..., 7) and covariances (..., 7, 7) give
    (..., 2) each."""
    z = np.asarray(z, dtype=float)
    c = np.asarray(covariance, dtype=float)
    change = z[..., 2:4] - z[..., 0:2]
    var = np.stack([c[..., 0, 0] + c[..., 2, 2] - 2.0 * c[..., 0, 2],
                    c[..., 1, 1] + c[..., 3, 3] - 2.0 * c[..., 1, 3]], axis=-1)
    return change, np.maximum(var, 0.0)


class BodyScale:
    """Trailing-window covariance matching of the body std (pitch, roll), rad (module doc).

    ``window_s`` ≤ 0 keeps the model's std. With fewer than ``min_pairs`` pairs in the window
    the shaking is not known well yet: the std is ``NoiseParams.initial_body_std_deg`` below
    three pairs, then the upper bound of the spread measured so far. A start that assumed the
    calm floor would weigh a shaking vehicle's first frames as exact and bias the mount
    towards them.
    """

    def __init__(self, noise: NoiseParams, window_s: float, min_pairs: int) -> None:
        self._floor = np.full(2, math.radians(noise.body_std_deg))
        self._unknown = np.full(2, math.radians(noise.initial_body_std_deg))
        self._tau0 = float(noise.body_tau_s)
        self._window_s = float(window_s)
        self._min_pairs = int(min_pairs)
        #: rows (t, pitch, roll, their variances, change of pitch, of roll, their variances,
        #: interval), s / rad / rad² / s, of the window: self._seen[self._start:self._end]
        self._seen = np.empty((64, 10))
        self._start = self._end = 0

    def add(self, t: float, level: FloatArray, level_var: FloatArray, change: FloatArray,
            change_var: FloatArray, dt: float) -> None:
        """One pair at time ``t`` (s, increasing): its current frame's (pitch, roll) ``level``
        (rad), their measurement variances (rad²), its measured ``change`` of them over its
        interval ``dt`` (s) and that change's variances (``pair_change``); drops what left
        the window. A pair with a value that is not finite, or ``dt`` ≤ 0, is ignored."""
        values = np.concatenate([level, level_var, change, change_var])
        if self._window_s <= 0 or not (dt > 0 and np.all(np.isfinite(values))):
            return
        if self._end == len(self._seen):  # full: move the window to the front, or grow
            n = self._end - self._start
            if n > len(self._seen) // 2:
                self._seen = np.concatenate([self._seen, np.empty_like(self._seen)])
            self._seen[:n] = self._seen[self._start:self._end]
            self._start, self._end = 0, n
        self._seen[self._end, 0] = t
        self._seen[self._end, 1:9] = values
        self._seen[self._end, 9] = dt
        self._end += 1
        self._start += int(np.searchsorted(self._seen[self._start:self._end, 0],
                                           t - self._window_s))

    @property
    def pairs(self) -> int:
        """Pairs in the window now."""
        return self._end - self._start

    def std(self) -> FloatArray:
        """Stationary body std (pitch, roll), rad: the model's, or the larger matched reading
        of the window (module doc), as far as its pairs can be trusted (``cautious_std``)."""
        if self._window_s <= 0:
            return self._floor.copy()
        n = self._end - self._start
        out = np.empty(2)
        if n >= _FEWEST_PAIRS:
            _matched_std(self._seen[self._start:self._end], self._floor, self._tau0, out)
        return cautious_std(out, n, self._min_pairs, self._unknown, self._floor)


@kernel
def _matched_std(seen: FloatArray, floor: FloatArray, tau0: float, out: FloatArray) -> None:
    """out = the larger of the levels' and the changes' matched std, at least ``floor``, per
    axis of the window ``seen`` (rows: ``BodyScale._seen``; module doc); Δt the median."""
    dt = np.median(seen[:, 9])
    for axis in range(2):
        s0 = floor[axis]
        b = seen[:, 1 + axis]
        mad = np.median(np.abs(b - np.median(b)))
        level = math.sqrt(max(s0 * s0, (1.4826 * mad) ** 2 - np.median(seen[:, 3 + axis])))
        d = seen[:, 5 + axis]
        mad = np.median(np.abs(d - np.median(d)))
        v = (1.4826 * mad) ** 2 - np.median(seen[:, 7 + axis])
        f0 = 2.0 * s0 * s0 * (1.0 - math.exp(-dt / tau0))
        change = s0
        if v > f0:
            lo, hi = s0, s0 * math.sqrt(v / f0)  # f(hi) ≥ v: its exponent is at least dt/τ₀
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                f = 2.0 * mid * mid * (1.0 - math.exp(-dt * mid * mid / (tau0 * s0 * s0)))
                if f < v:
                    lo = mid
                else:
                    hi = mid
            change = 0.5 * (lo + hi)
        out[axis] = max(level, change)
