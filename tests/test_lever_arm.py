"""The camera's lever arms (``filters.lever_arm``): the filters' lateral motion against the
truth of simulated drives whose camera sits away from the vehicle's axes, and of KITTI 07."""

from __future__ import annotations

import math
from dataclasses import replace
from unittest import mock

import numpy as np
import pytest

from tests.test_kitti import KITTI_ESTIMATES, _kitti_truth
from vipm_track.filters.drive_sim import DriveConfig, simulate_drive
from vipm_track.filters.ekf import run_filter
from vipm_track.filters.ekf_state import EkfConfig
from vipm_track.filters.filter_common import FrameEstimate
from vipm_track.filters.lever_arm import LeverArm, corrected_drive
from vipm_track.filters.model import BODY_ROLL, PREV_BODY_ROLL, STATE_DIM, NoiseParams
from vipm_track.filters.smoother_config import SmootherConfig
from vipm_track.filters.smoothing import smooth
from vipm_track.measurement import PairMeasurement, measurements_from_table
from vipm_track.table import read_table


def _tx_errors(frames, truth_tx: dict[int, float]) -> tuple[np.ndarray, np.ndarray]:
    """Lateral motion errors [m] and their stated σ of every frame with a motion."""
    rows = [(f.motion[0] - truth_tx[f.frame], math.sqrt(f.motion_cov[0, 0])) for f in frames
            if f.frame in truth_tx and np.isfinite(truth_tx[f.frame])
            and f.motion is not None and np.all(np.isfinite(f.motion))]
    e, s = np.array(rows).T
    return e, s


def _without_arms():
    return mock.patch.object(LeverArm, "apply", lambda self, estimate: estimate)


@pytest.fixture(scope="module")
def car_with_arms():
    cfg = DriveConfig.preset("car", duration_s=30.0, lever_arm_m=1.2, roll_arm_m=1.4)
    run = simulate_drive(cfg, seed=3)
    return run, {m.frame: float(run.truth.tx[m.frame]) for m in run.measurements}


def test_the_simulated_camera_slides_by_its_lever_arms():
    # the drive's truth: the camera's lateral motion is the vehicle's plus L·sin Δψ (ahead
    # of the turning point) plus the sway of its height above the roll axis
    base = simulate_drive(DriveConfig.preset("car", duration_s=20.0), seed=1)
    ahead = simulate_drive(DriveConfig.preset("car", duration_s=20.0, lever_arm_m=1.5), seed=1)
    above = simulate_drive(DriveConfig.preset("car", duration_s=20.0, roll_arm_m=1.5), seed=1)
    yaw, roll = base.truth.yaw[1:], base.truth.body_roll
    assert np.abs(yaw).max() > math.radians(0.1)  # the drive turns
    np.testing.assert_allclose(ahead.truth.tx[1:] - base.truth.tx[1:], 1.5 * np.sin(yaw),
                               atol=2e-4)
    sway = 1.5 * np.diff(np.sin(roll))
    np.testing.assert_allclose(above.truth.tx[1:] - base.truth.tx[1:], sway, atol=2e-4)
    assert np.std(sway) > 1e-3
    np.testing.assert_array_equal(ahead.truth.x, base.truth.x)  # the vehicle's own path


@pytest.mark.parametrize("which", ["EKF", "batch", "fixed lag"])
def test_lateral_motion_holds_the_truth_with_the_arms(car_with_arms, which):
    run, truth = car_with_arms

    def filtered():
        if which == "EKF":
            return run_filter(run.measurements, run.speed, EkfConfig(height_m=1.5))
        lag = 2.0 if which == "fixed lag" else 0.0
        return smooth(run.measurements, run.speed, SmootherConfig(height_m=1.5, lag_s=lag))

    e, s = _tx_errors(filtered(), truth)
    with _without_arms():
        e0, _ = _tx_errors(filtered(), truth)
    rms, rms0 = np.sqrt(np.mean(e**2)), np.sqrt(np.mean(e0**2))
    cover = np.mean(np.abs(e / s) < 1.96)
    # before: 5–6 mm off (the errors' correlation widened σ to hold 55–70 % of the frames)
    assert rms0 > 4e-3
    assert rms < 0.6 * rms0 and rms < 2.5e-3
    assert cover > 0.88


