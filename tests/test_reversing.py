"""The filters on a drive that reverses (parking), with a wheel speed that is a magnitude."""

from __future__ import annotations

import numpy as np
import pytest

from vipm_track.filters import model as M
from vipm_track.filters.drive_sim import DriveConfig, DriveProfile, simulate_drive
from vipm_track.filters.ekf import run_filter
from vipm_track.filters.ekf_state import EkfConfig
from vipm_track.filters.smoother_config import SmootherConfig
from vipm_track.filters.smoothing import smooth

H_TRUE, H0 = 1.53, 1.5


@pytest.fixture(scope="module")
def parking():
    # forward 6 m/s, stop, reverse at 2 m/s for 14 s, stop, forward again; steering held, so
    # the yaw rate changes sign with the speed
    knots = (0.0, 10.0, 12.0, 14.0, 16.0, 30.0, 32.0, 34.0, 36.0)
    speeds = (6.0, 6.0, 0.0, 0.0, -2.0, -2.0, 0.0, 0.0, 4.0)
    profile = DriveProfile(knots, speeds, (0.01,) * len(knots))
    cfg = DriveConfig.preset("car", duration_s=45.0, height_m=H_TRUE, height_assumed_m=H0,
                             failure_fraction=0.0)
    return simulate_drive(cfg, 3, profile)


def test_the_simulated_wheel_speed_is_a_magnitude(parking):
    assert np.min(parking.truth.speed) < -1.9
    assert np.all(parking.speed.speed_mps >= 0.0)


@pytest.mark.parametrize("method", ["ekf", "fixed-lag", "batch"])
def test_filters_follow_the_vehicle_backwards(parking, method):
    # a non-negative wheel speed takes its direction from the pairs (model.travel_direction):
    # taken as forward, it made every reversing pair an outlier — the EKF gated them and
    # reported the vehicle driving forward, the batch turned its mount yaw by 180°
    run = parking
    noise = run.config.noise
    if method == "ekf":
        frames = run_filter(run.measurements, run.speed, EkfConfig(height_m=H0, noise=noise))
    else:
        lag = 2.0 if method == "fixed-lag" else 0.0
        frames = smooth(run.measurements, run.speed,
                        SmootherConfig(height_m=H0, noise=noise, lag_s=lag))
    tr = run.truth
    v = np.array([f.speed for f in frames])
    moving = (np.abs(tr.speed) > 0.3) & np.isfinite(v)  # the EKF waits for its first pairs
    assert moving.sum() > 0.8 * len(v)
    assert np.all(np.sign(v[moving]) == np.sign(tr.speed[moving]))
    assert np.max(np.abs(v[moving] - tr.speed[moving])) < 0.2
    h = np.array([f.state[M.MOUNT_HEIGHT] for f in frames])
    assert np.max(np.abs(h[tr.t > 10.0] / H_TRUE - 1.0)) < 0.005
    yaw_m = np.degrees([f.state[M.MOUNT_YAW] for f in frames])
    assert np.max(np.abs(yaw_m[tr.t > 5.0])) < 1.0
    pos = np.array([f.position for f in frames])
    err = np.hypot(pos[:, 0] - tr.x, pos[:, 1] - tr.y)
    travelled = np.sum(np.hypot(np.diff(tr.x), np.diff(tr.y)))
    assert err[-1] < 0.01 * travelled  # dead reckoning: 0.2–0.8 % over seeds


@pytest.mark.parametrize(("previous", "reading", "tz", "expected"), [
    (1.0, 5.0, -0.2, 1.0),    # at speed a backward pair is an outlier: keep going forward
    (1.0, 0.5, -0.05, -1.0),  # slow: the pair says the vehicle reverses
    (-1.0, 0.5, 0.05, 1.0),   # and forward again
    (-1.0, 0.5, None, -1.0),  # no pair: keep the direction
    (1.0, -0.5, 0.05, 1.0),   # a signed reading the pair contradicts: the image decides
    (1.0, -0.5, -0.05, -1.0),  # and one it confirms
    (-1.0, float("nan"), 0.05, -1.0),  # no reading: keep it
])
def test_travel_direction(previous, reading, tz, expected):
    z = None if tz is None else np.array([0, 0, 0, 0, 0.0, tz, 0])
    direction = M.travel_direction(previous, reading, z)
    assert direction == expected
    if np.isfinite(reading):
        assert M.signed_speed(reading, direction) == direction * abs(reading)


@pytest.mark.parametrize("method", ["ekf", "batch"])
def test_pairs_that_alias_backwards_at_speed_do_not_reverse_the_drive(method):
    """Beyond the estimator's range (a car at 35 m/s, 10 fps) the few pairs that pass read
    a short backward travel (aliased); the batch smoother took its first pairs' direction and
    reported the car reversing at 35 m/s all drive. Its wheels are far faster than any
    vehicle reverses: forward."""
    from dataclasses import replace

    profile = DriveProfile((0.0, 20.0), (30.0, 30.0), (0.01, 0.01))
    cfg = DriveConfig.preset("car", duration_s=20.0, height_m=H0, height_assumed_m=H0,
                             failure_fraction=0.0)
    run = simulate_drive(cfg, 4, profile)
    measurements = []
    for k, m in enumerate(run.measurements):
        if k % 8 == 5:
            z = m.z.copy()
            z[5] = -0.6 * z[5]
            measurements.append(replace(m, z=z))
        else:
            measurements.append(replace(m, z=np.full(7, np.nan), covariance=np.full((7, 7), np.nan),
                                        status="too few inliers"))
    assert sum(m.ok for m in measurements) >= 20
    if method == "ekf":
        frames = run_filter(measurements, run.speed, EkfConfig(height_m=H0, noise=cfg.noise))
    else:
        frames = smooth(measurements, run.speed, SmootherConfig(height_m=H0, noise=cfg.noise))
    v = np.array([f.speed for f in frames])
    assert np.isfinite(v).sum() > 0.5 * len(v)
    assert np.all(v[np.isfinite(v)] > 25.0)


def test_initial_direction_from_pairs_only_at_a_reversing_speed():
    back = np.array([[0, 0, 0, 0, 0.0, -0.2, 0]] * 3)
    assert M.initial_direction(back) == -1.0
    assert M.initial_direction(back, np.array([2.0, np.nan, 2.5])) == -1.0  # backing out
    assert M.initial_direction(back, np.array([30.0, 31.0, np.nan])) == 1.0
    assert M.initial_direction(back, np.full(3, np.nan)) == -1.0
    assert M.initial_direction(np.zeros((0, 7)), np.zeros(0)) == 1.0
