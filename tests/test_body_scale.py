"""The adaptive body std: covariance matching over a trailing window."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from filters.body_scale import BodyScale
from filters.model import NoiseParams


def _direct(rows: list[tuple[float, float, float, float, float]], t: float, window_s: float,
            floor: float, min_pairs: int, unknown: float) -> np.ndarray:
    """The definition, from scratch: the rows at t - window_s or later, robust variance of
    the body less the median measurement variance, floored; below ``min_pairs`` rows its
    upper bound (× 1 + 2·1.17/√n), and below three rows the ``unknown`` std."""
    seen = np.array([r for r in rows if r[0] >= t - window_s])
    if len(seen) < 3:
        return np.full(2, unknown)
    b, var = seen[:, 1:3], seen[:, 3:5]
    mad = np.median(np.abs(b - np.median(b, axis=0)), axis=0)
    std = np.sqrt(np.maximum(floor**2, (1.4826 * mad) ** 2 - np.median(var, axis=0)))
    if len(seen) < min_pairs:
        std = np.maximum(floor, std * (1.0 + 2.0 * 1.17 / math.sqrt(len(seen))))
    return std


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    window_s=st.floats(0.2, 20.0),
    n=st.integers(1, 400),
)
def test_window_std_is_the_definition_at_every_frame(seed: int, window_s: float, n: int) -> None:
    rng = np.random.default_rng(seed)
    noise = NoiseParams()
    floor = math.radians(noise.body_std_deg)
    unknown = math.radians(noise.body_std_unknown_deg)
    scale = BodyScale(noise, window_s, 10)
    rows: list[tuple[float, float, float, float, float]] = []
    t = 0.0
    for _ in range(n):
        t += float(rng.uniform(0.0, 0.3))  # repeated times too
        body = rng.normal(size=2) * rng.uniform(1e-4, 1e-2)
        var = rng.uniform(1e-9, 1e-5, size=2)
        scale.add(t, body, var)
        rows.append((t, *body, *var))
        np.testing.assert_allclose(
            scale.std(), _direct(rows, t, window_s, floor, 10, unknown), rtol=1e-12)


def test_shaking_above_the_floor_is_measured() -> None:
    """20 fps, body shaking of 0.3° std under 0.05° pair noise: the matched std is ~0.3°."""
    rng = np.random.default_rng(0)
    noise = NoiseParams()
    scale = BodyScale(noise, 6.0, 10)
    sigma_body, sigma_pair = math.radians(0.3), math.radians(0.05)
    for k in range(600):
        body = rng.normal(scale=sigma_body, size=2) + rng.normal(scale=sigma_pair, size=2)
        scale.add(k / 20.0, body, np.full(2, sigma_pair**2))
    assert np.all(np.abs(np.degrees(scale.std()) - 0.3) < 0.03)
    assert math.radians(noise.body_std_deg) < sigma_body  # the floor is not the answer


def test_no_window_keeps_the_model() -> None:
    noise = NoiseParams()
    scale = BodyScale(noise, 0.0, 10)
    for k in range(50):
        scale.add(k * 0.1, np.full(2, 0.1), np.full(2, 1e-8))
    np.testing.assert_array_equal(scale.std(), np.full(2, math.radians(noise.body_std_deg)))


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
        calm.add(k * 0.1, rng.normal(scale=1e-4, size=2), np.full(2, 1e-10))
        shaking.add(k * 0.1, rng.normal(scale=math.radians(1.0), size=2), np.full(2, 1e-10))
        if k < 2:
            np.testing.assert_array_equal(calm.std(), np.full(2, unknown))
        elif k < 9:
            assert np.all(calm.std() > floor)  # the floor's upper bound
            assert np.all(shaking.std() > 2.0 * floor)
        else:
            np.testing.assert_array_equal(calm.std(), np.full(2, floor))
    assert np.all(np.abs(np.degrees(shaking.std()) - 1.0) < 0.5)