def test_a_camera_on_the_vehicle_axes_is_left_as_it_was():
    run = simulate_drive(DriveConfig.preset("car", duration_s=30.0), seed=4)
    truth = {m.frame: float(run.truth.tx[m.frame]) for m in run.measurements}
    cfg = SmootherConfig(height_m=1.5)
    e, s = _tx_errors(smooth(run.measurements, run.speed, cfg), truth)
    with _without_arms():
        e0, _ = _tx_errors(smooth(run.measurements, run.speed, cfg), truth)
    assert np.sqrt(np.mean(e**2)) < 1.3 * np.sqrt(np.mean(e0**2)) + 1e-4
    assert np.mean(np.abs(e / s) < 1.96) > 0.95


def test_kitti_lateral_motion_with_the_arms():
    # KITTI 07's camera sits about a metre ahead of the rear axle and turns at up to 35°/s:
    # the smoothed lateral motion was 30 mm RMS off (the pairs' own 10 mm) at σ 1.3 mm
    truth_table = _kitti_truth()
    truth = {int(f): float(x) for f, x in zip(truth_table["frame"], truth_table["tx_m"],
                                                strict=True)}
    ms = measurements_from_table(read_table(KITTI_ESTIMATES))
    cfg = SmootherConfig(height_m=1.65)
    e, s = _tx_errors(smooth(ms, None, cfg), truth)
    with _without_arms():
        e0, _ = _tx_errors(smooth(ms, None, cfg), truth)
    assert np.sqrt(np.mean(e0**2)) > 0.025
    # 6.2 mm; 6.8 where the batch took the arms of the pairs so far, not the whole drive's
    assert np.sqrt(np.mean(e**2)) < 0.0065
    # still too narrow (docs/filters.md): the rest of the camera's lateral motion; 50 %
    # (z RMS 2.75; 45 % and 3.0 without the fit's own variance)
    assert np.mean(np.abs(e / s) < 1.96) > 0.48
    assert np.sqrt(np.mean((e / s) ** 2)) < 2.85


def _estimate(frame: int, tx: float, yaw: float, roll_change: float) -> FrameEstimate:
    state = np.zeros(STATE_DIM)
    state[BODY_ROLL], state[PREV_BODY_ROLL] = roll_change, 0.0
    cov = np.eye(STATE_DIM) * 1e-10
    return FrameEstimate(
        frame=frame, t=0.1 * frame, status="ok", mount=np.array([0.05, 0.0, 3.0]),
        mount_cov=np.eye(3) * 1e-8, mount_yaw=0.0, pose=np.zeros(3), pose_cov=np.eye(3) * 1e-8,
        motion=np.array([tx, 1.0, yaw]), motion_cov=np.diag([1e-6, 1e-6, 1e-8]), speed=10.0,
        yaw_rate=yaw / 0.1, position=np.zeros(2), heading=0.0, state=state, covariance=cov)


def _pair(frame: int, tx_measured: float, std: float = 0.003) -> PairMeasurement:
    # measured at an assumed height of 1.5 m where the filter's is 3 m: half the metres
    z = np.array([0.0, 0.0, 0.0, 0.0, tx_measured / 2.0, 0.5, 0.0])
    return PairMeasurement(frame, 0.1 * frame, z, np.eye(7) * (std / 2.0) ** 2,
                           height_assumed=1.5)


