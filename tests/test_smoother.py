"""Factor-graph smoother (filters/smoother.py, filters/factors.py) on simulated drives."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np
import pytest
from conftest import stop_in_a_turn

from vipm_track.cli import main
from vipm_track.filters import factors as F
from vipm_track.filters import model as M
from vipm_track.filters.drive_sim import DriveConfig, DriveProfile, simulate_drive
from vipm_track.filters.drive_summary import summarize_mount, summary_markdown
from vipm_track.filters.ekf import run_filter
from vipm_track.filters.ekf_state import EkfConfig
from vipm_track.filters.fixed_lag import FixedLagSmoother, SolveError
from vipm_track.filters.metrics import from_filter_states, rms_after
from vipm_track.filters.smoother import smooth_batch
from vipm_track.filters.smoother_config import SmootherConfig
from vipm_track.filters.smoother_marginals import block_marginals
from vipm_track.filters.smoothing import smooth, speeds_at_frames
from vipm_track.filters.wheel_speed import read_speed_csv
from vipm_track.measurement import PairMeasurement, measurement_row, read_measurements
from vipm_track.table import ESTIMATE_COLUMNS, read_table, write_table

DATA = Path(__file__).parent / "data"
H_TRUE, H0 = 1.53, 1.5


def _drive(seed: int, duration: float = 30.0, **kw) -> object:
    cfg = DriveConfig.preset("car", duration_s=duration, height_m=H_TRUE, height_assumed_m=H0, **kw)
    return simulate_drive(cfg, seed)


@pytest.fixture(scope="module")
def drive():
    return _drive(1)


@pytest.fixture(scope="module")
def batch(drive):
    cfg = SmootherConfig(height_m=H0, noise=drive.config.noise)
    return smooth_batch(drive.measurements, speeds_at_frames(drive.measurements, drive.speed), cfg)


def _mount_rms_deg(run, frames, settle=5.0) -> tuple[float, float]:
    est = from_filter_states(frames)
    tr = run.truth
    return (
        math.degrees(rms_after(tr.t, est.states[:, 0] - tr.mount_pitch, settle)),
        math.degrees(rms_after(tr.t, est.states[:, 1] - tr.mount_roll, settle)),
    )


# --- factors --------------------------------------------------------------------------------


def _numeric_jacobians(factor, values, keys, dims, eps=1e-7):
    """Central differences of the factor's unwhitened error along each key's tangent."""
    cols = []
    for kk, n in zip(keys, dims, strict=True):
        for i in range(n):
            plus, minus = gtsam.VectorValues(), gtsam.VectorValues()
            for other, m in zip(keys, dims, strict=True):
                vec = np.zeros(m)
                if other == kk:
                    vec[i] = eps
                plus.insert(other, vec)
                minus.insert(other, -vec)
            diff = factor.unwhitenedError(values.retract(plus)) - factor.unwhitenedError(
                values.retract(minus)
            )
            cols.append(diff / (2 * eps))
    return np.array(cols).T


def _random_values(rng, ks):
    v = gtsam.Values()
    for k in ks:
        v.insert(F.key("X", k), gtsam.Pose2(*rng.normal(0, [5, 5, 1])))
        v.insert(F.key("V", k), np.array([rng.uniform(3, 15)]))
        v.insert(F.key("W", k), np.array([rng.normal(0, 0.2)]))
        v.insert(F.key("M", k), rng.normal(0, 0.05, 2))
        v.insert(F.key("H", k), np.array([rng.uniform(1.2, 1.8)]))
        v.insert(F.key("Y", k), np.array([rng.normal(0, 0.05)]))
        v.insert(F.key("B", k), rng.normal(0, 0.01, 2))
    return v


def test_motion_factor_is_the_model_and_its_jacobians_are_right():
    rng = np.random.default_rng(0)
    v = _random_values(rng, (0, 1))
    # put frame 1 ahead of frame 0 along its heading
    p0 = v.atPose2(F.key("X", 0))
    v.update(F.key("X", 1), p0.compose(gtsam.Pose2(0.8, 0.05, 0.03)))
    z = np.array([0.01, 0.7, 0.02])
    f = F.motion_pair_factor(1, z, np.diag([1e-4, 1e-4, 1e-6]), H0, loss="none")
    s = np.zeros(M.STATE_DIM)
    s[[M.PREV_POS_X, M.PREV_POS_Y, M.PREV_HEADING]] = F.model_from_pose2(p0)
    s[[M.POS_X, M.POS_Y, M.HEADING]] = F.model_from_pose2(v.atPose2(F.key("X", 1)))
    s[M.MOUNT_HEIGHT] = v.atVector(F.key("H", 1))[0]
    s[M.MOUNT_YAW] = v.atVector(F.key("Y", 1))[0]
    expected = M.pair_measurement(s, H0)[0][4:7] - z
    np.testing.assert_allclose(f.unwhitenedError(v), expected, atol=1e-12)
    keys = [F.key("X", 0), F.key("X", 1), F.key("H", 1), F.key("Y", 1)]
    numeric = _numeric_jacobians(f, v, keys, [3, 3, 1, 1])
    a_all, _ = f.linearize(v).jacobian()
    whiten = np.diag(1.0 / np.array([1e-2, 1e-2, 1e-3]))
    np.testing.assert_allclose(a_all, whiten @ numeric, rtol=1e-5, atol=1e-4)


def test_motion_given_pose_factor_subtracts_the_regression_on_the_pose_residual():
    rng = np.random.default_rng(4)
    v = _random_values(rng, (0, 1))
    p0 = v.atPose2(F.key("X", 0))
    v.update(F.key("X", 1), p0.compose(gtsam.Pose2(0.8, 0.05, 0.03)))
    a = rng.normal(size=(7, 7))
    cov = a @ a.T * 1e-5 + np.eye(7) * 1e-6
    gain, cond = M.motion_given_pose(cov)
    # the decomposition: motion − A·angles is uncorrelated with the angles, of covariance cond
    t = np.hstack([-gain, np.eye(3)])
    np.testing.assert_allclose((t @ cov)[:, :4], 0.0, atol=1e-18)
    np.testing.assert_allclose(t @ cov @ t.T, cond, rtol=1e-9, atol=1e-18)
    z = np.array([0.01, 0.02, 0.015, 0.01, 0.01, 0.7, 0.02])
    keys = [F.key(c, k) for c, k in (("X", 0), ("X", 1), ("H", 1), ("Y", 1), ("M", 1),
                                    ("B", 0), ("B", 1))]
    marginal = F.motion_pair_factor(1, z[4:], cov[4:, 4:], H0, loss="none")
    pose = F.pose_pair_factor(1, z[:4], cov[:4, :4], loss="none")
    pose_res = pose.unwhitenedError(v)
    for loss, k4 in (("none", 1.0), ("geman-mcclure", 0.5 * pose.whitenedError(v).dot(
            pose.whitenedError(v)) ** 0.5)):
        given = F.GivenPose.of_pair(cov, z[:4], loss, k4)
        f = F.motion_pair_factor(1, z[4:], cov[4:, 4:], H0, loss="none", given_pose=given)
        # the pose block's robust weight w: the angles' covariance inflated by 1/w
        w = 1.0 if loss == "none" else 1.0 / (1.0 + 4.0) ** 2  # GM at half the norm: 1/25
        inflated = cov.copy()
        inflated[:4, :4] /= w
        gain_w, cond_w = M.motion_given_pose(inflated)
        np.testing.assert_allclose(gain_w, w * gain, rtol=1e-9, atol=1e-15)
        # self-whitened: W(cond_w) · (motion residual − w·A·pose residual)
        expected = F.whitener(cond_w) @ (marginal.unwhitenedError(v) - gain_w @ pose_res)
        np.testing.assert_allclose(f.unwhitenedError(v), expected, rtol=1e-9, atol=1e-9)
        # Jacobians with w held fixed (IRLS): numeric ones of the same expression
        numeric = _numeric_jacobians(f, v, keys, [3, 3, 1, 1, 2, 2, 2]) if w == 1.0 else None
        if numeric is not None:
            a_all, _ = f.linearize(v).jacobian()
            np.testing.assert_allclose(a_all, numeric, rtol=1e-5, atol=1e-6 * np.abs(a_all).max())


def test_process_factor_follows_propagate_pose_and_its_jacobians_are_right():
    rng = np.random.default_rng(1)
    v = _random_values(rng, (0, 1))
    dt = 0.05
    x0 = F.model_from_pose2(v.atPose2(F.key("X", 0)))
    v0, w0 = v.atVector(F.key("V", 0))[0], v.atVector(F.key("W", 0))[0]
    pred = M.propagate_pose(*x0, v0, w0, dt)
    v.update(F.key("X", 1), F.pose2_from_model(pred[0] + 0.01, pred[1] - 0.02, pred[2] + 0.003))
    f = F.process_factor(1, dt, M.NoiseParams(), 0.001)
    e = f.unwhitenedError(v)
    # the position residual is the prediction error rotated to along/across the heading
    a = x0[2] + 0.5 * w0 * dt
    d = np.array([0.01, -0.02])
    np.testing.assert_allclose(
        e[:2],
        [math.sin(a) * d[0] + math.cos(a) * d[1], math.cos(a) * d[0] - math.sin(a) * d[1]],
        atol=1e-9,
    )
    np.testing.assert_allclose(e[2], 0.003, atol=1e-9)
    keys = [F.key(c, j) for j in (0, 1) for c in "XVW"]
    numeric = _numeric_jacobians(f, v, keys, [3, 1, 1, 3, 1, 1])
    a_all, _ = f.linearize(v).jacobian()
    # undo the whitening: A = R·J with R the noise model's square-root information
    r = np.linalg.cholesky(np.linalg.inv(_process_cov(dt))).T
    j_all = np.linalg.solve(r, a_all)
    np.testing.assert_allclose(j_all, numeric, rtol=1e-5, atol=1e-6)


def _process_cov(dt):
    q = F.process_noise(dt, M.NoiseParams())
    idx = [M.POS_Y, M.POS_X, M.HEADING, M.SPEED, M.YAW_RATE]
    cov = q[np.ix_(idx, idx)].copy()
    cov[1, :] = cov[:, 1] = 0.0
    cov[1, 1] = 0.001**2
    return cov


# --- batch ----------------------------------------------------------------------------------

# the variables of frames k and k-1 in a gtsam joint marginal, and the model-state entries
# their tangent blocks map to (the reference for the smoother's own covariance sweep)
_MARGINAL_LAYOUT: tuple[tuple[str, int, list[int]], ...] = (
    ("M", 0, [M.MOUNT_PITCH, M.MOUNT_ROLL]),
    ("H", 0, [M.MOUNT_HEIGHT]),
    ("Y", 0, [M.MOUNT_YAW]),
    ("B", 0, [M.BODY_PITCH, M.BODY_ROLL]),
    ("V", 0, [M.SPEED]),
    ("W", 0, [M.YAW_RATE]),
    ("X", 0, [M.POS_X, M.POS_Y, M.HEADING]),
    ("B", -1, [M.PREV_BODY_PITCH, M.PREV_BODY_ROLL]),
    ("X", -1, [M.PREV_POS_X, M.PREV_POS_Y, M.PREV_HEADING]),
)


def _marginal_keys(k: int) -> list[int]:
    return [F.key(c, k + d) for c, d, _ in _MARGINAL_LAYOUT]


def _state_covariance(joint, state: np.ndarray) -> np.ndarray:
    """16×16 model-layout covariance from gtsam's joint marginal over ``_marginal_keys``
    (Pose2 tangents mapped to (x, y, ψ))."""
    full = np.asarray(joint.fullMatrix())
    t = np.zeros((M.STATE_DIM, full.shape[0]))
    col = 0
    for c, _, idx in _MARGINAL_LAYOUT:
        n = len(idx)
        t[np.ix_(idx, range(col, col + n))] = (
            F.tangent_jacobian(state[idx[2]]) if c == "X" else np.eye(n)
        )
        col += n
    return t @ full @ t.T



def test_block_marginals_equal_gtsams():
    run = _drive(2, duration=6.0)
    sp = speeds_at_frames(run.measurements, run.speed)
    import vipm_track.filters.smoother as S

    captured = {}
    original = S.optimize

    def spy(graph, values, *args, **kw):
        out = original(graph, values, *args, **kw)
        captured["graph"], captured["values"] = graph, out[0]
        return out

    S.optimize = spy
    try:
        frames, _ = smooth_batch(
            run.measurements, sp, SmootherConfig(height_m=H0, noise=run.config.noise)
        )
    finally:
        S.optimize = original
    graph, values = captured["graph"], captured["values"]
    # the frames' covariances are gtsam's marginals of the graph linearised at the estimate
    ref = gtsam.Marginals(graph.linearize(values), values)
    for k in (1, 40, len(frames) - 1):
        got = frames[k].covariance
        joint = ref.jointMarginalCovariance(_marginal_keys(k))
        want = _state_covariance(joint, frames[k].state)
        scale = np.sqrt(np.outer(np.diag(want), np.diag(want)))
        assert np.nanmax(np.abs(got - want) / scale) < 1e-6
    sigma, _ = block_marginals(graph.linearize(values), len(frames))
    assert np.all(np.linalg.eigvalsh(sigma) > 0)


def test_batch_beats_the_ekf_on_mount_pitch_and_roll(drive, batch):
    frames, info = batch
    assert len(frames) == len(drive.measurements)
    assert info.final_error < info.initial_error
    ekf = run_filter(
        drive.measurements, drive.speed, EkfConfig(height_m=H0, noise=drive.config.noise)
    )
    sp, sr = _mount_rms_deg(drive, frames)
    ep, er = _mount_rms_deg(drive, ekf)
    assert sp < ep and sr < er
    assert math.hypot(sp, sr) < 0.8 * math.hypot(ep, er)
    assert sp < 0.05 and sr < 0.05


def test_wheel_speed_makes_the_height_converge(drive, batch):
    frames, _ = batch
    h = np.array([f.mount[2] for f in frames])
    assert np.max(np.abs(h - drive.truth.mount_height)) / H_TRUE < 0.003
    # without speed the height stays at its prior (scale unobservable), pitch/roll unchanged
    no_speed, _ = smooth_batch(
        drive.measurements, None, SmootherConfig(height_m=H0, noise=drive.config.noise)
    )
    h2 = np.array([f.mount[2] for f in no_speed])
    np.testing.assert_allclose(h2, H0, atol=1e-3)
    assert abs(no_speed[-1].mount_std[2] - 0.05 * H0) < 0.01 * H0


def test_marginal_stds_are_positive_and_consistent(drive, batch):
    frames, _ = batch
    tr = drive.truth
    late = tr.t > 2.0
    pose = np.array([f.pose for f in frames])[late]
    std = np.array([f.pose_std for f in frames])[late]
    mstd = np.array([f.mount_std for f in frames])
    assert np.all(std > 0) and np.all(mstd > 0)
    # the frame pose (mount + body) changes within a second: many nearly independent errors
    z = (pose[:, :2] - np.c_[tr.pitch, tr.roll][late]) / std[:, :2]
    nees = float(np.mean(z**2))
    assert 0.5 < nees < 2.0, nees
    motion = np.array([f.motion for f in frames])[late]
    mstd = np.array([f.motion_std for f in frames])[late]
    good = np.all(np.isfinite(motion), axis=1)
    zt = (motion[good, :2] - np.c_[tr.tx, tr.tz][late][good]) / mstd[good, :2]
    # conservative: the motion priors (speed / yaw-rate random walks) are looser than the
    # simulated drive profiles, and the robust loss gives inliers weights a little below 1
    assert 0.2 < float(np.mean(zt**2)) < 3.0


def _with_burst(run, t0: float, t1: float, seed: int = 0) -> list:
    """The drive's measurements with every pair in [t0, t1) replaced by a wrong solution as
    ``drive_sim`` makes them: each angle off by ±1–2°, the translation ±15–30 %, the yaw
    ±0–2°. (A *consistent* offset over seconds is indistinguishable from real body pitch, e.g.
    braking, and is rightly followed by the frame pose.)"""
    rng = np.random.default_rng(seed)
    out = []
    for m in run.measurements:
        if t0 <= m.t < t1 and m.ok:
            z = m.z.copy()
            sign = rng.choice([-1.0, 1.0], size=5)
            z[:4] += np.radians(2.0) * sign[:4] * rng.uniform(0.5, 1.0, 4)
            z[4:6] *= 1.0 + 0.3 * sign[4] * rng.uniform(0.5, 1.0)
            z[6] += np.radians(2.0) * rng.uniform(-1.0, 1.0)
            m = replace(m, z=z)
        out.append(m)
    return out


def test_an_outlier_burst_does_not_pull_the_estimate():
    run = _drive(4, duration=20.0)
    sp = speeds_at_frames(run.measurements, run.speed)
    cfg = SmootherConfig(height_m=H0, noise=run.config.noise)
    clean, _ = smooth_batch(run.measurements, sp, cfg)
    burst = _with_burst(run, 8.0, 10.0)  # 2 s, 40 pairs in a row
    robust, _ = smooth_batch(burst, sp, cfg)
    plain, _ = smooth_batch(burst, sp, replace(cfg, loss="none"))

    def shift(frames, i):
        a = np.array([f.mount[i] for f in frames])
        b = np.array([f.mount[i] for f in clean])
        return float(np.max(np.abs(a - b)))

    # the angles move by less than their own 1-σ; random-sign angle errors average out even
    # without a robust loss, but the scale (height) does not: there the loss matters
    sigma = np.median([f.mount_std for f in clean], axis=0)
    assert shift(robust, 0) < sigma[0] and shift(robust, 1) < sigma[1]
    assert shift(robust, 2) < 0.002  # metres
    assert shift(plain, 2) > 3 * shift(robust, 2)
    inside = [f for f in robust if 8.0 <= f.t < 10.0 and f.status != "predicted"]
    assert sum(f.status in ("partial", "gated") for f in inside) >= 0.9 * len(inside)
    outside = [f for f in robust if not 8.0 <= f.t < 10.0 and f.status != "predicted"]
    assert sum(f.status != "ok" for f in outside) <= 0.01 * len(outside)


# --- fixed lag --------------------------------------------------------------------------------


def test_fixed_lag_gives_one_row_per_frame_in_order():
    run = _drive(5, duration=12.0)
    cfg = SmootherConfig(height_m=H0, noise=run.config.noise, lag_s=1.0)
    frames = smooth(run.measurements, run.speed, cfg)
    assert [f.frame for f in frames] == [m.frame for m in run.measurements]
    p, r = _mount_rms_deg(run, frames, settle=5.0)
    assert p < 0.15 and r < 0.15
    h = np.array([f.mount[2] for f in frames])
    assert abs(h[-1] - run.truth.mount_height[-1]) / H_TRUE < 0.005
    assert np.all(np.array([f.pose_std[0] for f in frames[10:]]) > 0)


def test_fixed_lag_streams_frames_after_the_lag():
    run = _drive(6, duration=4.0)
    sm = FixedLagSmoother(SmootherConfig(height_m=H0, noise=run.config.noise, lag_s=0.5))
    emitted = []
    for m in run.measurements:
        for f in sm.step(m):
            assert m.t - f.t >= 0.5 - 1e-9
            emitted.append(f.frame)
    emitted += [f.frame for f in sm.finish()]
    assert emitted == [m.frame for m in run.measurements]


def test_a_change_that_never_comes_holds_frames_no_longer_than_the_bound(monkeypatch):
    """The mount-change test's statistic stuck just below its threshold all drive: frames are
    held at most ``MAX_HOLD_S`` beyond the lag, then reported; the stream goes on."""
    from vipm_track.filters import fixed_lag

    run = _drive(6, duration=12.0)
    sm = FixedLagSmoother(SmootherConfig(height_m=H0, noise=run.config.noise, lag_s=0.5))
    monkeypatch.setattr(sm._mount_change, "pending_since", lambda share: 0.0)
    waits, emitted = [], []
    for m in run.measurements:
        for f in sm.step(m):
            waits.append(m.t - f.t)
            emitted.append(f.frame)
    emitted += [f.frame for f in sm.finish()]
    assert emitted == [m.frame for m in run.measurements]
    frame_s = float(np.median(np.diff([m.t for m in run.measurements])))
    assert len(waits) > 0.4 * len(emitted)
    assert max(waits) <= 0.5 + fixed_lag.MAX_HOLD_S + 1.5 * frame_s, max(waits)
    assert max(waits) >= 0.5 + fixed_lag.MAX_HOLD_S - 1.5 * frame_s  # (they were held)


def _fixed_lag_pitch_errors(name: str, height: float, preset: str, start_s: float = 0.0,
                            from_end_s: float = math.inf, frames_from_s: float = 0.0,
                            ) -> tuple[np.ndarray, np.ndarray]:
    """The rendered drive ``tests/data/{name}_*`` from ``start_s`` [s], smoothed with a 2-s
    lag: its frames' mount pitch error and σ [deg], of the frames from ``frames_from_s`` [s]
    and within ``from_end_s`` of its end."""
    ms = [m for m in read_measurements(DATA / f"{name}_est.csv") if m.t >= start_s]
    truth = read_table(DATA / f"{name}_gt.csv")["mount_pitch_deg"]
    frames = smooth(ms, read_speed_csv(DATA / f"{name}_speed.csv"),
                    SmootherConfig(height_m=height, noise=M.NoiseParams.for_preset(preset),
                                   lag_s=2.0))
    late = [f for f in frames if f.t >= max(frames[-1].t - from_end_s, frames_from_s)]
    return (np.array([math.degrees(f.mount[0]) - truth[f.frame] for f in late]),
            np.array([math.degrees(f.mount_std[0]) for f in late]))


@pytest.mark.parametrize("name, height, preset, knock_s", [
    ("car_knock", 1.5, "car", 6.38), ("knock_cart", 0.7, "cart", 7.16)])
def test_fixed_lag_jumps_once_at_a_knock_both_its_tests_find(name, height, preset, knock_s):
    """A knock the online test calls is in the pairs' steps too: the step watch leaves it
    to the call, and the mount jumps once, where the knock was."""
    ms = read_measurements(DATA / f"{name}_est.csv")
    speeds = speeds_at_frames(ms, read_speed_csv(DATA / f"{name}_speed.csv"))
    sm = FixedLagSmoother(SmootherConfig(height_m=height,
                                         noise=M.NoiseParams.for_preset(preset), lag_s=2.0))
    for m, v in zip(ms, speeds, strict=True):
        sm.step(m, float(v))
    sm.finish()
    assert len(sm.mount_changes) == 1, sm.mount_changes
    (at, axis, step), = sm.mount_changes
    assert axis == 0 and abs(at - knock_s) < 0.3 and 0.5 < math.degrees(step) < 1.5


def test_fixed_lag_holds_the_mount_across_a_knock_its_test_calls_late():
    # A rendered car on a shaking body, its camera knocked 1° in pitch at 6.4 s: the
    # mount-change test calls it 3 s later. The frames reported before the call had the new
    # mount taken for the old — 0.2–0.3° off at z 2–4 before the knock, 0.7° at z 13 after
    # it, 83 % of the frames in their 95 % interval. The frames are now held while a change
    # builds up, and the step is put where the pairs' angles step.
    err, std = _fixed_lag_pitch_errors("car_knock", 1.5, "car", frames_from_s=2.0)
    assert np.mean(np.abs(err) <= 1.96 * std) >= 0.95
    assert np.max(np.abs(err)) < 0.2


def test_fixed_lag_follows_a_knock_before_its_online_test_is_armed():
    # A rendered robot (0.3 m, 30°) knocked +1° in pitch at 4.8 s, before the mount-change
    # test has measured the road's wander (6 s): the window's body and mount took the step
    # up and the test never called it — the mount ended at 30.60 ± 0.05° for 31° (8σ), none
    # of the last 3 s in their interval. The batch's step test, run as the drive goes on,
    # finds it once 8 s of pairs are in; the frames reported after that hold the new mount.
    err, std = _fixed_lag_pitch_errors("robot_early_knock", 0.3, "cart", from_end_s=3.0)
    assert np.all(np.abs(err) <= 1.96 * std), (err, std)
    assert np.max(np.abs(err)) < 0.15


def test_fixed_lag_looks_for_a_knock_in_the_frames_it_started_on():
    # The rendered cart knocked +1° at 7.16 s, its drive cut to start 1.6 s before: the
    # knock falls into the frames the smoother collects before its window opens. A step
    # test on the window's frames only saw 0.6 s before the step, too little to find it:
    # the mount ended 0.14° off, none of the last 3 s in their interval.
    err, std = _fixed_lag_pitch_errors("knock_cart", 0.7, "cart", start_s=7.16 - 1.6,
                                       from_end_s=3.0)
    assert np.all(np.abs(err) <= 1.96 * std), (err, std)
    assert np.max(np.abs(err)) < 0.05


def test_fixed_lag_tests_for_a_knock_once_more_at_the_drive_s_end():
    # The rendered cart knocked +1° at 7.16 s, its drive cut at 8.7 s: the step watch's last
    # test, at 8 s, had too little after the knock to find it, and the window's frames held
    # the old mount (0.84° off at 0.06° σ where the drive ended at 8.4 s). ``finish`` tests
    # the pairs once more and re-solves the window with the jump.
    ms = [m for m in read_measurements(DATA / "knock_cart_est.csv") if m.t <= 8.7]
    truth = read_table(DATA / "knock_cart_gt.csv")["mount_pitch_deg"]
    speeds = speeds_at_frames(ms, read_speed_csv(DATA / "knock_cart_speed.csv"))
    sm = FixedLagSmoother(SmootherConfig(height_m=0.7, noise=M.NoiseParams.for_preset("cart"),
                                         lag_s=2.0))
    for m, v in zip(ms, speeds, strict=True):
        sm.step(m, float(v))
    assert sm.mount_changes == []
    late = [f for f in sm.finish() if f.t >= 7.4]
    (at, axis, step), = sm.mount_changes
    assert axis == 0 and abs(at - 7.16) < 0.3 and 0.7 < math.degrees(step) < 1.3
    err = np.array([math.degrees(f.mount[0]) - truth[f.frame] for f in late])
    std = np.array([math.degrees(f.mount_std[0]) for f in late])
    assert len(late) >= 10 and np.all(np.abs(err) <= 1.96 * std) and np.max(np.abs(err)) < 0.05


def test_bad_times_are_reported_and_skipped(drive):
    ms = list(drive.measurements[:60])
    ms[30] = replace(ms[30], t=ms[29].t)  # a repeated time stamp
    frames, _ = smooth_batch(ms, None, SmootherConfig(height_m=H0, noise=drive.config.noise))
    assert frames[30].status == "skipped" and "not after" in frames[30].reason
    assert all(f.status != "skipped" for i, f in enumerate(frames) if i != 30)


def test_summary_reports_mean_interval_and_drift(batch, drive):
    s = summarize_mount(batch[0])
    p = s["pitch"]
    truth = math.degrees(float(np.mean(drive.truth.mount_pitch)))
    assert p["ci95"][0] < truth < p["ci95"][1]
    assert abs(p["drift_per_min"]) < 0.1
    assert s["frames"] == len(drive.measurements)


def test_summary_interval_widens_to_slow_errors_the_model_lacks(batch, drive):
    # Where the model is right, the data's batch-means error matches the model's σ; add a
    # slow 0.5° wander (period 10 s: road camber, load) to the measured pitch and the model
    # still claims 0.03°, while the data widen the interval so that it covers the truth.
    ms = drive.measurements
    plain = summarize_mount(batch[0], ms)
    for axis in ("pitch", "roll"):
        assert 0.6 < plain[axis]["std_data"] / plain[axis]["std_model"] < 1.5
    t = np.array([m.t for m in ms])
    wander = np.radians(0.5) * np.sin(2 * np.pi * t / 10.0)
    bent = [replace(m, z=m.z + np.array([w0, 0, w1, 0, 0, 0, 0]))
            for m, w0, w1 in zip(ms, np.r_[0.0, wander[:-1]], wander, strict=True)]
    cfg = SmootherConfig(height_m=H0, noise=drive.config.noise)
    frames, _ = smooth_batch(bent, speeds_at_frames(bent, drive.speed), cfg)
    s = summarize_mount(frames, bent)
    p = s["pitch"]
    assert p["interval_from"] == "data" and s["roll"]["interval_from"] == "model"
    assert p["std_data"] > 2 * p["std_model"]
    truth = math.degrees(float(np.mean(drive.truth.mount_pitch)))
    assert p["ci95"][0] < truth < p["ci95"][1]


def test_summary_interval_leaves_out_a_pair_the_smoother_rejected(batch, drive):
    # One pair whose pose is 75° off (a corrupt row): the smoother rejects its pose, and the
    # data's spread must not take it in (it widened the interval fifteenfold).
    ms = list(drive.measurements)
    plain = summarize_mount(batch[0], ms)
    ms[40] = replace(ms[40], z=ms[40].z + np.radians([0, 0, -75.0, 0, 0, 0, 0]))
    cfg = SmootherConfig(height_m=H0, noise=drive.config.noise)
    frames, _ = smooth_batch(ms, speeds_at_frames(ms, drive.speed), cfg)
    assert "pose" in frames[40].gated
    s = summarize_mount(frames, ms)
    for axis in ("pitch", "roll"):
        width = np.diff(s[axis]["ci95"])[0] / np.diff(plain[axis]["ci95"])[0]
        assert width < 1.2, (axis, width)


def test_summary_warns_of_a_height_the_wheel_speed_scaled(batch, drive):
    # A wheel speed 3× the drive's (another drive, km/h read as m/s) moves the height with
    # it and most pairs still fit: the summary said nothing (a CAN log of another drive gave
    # a 0.7 m cart 5.56 m).
    ms = drive.measurements
    assert "height_scale" not in summarize_mount(batch[0], ms)
    cfg = SmootherConfig(height_m=H0, noise=drive.config.noise)
    frames, _ = smooth_batch(ms, 3.0 * speeds_at_frames(ms, drive.speed), cfg)
    s = summarize_mount(frames, ms)
    assert s["height"]["mean"] > 1.25 * H0
    assert "wheel speed" in s["height_scale"] and "Warning" in summary_markdown(s)


def test_summary_height_is_checked_against_the_pairs_heights(batch, drive):
    # A steady body: the heights the wheel speed and the pairs measure agree with the
    # smoothed mount's, which stays the summary's (the check moves nothing).
    ms = drive.measurements
    plain = summarize_mount(batch[0], ms)
    s = summarize_mount(batch[0], ms, speed=drive.speed)
    assert "height_from_pairs" not in s
    assert s["height"]["mean"] == plain["height"]["mean"]
    assert abs(s["height"]["mean"] - H_TRUE) < 0.005


def test_smooth_summary_height_of_a_swinging_camera_holds_its_mean(tmp_path):
    # A rendered car whose camera height swings ±10 % over 6 s (1.35–1.65 m, mean 1.513 m
    # over the drive): the smoothed mount, which the model holds the frames' height at,
    # settled at 1.619 ± 0.002 m and the summary said so without a word. With the wheel
    # speed the summary's height is the pairs' mean, its interval theirs, and it says why.
    out = tmp_path / "smooth.csv"
    args = ["smooth", "--estimates", str(DATA / "car_height_est.csv"), "--vehicle", "car",
            "--out", str(out), "--quiet"]
    assert main([*args, "--speed-csv", str(DATA / "car_height_speed.csv")]) == 0
    summary = json.loads(out.with_suffix(".summary.json").read_text())
    truth = float(np.mean(read_table(DATA / "car_height_gt.csv")["height_m"]))
    h = summary["height"]
    assert h["ci95"][0] <= truth <= h["ci95"][1], (h, truth)
    assert abs(h["mean"] - truth) < 0.02 and h["interval_from"] == "data"
    assert "swings" in summary["height_from_pairs"]
    assert abs(h["start"] - truth) > 0.08  # the smoothed mount, still off the mean
    # without wheel speed the height is the assumed one at its prior: nothing to check it with
    assert main(args) == 0
    assert "height_from_pairs" not in json.loads(out.with_suffix(".summary.json").read_text())


# --- command line -----------------------------------------------------------------------------


def test_smooth_from_images_equals_smooth_of_the_saved_estimates(tmp_path):
    # "a drive is estimated once and smoothed many times": both paths give the same answer
    # (the table keeps the pairs' full covariance). Taken as reported, the correlations made the
    # Geman-McClure loss reject most pose blocks of this drive (frame pitch 0.28° RMS); the
    # pitch-change floor (NoiseParams.min_angle_change_std_deg) keeps them usable.
    from vipm_track.sim import PRESETS, simulate_sequence

    preset = PRESETS["car"]
    traj = simulate_sequence(preset, 8, tmp_path, seed=2, profile="drift")
    common = ["--camera", str(tmp_path / "camera.yaml"), "--height", str(preset.height_m),
              "--speed-csv", str(tmp_path / "speed.csv"), "--lag", "2", "--quiet"]
    assert main(["estimate", "--images", str(tmp_path / "images"), *common[:4],
                 "--out", str(tmp_path / "est.csv"), "--quiet"]) == 0
    assert main(["smooth", "--images", str(tmp_path / "images"), *common,
                 "--out", str(tmp_path / "a.csv")]) == 0
    assert main(["smooth", "--estimates", str(tmp_path / "est.csv"), *common[2:],
                 "--out", str(tmp_path / "b.csv")]) == 0
    a, b = read_table(tmp_path / "a.csv"), read_table(tmp_path / "b.csv")
    for column in ("pitch_deg", "roll_deg", "mount_pitch_deg", "tz_m"):
        assert np.allclose(a[column], b[column], atol=1e-6, equal_nan=True), column
    raw = read_table(tmp_path / "est.csv")
    ok = raw["status"] == "ok"
    truth = np.degrees(traj.pitch)
    assert (np.sqrt(np.mean((a["pitch_deg"][ok] - truth[ok]) ** 2))
            < np.sqrt(np.mean((raw["pitch_deg"][ok] - truth[ok]) ** 2)))
    # the motion given the angles and a fixed body std: run through the CLI, recorded in the
    # summary (the default is each pair's own motion, body std matched over 6 s)
    assert json.loads((tmp_path / "b.summary.json").read_text())["smoother"][
        "motion_given_pose"] is False
    assert main(["smooth", "--estimates", str(tmp_path / "est.csv"), *common[2:],
                 "--motion-given-pose", "--body-window", "0",
                 "--out", str(tmp_path / "c.csv")]) == 0
    summary = json.loads((tmp_path / "c.summary.json").read_text())
    assert summary["smoother"]["motion_given_pose"] is True
    assert summary["smoother"]["body_window_s"] == 0.0
    c = read_table(tmp_path / "c.csv")
    assert np.all(np.isfinite(c["tz_m"][ok]))
    assert not np.allclose(c["tz_m"][ok], b["tz_m"][ok], atol=1e-9)


def test_cli_warns_when_no_pair_is_usable(tmp_path, capsys):
    # a forward camera started cold from the default pitch fails every pair: nothing is
    # usable, so no table and no summary (the priors must not pass for an answer), exit 1
    nan7, nan77 = np.full(7, np.nan), np.full((7, 7), np.nan)
    ms = [PairMeasurement(k, 0.05 * k, nan7, nan77, H0, "did not converge") for k in range(20)]
    est = tmp_path / "est.csv"
    write_table(est, [measurement_row(m) for m in ms], ESTIMATE_COLUMNS)
    assert main(["smooth", "--estimates", str(est), "--height", str(H0),
                 "--out", str(tmp_path / "s.csv"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "no frame has a usable pair" in err and "20× did not converge" in err
    assert not (tmp_path / "s.summary.json").exists()


def test_cli_smooths_an_estimates_table(tmp_path, capsys):
    run = _drive(7, duration=10.0)
    est = tmp_path / "est.csv"
    write_table(est, [measurement_row(m) for m in run.measurements], ESTIMATE_COLUMNS)
    spd = tmp_path / "speed.csv"
    spd.write_text(
        "t,speed_mps\n"
        + "".join(
            f"{float(t)!r},{float(v)!r}\n"
            for t, v in zip(run.speed.t, run.speed.speed_mps, strict=True)
        )
    )
    out = tmp_path / "smooth.csv"
    rc = main(
        [
            "smooth",
            "--estimates",
            str(est),
            "--height",
            str(H0),
            "--speed-csv",
            str(spd),
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert rc == 0
    table = read_table(out)
    assert len(table["frame"]) == len(run.measurements)
    late = table["t"] > 3.0
    assert np.all(np.abs(table["mount_height_m"][late] - H_TRUE) < 0.01)
    assert np.all(table["pitch_std_deg"][late] > 0)
    summary = json.loads((tmp_path / "smooth.summary.json").read_text())
    assert abs(summary["height"]["mean"] - H_TRUE) < 0.01
    assert (tmp_path / "smooth.summary.md").exists()

    rc = main(
        [
            "smooth",
            "--estimates",
            str(tmp_path / "missing.csv"),
            "--height",
            "1.5",
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert rc == 2
    assert "missing.csv" in capsys.readouterr().err
    rc = main(
        [
            "smooth",
            "--estimates",
            str(est),
            "--height",
            "1.5",
            "--lag",
            "-1",
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert rc == 2
    # ... and values no vehicle needs, which gave tracebacks from the solver (1e300: NaN
    # information, 1e20 s: a division by zero, an OverflowError)
    for option, value in (("--lever-arm-std", "-1"), ("--body-tau", "0"), ("--body-std", "nan"),
                          ("--body-window", "-1"), ("--body-std", "1e300"),
                          ("--mount-angle-rw", "1e300"), ("--body-tau", "1e20"),
                          ("--mount-height-rw", "1e300"), ("--lever-arm-std", "1e300"),
                          ("--body-window", "1e9")):
        capsys.readouterr()
        rc = main(["smooth", "--estimates", str(est), "--height", "1.5", option, value,
                   "--out", str(out), "--quiet"])
        assert rc == 2
        assert option in capsys.readouterr().err


def _fail_once(monkeypatch, method: str, at_call: int) -> None:
    """Make ``FixedLagSmoother.<method>`` raise a SolveError on its ``at_call``-th call."""
    calls = {"n": 0}
    original = getattr(FixedLagSmoother, method)

    def flaky(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == at_call:
            raise SolveError("not positive definite (test)")
        return original(self, *args, **kwargs)

    monkeypatch.setattr(FixedLagSmoother, method, flaky)


def _smooth_with_failure(monkeypatch, method: str, at_call: int, speed: bool):
    run = _drive(6, duration=4.0)
    _fail_once(monkeypatch, method, at_call)
    cfg = SmootherConfig(height_m=H0, noise=run.config.noise, lag_s=0.5)
    frames = smooth(run.measurements, run.speed if speed else None, cfg)
    # every frame reported once, in order
    assert [f.frame for f in frames] == [m.frame for m in run.measurements]
    return frames


@pytest.mark.parametrize(
    ("method", "at_call", "speed", "why"),
    [
        ("_solve", 30, False, "restarted"),  # a failed update: the window restarts
    ],
)
def test_fixed_lag_goes_on_after_a_failed_solve(monkeypatch, method, at_call, speed, why):
    frames = _smooth_with_failure(monkeypatch, method, at_call, speed)
    resets = [f for f in frames if f.status == "reset"]
    assert len(resets) == 1 and why in resets[0].reason
    # the trajectory continues where it was: the new window's first frame is moved from
    # the last one by its own pair (the true step within 5 %: no wheel speed, so scaled by
    # the nominal height; not left where the last frame was)
    i = frames.index(resets[0])
    tr = _drive(6, duration=4.0).truth
    step = frames[i].position - frames[i - 1].position
    true_step = np.array([tr.x[i] - tr.x[i - 1], tr.y[i] - tr.y[i - 1]])
    assert np.hypot(*true_step) > 0.1
    assert np.hypot(*(step - true_step)) < 0.05 * np.hypot(*true_step)
    assert all(np.all(np.isfinite(f.mount)) for f in frames)


def test_fixed_lag_reports_a_frame_without_covariance_when_its_marginal_fails(monkeypatch):
    frames = _smooth_with_failure(monkeypatch, "_joint_marginal", 20, speed=True)
    bare = [f for f in frames if "no covariance" in f.reason]
    assert len(bare) == 1
    assert np.all(np.isnan(bare[0].mount_cov)) and np.all(np.isfinite(bare[0].mount))
    later = frames[frames.index(bare[0]) + 1 :]
    assert later and all(np.all(np.isfinite(f.mount_cov)) for f in later)


@pytest.mark.parametrize("lag_s", [0.0, 2.0])
def test_smoothed_heading_does_not_drift_during_a_stop(lag_s):
    run, a, b = stop_in_a_turn()
    tr = run.truth
    drift = {}
    for on in (True, False):
        noise = replace(run.config.noise, standstill_update=on)
        frames = smooth(run.measurements, run.speed,
                        SmootherConfig(height_m=0.7, noise=noise, lag_s=lag_s))
        herr = np.degrees(np.array([f.heading for f in frames]) - tr.heading)
        drift[on] = herr[b] - herr[a]
        if on:
            assert np.hypot(*(frames[b].position - frames[a].position)) < 0.005  # metres
            assert np.max(np.abs(herr)) < 1.5
            assert all(abs(f.yaw_rate) < math.radians(0.05) for f in frames[a + 5:b])
    assert abs(drift[True]) < 0.05
    # without it the process model bridges the stop: the yaw rate ramps from the last
    # measured ~1.4°/s to the one after the stop
    assert abs(drift[False]) > 3.0


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("lag_s", [0.0, 2.0])
def test_loose_pair_poses_with_precise_changes_are_not_rejected(seed, lag_s):
    # as a slow forward camera in traffic measures: each pair's pose within 0.7° but its
    # change within the pair correlated 0.999, on a body shaking 1°. Two pairs then disagree
    # on their shared frame by a degree or two, which a redescending loss started from the
    # pairs' own poses took for outliers (2–3 pairs rejected, frame pitch 0.11–0.24° RMS)
    config = DriveConfig.preset("car", duration_s=6.0, angle_std_deg=0.7, prev_curr_corr=0.999,
                                failure_fraction=0.0)
    run = simulate_drive(replace(config, noise=replace(config.noise, body_std_deg=1.0)), seed)
    cfg = SmootherConfig(height_m=run.config.h0, noise=run.config.noise, lag_s=lag_s)
    frames = smooth(run.measurements, run.speed, cfg)
    assert not [f for f in frames if f.status in ("partial", "gated")]
    pitch = np.array([f.pose[0] for f in frames])
    raw = np.array([m.z[2] if m.ok else np.nan for m in run.measurements])
    err, raw_err = (np.degrees(np.sqrt(np.nanmean((p - run.truth.pitch) ** 2)))
                    for p in (pitch, raw))
    assert raw_err > 0.5 and err < min(0.1, raw_err / 5)  # degrees


@pytest.mark.parametrize("start", ["moving", "standing"])
def test_fixed_lag_longer_than_the_drive_is_the_batch(start):
    if start == "moving":
        run = _drive(4, duration=6.0)
    else:  # the first frames stand (standstill in the first frame's prior), then drive off
        profile = DriveProfile((0.0, 3.0, 5.0), (0.0, 0.0, 1.0), (0.1, 0.1, 0.1))
        run = simulate_drive(DriveConfig.preset(
            "cart", duration_s=8.0, height_m=0.714, height_assumed_m=0.7), 4, profile)
    # both converged to the end (the defaults stop at steps below 0.1 χ², ~0.4 σ, or 1e-5 of
    # the cost: from the convex solution the batch's Geman–McClure stage starts so close
    # that this stops it 2e-5 rad/s short in yaw rate)
    cfg = SmootherConfig(height_m=run.config.h0, noise=run.config.noise, tolerance_chi2=0.0,
                         tolerance=1e-12, max_iterations=60)
    speeds = speeds_at_frames(run.measurements, run.speed)
    batch, _ = smooth_batch(run.measurements, speeds, cfg)
    tight = replace(cfg, lag_s=100.0, lag_tolerance_chi2=1e-10, lag_max_iterations=30)
    # the smoothers themselves: `smooth` widens the pose and travel σ of each by windows of
    # its own (row_correlation, heave)
    sm = FixedLagSmoother(tight)
    window = [f for m, v in zip(run.measurements, speeds, strict=True)
              for f in sm.step(m, float(v))] + list(sm.finish())
    # the first frame's 3°-wide mount prior is centred on the median of the pairs each has at
    # its start (batch: all, window: the first 10, enough to measure the body's shaking):
    # 1.2e-6 rad (0.00007°) on the moving drive, more with only 30 pairs standing
    mount_atol = 2e-6 if start == "moving" else 1e-5
    for b, w in zip(batch, window, strict=True):
        assert b.frame == w.frame and b.status == w.status
        np.testing.assert_allclose(w.mount, b.mount, atol=mount_atol)
        np.testing.assert_allclose(w.position, b.position, atol=1e-4)
        assert w.speed == pytest.approx(b.speed, abs=1e-4)  # m/s
        assert w.yaw_rate == pytest.approx(b.yaw_rate, abs=1e-5)  # rad/s
        np.testing.assert_allclose(w.mount_std, b.mount_std, rtol=1e-4)
        if np.all(np.isfinite(b.motion_cov)):
            np.testing.assert_allclose(w.motion_cov, b.motion_cov, rtol=1e-3, atol=1e-12)


def test_fixed_lag_runs_through_standstills_and_beats_the_ekf():
    # cart drive with several standstills (no pairs, zero speed) and 10 % outlier pairs
    cfg_d = DriveConfig.preset(
        "cart", duration_s=60.0, height_m=0.714, height_assumed_m=0.7, outlier_fraction=0.1
    )
    run = simulate_drive(cfg_d, 1)
    assert np.sum(run.status != "ok") > 50
    cfg = SmootherConfig(height_m=0.7, noise=run.config.noise, lag_s=2.0)
    frames = smooth(run.measurements, run.speed, cfg)
    assert not [f for f in frames if f.status in ("reset", "skipped")]
    # against the EKF of the same model (its shaking adaptation off: the smoother's body model
    # is the fixed Gauss-Markov one); on this single drive the adaptive EKF's roll is better
    ekf = run_filter(
        run.measurements,
        run.speed,
        EkfConfig(height_m=0.7, noise=run.config.noise, body_window_s=0.0),
    )
    fl, ek = _mount_rms_deg(run, frames), _mount_rms_deg(run, ekf)
    assert fl[0] < 1.05 * ek[0] and fl[1] < 1.05 * ek[1]
    assert sum(f.status in ("partial", "gated") for f in frames) > 0.05 * len(frames)


def test_fixed_lag_frame_is_the_batch_of_the_data_up_to_its_lag():
    # frame k is reported with the data up to t_k + lag: the marginalised past (the window's
    # prior) must carry exactly the information of the frames that left
    run = _drive(8, duration=6.0)
    cfg = SmootherConfig(height_m=H0, noise=run.config.noise, lag_tolerance_chi2=1e-10,
                         lag_max_iterations=30)
    sm = FixedLagSmoother(replace(cfg, lag_s=1.0))
    ms = run.measurements
    sp = speeds_at_frames(ms, run.speed)
    got = {}
    for i, m in enumerate(ms):
        for f in sm.step(m, float(sp[i])):
            got[f.frame] = (f, i)
    for k in (40, 80):
        f, last = got[ms[k].frame]
        ref = smooth_batch(ms[: last + 1], sp[: last + 1], cfg)[0][k]
        # equal up to the linearisation of the prior where frames left: ≤ 5 % of a σ
        assert np.all(np.abs(f.mount - ref.mount) < 0.05 * ref.mount_std)
        assert np.all(np.abs(f.pose - ref.pose) < 0.05 * ref.pose_std)
        np.testing.assert_allclose(f.mount_std, ref.mount_std, rtol=0.02)


# --- the clairvoyant reference of scripts/bench_filters.py -----------------------------------


@pytest.fixture(scope="module")
def bench_filters():
    from conftest import load_script

    return load_script("bench_filters")


def test_reference_lag_beyond_the_drive_is_its_batch(bench_filters):
    run = _drive(2, duration=10.0)
    ref = bench_filters.clairvoyant(run, True, lags_s=(0.5, 100.0))
    np.testing.assert_allclose(ref["lag 100 s"], ref["batch"], rtol=0, atol=1e-9)
    # a short lag lies between the filter and the smoother: the last frame is the filter's
    np.testing.assert_allclose(ref["lag 0.5 s"][-1], ref["causal"][-1], atol=1e-12)
    assert not np.allclose(ref["lag 0.5 s"][:-20], ref["causal"][:-20])


def test_batch_smoother_is_at_the_clairvoyant_bound(drive, batch, bench_filters):
    """The batch smoother's mount and height errors are within 15 % of the clairvoyant RTS
    smoother's (the model linearised about the truth), whose pitch/roll beat its filter's."""
    ref = bench_filters.clairvoyant(drive, True)
    tr = drive.truth
    ours = from_filter_states(batch[0]).states
    for i, truth, settle in ((0, tr.mount_pitch, 5.0), (1, tr.mount_roll, 5.0),
                             (2, tr.mount_height, 10.0)):
        bound = rms_after(tr.t, ref["batch"][:, i] - truth, settle)
        causal = rms_after(tr.t, ref["causal"][:, i] - truth, settle)
        got = rms_after(tr.t, ours[:, i] - truth, settle)
        if i < 2:  # (height: a 30 s drive is too short to promise it drive by drive)
            assert bound < causal, (i, bound, causal)
        assert got < 1.15 * bound, (i, got, bound)


def test_yaw_outliers_barely_bend_the_trajectory():
    # the cart's yaw-rate model is loose, so a wrong yaw pulls the heading unless the loss
    # redescends fast: Geman–McClure (the default) must hold the heading and the trajectory
    # of a drive with ±2° yaw on every 10th pair far closer to the clean drive's than Cauchy
    cfg_d = DriveConfig.preset("cart", duration_s=30.0, height_m=0.714, height_assumed_m=0.7)
    run = simulate_drive(cfg_d, 0)
    rng = np.random.default_rng(0)
    bad = []
    for m in run.measurements:
        if m.ok and m.frame % 10 == 5:
            z = m.z.copy()
            z[6] += math.radians(2.0) * rng.choice([-1.0, 1.0])
            m = replace(m, z=z)
        bad.append(m)
    base = SmootherConfig(height_m=0.7, noise=run.config.noise)
    assert base.loss == "geman-mcclure"
    for lag in (0.0, 2.0):
        dev = {}
        for loss in ("geman-mcclure", "cauchy"):
            cfg = replace(base, loss=loss, lag_s=lag, marginals=False)
            clean, wrong = smooth(run.measurements, run.speed, cfg), smooth(bad, run.speed, cfg)
            dh = [math.degrees(abs(math.remainder(a.heading - b.heading, math.tau)))
                  for a, b in zip(clean, wrong, strict=True)]
            dp = np.array([a.position - b.position for a, b in zip(clean, wrong, strict=True)])
            dev[loss] = (max(dh), float(np.sqrt(np.mean(np.sum(dp**2, axis=1)))))
        gm, cauchy = dev["geman-mcclure"], dev["cauchy"]
        assert gm[0] < 0.3 and gm[0] < 0.6 * cauchy[0], (lag, dev)
        assert gm[1] < 0.05 and gm[1] < 0.6 * cauchy[1], (lag, dev)


def test_mount_rw_sweep_drives_walk_at_their_rate(bench_filters):
    """``bench_filters --mount-rw-sweep``: each scenario's sim draws the mount at the rate in
    its name, and the methods are told it (the drive config carries it)."""
    from vipm_track.filters.drive_sim import DriveConfig, simulate_drive

    scs = bench_filters.scenarios(300.0, (0.002, 0.05))
    assert [s.name for s in scs] == [
        f"{p} + wheel speed, mount rw {rw:g}" for p in ("car", "cart") for rw in (0.002, 0.05)
    ]
    for sc, rw in zip(scs[:2], (0.002, 0.05), strict=True):
        cfg = DriveConfig.preset(sc.preset, **sc.overrides)
        assert cfg.noise.mount_angle_rw_deg_per_sqrt_s == rw and sc.use_speed
        tr = simulate_drive(cfg, 0).truth
        steps = np.degrees(np.concatenate([np.diff(tr.mount_pitch), np.diff(tr.mount_roll)]))
        rate = np.std(steps) / np.sqrt(np.median(np.diff(tr.t)))
        assert rate == pytest.approx(rw, rel=0.1)


def test_fixed_lag_follows_a_knocked_camera():
    # a 3° knock: the mount-change test lets the window's mount jump by replacing the factors
    # of the frame where it began (without the jump the mount stays ~3° off for the drive)
    from vipm_track.filters.drive_sim import MountChange

    run = _drive(4, duration=20.0, mount_changes=(MountChange(t_s=12.0, pitch_deg=3.0),))
    cfg = SmootherConfig(height_m=H0, noise=run.config.noise, lag_s=2.0)
    frames = smooth(run.measurements, run.speed, cfg)
    assert not [f for f in frames if f.status in ("reset", "skipped")]
    t = np.array([f.t for f in frames])
    err = np.degrees(np.array([f.mount[0] for f in frames]) - run.truth.mount_pitch)
    assert np.max(np.abs(err[(t > 5.0) & (t < 11.5)])) < 0.1
    assert np.max(np.abs(err[t > 12.5])) < 0.25  # the EKF test's bound one second on


def test_fixed_lag_keeps_the_track_of_a_rendered_wheel_speed_drive():
    """A rendered cart drive (26 s, 45° down, wheel speed at 50 Hz) whose marginalisation
    once made gtsam's Cholesky give up near a height ("indeterminate system"): the window
    must not restart, and the trajectory stays within millimetres of the batch's."""
    ms = read_measurements(DATA / "drift_cart_est.csv")
    speed = read_speed_csv(DATA / "drift_cart_speed.csv")
    noise = M.NoiseParams.for_preset("cart")
    fixed = smooth(ms, speed, SmootherConfig(height_m=0.7 / 1.02, noise=noise, lag_s=2.0))
    batch = smooth(ms, speed, SmootherConfig(height_m=0.7 / 1.02, noise=noise))
    assert not [f.frame for f in fixed if f.status == "reset"]
    gap = np.array([f.position for f in fixed]) - np.array([b.position for b in batch])
    assert np.sqrt(np.mean(np.sum(gap**2, axis=1))) < 0.005  # metres


