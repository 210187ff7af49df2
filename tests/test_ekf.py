"""EKF over simulated measurement streams: accuracy vs truth, height from wheel speed,
consistency, outliers, gaps, resets, and the ``track`` subcommand."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from filters import model as M
from filters.drive_sim import DriveConfig, MountChange, simulate_drive
from filters.ekf import EkfConfig, ExtrinsicsEKF, run_filter
from filters.metrics import consistency, from_filter_states, score_run
from vipm_track.cli import main
from vipm_track.measurement import PairMeasurement, measurement_row
from vipm_track.table import ESTIMATE_COLUMNS, read_table, write_table


def _drive(preset="car", seed=0, **kw):
    h0 = 1.5 if preset == "car" else 0.7
    kw = {"duration_s": 40.0, "height_m": 1.02 * h0, "height_assumed_m": h0, **kw}
    return simulate_drive(DriveConfig.preset(preset, **kw), seed)


def _filter(run, speed=False, **kw):
    cfg = EkfConfig(height_m=run.config.h0, noise=run.config.noise, **kw)
    return run_filter(run.measurements, run.speed if speed else None, cfg)


# --- model ----------------------------------------------------------------------------------


def _state(rng):
    x = rng.normal(0, 0.05, M.STATE_DIM)
    x[M.MOUNT_HEIGHT], x[M.SPEED], x[M.YAW_RATE] = 1.4, 12.0, 0.1
    x[M.POS_X], x[M.POS_Y], x[M.HEADING] = 3.0, 40.0, 0.4
    x[M.PREV_POS_X], x[M.PREV_POS_Y], x[M.PREV_HEADING] = 2.7, 39.4, 0.39
    return x


def test_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    x = _state(rng)
    eps = 1e-6
    fns = (
        lambda s: M.pair_measurement(s, 1.5),
        lambda s: M.transition(s, 0.05, M.NoiseParams())[:2],
        M.metric_motion,
    )
    for fn in fns:
        _, jac = fn(x)
        num = np.stack([(fn(x + eps * e)[0] - fn(x - eps * e)[0]) / (2 * eps)
                        for e in np.eye(M.STATE_DIM)], axis=1)
        np.testing.assert_allclose(jac, num, atol=1e-6)


def test_pair_model_matches_the_simulated_truth():
    """expected_pair of the true states reproduces the simulator's noise-free pair (so the
    model and drive_sim agree on frames, signs and scale)."""
    cfg = DriveConfig(duration_s=20, height_m=1.6, height_assumed_m=1.5, yaw_offset_deg=1.5,
                      angle_std_deg=0.0, trans_std_rel=0.0, trans_std_abs_m=0.0, yaw_std_deg=0.0,
                      failure_fraction=0.0)
    run = simulate_drive(cfg, seed=3)
    tr = run.truth
    for k in range(1, len(tr.t), 37):
        z = M.expected_pair(
            (tr.mount_pitch[k], tr.mount_roll[k], tr.mount_height[k], tr.mount_yaw[k - 1]),
            (tr.body_pitch[k - 1], tr.body_roll[k - 1]), (tr.body_pitch[k], tr.body_roll[k]),
            (tr.x[k - 1], tr.y[k - 1], tr.heading[k - 1]), (tr.x[k], tr.y[k], tr.heading[k]), 1.5)
        np.testing.assert_allclose(z[4:], run.z[k, 4:], atol=1e-9)
        np.testing.assert_allclose(z[[1, 3]], run.z[k, [1, 3]], atol=1e-4)  # mount walk


# --- accuracy -------------------------------------------------------------------------------


@pytest.mark.parametrize("preset", ["car", "cart"])
def test_mount_rms_after_5s(preset):
    """Pooled over 3 drives: mount pitch/roll RMS after 5 s ≤ 0.05° and ≥ 2× below raw."""
    scores = [score_run(r, from_filter_states(_filter(r)))
              for r in (_drive(preset, seed=s, duration_s=60.0) for s in range(3))]
    pitch = np.sqrt(np.mean([s.pitch_rms_deg**2 for s in scores]))
    roll = np.sqrt(np.mean([s.roll_rms_deg**2 for s in scores]))
    raw = min(np.sqrt(np.mean([s.raw_pitch_rms_deg**2 for s in scores])),
              np.sqrt(np.mean([s.raw_roll_rms_deg**2 for s in scores])))
    assert pitch <= 0.05 and roll <= 0.05
    assert max(pitch, roll) * 2 <= raw


def test_height_from_wheel_speed_and_prior_without():
    run = _drive(seed=1)  # true height 1.53 m, nominal 1.5 m
    with_speed = np.array([s.mount[2] for s in _filter(run, speed=True)])
    without = np.array([s.mount[2] for s in _filter(run, speed=False)])
    late = run.truth.t >= 10
    err = np.abs(with_speed[late] / run.truth.mount_height[late] - 1)
    assert err.max() < 0.01
    np.testing.assert_allclose(without[np.isfinite(without)], 1.5, atol=1e-9)  # stays at prior


def test_consistency_nees_nis_inside_bounds():
    runs = [_drive(seed=s, duration_s=30.0) for s in range(6)]
    ests = [from_filter_states(_filter(r, speed=True)) for r in runs]
    con = consistency(runs, ests, [0, 1, 2, 3, 4])
    assert con.anees_bounds[0] <= con.anees <= con.anees_bounds[1]
    assert con.anis_bounds[0] <= con.anis <= con.anis_bounds[1]
    assert con.anees_inside > 0.85 and con.anis_inside > 0.85


def test_overconfident_measurements_fail_consistency():
    """The check can fail: an estimator that reports 3× too small std breaks NIS."""
    runs = [_drive(seed=s, duration_s=20.0, cov_scale=1 / 9) for s in range(4)]
    ests = [from_filter_states(_filter(r)) for r in runs]
    con = consistency(runs, ests, [0, 1, 3, 4])
    assert con.anis > con.anis_bounds[1]


def test_outliers_do_not_pull_the_state():
    clean = [_drive(seed=s, duration_s=40.0) for s in range(3)]
    dirty = [_drive(seed=s, duration_s=40.0, outlier_fraction=0.1) for s in range(3)]
    rms = []
    for runs in (clean, dirty):
        states = [_filter(r, speed=True) for r in runs]
        assert all(s.status != "reset" for st in states for s in st)
        sc = [score_run(r, from_filter_states(st)) for r, st in zip(runs, states, strict=True)]
        rms.append(np.sqrt(np.mean([s.pitch_rms_deg**2 + s.roll_rms_deg**2 for s in sc])))
        if runs is dirty:
            gated = np.array([s.gated != "" for s in states[0]])
            assert gated[dirty[0].outlier].mean() > 0.95  # outliers are caught
            assert max(s.height_err_max_pct for s in sc) < 1.0
    assert rms[1] <= 1.5 * rms[0]


# --- gaps, resets, bad input ----------------------------------------------------------------


def test_predicts_through_gaps():
    run = _drive(seed=2, duration_s=30.0, failure_fraction=0.0)
    ms = list(run.measurements)
    nan7, nan77 = np.full(7, np.nan), np.full((7, 7), np.nan)
    for k in range(200, 240):  # a 2-s gap
        ms[k] = PairMeasurement(k, ms[k].t, nan7, nan77, 1.5, "too few inliers")
    states = run_filter(ms, run.speed, EkfConfig(height_m=1.5))
    assert all(s.status == "predicted" for s in states[200:240])
    assert states[239].pose_std[0] > states[199].pose_std[0]  # body uncertainty grows
    assert all(s.status != "reset" for s in states)
    err = np.degrees(states[-1].mount[0] - run.truth.mount_pitch[-1])
    assert abs(err) < 0.1


def test_mount_step_resets_with_reason_and_reconverges():
    run = _drive(seed=4, duration_s=40.0, mount_changes=(MountChange(t_s=15.0, pitch_deg=3.0),))
    states = _filter(run, speed=True)
    resets = [s for s in states if s.status == "reset"]
    assert len(resets) >= 1 and "gated on pitch/roll" in resets[0].reset_reason
    assert 15.0 < resets[0].t < 17.0
    assert any("re-initialised after" in s.reset_reason for s in states)
    final = states[-1].mount[0] - run.truth.mount_pitch[-1]
    assert abs(final) < 4 * states[-1].mount_std[0] and abs(np.degrees(final)) < 0.15


def test_malformed_covariance_never_diverges_silently():
    run = _drive(seed=5, duration_s=10.0)
    ekf = ExtrinsicsEKF(EkfConfig(height_m=1.5))
    for k, m in enumerate(run.measurements):
        if k == 100:  # a pair claiming negative variances
            m = replace(m, covariance=-np.eye(7))
        s = ekf.step(m)
        if s.initialised and s.status != "reset":
            assert np.all(np.isfinite(s.state)) and np.all(np.diag(s.covariance) >= 0)
            assert np.min(np.linalg.eigvalsh(s.covariance)) > -1e-9 * np.max(np.diag(s.covariance))


def test_out_of_order_time_is_reported_not_applied():
    run = _drive(seed=0, duration_s=5.0)
    ekf = ExtrinsicsEKF(EkfConfig(height_m=1.5))
    for m in run.measurements[:50]:
        last = ekf.step(m)
    again = ekf.step(run.measurements[10])
    assert "not after" in again.reset_reason
    np.testing.assert_array_equal(again.state, last.state)


# --- CLI ------------------------------------------------------------------------------------


def test_track_cli_from_estimates_with_speed(tmp_path):
    run = _drive(seed=7, duration_s=20.0)
    est = tmp_path / "est.csv"
    write_table(est, [measurement_row(m) for m in run.measurements], ESTIMATE_COLUMNS)
    speed = tmp_path / "speed.csv"
    np.savetxt(speed, np.c_[run.speed.t, run.speed.speed_mps], delimiter=",",
               header="t,speed_mps", comments="")
    out = tmp_path / "track.csv"
    assert main(["track", "--estimates", str(est), "--height", "1.5", "--speed-csv", str(speed),
                 "--out", str(out), "--quiet"]) == 0
    tab = read_table(out)
    assert len(tab["frame"]) == len(run.measurements)
    head = out.read_text().splitlines()[0].split(",")
    assert head[:9] == ["frame", "t", "pitch_deg", "roll_deg", "height_m", "tx_m", "tz_m",
                        "yaw_deg", "status"]
    late = tab["t"] > 10
    assert np.all(np.abs(tab["mount_height_m"][late] - 1.53) < 0.015)
    mp = np.radians(tab["mount_pitch_deg"][late])
    assert np.sqrt(np.mean((mp - run.truth.mount_pitch[late]) ** 2)) < np.radians(0.08)
    assert tab["status"][0] == "waiting for first pairs" and tab["status"][-1] == "ok"


def test_track_cli_errors(tmp_path, capsys):
    bad = tmp_path / "speed.csv"
    bad.write_text("t,v\n0,1\n")
    est = tmp_path / "est.csv"
    run = _drive(seed=0, duration_s=2.0)
    write_table(est, [measurement_row(m) for m in run.measurements], ESTIMATE_COLUMNS)
    out = str(tmp_path / "o.csv")
    assert main(["track", "--estimates", str(est), "--height", "1.5", "--speed-csv", str(bad),
                 "--out", out]) == 2
    assert "speed_mps" in capsys.readouterr().err
    assert main(["track", "--estimates", str(tmp_path / "none.csv"), "--height", "1.5",
                 "--out", out]) == 2
    assert main(["track", "--height", "1.5", "--out", out]) == 2
    assert main(["track", "--estimates", str(est), "--height", "-1", "--out", out]) == 2