def _turning_drive(ahead: float, above: float, n: int = 300, noise_m: float = 0.003,
                   outliers: tuple[int, ...] = ()):
    """Estimates without the slide and pairs measuring it (``outliers``: frames half a
    metre off sideways, the first turning by 0.08 rad)."""
    rng = np.random.default_rng(0)
    estimates, pairs = [], {}
    for k in range(1, n + 1):
        yaw, roll_change = rng.normal(0, 0.03), rng.normal(0, 0.003)
        if k == 1:
            yaw = 0.08
        measured = ahead * math.sin(yaw) + above * roll_change + rng.normal(0, noise_m)
        if k in outliers:
            measured += 0.5
        estimates.append(_estimate(k, 0.0, yaw, roll_change))
        pairs[k] = _pair(k, measured)
    return estimates, pairs


def test_the_fit_finds_both_arms_and_passes_over_an_outlier():
    ahead, above = 0.8, 1.3
    # outliers: among the first pairs that turn (it must not set the arms and shut the good
    # pairs out) and later
    estimates, pairs = _turning_drive(ahead, above, outliers=(1, 150))
    fit = LeverArm(2.0)
    for e in estimates:
        fit.observe(e, pairs[e.frame])
    # pair by pair (the EKF, the fixed lag): the first outlier stays in, its scatter widens
    # the fit's σ; the later one is gated
    std = np.sqrt(np.diag(fit.covariance))
    assert np.all(np.abs(fit.arms_m - [ahead, above]) < 3 * std)
    assert fit._pairs == 299
    # the batch fits twice, gating every pair against the first fit: neither stays in
    out = corrected_drive(estimates, pairs, 2.0)
    truth = np.array([ahead * math.sin(e.motion[2]) + above * e.state[BODY_ROLL]
                      for e in estimates])
    err = np.array([o.motion[0] for o in out]) - truth
    assert np.sqrt(np.mean(err**2)) < 1e-3
    # a pair the filter gated, one without a usable measurement and a frame without motion
    gated = replace(estimates[0], gated="motion")
    before = fit.arms_m.copy()
    fit.observe(gated, _pair(1, 5.0))
    fit.observe(estimates[0], PairMeasurement(1, 0.1, np.full(7, np.nan), np.eye(7), 1.5,
                                              status="failed"))
    np.testing.assert_array_equal(fit.arms_m, before)
    still = replace(estimates[0], motion=np.full(3, np.nan))
    assert fit.apply(still) is still
    with pytest.raises(ValueError, match="prior_std_m"):
        LeverArm(-1.0)


def test_the_slide_and_its_variance_are_the_fits():
    # pairs scattering twice their stated σ: the fit's covariance is its information's
    # inverse times the reduced χ² (the prior's share taken out), and each frame's tx
    # variance gains the yaw Jacobian's, the roll change's and the fit's
    estimates, pairs = _turning_drive(0.8, 1.3, n=120, noise_m=0.006)
    fit = LeverArm(2.0)
    for e in estimates:
        fit.observe(e, pairs[e.frame])
    x = np.array([[math.sin(e.motion[2]), e.state[BODY_ROLL]] for e in estimates])
    r = np.array([pairs[e.frame].z[4] * 2.0 for e in estimates])  # metres at 3 m
    w = 1.0 / 0.003**2
    info = x.T @ x * w + np.eye(2) / 4.0
    arms = np.linalg.solve(info, x.T @ r * w)
    chi2 = np.sum((r - x @ arms) ** 2) * w
    cov = np.linalg.inv(info) * max(1.0, chi2 / (len(r) - 2))
    assert chi2 / (len(r) - 2) > 3.0
    np.testing.assert_allclose(fit.arms_m, arms, rtol=1e-9)
    np.testing.assert_allclose(fit.covariance, cov, rtol=1e-9)
    e = replace(estimates[7], motion_cov=np.array([[4e-6, 1e-7, 2e-8], [1e-7, 1e-6, 0.0],
                                                   [2e-8, 0.0, 1e-8]]))
    p = np.eye(STATE_DIM) * 1e-10
    p[BODY_ROLL, BODY_ROLL], p[PREV_BODY_ROLL, PREV_BODY_ROLL] = 4e-6, 3e-6
    p[BODY_ROLL, PREV_BODY_ROLL] = p[PREV_BODY_ROLL, BODY_ROLL] = 1e-6
    e = replace(e, covariance=p)
    out = fit.apply(e)
    j = arms[0] * math.cos(e.motion[2])
    xe = np.array([math.sin(e.motion[2]), e.state[BODY_ROLL]])
    var = (4e-6 + 2 * j * 2e-8 + j**2 * 1e-8 + arms[1] ** 2 * (4e-6 + 3e-6 - 2e-6)
           + xe @ cov @ xe)
    assert out.motion_cov[0, 0] == pytest.approx(var, rel=1e-9)
    assert out.motion_cov[0, 2] == pytest.approx(2e-8 + j * 1e-8, rel=1e-9)
    assert out.motion[0] == pytest.approx(e.motion[0] + xe @ arms, rel=1e-9)


