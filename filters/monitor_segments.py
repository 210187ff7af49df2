"""Where the monitor's new extrinsics begin: the frames after the last step of the mount
(``last_step``), found on the whitening filter's innovations.

The CUSUM's change time (``MonitorCore.change_onset``) can be many frames early (its small
design shifts keep evidence from body excursions before the step) or late, and once
RECALIBRATE is latched the camera may move again (knocked further, set back, a ramp that goes
on). A median over frames from before such a step reports extrinsics the camera never had,
inside an interval that does not hold it.

A step is sharper than the body can move, and the monitor's whitening Kalman filter on the
body (``filters.monitor_core``) shows it so: a step Δ at frame m adds g_{k−m}·Δ to its
innovations ν_k, with g_0 = 1 (the filter has not absorbed any of it yet), decaying to the
steady ρ (g_j = 1 − a x_{j−1}, x_j = a x_{j−1} + K g_j, x_{−1} = 0). The generalised
likelihood ratio of a step at m (Willsky & Jones 1976),

    Λ_m = (Σ_{k≥m} g_{k−m} ν_k / S_k)² / Σ_{k≥m} g_{k−m}² / S_k,

divided by the errors' measured correlation factor, is χ²₁ for a given m where there is no
step; its largest over m places the step. The steps are found one after the other: the
strongest, then on the innovations less its fitted signature the next after it, while
√Λ ≥ ``STEP_Z``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: √Λ of a step: the largest of a few hundred candidate frames without a step stays below
#: about 3.5 per axis
STEP_Z = 5.0
MAX_STEPS = 4


def step_signature(a: float, gain: float, n: int) -> FloatArray:
    """(n,) g_j: the share of a step j frames ago left in the innovations of a steady
    whitening filter of AR(1) coefficient ``a`` and Kalman gain ``gain`` (module doc)."""
    g = np.empty(n)
    x = 0.0
    for j in range(n):
        g[j] = 1.0 - a * x
        x = a * x + gain * g[j]
    return g


def last_step(nu: FloatArray, s: FloatArray, a: FloatArray, gain: FloatArray,
              factor: FloatArray, min_after: int = 2, z: float = STEP_Z) -> int:
    """Index of the first frame after the last step found (0: none).

    ``nu`` (n, 3): the whitening filter's innovations per frame and axis (NaN where the
    axis was not used), ``s`` (n, 3) their variances; per axis the filter's typical AR(1)
    coefficient ``a`` and gain ``gain``, and ``factor`` ≥ 1, the long-run variance factor
    of the errors' correlation. A step needs ``min_after`` frames after it."""
    n = len(nu)
    resid = np.array(nu, dtype=float)
    start = 0
    for _ in range(MAX_STEPS):
        found = _strongest_step(resid, s, a, gain, factor, start, min_after, z)
        if found is None:
            break
        start, fitted = found
        resid = resid - fitted
    return min(start, n)


def _strongest_step(nu: FloatArray, s: FloatArray, a: FloatArray, gain: FloatArray,
                    factor: FloatArray, after: int, min_after: int, z: float,
                    ) -> tuple[int, FloatArray] | None:
    """The frame m > ``after`` of the largest √Λ on any axis where that is at least ``z``,
    and the (n, 3) innovations its fitted step explains (on that axis); None otherwise."""
    n = len(nu)
    best: tuple[int, float] | None = None  # (m, √Λ)
    fits = []  # per axis: (signature, Δ̂ at each m)
    for j in range(nu.shape[1]):
        use = np.isfinite(nu[:, j]) & np.isfinite(s[:, j]) & (s[:, j] > 0)
        g = step_signature(float(a[j]), float(gain[j]), n)
        if use.sum() < min_after + 1:
            fits.append((g, np.zeros(n)))
            continue
        y = np.where(use, nu[:, j] / np.where(use, s[:, j], 1.0), 0.0)
        q = np.where(use, 1.0 / np.where(use, s[:, j], 1.0), 0.0)
        pad = np.zeros(n)
        num = np.correlate(np.concatenate([y, pad]), g, "valid")[:n]  # Σ_i g_i y[m+i]
        den = np.correlate(np.concatenate([q, pad]), g * g, "valid")[:n]
        fits.append((g, np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)))
        after_n = use[::-1].cumsum()[::-1]  # used frames from m on
        valid = (np.arange(n) > after) & (after_n >= min_after) & (den > 0)
        if not valid.any():
            continue
        score = np.where(valid, np.abs(num) / np.sqrt(np.where(den > 0, den, 1.0)
                                                      * factor[j]), 0.0)
        m = int(np.argmax(score))
        if score[m] >= z and (best is None or score[m] > best[1]):
            best = (m, float(score[m]))
    if best is None:
        return None
    m = best[0]
    # every axis's fitted step at m (a knock often moves two): what the next search is left
    fitted = np.zeros_like(nu)
    for j, (g, delta) in enumerate(fits):
        fitted[m:, j] = np.where(np.isfinite(nu[m:, j]), g[:n - m] * delta[m], 0.0)
    return m, fitted
