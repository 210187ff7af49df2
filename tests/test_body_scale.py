"""The adaptive body std: covariance matching of the pairs' pitch/roll levels and changes over
a trailing window (the changes solved through the model's Gauss–Markov body)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from vipm_track.filters.body_scale import BodyScale, pair_change
from vipm_track.filters.model import NoiseParams, body_transition

Row = tuple[float, ...]  # t, level (2), level var (2), change (2), change var (2), dt


def _solve(v: float, dt: float, floor: float, tau0: float) -> float:
    """σ ≥ floor with 2σ²(1 − exp(−dt σ²/(τ₀ floor²))) = v (brentq, not the kernel's
    bisection)."""
    def f(s: float) -> float:
        return 2 * s * s * (1 - math.exp(-dt * s * s / (tau0 * floor * floor))) - v
    if f(floor) >= 0:
        return floor
    return brentq(f, floor, floor * 1e4, xtol=1e-15, rtol=1e-13)


def _direct(rows: list[Row], t: float, window_s: float, noise: NoiseParams,
            min_pairs: int) -> np.ndarray:
    """The definition, from scratch: the rows at t − window_s or later; the larger of the
    levels' robust variance less their median measurement variance and the changes' solved
    for σ at the median interval; below ``min_pairs`` rows its upper bound (× 1 + 2·1.17/√n),
    below three rows the 'unknown' std."""
    floor = math.radians(noise.body_std_deg)
    seen = np.array([r for r in rows if r[0] >= t - window_s])
    if len(seen) < 3:
        return np.full(2, math.radians(noise.initial_body_std_deg))
    dt = float(np.median(seen[:, 9]))
    out = np.empty(2)
    for j in range(2):
        b = seen[:, 1 + j]
        mad = np.median(np.abs(b - np.median(b)))
        level = math.sqrt(max(floor**2, (1.4826 * mad) ** 2 - np.median(seen[:, 3 + j])))
        d = seen[:, 5 + j]
        mad = np.median(np.abs(d - np.median(d)))
        v = (1.4826 * mad) ** 2 - np.median(seen[:, 7 + j])
        out[j] = max(level, _solve(v, dt, floor, noise.body_tau_s))
    if len(seen) < min_pairs:
        out = np.maximum(floor, out * (1.0 + 2.0 * 1.17 / math.sqrt(len(seen))))
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), window_s=st.floats(0.2, 20.0), n=st.integers(1, 300))
def test_window_std_is_the_definition_at_every_frame(seed: int, window_s: float, n: int) -> None:
    rng = np.random.default_rng(seed)
    noise = NoiseParams()
    scale = BodyScale(noise, window_s, 10)
    rows: list[Row] = []
    t = 0.0
    for _ in range(n):
        dt = float(rng.uniform(0.02, 0.2))
        t += float(rng.uniform(0.0, 0.3))  # repeated times too
        level = rng.normal(size=2) * rng.uniform(1e-4, 2e-2)
        change = rng.normal(size=2) * rng.uniform(1e-4, 3e-2)
        level_var, var = rng.uniform(1e-9, 1e-5, size=(2, 2))
        scale.add(t, level, level_var, change, var, dt)
        rows.append((t, *level, *level_var, *change, *var, dt))
        np.testing.assert_allclose(scale.std(), _direct(rows, t, window_s, noise, 10),
                                   rtol=1e-9)


def _body(rng: np.random.Generator, n: int, dt: float, std_deg: float,
          noise: NoiseParams) -> np.ndarray:
    """(n, 2) a Gauss–Markov body of stationary std ``std_deg`` as the model describes it
    (time constant shortened with the std, ``model.body_transition``), rad."""
    std = np.full(2, math.radians(std_deg))
    decay, var = body_transition(dt, noise, std)
    b = np.empty((n, 2))
    b[0] = rng.normal(scale=std)
    for k in range(1, n):
        b[k] = decay * b[k - 1] + rng.normal(scale=np.sqrt(var))
    return b


def _feed(scale: BodyScale, angles: np.ndarray, dt: float, meas_std: float,
          rng: np.random.Generator) -> None:
    """Pairs of consecutive frames of ``angles`` (n, 2) measured with noise ``meas_std``."""
    for k in range(1, len(angles)):
        z = np.zeros(7)
        z[0:2] = angles[k - 1] + rng.normal(scale=meas_std, size=2)
        z[2:4] = angles[k] + rng.normal(scale=meas_std, size=2)
        cov = np.eye(7) * meas_std**2
        scale.add(k * dt, z[2:4], np.diag(cov)[2:4], *pair_change(z, cov), dt)


def test_shaking_above_the_floor_is_measured() -> None:
    """20 fps, a model body of 0.6° std under 0.05° pair noise: the matched std is ~0.6°."""
    rng = np.random.default_rng(0)
    noise = NoiseParams()
    scale = BodyScale(noise, 6.0, 10)
    _feed(scale, _body(rng, 600, 0.05, 0.6, noise), 0.05, math.radians(0.05), rng)
    assert np.all(np.abs(np.degrees(scale.std()) - 0.6) < 0.08), np.degrees(scale.std())


def test_fast_shaking_is_seen_in_the_changes_and_slow_sway_in_the_levels() -> None:
    """A 0.5° white shake on a mount that steps by 1°: the changes give 0.5° whatever the
    step (the levels alone would read the step as shaking); a 0.5° sway at 0.2 Hz, whose
    changes are small at 20 fps, is read off the levels."""
    rng = np.random.default_rng(3)
    noise = NoiseParams()
    n = 120
    white = rng.normal(scale=math.radians(0.5), size=(n, 2))
    step = np.where(np.arange(n) >= n // 2, math.radians(1.0), 0.0)[:, None] * np.array([1, 0])
    knocked = BodyScale(noise, 6.0, 10)
    _feed(knocked, white + step, 0.1, math.radians(0.02), rng)
    assert abs(math.degrees(knocked.std()[1]) - 0.5) < 0.1  # roll: no step
    sway_t = np.arange(n) / 20.0
    sway = math.radians(0.5) * math.sqrt(2) * np.sin(2 * np.pi * 0.2 * sway_t)[:, None]
    swaying = BodyScale(noise, 6.0, 10)
    _feed(swaying, np.repeat(sway, 2, axis=1), 0.05, math.radians(0.02), rng)
    # a sinusoid's MAD is 1.05 × its std, over 1.2 periods of the window a little more
    assert np.all(np.abs(np.degrees(swaying.std()) - 0.55) < 0.15), np.degrees(swaying.std())


def test_the_start_assumes_a_shaking_body_until_measured() -> None:
    """Before three pairs the std is the 'unknown' one, then the upper bound of the spread
    seen (a calm floor at the start let a shaking cart's first frames bias the mount by
    0.35°): a shaking body is never taken for a calm one, and a calm one is known calm once
    the window holds enough pairs."""
    noise = NoiseParams()
    floor = math.radians(noise.body_std_deg)
    unknown = math.radians(noise.body_std_unknown_deg)
    rng = np.random.default_rng(1)
    calm, shaking = BodyScale(noise, 6.0, 10), BodyScale(noise, 6.0, 10)
    np.testing.assert_array_equal(calm.std(), np.full(2, unknown))
    for k in range(12):
        tiny = np.full(2, 1e-10)
        calm.add(k * 0.1, rng.normal(scale=1e-4, size=2), tiny, rng.normal(scale=1e-4, size=2),
                 tiny, 0.1)
        shaking.add(k * 0.1, rng.normal(scale=math.radians(1.0), size=2), tiny,
                    rng.normal(scale=math.radians(1.4), size=2), tiny, 0.1)
        if k < 2:
            np.testing.assert_array_equal(calm.std(), np.full(2, unknown))
        elif k < 9:
            assert np.all(calm.std() > floor)  # the floor's upper bound
            assert np.all(shaking.std() > 2.0 * floor)
        else:
            np.testing.assert_array_equal(calm.std(), np.full(2, floor))
    # changes of 1.4° std are a white body of ~1° std
    assert np.all(np.abs(np.degrees(shaking.std()) - 1.0) < 0.5)


def test_no_window_keeps_the_model() -> None:
    noise = NoiseParams()
    scale = BodyScale(noise, 0.0, 10)
    for k in range(50):
        scale.add(k * 0.1, np.full(2, 0.1), np.full(2, 1e-8), np.full(2, 0.1), np.full(2, 1e-8),
                  0.1)
    np.testing.assert_array_equal(scale.std(), np.full(2, math.radians(noise.body_std_deg)))


def test_pair_change_of_many_pairs_is_that_of_each():
    rng = np.random.default_rng(2)
    z = rng.normal(size=(5, 7))
    a = rng.normal(size=(5, 7, 7))
    cov = a @ np.swapaxes(a, 1, 2)
    change, var = pair_change(z, cov)
    for k in range(5):
        c1, v1 = pair_change(z[k], cov[k])
        np.testing.assert_allclose(change[k], c1)
        np.testing.assert_allclose(var[k], v1)
        np.testing.assert_allclose(v1[0], cov[k, 0, 0] + cov[k, 2, 2] - 2 * cov[k, 0, 2])