def test_the_batch_takes_one_fit_of_the_whole_drive(car_with_arms):
    # the batch's correction is the same arms on every frame (the EKF and the fixed lag
    # take the pairs so far)
    run, _ = car_with_arms
    cfg = SmootherConfig(height_m=1.5)
    now = smooth(run.measurements, run.speed, cfg)
    with _without_arms():
        before = smooth(run.measurements, run.speed, cfg)
    rows = [(n.motion[0] - b.motion[0], math.sin(b.motion[2]),
             b.state[BODY_ROLL] - b.state[PREV_BODY_ROLL])
            for n, b in zip(now, before, strict=True) if np.all(np.isfinite(n.motion))]
    d, *x = np.array(rows).T
    arms, *_ = np.linalg.lstsq(np.array(x).T, d, rcond=None)
    assert np.max(np.abs(np.array(x).T @ arms - d)) < 1e-9
    assert 0.9 < arms[0] < 1.3 and 1.0 < arms[1] < 1.6


def test_a_late_pair_does_not_enter_the_fit(car_with_arms):
    # a pair the EKF leaves out (its time not after the last) must not be fitted against
    # the state of another frame (nor widen its σ: row_correlation, heave)
    run, _ = car_with_arms
    ms = run.measurements[:200]
    late = replace(ms[120], frame=10_000, z=ms[120].z + np.array([0, 0, 0, 0, 0.3, 0, 0]))
    cfg = EkfConfig(height_m=1.5)
    plain = run_filter(ms, run.speed, cfg)
    with_late = run_filter([*ms[:150], late, *ms[150:]], run.speed, cfg)
    with_late = [s for s in with_late if s.frame != 10_000]
    np.testing.assert_array_equal([s.motion for s in plain[150:]],
                                  [s.motion for s in with_late[150:]])
    np.testing.assert_array_equal([s.motion_cov for s in plain[150:]],
                                  [s.motion_cov for s in with_late[150:]])


def test_no_lever_arm_leaves_the_lateral_motion_as_the_model_has_it(tmp_path):
    # `--lever-arm-std 0`: the camera moves as the vehicle; nothing is fitted or added
    from vipm_track.cli import main

    out = tmp_path / "s.csv"
    assert main(["smooth", "--estimates", str(KITTI_ESTIMATES), "--height", "1.65",
                 "--lever-arm-std", "0", "--out", str(out), "--quiet"]) == 0
    table = read_table(out)
    ms = measurements_from_table(read_table(KITTI_ESTIMATES))
    cfg = SmootherConfig(height_m=1.65, noise=NoiseParams(lever_arm_std_m=0.0))
    with _without_arms():
        frames = smooth(ms, None, cfg)
    np.testing.assert_allclose(table["tx_m"].astype(float),
                               [f.motion[0] for f in frames], rtol=1e-9, equal_nan=True)
    fit = LeverArm(0.0)
    fit.observe(*_turning_drive(0.8, 1.3, n=1)[0], _pair(1, 0.3))
    np.testing.assert_array_equal(fit.arms_m, [0.0, 0.0])