@pytest.mark.parametrize(("tz", "status", "expected_y"), [
    (1.05, "ok", 1.05),  # the pair agrees with the last speed: its own travel
    (3.0, "ok", 1.0),  # an outlier pair (3x the speed): the last speed and yaw rate
    (1.05, "no motion", 1.0),  # no usable pair: the last speed and yaw rate
])
def test_a_restarted_window_starts_where_the_track_goes_on(tz, status, expected_y):
    from types import SimpleNamespace

    from vipm_track.filters.fixed_lag import restart_pose

    last = SimpleNamespace(position=np.array([2.0, 0.0]), heading=0.0, speed=10.0,
                           yaw_rate=0.0, t=5.0, mount=np.array([0.01, 0.0, 1.5]),
                           mount_yaw=0.0)
    z = np.array([0.01, 0.0, 0.01, 0.0, 0.0, tz, 0.0])
    cov = np.diag(np.full(7, 1e-4**2))
    m = PairMeasurement(frame=51, t=5.1, z=z, covariance=cov, height_assumed=1.5,
                        status=status)
    x, y, psi = restart_pose(last, m)
    assert (x, psi) == pytest.approx((2.0, 0.0), abs=1e-9)
    assert y == pytest.approx(expected_y, abs=1e-9)


def test_summary_warns_where_most_pairs_were_rejected():
    """A drive whose pairs the smoother rejected on most frames (a wheel speed from another
    drive made the images' motion disagree on 54 of 80) says so under its mount table; a
    drive with a few rejected pairs does not."""
    from vipm_track.filters.drive_summary import summary_markdown

    text = summary_markdown({"frames": 80, "status_counts": {"ok": 26, "partial": 54}})
    assert "rejected on 54 of 80 frames" in text and "another drive" in text
    text = summary_markdown({"frames": 80, "status_counts": {"ok": 75, "partial": 3, "gated": 2}})
    assert "Warning" not in text


