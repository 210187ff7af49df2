"""Simulated measurement streams: determinism, truth geometry, noise, bad data, wheel speed."""

from __future__ import annotations

import numpy as np
import pytest

from vipm_track.filters.drive_sim import DriveConfig, MountChange, simulate_drive
from vipm_track.geometry import PlanarMotion, compose_motion


def test_deterministic_from_seed():
    a = simulate_drive(DriveConfig(duration_s=10), seed=4)
    b = simulate_drive(DriveConfig(duration_s=10), seed=4)
    c = simulate_drive(DriveConfig(duration_s=10), seed=5)
    np.testing.assert_array_equal(a.z, b.z)
    np.testing.assert_array_equal(a.speed.speed_mps, b.speed.speed_mps)
    assert not np.allclose(np.nan_to_num(a.z), np.nan_to_num(c.z))
    assert len(a.measurements) == 201 and a.measurements[0].status == "first frame"


def test_true_motion_composes_to_world_positions():
    """The per-pair motions, composed with geometry.compose_motion, land on the world track
    (world = first frame's planar frame: x right, y forward)."""
    cfg = DriveConfig(duration_s=30, mount_random_walk=False, max_curvature_per_m=1 / 20,
                      turn_probability=1.0, segment_mean_s=4.0)
    tr = simulate_drive(cfg, seed=1).truth
    assert np.ptp(np.degrees(tr.heading)) > 10  # it really turns
    acc = PlanarMotion(0.0, 0.0, 0.0)
    for k in range(1, len(tr.t)):
        acc = compose_motion(acc, PlanarMotion(tr.tx[k], tr.tz[k], tr.yaw[k]))
    assert acc.tx == pytest.approx(tr.x[-1], abs=1e-6)
    assert acc.tz == pytest.approx(tr.y[-1], abs=1e-6)
    assert acc.yaw == pytest.approx(tr.heading[-1], abs=1e-9)


def test_yaw_offset_shows_as_lateral_motion():
    """A camera turned 2° right sees straight travel drift left: tx/tz = -tan 2°."""
    cfg = DriveConfig(duration_s=5, yaw_offset_deg=2.0, turn_probability=0.0,
                      mount_random_walk=False)
    tr = simulate_drive(cfg, seed=0).truth
    ratio = tr.tx[1:] / tr.tz[1:]
    np.testing.assert_allclose(ratio, -np.tan(np.radians(2.0)), atol=1e-9)


def test_noise_matches_reported_covariance_and_scale():
    cfg = DriveConfig(duration_s=200, height_m=1.6, height_assumed_m=1.5, angle_std_deg=0.1)
    run = simulate_drive(cfg, seed=2)
    tr, ok = run.truth, run.status == "ok"
    err = np.degrees(run.z[ok, 2] - tr.pitch[ok])
    assert np.std(err) == pytest.approx(0.1, rel=0.08)
    assert abs(np.mean(err)) < 0.01
    # prev/curr correlation of the angle noise
    e_prev = run.z[ok, 0] - np.concatenate([[np.nan], tr.pitch[:-1]])[ok]
    assert np.corrcoef(e_prev, run.z[ok, 2] - tr.pitch[ok])[0, 1] == pytest.approx(0.5, abs=0.05)
    # translation at the assumed height: t_meas = t_true · h0 / h
    scale = np.median(run.z[ok, 5] / tr.tz[ok])
    assert scale == pytest.approx(1.5 / 1.6, rel=1e-3)
    z_err = (run.z[ok, 5] - tr.tz[ok] * 1.5 / 1.6) / np.sqrt(run.covariance[ok, 5, 5])
    assert np.std(z_err) == pytest.approx(1.0, rel=0.08)


def test_outliers_failures_and_standstill():
    cfg = DriveConfig(duration_s=120, outlier_fraction=0.1, failure_fraction=0.05,
                      stop_probability=1.0, segment_mean_s=5.0)
    run = simulate_drive(cfg, seed=3)
    ok = run.status == "ok"
    assert run.outlier.sum() / ok.sum() == pytest.approx(0.1, abs=0.03)
    assert not np.any(run.outlier & ~ok)
    assert np.all(np.isnan(run.z[~ok]))
    assert not any(m.ok for m, s in zip(run.measurements, run.status, strict=True) if s != "ok")
    still = run.status == "no motion"
    assert still.sum() > 10 and np.all(run.truth.speed[still] < 0.5)
    failed = (run.status == "too few inliers").sum() / len(run.status)
    assert failed == pytest.approx(0.05, abs=0.02)
    bad = np.abs(np.degrees(run.z[run.outlier, 2] - run.truth.pitch[run.outlier]))
    assert np.median(bad) > 0.8


def test_mount_step_and_ramp():
    cfg = DriveConfig(duration_s=20, mount_random_walk=False, mount_changes=(
        MountChange(t_s=5.0, pitch_deg=0.5), MountChange(t_s=10.0, roll_deg=1.0, duration_s=4.0),
    ))
    tr = simulate_drive(cfg, seed=0).truth
    p, r = np.degrees(tr.mount_pitch), np.degrees(tr.mount_roll)
    assert p[tr.t < 5].max() == pytest.approx(3.0) and p[tr.t >= 5].min() == pytest.approx(3.5)
    assert r[tr.t == 12.0][0] == pytest.approx(0.5) and r[-1] == pytest.approx(1.0)


def test_wheel_speed_noise_quantisation_and_clock():
    cfg = DriveConfig(duration_s=60, speed_clock_offset_s=0.2)
    run = simulate_drive(cfg, seed=6)
    s = run.speed
    assert np.median(np.diff(s.t)) == pytest.approx(0.02)
    kmh = s.speed_mps * 3.6 / 0.01
    np.testing.assert_allclose(kmh, np.round(kmh), atol=1e-6)
    true = np.interp(s.t + 0.2, run.truth.t, run.truth.speed)
    rel = (s.speed_mps - true) / true
    assert np.std(rel) == pytest.approx(0.005, rel=0.15)
    # the camera-clock lookup undoes the offset
    v = s.at(run.truth.t[10:-10], clock_offset_s=0.2)
    np.testing.assert_allclose(v, run.truth.speed[10:-10], rtol=0.03)


def test_cart_preset_and_bad_config():
    run = simulate_drive(DriveConfig.preset("cart", duration_s=20), seed=0)
    assert 0.8 <= np.nanmedian(run.truth.speed) <= 1.6
    assert np.nanmedian(run.truth.tz) == pytest.approx(np.nanmedian(run.truth.speed) / 10, rel=0.1)
    with pytest.raises(ValueError, match="preset"):
        DriveConfig.preset("truck")
    with pytest.raises(ValueError, match="must be > 0"):
        simulate_drive(DriveConfig(height_m=-1.0))


def test_an_hour_is_fast():
    """Vectorised: an hour at 20 fps (72 001 frames) is produced at once (no timing assert,
    just that it completes and is sane)."""
    run = simulate_drive(DriveConfig(duration_s=3600), seed=9)
    assert run.z.shape == (72001, 7) and np.isfinite(run.truth.x[-1])
