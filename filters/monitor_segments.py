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


def step_signature(a: float, gain: float, n: int, settled: float = 1e-6,
                   ) -> tuple[FloatArray, float]:
    """g_j, the share of a step j frames ago left in the innovations of a steady whitening
    filter of AR(1) coefficient ``a`` and Kalman gain ``gain`` (module doc), for j < n or
    until it is within ``settled`` of its limit ρ; and ρ (it stays there)."""
    rho = (1.0 - a) / (1.0 - a + a * gain)
    g = []
    x = 0.0
    for _ in range(n):
        g.append(1.0 - a * x)
        x = a * x + gain * g[-1]
        if abs(g[-1] - rho) < settled:
            break
    return np.array(g), rho


def last_step(nu: FloatArray, s: FloatArray, a: FloatArray, gain: FloatArray,
              factor: FloatArray, least: FloatArray, min_after: int = 2,
              z: float = STEP_Z) -> int:
    """Index of the first frame after the last step found (0: none).

    ``nu`` (n, 3): the whitening filter's innovations per frame and axis (NaN where the
    axis was not used), ``s`` (n, 3) their variances; per axis the filter's typical AR(1)
    coefficient ``a`` and gain ``gain``, ``factor`` ≥ 1, the long-run variance factor of
    what runs on in the innovations (the errors' correlation, the road's wander), and
    ``least``, the smallest step that counts (the tolerance: a smaller move is no new
    calibration). A step needs ``min_after`` frames after it."""
    n = len(nu)
    resid = np.array(nu, dtype=float)
    start = 0
    for _ in range(MAX_STEPS):
        found = _strongest_step(resid, s, a, gain, factor, least, start, min_after, z)
        if found is None:
            break
        start, fitted = found
        resid = resid - fitted
    return min(start, n)


def _strongest_step(nu: FloatArray, s: FloatArray, a: FloatArray, gain: FloatArray,
                    factor: FloatArray, least: FloatArray, after: int, min_after: int,
                    z: float) -> tuple[int, FloatArray] | None:
    """The frame m > ``after`` of the largest √Λ on any axis where that is at least ``z`` and
    the step beyond ``least``, and the (n, 3) innovations the steps fitted there explain (on
    every axis: a knock often moves two); None otherwise."""
    n = len(nu)
    best: tuple[int, float] | None = None  # (m, √Λ)
    fits = []  # per axis: (signature, ρ, Δ̂ at each m)
    for j in range(nu.shape[1]):
        use = np.isfinite(nu[:, j]) & np.isfinite(s[:, j]) & (s[:, j] > 0)
        g, rho = step_signature(float(a[j]), float(gain[j]), n)
        if use.sum() < min_after + 1:
            fits.append((g, rho, np.zeros(n)))
            continue
        y = np.where(use, nu[:, j] / np.where(use, s[:, j], 1.0), 0.0)
        q = np.where(use, 1.0 / np.where(use, s[:, j], 1.0), 0.0)
        num = _signature_sums(y, g, rho)  # Σ_i g_i y[m+i]
        den = _signature_sums(q, g * g, rho * rho)
        delta = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
        fits.append((g, rho, delta))
        after_n = use[::-1].cumsum()[::-1]  # used frames from m on
        valid = ((np.arange(n) > after) & (after_n >= min_after) & (den > 0)
                 & (np.abs(delta) > least[j]))
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
    fitted = np.zeros_like(nu)
    for j, (g, rho, delta) in enumerate(fits):
        shape = np.full(n - m, rho)
        shape[:min(len(g), n - m)] = g[:n - m]
        fitted[m:, j] = np.where(np.isfinite(nu[m:, j]), shape * delta[m], 0.0)
    return m, fitted


def _signature_sums(y: FloatArray, g: FloatArray, tail: float) -> FloatArray:
    """(n,) Σ_{k≥m} w_{k−m} y_k for every m, the weights ``g`` then ``tail`` for ever: a
    short correlation and a suffix sum (the signature settles within a few frames; the full
    correlation cost 30 ms a frame at 30 fps with a minute of history)."""
    n, k = len(y), len(g)
    head = np.correlate(np.concatenate([y, np.zeros(k)]), g, "valid")[:n]
    suffix = np.concatenate([np.cumsum(y[::-1])[::-1], [0.0]])  # Σ_{i≥m} y_i
    return head + tail * suffix[np.minimum(np.arange(n) + k, n)]