def test_a_drive_too_short_for_the_mount_change_test_says_so():
    """Shorter than the 6 s of blocks the mount-change test needs, a drive's summary warns
    that a change within it may go unseen (a 4-s knock render's mount stayed 5-8 sigma off
    with no word); a longer drive's does not."""
    from vipm_track.filters.drive_summary import summary_markdown
    from vipm_track.filters.mount_change import short_drive_note

    note = short_drive_note(4.0)
    assert "4.0 s" in note and "caught late or not at all" in note
    assert short_drive_note(6.5) == ""
    text = summary_markdown({"frames": 80, "status_counts": {"ok": 80}, "short_drive": note})
    assert "**Warning:** the drive spans 4.0 s" in text


def test_a_drive_too_short_for_the_step_test_says_so(tmp_path):
    """A drive whose frames fill fewer than the 8 one-second blocks the batch's step and drift
    tests need (6.5 s: 7) is warned of in the batch's summary, from the command line too; the
    fixed lag's summary does not say so (it has no such test), and a drive of 7.95 s (8 full
    blocks: the test runs) is not warned of."""
    from conftest import write_drive_inputs

    from vipm_track.cli import main
    from vipm_track.filters.drive_summary import summarize_mount
    from vipm_track.filters.mount_steps import StepTestConfig, untested_drive_note

    assert "fill 7 of the 8 blocks" in untested_drive_note(np.arange(0.0, 6.5, 0.05))
    assert untested_drive_note(np.arange(0.0, 7.95, 0.05)) == ""
    assert untested_drive_note(np.arange(0.0, 3.0, 0.05), StepTestConfig(False)) == ""
    run = simulate_drive(DriveConfig.preset("car", duration_s=6.5, height_m=H_TRUE,
                                            height_assumed_m=H0), 5)
    frames = smooth(run.measurements, run.speed,
                    SmootherConfig(height_m=H0, noise=run.config.noise))
    batch = summarize_mount(frames, run.measurements, StepTestConfig())
    assert "step and drift tests" in str(batch.get("short_drive"))
    assert "short_drive" not in summarize_mount(frames, run.measurements)
    write_drive_inputs(run, tmp_path)
    assert main(["smooth", "--estimates", str(tmp_path / "est.csv"), "--height", str(H0),
                 "--out", str(tmp_path / "smoothed.csv"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "smoothed.summary.json").read_text())
    assert "step and drift tests" in summary["short_drive"]


@pytest.mark.parametrize("lag_s", [0.0, 2.0])
def test_yaw_of_a_frame_whose_heading_crosses_half_a_turn_is_the_turn(lag_s):
    """A drive round a full circle: the smoothers' heading (gtsam's Pose2) wraps at ±180°,
    and each frame's yaw is still its small turn, not that turn − 360°."""
    circle = DriveProfile((0.0, 40.0), (8.0, 8.0), (0.03, 0.03))  # 0.24 rad/s: 1.5 turns
    run = simulate_drive(DriveConfig.preset("car", duration_s=40.0, height_m=H_TRUE,
                                            height_assumed_m=H0), 4, profile=circle)
    cfg = SmootherConfig(height_m=H0, noise=run.config.noise, lag_s=lag_s)
    frames = smooth(run.measurements, run.speed, cfg)
    yaw = np.array([f.motion[2] for f in frames if f.motion is not None])
    yaw = yaw[np.isfinite(yaw)]
    assert len(yaw) > 0.9 * len(frames)
    rate = 8.0 * 0.03 / run.config.fps
    assert np.all(np.abs(yaw - rate) < 0.01), np.abs(yaw - rate).max()


@pytest.mark.parametrize("ramp_deg_per_min, warned", [(0.0, False), (9.0, True), (12.0, False)])
def test_summary_warns_of_a_trend_the_drift_test_does_not_call_a_drift(
        tmp_path: Path, ramp_deg_per_min: float, warned: bool):
    # KITTI 07's real rows (a mount that did not move: pitch t = 1.8) with a creep of the
    # pitch added: 9°/min gives t = 6.1, between the step test's 5 and the drift test's 7, so
    # the batch holds the mount still and the summary says so; 12°/min (t = 7.6) is a drift
    # the mount walks with, no warning
    ramp = math.radians(ramp_deg_per_min / 60.0)
    rows = [replace(m, z=m.z + ramp * np.array([m.t - 0.1, 0, m.t, 0, 0, 0, 0]))
            for m in read_measurements(Path(__file__).parent / "data" / "kitti07_estimates.csv")]
    est = tmp_path / "est.csv"
    write_table(est, [measurement_row(m) for m in rows], ESTIMATE_COLUMNS)
    assert main(["smooth", "--estimates", str(est), "--height", "1.65", "--out",
                 str(tmp_path / "s.csv"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "s.summary.json").read_text())
    assert summary["pitch"]["pairs_trend_t"] == pytest.approx(
        {0.0: 1.8, 9.0: 6.1, 12.0: 7.6}[ramp_deg_per_min], abs=0.1)
    assert ("pairs_trend" in summary) == warned
    text = (tmp_path / "s.summary.md").read_text()
    assert ("the pairs' pitch by +" in text) == warned


def test_the_drive_summary_is_of_the_mount_since_a_knock():
    """The summary of a knocked cart (pitch +1° at 12 s of 30 s) gave one mean and interval
    across the knock, 45.6 [45.4, 45.8], which held neither mount. It now finds the step in
    the smoothed mount, says so, and gives the mount since."""
    from vipm_track.filters.drive_summary import summarize_mount, summary_markdown
    from vipm_track.filters.model import NoiseParams
    from vipm_track.filters.smoother_config import SmootherConfig
    from vipm_track.filters.smoothing import smooth
    from vipm_track.filters.wheel_speed import read_speed_csv
    from vipm_track.measurement import read_measurements
    from vipm_track.table import read_table

    ms = read_measurements(DATA / "knock_cart_est.csv")
    truth = read_table(DATA / "knock_cart_gt.csv")
    knock = truth["t"][np.flatnonzero(np.diff(truth["mount_pitch_deg"]))[0] + 1]
    # without the marginals (--no-std) the step is the batch's own test's on the pairs: it
    # was not looked for, and the summary's mean and tight interval held neither mount
    for marginals in (True, False):
        config = SmootherConfig(height_m=0.7, noise=NoiseParams.for_preset("cart"),
                                marginals=marginals)
        frames = smooth(ms, read_speed_csv(DATA / "knock_cart_speed.csv"), config)
        summary = summarize_mount(frames, ms, config.mount_steps)
        (step,) = summary["mount_steps"]
        assert abs(step["t"] - knock) < 0.35 and abs(step["pitch_deg"] - 1.0) < 0.15
        low, high = summary["pitch"]["ci95"]
        assert low < truth["mount_pitch_deg"][-1] < high
        assert "the mount stepped at" in summary_markdown(summary)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_fixed_lag_summary_warns_of_a_step_its_mount_did_not_follow(seed):
    """A 1° knock 6 s into a 20-s cart drive, smoothed with a 2-s lag: the mount crept, and
    the summary's mean and interval (45.37 [45.22, 45.52]) held neither 45° nor 46° and said
    nothing. The window now follows the step where its step watch finds it (seed 1), and
    the summary gives the mount since it; where the window does not follow (the watch off,
    or the step below its threshold), the pairs' own step test says so; a drive without a
    knock is not warned."""
    from vipm_track.filters.drive_sim import DriveConfig, MountChange, simulate_drive
    from vipm_track.filters.drive_summary import summarize_mount, summary_warnings
    from vipm_track.filters.mount_steps import StepTestConfig
    from vipm_track.filters.smoother_config import SmootherConfig
    from vipm_track.filters.smoothing import smooth

    for knock, watch in ((False, True), (True, True), (True, False)):
        changes = (MountChange(6.0, pitch_deg=1.0),) if knock else ()
        run = simulate_drive(DriveConfig.preset("cart", duration_s=20.0, mount_changes=changes,
                                                mount_random_walk=False), seed)
        frames = smooth(run.measurements, run.speed,
                        SmootherConfig(height_m=0.7, noise=run.config.noise, lag_s=2.0,
                                       mount_steps=StepTestConfig(enabled=watch)))
        summary = summarize_mount(frames, run.measurements, None)
        warned = [w for w in summary_warnings(summary) if "the pairs' pitch stepped" in w]
        if not knock:
            assert not warned and "pairs_steps" not in summary
            continue
        if watch and "since_step" in summary:
            # the summary's mount is the window's since its last step, the knock's
            last = float(summary["since_step"].split(" (pitch")[0].split(", ")[-1][-7:-2])
            assert not warned and abs(last - 6.0) < 0.3, summary["since_step"]
            low, high = summary["pitch"]["ci95"]
            assert low < 46.0 < high, (low, high)
            continue
        # a knock in a shaken cart's pairs below the watch's threshold (10, against a
        # road's wander) but above the drive's test's (5): not followed, and said
        assert len(warned) == 1 and "did not follow" in warned[0], summary_warnings(summary)
        (step,) = summary["pairs_steps"]
        assert abs(step["t"] - 6.0) < 0.3 and abs(step["step_deg"] - 1.0) < 0.15


def test_smooth_quiet_still_says_its_warnings(tmp_path, capsys):
    """`smooth --quiet` printed nothing where `track --quiet` warns: a 4-s drive's "too short
    for the step test" was in summary.md only."""
    from vipm_track.cli import main

    lines = (DATA / "knock_cart_est.csv").read_text().splitlines()
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines[:41]) + "\n")  # header and 4 s of frames
    assert main(["smooth", "--estimates", str(short), "--height", "0.7", "--vehicle", "cart",
                 "--out", str(tmp_path / "s.csv"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "vipm-track smooth: warning: the drive spans 3.9 s, less than the 6 s" in err, err
    assert "frames →" not in err  # the summary print itself stays off
