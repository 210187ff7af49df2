"""Batch-means standard error of a correlated series' mean (filters.long_run)."""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from vipm_track.filters.long_run import batch_means


def _ar1(rng: np.random.Generator, n: int, a: float, std: float) -> np.ndarray:
    """Stationary AR(1) series: x_k = a x_{k-1} + e_k with std ``std``."""
    e = rng.normal(0.0, std * math.sqrt(1.0 - a * a), n)
    x, _ = lfilter([1.0], [1.0, -a], e, zi=[a * rng.normal(0.0, std)])
    return x


def test_white_noise_gives_the_textbook_standard_error():
    rng = np.random.default_rng(0)
    ratios = [batch_means(rng.normal(0.0, 2.0, 900)).std / (2.0 / 30.0) for _ in range(50)]
    assert 0.9 < np.median(ratios) < 1.1


def test_correlated_series_gets_its_long_run_variance():
    # AR(1) with a = 0.9: the mean's variance is σ²(1 + a)/(1 − a)/n, 19× the white figure
    rng = np.random.default_rng(1)
    a, std, n = 0.9, 1.0, 3600
    truth = std * math.sqrt((1 + a) / (1 - a) / n)
    est = [batch_means(_ar1(rng, n, a, std)) for _ in range(40)]
    assert 0.8 < np.median([e.std for e in est]) / truth < 1.15
    assert est[0].batches == 30 and est[0].batch_length == 120
    hits = 0
    for _ in range(200):
        x = _ar1(rng, n, a, std)
        hits += abs(np.mean(x)) < batch_means(x).half_width95
    assert 0.88 < hits / 200 <= 1.0


def test_too_short_or_empty_series_say_so():
    assert batch_means([1.0, 2.0, 3.0]) is None
    assert batch_means([np.nan] * 50) is None
    u = batch_means([0.0, 1.0] * 10 + [np.nan])  # NaNs are skipped
    assert u is not None and u.batches == 5 and u.batch_length == 4
