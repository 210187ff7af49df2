"""A slow forward camera's pose over a longer baseline (``vipm_track.long_baseline``)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vipm_track.displacement_model import pack
from vipm_track.estimator import TwoFrameEstimator
from vipm_track.estimator_config import EstimatorConfig
from vipm_track.geometry import GroundPose, PlanarMotion, compose_motion
from vipm_track.long_baseline import RecentFrames, condition_on_pose
from vipm_track.pair_chain import PairChain, _FailedResult, _reads_long_baselines
from vipm_track.pair_result import PairResult
from vipm_track.rig import Rig
from vipm_track.sim import PRESETS, make_trajectory, preset_texture, render_trajectory_frame

#: the default's 0.3 camera heights at 1.65 m
BASELINE_M = 0.3 * 1.65


def _pair(tz: float = 0.2, pitch: float = 0.01, status: str = "ok",
          covariance: np.ndarray | None = None) -> PairResult:
    pose = GroundPose(pitch, 0.0, 1.65)
    return PairResult(status, pose_prev=pose, pose_curr=pose,
                      motion=PlanarMotion(0.0, tz, 0.0) if status == "ok" else None,
                      covariance=np.eye(7) * 1e-4 if covariance is None else covariance)


def _frames(pairs: list[PairResult], dt: float = 0.1) -> tuple[RecentFrames, list]:
    recent, images = RecentFrames(), [np.zeros(1) for _ in range(len(pairs) + 1)]
    for k, pair in enumerate(pairs, start=1):
        recent.add(images[k - 1], images[k], k * dt, dt, pair)
    return recent, images


def test_a_slow_pair_reaches_back_as_far_as_the_baseline_needs():
    # 0.2 m per frame at 1.65 m: 0.3 heights is 0.495 m, three frames back
    assert EstimatorConfig().long_baseline_heights * 1.65 == BASELINE_M
    pairs = [_pair(pitch=0.001 * k) for k in range(8)]
    recent, images = _frames(pairs)
    longer = recent.reference(BASELINE_M)
    assert longer is not None and longer.image is images[-4]
    assert math.isclose(longer.interval_s, 0.3) and math.isclose(longer.guess.motion.tz, 0.6)
    # frame r held to its own estimate (the pair starting there), frame k to the short pair's
    assert longer.guess.pose_prev is pairs[-3].pose_prev
    assert longer.guess.pose_curr is pairs[-1].pose_curr


def test_a_pair_that_travels_far_enough_or_a_broken_chain_is_left_alone():
    assert _frames([_pair(tz=0.6) for _ in range(6)])[0].reference(BASELINE_M) is None
    # a failed pair two frames back: frame k-2 is as far as the chain goes (0.4 m, twice
    # the short pair's travel)
    recent, images = _frames([_pair(), _pair(), _pair(status="too few inliers"), _pair(),
                              _pair()])
    assert recent.reference(BASELINE_M).image is images[-3]
    recent, _ = _frames([_pair(), _pair(status="too few inliers"), _pair()])
    assert recent.reference(BASELINE_M) is None  # only the short pair itself
    # frames 0.5 s apart: no earlier frame within 1 s but the one two back, which gains 2×
    recent, images = _frames([_pair(tz=0.2) for _ in range(5)], dt=0.5)
    assert recent.reference(BASELINE_M).image is images[-3]
    # a frame dropped: the next pair's previous frame is not the last one seen
    recent, images = _frames([_pair() for _ in range(5)])
    recent.add(np.zeros(1), np.zeros(1), 1.0, 0.1, _pair())
    assert recent.reference(BASELINE_M) is None


def _spd(data: st.DataObject) -> np.ndarray:
    a = np.array(data.draw(st.lists(st.floats(-1, 1), min_size=49, max_size=49))).reshape(7, 7)
    return a @ a.T + 0.05 * np.eye(7)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_conditioning_takes_the_longer_pairs_pose_and_keeps_a_covariance(data):
    cov = _spd(data)
    other = _spd(data)
    result = _pair(covariance=cov.copy())
    x = pack(result.pose_prev, result.pose_curr, result.motion)
    longer = _pair(pitch=0.03, covariance=other)
    longer.pose_curr = GroundPose(0.03, -0.02, 1.65)
    assert condition_on_pose(result, longer)
    assert math.isclose(result.pose_curr.pitch, 0.03, abs_tol=1e-9)
    assert math.isclose(result.pose_curr.roll, -0.02, abs_tol=1e-9)
    assert result.pose_curr.height == 1.65
    assert np.allclose(result.covariance[2:4, 2:4], other[2:4, 2:4])
    assert np.allclose(result.covariance, result.covariance.T)
    assert np.linalg.eigvalsh(result.covariance).min() > -1e-9
    # the rest moved as the short pair's correlations say: its regression on frame k's pose
    gain = cov[:, 2:4] @ np.linalg.inv(cov[2:4, 2:4])
    moved = x + gain @ (np.array([0.03, -0.02]) - x[2:4])
    assert np.allclose(pack(result.pose_prev, result.pose_curr, result.motion), moved)


def test_a_precise_change_is_kept_when_the_pose_moves():
    # frame k-1 and k each known to 1°, their change to 0.05°: moving frame k by 1.5° moves
    # frame k-1 with it and the change stays within its own σ
    sd, change_sd = math.radians(1.0), math.radians(0.05)
    cov = np.eye(7) * 1e-6
    cov[0, 0] = cov[2, 2] = sd**2
    cov[0, 2] = cov[2, 0] = sd**2 - change_sd**2 / 2
    result = _pair(pitch=0.0, covariance=cov)
    longer = _pair(covariance=np.eye(7) * math.radians(0.3) ** 2)
    longer.pose_curr = GroundPose(math.radians(1.5), 0.0, 1.65)
    before = result.pose_curr.pitch - result.pose_prev.pitch
    condition_on_pose(result, longer)
    after = result.pose_curr.pitch - result.pose_prev.pitch
    assert abs(after - before) < change_sd
    assert not condition_on_pose(result, _pair(covariance=np.full((7, 7), np.nan)))


def test_a_slow_level_camera_reads_its_pitch_over_a_longer_baseline():
    # KITTI's camera on an open road at 1.65 m/s (0.1 heights per frame), its body still at
    # pitch 1°: tracked from the nominal, pair by pair, the rows drifted 1.3-1.8° low (the
    # pitch trades against the travel over 0.17 m); over three frames' 0.5 m they stay
    # within 0.5° (measured 0.32-0.49°)
    preset, seed, n = PRESETS["kitti"], 3, 10
    traj = make_trajectory("static", n, None, preset, seed, 1.65)
    texture, camera = preset_texture(preset, None, seed), preset.camera()
    frames = [render_trajectory_frame(texture, camera, traj, k, None) for k in range(n)]
    errors = {}
    for long_baseline in (False, True):
        config = EstimatorConfig(long_baseline_heights=0.3 if long_baseline else 0.0)
        chain = PairChain(TwoFrameEstimator(Rig(camera, 1.65, 1.0), config))
        rows = [chain.estimate(frames[k - 1], frames[k], float(traj.t[k]),
                               float(traj.t[k] - traj.t[k - 1]))[0] for k in range(1, n)]
        assert all(r.ok for r in rows)
        errors[long_baseline] = np.degrees([r.pose_curr.pitch for r in rows[3:]]) - 1.0
    assert np.all(errors[False] < -1.2)
    assert np.all(np.abs(errors[True]) < 0.6)


def test_a_tight_turn_is_left_to_the_short_pair():
    turning = [_pair() for _ in range(6)]
    for pair in turning:
        pair.motion = PlanarMotion(0.0, 0.2, math.radians(1.0))  # 5°/m
    assert _frames(turning)[0].reference(BASELINE_M) is None
    for pair in turning:
        pair.motion = PlanarMotion(0.0, 0.2, math.radians(0.6))  # 3°/m
    assert _frames(turning)[0].reference(BASELINE_M) is not None


def test_a_shaking_body_is_left_to_the_short_pair():
    # pitch changing 0.5° per 0.1-s pair (5°/s): the heave that goes with it costs the longer
    # interval more than the baseline gains; 0.2° per pair (2°/s) is a body's gradual motion
    def pitching(change_deg: float) -> list[PairResult]:
        pairs = [_pair() for _ in range(6)]
        for k, pair in enumerate(pairs):
            pair.pose_prev = GroundPose(math.radians(change_deg * (k % 2)), 0.0, 1.65)
            pair.pose_curr = GroundPose(math.radians(change_deg * ((k + 1) % 2)), 0.0, 1.65)
        return pairs

    assert _frames(pitching(0.5))[0].reference(BASELINE_M) is None
    assert _frames(pitching(0.2))[0].reference(BASELINE_M) is not None


def test_the_guess_composes_the_pairs_between_in_order():
    # pairs that turn and drift sideways: the longer pair's motion is the first pair's
    # followed by the next ones' (G_r → G_k), which the reverse order is not
    pairs = [_pair() for _ in range(6)]
    for k, pair in enumerate(pairs):
        pair.motion = PlanarMotion(0.02 * k, 0.2, math.radians(0.1 * k))
    recent, _ = _frames(pairs)
    motion = recent.reference(BASELINE_M).guess.motion
    expected = compose_motion(compose_motion(pairs[-3].motion, pairs[-2].motion),
                              pairs[-1].motion)
    assert np.allclose([motion.tx, motion.tz, motion.yaw],
                       [expected.tx, expected.tz, expected.yaw], atol=1e-12)
    reverse = compose_motion(compose_motion(pairs[-1].motion, pairs[-2].motion),
                             pairs[-3].motion)
    assert not np.allclose([motion.tx, motion.tz], [reverse.tx, reverse.tz], atol=1e-4)


def test_a_failed_attempt_or_a_repeated_frame_time_breaks_no_run():
    # an estimator that raised leaves a stand-in with a status only; frame times that repeat
    recent, images = RecentFrames(), [np.zeros(1) for _ in range(6)]
    for k in range(1, 6):
        pair = _FailedResult("estimator error: boom") if k == 3 else _pair()
        recent.add(images[k - 1], images[k], 0.1 * k, 0.1, pair)
    assert recent.reference(BASELINE_M).image is images[3]  # back to the failed pair's end
    recent = RecentFrames()
    for k, t in enumerate([0.1, 0.2, 0.2, 0.3, 0.4], start=1):
        recent.add(images[k - 1], images[k], t, 0.1, _pair())
    assert recent.reference(BASELINE_M) is None


def test_a_second_starts_spread_stays_in_the_sigma_and_does_not_steer():
    # the spread d dᵀ of two minima (frame k's pitch and the travel) is added back, not used
    # to move frame k-1 or the travel along d
    cov = np.eye(7) * 1e-4
    spread = np.zeros((7, 7))
    d = np.array([0.0, 0.0, 0.03, 0.0, 0.0, 0.05, 0.0])
    spread += np.outer(d, d)
    result = _pair(covariance=cov + spread)
    longer = _pair(covariance=np.eye(7) * 1e-4)
    longer.pose_curr = GroundPose(0.02, 0.0, 1.65)
    assert condition_on_pose(result, longer, spread)
    assert math.isclose(result.motion.tz, 0.2)  # the travel did not move along d
    assert np.allclose(result.covariance[2:4, 2:4], longer.covariance[2:4, 2:4] + spread[2:4, 2:4])


def test_only_a_level_global_shutter_camera_without_vertical_motion_reads_longer_pairs():
    camera = PRESETS["kitti"].camera()

    def reads(rig: Rig, **config) -> bool:
        return _reads_long_baselines(TwoFrameEstimator(rig, EstimatorConfig(**config)))

    level = Rig(camera, 1.65, 1.0)
    assert reads(level)
    assert not reads(level, long_baseline_heights=0.0)
    assert not reads(level, vertical_motion=True)  # its height would be left behind
    assert not reads(level.with_readout(0.03))
    assert not reads(Rig(camera, 1.65, 45.0))  # a steep camera: no pose prior
