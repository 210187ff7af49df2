"""The adaptive body std: covariance matching over a trailing window."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from filters.body_scale import BodyScale
from filters.model import NoiseParams


def _direct(rows: list[tuple[float, float, float, float, float]], t: float, window_s: float,
            floor: float, min_pairs: int) -> np.ndarray:
    """The definition, from scratch: the rows at t - window_s or later, robust variance of
    the body less the median measurement variance, floored."""
    seen = np.array([r for r in rows if r[0] >= t - window_s])
    if len(seen) < min_pairs:
        return np.full(2, floor)
    b, var = seen[:, 1:3], seen[:, 3:5]
    mad = np.median(np.abs(b - np.median(b, axis=0)), axis=0)
    return np.sqrt(np.maximum(floor**2, (1.4826 * mad) ** 2 - np.median(var, axis=0)))


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
    scale = BodyScale(noise, window_s, 10)
    rows: list[tuple[float, float, float, float, float]] = []
    t = 0.0
    for _ in range(n):
        t += float(rng.uniform(0.0, 0.3))  # repeated times too
        body = rng.normal(size=2) * rng.uniform(1e-4, 1e-2)
        var = rng.uniform(1e-9, 1e-5, size=2)
        scale.add(t, body, var)
        rows.append((t, *body, *var))
        np.testing.assert_allclose(scale.std(), _direct(rows, t, window_s, floor, 10),
                                   rtol=1e-12)


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
