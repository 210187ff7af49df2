"""The filters' per-frame pose σ widened by the pairs' error correlation (row_correlation)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vipm_track.filters.row_correlation import PoseErrorCorrelation, widened_drive
from vipm_track.measurement import PairMeasurement


@dataclass(frozen=True)
class _Estimate:
    frame: int
    pose: np.ndarray
    pose_cov: np.ndarray


def _drive(errors_deg: np.ndarray, std_deg: float = 0.7):
    """Estimates at pose 0 and pairs whose pitch/roll err by ``errors_deg`` (n, 2)."""
    estimates, pairs = [], {}
    cov = np.diag(np.radians([std_deg] * 4 + [1.0, 1.0, 1.0])) ** 2
    for k, e in enumerate(np.radians(errors_deg)):
        z = np.zeros(7)
        z[2:4] = e
        pairs[k] = PairMeasurement(frame=k, t=0.1 * k, z=z, covariance=cov, height_assumed=1.5)
        estimates.append(_Estimate(k, np.zeros(3), np.diag([1e-6, 1e-6, 1e-4])))
    return estimates, pairs


def _ar1(rng, n: int, rho: float) -> np.ndarray:
    e = np.zeros((n, 2))
    e[0] = rng.normal(size=2)
    for k in range(1, n):
        e[k] = rho * e[k - 1] + np.sqrt(1 - rho**2) * rng.normal(size=2)
    return 0.7 * e


def _scale(estimates, pairs) -> np.ndarray:
    out = widened_drive(estimates, pairs)
    return np.sqrt(np.diag(out[0].pose_cov)[:2] / np.diag(estimates[0].pose_cov)[:2])


def test_independent_pairs_leave_the_sigma_alone():
    # white errors: the autocorrelation stays below its 2/sqrt(n) bound but now and then
    widened = [_scale(*_drive(0.7 * np.random.default_rng(seed).normal(size=(150, 2))))
               for seed in range(40)]
    assert np.mean(np.asarray(widened) > 1.0) <= 0.1
    assert np.median(widened) == 1.0


def test_correlated_pairs_widen_the_sigma_by_their_effective_sample_size():
    # AR(1) errors with rho 0.8: a mean of them varies (1+rho)/(1-rho) = 9 times more, so
    # the sigma widens by about 3 (2.1–3.3 over these seeds: the factor is steep in rho)
    scales = [_scale(*_drive(_ar1(np.random.default_rng(seed), 150, 0.8)))
              for seed in range(5)]
    assert np.all((np.asarray(scales) > 1.9) & (np.asarray(scales) < 4.0)), scales
    assert 2.5 < np.median(scales) < 3.5
    # the height's sigma and the estimates are not touched
    estimates, pairs = _drive(_ar1(np.random.default_rng(0), 150, 0.8))
    out = widened_drive(estimates, pairs)
    assert out[5].pose_cov[2, 2] == estimates[5].pose_cov[2, 2]
    assert np.array_equal(out[5].pose, estimates[5].pose)


def test_trailing_window_widens_once_it_has_seen_enough_pairs():
    estimates, pairs = _drive(_ar1(np.random.default_rng(1), 150, 0.8))
    correlation = PoseErrorCorrelation()
    out = [correlation.widened(e, pairs[e.frame]) for e in estimates]
    ratio = [np.sqrt(o.pose_cov[0, 0] / e.pose_cov[0, 0]) for o, e in zip(out, estimates,
                                                                            strict=True)]
    assert ratio[5] == 1.0  # fewer than 10 lag pairs: nothing to judge by
    # a 6-s window (60 pairs) sees less of the correlation than the whole drive (1.5–1.8
    # against 3: its mean takes the slow part), but widens it all the same
    assert np.median(ratio[70:]) > 1.4
