"""Two-frame estimator: accuracy against rendered ground truth, cold start, refinement,
tracking seeds, outliers, failure statuses and the covariance."""

from __future__ import annotations

import dataclasses
from functools import cache

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vipm_track import bundle, geometry
from vipm_track import displacement_model as dm
from vipm_track.errors import InputError
from vipm_track.estimator import TwoFrameEstimator
from vipm_track.estimator_config import EstimatorConfig
from vipm_track.measurement import PairMeasurement
from vipm_track.pair_chain import predict_guess
from vipm_track.pair_result import (
    STATUS_FEW_INLIERS,
    STATUS_NO_MOTION,
    STATUS_NO_TEXTURE,
    PairGuess,
    PairResult,
)
from vipm_track.render import OBSTACLE_POLYGON, Effects, render_frame
from vipm_track.rig import DEFAULT_PITCH_DEG, Rig
from vipm_track.sim import (
    PRESETS,
    Trajectory,
    make_trajectory,
    preset_texture,
    render_trajectory_frame,
)
from vipm_track.stage_context import pose_prior
from vipm_track.static_content import noise_sigma, on_static, static_pixels, static_share
from vipm_track.traffic import Vehicle


@cache
def _sequence(
    preset: str = "cart", profile: str = "static", frames: int = 2, pitch_deg: float | None = None,
    obstacle: bool = False, seed: int = 1, fps: float | None = None, speed: float | None = None,
) -> tuple[Trajectory, tuple[np.ndarray, ...], object]:
    p = PRESETS[preset]
    if pitch_deg is not None:
        p = dataclasses.replace(p, pitch_deg=pitch_deg)
    traj = make_trajectory(profile, frames, fps=fps, preset=p, seed=seed, speed=speed)
    tex = preset_texture(p)
    cam = p.camera()
    fx = Effects(obstacle=obstacle) if obstacle else None
    imgs = tuple(render_trajectory_frame(tex, cam, traj, k, fx) for k in range(frames))
    return traj, imgs, cam


def _errors(traj: Trajectory, k: int, pose_prev, pose_curr, motion) -> dict[str, float]:
    """Absolute errors of a pair's estimate: pitch/roll (both frames) in degrees, travel
    distance in mm, yaw change in degrees."""
    tp, tc, tm = traj.pose(k - 1), traj.pose(k), traj.motion(k)
    return {
        "pitch": float(np.degrees(max(abs(pose_prev.pitch - tp.pitch),
                                      abs(pose_curr.pitch - tc.pitch)))),
        "roll": float(np.degrees(max(abs(pose_prev.roll - tp.roll),
                                     abs(pose_curr.roll - tc.roll)))),
        "dist_mm": abs(motion.distance - tm.distance) * 1e3,
        "yaw": float(np.degrees(abs(motion.yaw - tm.yaw))),
    }


def _estimate(preset="cart", profile="static", k=1, frames=2, pitch_deg=None, config=None,
              guess=None, obstacle=False) -> tuple[PairResult, Trajectory, object]:
    traj, imgs, cam = _sequence(preset, profile, frames, pitch_deg, obstacle)
    est = TwoFrameEstimator(Rig(cam, float(traj.height[k]), DEFAULT_PITCH_DEG), config)
    return est.estimate(imgs[k - 1], imgs[k], guess), traj, cam


# --- model consistency --------------------------------------------------------------------


def test_batched_homographies_equal_geometry():
    k = PRESETS["cart"].camera().k
    rng = np.random.default_rng(0)
    xs = rng.normal(size=(6, 7)) * [0.3, 0.1, 0.3, 0.1, 0.2, 0.5, 0.1] + [0.8, 0, 0.8, 0, 0, 0, 0]
    g_from_i, out_from_g = dm.pair_homographies(k, 0.7, xs)
    for b, x in enumerate(xs):
        pp, pc, mo = dm.unpack(x, 0.7)
        h_ref = geometry.pair_homography(k, pp, pc, mo)
        h = out_from_g[b] @ g_from_i[b]
        np.testing.assert_allclose(h / h[2, 2], h_ref / h_ref[2, 2], atol=1e-9)


def _assert_jacobian_matches_differences(model: dm.DisplacementModel, x: np.ndarray) -> None:
    """The model's Jacobian against central differences of its residuals."""
    jac = model.jacobian(x)
    for i in range(len(x)):
        dx = np.zeros(len(x))
        dx[i] = 1e-5
        fd = (model.residuals(x + dx) - model.residuals(x - dx)) / 2e-5
        np.testing.assert_allclose(jac[:, i], fd, rtol=1e-3, atol=1e-3)


def test_model_residual_is_zero_at_truth_and_jacobian_matches():
    k = PRESETS["cart"].camera().k
    pp, pc = geometry.GroundPose(0.8, 0.02, 0.7), geometry.GroundPose(0.81, 0.01, 0.7)
    mo = geometry.PlanarMotion(0.01, 0.1, 0.02)
    pix = np.stack(np.meshgrid(np.linspace(50, 750, 5), np.linspace(50, 550, 4)), -1).reshape(-1, 2)
    target = geometry.predict_pixels(k, pp, pc, mo, pix)
    model = dm.DisplacementModel(k, 0.7, pix, target)
    x = dm.pack(pp, pc, mo)
    assert np.abs(model.residuals(x)).max() < 1e-9
    _assert_jacobian_matches_differences(model, x)
    # the same with per-point whitening (the weighted refinement's residuals)
    rng = np.random.default_rng(0)
    w = np.eye(2) + 0.3 * rng.normal(size=(len(pix), 2, 2))
    _assert_jacobian_matches_differences(dataclasses.replace(model, point_whitening=w), x)


@settings(max_examples=40, deadline=None)
@given(
    pitch=st.floats(0.0, 1.2), roll=st.floats(-0.05, 0.05), tx=st.floats(-0.2, 0.2),
    tz=st.floats(0.05, 1.0), yaw=st.floats(-0.05, 0.05), readout=st.floats(0.05, 1.0),
    accel=st.floats(-0.3, 0.3), turn=st.floats(-0.03, 0.03), heave=st.floats(-0.01, 0.01),
)
def test_rolling_shutter_prediction_moves_each_point_over_its_rows_times(
        pitch, roll, tx, tz, yaw, readout, accel, turn, heave):
    """A point seen on row v_p of frame k-1 (time a = v_p·readout/rows) is back-projected
    with the pose at k-1+a, travels (1 + b − a)·Ψ + (b² − a² + a + b)/2·(Ψ − Ψ₋₁) (constant
    acceleration) and is projected with the pose at k+b, the poses changing at the pair's
    rate (geometry's own prediction, within 1e-3 px, where it lands in the image); a readout
    of 0 is the global shutter's model."""
    cam = PRESETS["cart"].camera()
    pose_p = geometry.GroundPose(pitch, roll, 0.7)
    pose_c = geometry.GroundPose(pitch + turn, roll - turn, 0.7 + heave)
    motion = geometry.PlanarMotion(tx * 0.7 / 1.5, tz * 0.7 / 1.5, yaw)
    psi = np.array([motion.tx, motion.tz, motion.yaw])
    pix = np.stack(np.meshgrid(np.linspace(50, 750, 5), np.linspace(300, 590, 4)), -1)
    pix = pix.reshape(-1, 2)
    model = dm.DisplacementModel(cam.k, 0.7, pix, pix, readout_frames=readout,
                                     image_rows=cam.height, previous_motion=psi * (1 - accel))
    x = np.append(dm.pack(pose_p, pose_c, motion), heave)
    pred = model.predict(x)
    ok = np.all(np.isfinite(pred), axis=1) & (pred[:, 1] >= 0) & (pred[:, 1] < cam.height)

    def at(pose: geometry.GroundPose, t: float) -> geometry.GroundPose:
        return geometry.GroundPose(pose.pitch + t * turn, pose.roll - t * turn,
                                   pose.height + t * heave)

    for p_prev, p_curr in zip(pix[ok], pred[ok], strict=True):
        a, b = p_prev[1] * readout / cam.height, p_curr[1] * readout / cam.height
        travel = (1 + b - a) * psi + (b * b - a * a + a + b) / 2 * accel * psi
        np.testing.assert_allclose(
            geometry.predict_pixels(cam.k, at(pose_p, a), at(pose_c, b),
                                    geometry.PlanarMotion(*travel), p_prev[None])[0],
            p_curr, atol=1e-3)
    np.testing.assert_allclose(
        dataclasses.replace(model, readout_frames=0.0, previous_motion=None).predict(x),
        geometry.predict_pixels(cam.k, pose_p, pose_c, motion, pix), atol=1e-9)


def test_pose_prior_residuals_jacobian_and_pull():
    k = PRESETS["car"].camera().k
    pp, pc = geometry.GroundPose(0.02, 0.0, 1.5), geometry.GroundPose(0.021, 0.001, 1.5)
    mo = geometry.PlanarMotion(0.02, 0.8, 0.01)
    pix = np.stack(np.meshgrid(np.linspace(100, 1180, 6), np.linspace(420, 700, 4)),
                   -1).reshape(-1, 2)
    target = geometry.predict_pixels(k, pp, pc, mo, pix)
    x = dm.pack(pp, pc, mo)
    mean = x[:4] + np.radians([1.0, -0.5, 1.0, -0.5])
    model = dm.DisplacementModel(k, 1.5, pix, target, prior_mean=mean, prior_scale=30.0)
    r = model.residuals(x)
    assert r.size == 2 * len(pix) + 4 and model.n_prior == 4
    np.testing.assert_allclose(r[-4:], 30.0 * (x[:4] - mean), atol=1e-12)
    assert np.abs(r[:-4]).max() < 1e-9
    _assert_jacobian_matches_differences(model, x)
    # Exact data outweighs a weak prior; a strong one pulls the pose towards its mean.
    usable = np.ones(len(pix), bool)
    rng = np.random.default_rng(0)
    weak = bundle.robust_fit(dataclasses.replace(model, prior_scale=1e-3), x, usable, 0, 1.0,
                             1.0, rng)
    strong = bundle.robust_fit(dataclasses.replace(model, prior_scale=1e6), x, usable, 0, 1.0,
                               1.0, rng)
    assert np.abs(weak.x[:4] - x[:4]).max() < np.radians(0.01)
    assert np.abs(strong.x[:4] - mean).max() < np.radians(0.05)


def test_camera_pitched_down_with_the_horizon_in_view_gets_the_steep_defaults():
    # a car camera 15° down sees the horizon but is not level: the level-camera defaults
    # (tuned on KITTI at ~1°) left 0.15° of pitch error on a shaking render, the steep ones
    # 0.01°
    traj, imgs, cam = _sequence("car", "shaking", 4, pitch_deg=15.0, seed=6)
    est = TwoFrameEstimator(Rig(cam, PRESETS["car"].height_m, 15.0))
    assert not est.steep and not est.level
    assert est.config.vertical_motion and est.config.weight_patches
    assert est.config.pose_prior_deg == 0.0 and est.config.refinements == 1
    errors = []
    guess = None
    for k in range(1, 4):
        result = est.estimate(imgs[k - 1], imgs[k], guess)
        assert result.status == "ok", result.reason
        errors.append(_errors(traj, k, result.pose_prev, result.pose_curr, result.motion))
        guess = PairGuess.from_previous(result)
    assert max(e["pitch"] for e in errors) < 0.05
    assert max(e["roll"] for e in errors) < 0.05


def test_forward_and_steep_defaults():
    car = TwoFrameEstimator(Rig(PRESETS["car"].camera(), 1.5, 3.0))
    assert not car.steep and car.level
    assert car.config.refinements == 2 and car.config.pose_prior_deg == 2.0
    assert pose_prior(car.config, car.nominal, None)[1] == pytest.approx(np.radians(2.0))
    cart = TwoFrameEstimator(Rig(PRESETS["cart"].camera(), 0.7, DEFAULT_PITCH_DEG))
    assert cart.steep and cart.config.refinements == 1 and cart.config.pose_prior_deg == 0.0
    assert pose_prior(cart.config, cart.nominal, None)[0] is None
    assert car.config.stage_median and not cart.config.stage_median
    assert cart.config.weight_patches and cart.config.recentre_windows
    assert cart.config.inlier_median_factor == 6.0
    assert not car.config.weight_patches and not car.config.recentre_windows
    assert car.config.inlier_median_factor == 0.0
    with pytest.raises(InputError, match="pose_prior_deg"):
        EstimatorConfig(pose_prior_deg=-1.0)


# --- accuracy ----------------------------------------------------------------------------


def test_cart_static_pair_accuracy():
    result, traj, _ = _estimate()
    assert result.status == "ok", result.reason
    err = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    assert err["pitch"] < 0.1 and err["roll"] < 0.1, err
    assert err["dist_mm"] < 0.2, err
    assert err["yaw"] < 0.05, err
    assert set(result.timings) >= {"poc", "warp", "lm", "total"}
    assert [s.plane for s in result.stages] == ["image", "ipm"]
    assert len(result.stage_estimates) == 2


@pytest.mark.parametrize("pitch_deg", [45.0, 70.0])
def test_cold_start_from_60_degrees_converges(pitch_deg):
    result, traj, _ = _estimate(pitch_deg=pitch_deg)
    assert result.status == "ok", result.reason
    err = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    assert err["pitch"] < 0.2 and err["roll"] < 0.2, err


def test_refinement_lowers_error_against_initial():
    initial, refined = [], []
    for k in (1, 2, 3):
        result, traj, _ = _estimate(profile="gradual", k=k, frames=4)
        assert result.ok, result.reason
        e0 = _errors(traj, k, *result.stage_estimates[0])
        e1 = _errors(traj, k, *result.stage_estimates[1])
        initial.append(e0["pitch"] + e0["roll"])
        refined.append(e1["pitch"] + e1["roll"])
    assert np.mean(refined) < 0.5 * np.mean(initial), (initial, refined)


def test_weighted_refinement_beats_the_papers_uniform_one():
    """Patch noise weights, re-centred windows and the self-tightening inlier threshold
    (steep-camera defaults) against the paper's uniform refinement, same shaking pairs."""
    traj, imgs, cam = _sequence(profile="shaking", frames=6)
    paper = EstimatorConfig(weight_patches=False, recentre_windows=False,
                            inlier_median_factor=0.0)
    errors: dict[bool, list[float]] = {True: [], False: []}
    for k in range(1, 6):
        for ours, config in ((True, None), (False, paper)):
            est = TwoFrameEstimator(Rig(cam, float(traj.height[k - 1]), DEFAULT_PITCH_DEG), config)
            result = est.estimate(imgs[k - 1], imgs[k])
            assert result.ok, result.reason
            err = _errors(traj, k, result.pose_prev, result.pose_curr, result.motion)
            errors[ours].append(err["pitch"] + err["roll"])
    assert np.mean(errors[True]) < 0.7 * np.mean(errors[False]), errors


def _pitch_smeared(traj: Trajectory, k: int, smear_deg: float) -> np.ndarray:
    """Frame k of ``traj`` exposed while the body pitches through ``smear_deg`` degrees at a
    constant rate, centred on the frame's pose (the travel during the exposure left out)."""
    preset = PRESETS["cart"]
    pose, xz, heading = traj.pose(k), traj.world_xz[k], float(traj.world_heading[k])
    poses = [(geometry.GroundPose(pose.pitch + np.radians(smear_deg) * s, pose.roll, pose.height),
              xz, heading) for s in np.linspace(-0.5, 0.5, 25 if smear_deg else 1)]
    return render_frame(preset_texture(preset, seed=3), preset.camera(), pose, xz, heading,
                        Effects(motion_blur=1.0), frame_index=k,
                        exposure=[(0, preset.camera().height, poses)])


@pytest.mark.parametrize("k", [3, 9])
def test_steep_refinement_is_not_biased_by_a_pitch_smear_in_one_frame(k: int) -> None:
    """A body pitching through 1° during one frame's exposure and not the other's: the
    box's negative lobe turns the upper band's phases by π in one frame only, which moved
    the plain POC peaks by pixels (0.7–0.8° of pitch here, σ a few hundredths); the
    blur-invariant refinement (a steep camera's default) stays within 0.1°."""
    traj = make_trajectory("static", 12, preset=PRESETS["cart"], seed=3)
    prev, curr = _pitch_smeared(traj, k - 1, 1.0), _pitch_smeared(traj, k, 0.0)
    rig = Rig(PRESETS["cart"].camera(), 0.7, DEFAULT_PITCH_DEG)
    errors = {}
    for invariant in (None, False):
        result = TwoFrameEstimator(rig, EstimatorConfig(blur_invariant_ipm=invariant)).estimate(
            prev, curr, None, 0.1)
        assert result.ok, result.reason
        errors[invariant] = _errors(traj, k, result.pose_prev, result.pose_curr, result.motion)
    assert errors[None]["pitch"] < 0.1 and errors[None]["roll"] < 0.1, errors
    assert errors[False]["pitch"] > 0.4, errors


def test_a_blur_invariant_fit_on_a_few_of_its_patches_is_not_taken() -> None:
    """A shaking cart under motion blur (seed 52, frames 73 → 74, exposure 0.3 of the frame
    interval), tracked from the pair before: the blur-invariant refinement's fit kept 15 of
    some 60 patches and printed `ok` 7.3° off (σ 0.8°). A fit on under 30 % of the patches
    measured now fails that refinement (here the pair is then refined from the guess:
    0.06° off)."""
    preset = PRESETS["cart"]
    traj = make_trajectory("shaking", 120, preset=preset, seed=52)  # as `simulate --frames 120`
    texture, camera, blur = preset_texture(preset, seed=52), preset.camera(), Effects(
        motion_blur=0.3, seed=52)
    prev, curr = (render_trajectory_frame(texture, camera, traj, k, blur) for k in (73, 74))
    # the tracked guess as the table held it (the pair is chaotic: a rounded guess misses it)
    pose = geometry.GroundPose(np.radians(44.2331982323352), np.radians(0.405657497124236), 0.7)
    guess = PairGuess(pose, pose, geometry.PlanarMotion(
        -0.000188598911743533, 0.123269360713467, np.radians(0.00218852907697663)))
    result = TwoFrameEstimator(Rig(camera, 0.7, DEFAULT_PITCH_DEG)).estimate(
        prev, curr, guess, 0.1)
    # the rule fired (the reason says so) and what was taken instead is not the wrong pose
    assert "blur-invariant" in result.reason, result.reason
    if result.ok:
        assert _errors(traj, 74, result.pose_prev, result.pose_curr, result.motion)[
            "pitch"] < 1.5
    else:
        assert result.status == STATUS_FEW_INLIERS


def test_turning_pair_is_as_accurate_as_a_straight_one():
    # 1.5° of yaw per frame: on planes that keep each frame's own ground, a patch's content
    # is rotated against its pair, which biased POC (pitch ~0.07°, roll ~0.04° here);
    # frame k's plane moved onto frame k-1's by the estimate leaves no rotation.
    traj, imgs, cam = _sequence("cart", "turn", 12)
    assert abs(np.degrees(traj.motion(11).yaw)) > 1.0
    errors = {}
    for moved in (True, False):
        rig = Rig(cam, float(traj.height[0]), DEFAULT_PITCH_DEG)
        est = TwoFrameEstimator(rig, EstimatorConfig(moved_ipm=moved))
        result = est.estimate(imgs[10], imgs[11])
        assert result.ok, result.reason
        errors[moved] = _errors(traj, 11, result.pose_prev, result.pose_curr, result.motion)
    assert errors[True]["pitch"] < 0.02 and errors[True]["roll"] < 0.02, errors
    assert errors[True]["dist_mm"] < 0.01 and errors[True]["yaw"] < 0.005, errors
    assert errors[True]["pitch"] + errors[True]["roll"] < 0.5 * (
        errors[False]["pitch"] + errors[False]["roll"]), errors


def _corner_lots(radius_m: float, kerb_m: float) -> list[Vehicle]:
    """Pavement lots ``kerb_m`` high round a right turn of ``radius_m`` from world heading 0
    (start at the origin, the new road along world x at z = radius_m): the two lots beyond
    the new road, which the camera looks across in mid-turn, and the near one on the left.
    Our lane is centred on the path, the roads 7 m wide."""
    right, left = 1.75, 5.25
    far = radius_m + left
    lots = ((right, right + 25.0, far, far + 25.0), (-left - 25.0, -left, far, far + 25.0),
            (-left - 25.0, -left, -25.0, radius_m - right))
    return [Vehicle(i, "car", "parked", (x0 + x1) / 2, (z0 + z1) / 2, 0.0, z1 - z0, x1 - x0,
                    kerb_m, texture="brick", gain=0.9, offset=10.0, look_seed=i)
            for i, (x0, x1, z0, z1) in enumerate(lots)]


@pytest.mark.parametrize("frames, kerb_m, bound_deg",
                         [((0, 6), 0.0, 0.4), ((12, 18), 0.0, 0.4), ((12, 18), 0.15, 0.6)])
def test_a_car_in_a_tight_slow_turn_keeps_its_pose(frames, kerb_m, bound_deg):
    # KITTI 07's wrong `ok` rows lie in its slow corners (3° of yaw per 0.3 m: docs/traffic.md,
    # "Where KITTI 07's wrong ok rows are"), 1.5-4° off; the same turn, tracked from a nominal
    # pitch 1° below the truth, stays within 0.4° on a flat ground (measured 0.24° as it
    # enters the turn, 0.23° in mid-turn) and within 0.6° (0.43°) in mid-turn looking across a
    # corner's pavement 0.15 m high: a plane parallel to the road whose patches move 11 %
    # faster than the road's must not tilt the fit.
    p = PRESETS["car"]
    traj = make_trajectory("turn", frames[1], fps=10.0, preset=p, seed=3, speed=3.0,
                           amplitude=3.75)
    assert np.degrees(traj.motion(3).yaw) == pytest.approx(3.0, abs=0.05)
    radius = 3.0 / np.radians(3.75 * p.turn_rate_dps)
    lots = _corner_lots(radius, kerb_m) if kerb_m else None
    texture, cam = preset_texture(p), p.camera()
    imgs = {k: render_trajectory_frame(texture, cam, traj, k, traffic=lots)
            for k in range(*frames)}
    if lots:  # the pavement covers a fifth of the image below its centre or more
        flat = render_trajectory_frame(texture, cam, traj, frames[0])
        covered = (imgs[frames[0]] != flat)[cam.height // 2:]
        assert covered.mean() > 0.2, covered.mean()
    est = TwoFrameEstimator(Rig(cam, float(traj.height[0]), p.pitch_deg - 1.0))
    result = None
    for k in range(frames[0] + 1, frames[1]):
        result = est.estimate(imgs[k - 1], imgs[k], PairGuess.from_previous(result), 0.1)
        assert result.ok, (k, result.reason)
        errors = _errors(traj, k, result.pose_prev, result.pose_curr, result.motion)
        assert errors["pitch"] < bound_deg and errors["roll"] < bound_deg, (k, errors)
        assert errors["yaw"] < 0.05, (k, errors)
        assert errors["dist_mm"] < 0.02 * 1e3 * traj.motion(k).distance, (k, errors)


@pytest.mark.parametrize("ipm_start", [True, False])
def test_car_camera_10deg_down_starts_cold(ipm_start):
    # A car camera 10° down at 0.6 m per frame: the nominal pose's virtual IPM is stretched
    # in the near field (its patches alone failed here, before the whole-plane shift); the
    # image-plane cold start of steep cameras (the fallback where the IPM start fails, or
    # chosen with cold_start_ipm=False) converges too.
    traj, imgs, cam = _sequence("car", "static", 2, pitch_deg=10.0)
    config = EstimatorConfig(cold_start_ipm=ipm_start)
    est = TwoFrameEstimator(Rig(cam, float(traj.height[0]), 10.0), config)
    assert not est.steep
    result = est.estimate(imgs[0], imgs[1])
    assert result.ok, result.reason
    err = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    assert err["pitch"] < 0.3 and err["roll"] < 0.3, err
    assert err["dist_mm"] / (traj.motion(1).distance * 1e3) < 0.02, err


@pytest.mark.parametrize("ipm_start", [True, False])
def test_fast_cart_starts_cold_from_the_nominal_pose_ipm(ipm_start):
    # The cart at 4 m/s and 10 fps: 0.4 m per frame from ~1 m above the ground, so the image
    # scales by a third between the frames and the image-plane cold start matched nothing
    # (2 of 99 patches). On the nominal pose's bird's-eye plane the motion is a translation:
    # a steep camera falls back to that start (cold_start_ipm, the default).
    p = PRESETS["cart"]
    traj, imgs, cam = _sequence("cart", "gradual", 2, fps=10.0, speed=4.0)
    assert traj.motion(1).distance > 0.35
    config = EstimatorConfig(cold_start_ipm=ipm_start)
    est = TwoFrameEstimator(Rig(cam, p.height_m, p.pitch_deg), config)
    assert est.steep
    result = est.estimate(imgs[0], imgs[1])
    if not ipm_start:
        assert not result.ok
        return
    assert result.ok, result.reason
    assert "cold start from the nominal-pose IPM" in result.reason, result.reason
    err = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    assert err["pitch"] < 0.05 and err["roll"] < 0.05, err
    assert err["dist_mm"] / (traj.motion(1).distance * 1e3) < 0.005, err


def test_cold_start_off_the_nominal_pitch_tries_pitch_steps():
    # A level car at 2.5 m per frame whose nominal pitch is 2° above the truth (the road's
    # slope does that): neither cold start converges from the nominal pose (10 and 4 of 99
    # patches agree), but one from 2° below it does, and it is the truth.
    traj, imgs, cam = _sequence("car", "static", 2, pitch_deg=1.0, fps=10.0, speed=25.0)
    assert traj.motion(1).distance > 2.4
    results = {}
    for steps in ((), None):
        config = EstimatorConfig(cold_pitch_steps_deg=steps)
        results[steps] = TwoFrameEstimator(Rig(cam, 1.5, 3.0), config).estimate(imgs[0], imgs[1])
    assert results[()].status == STATUS_FEW_INLIERS
    result = results[None]
    assert result.ok and "from -2° off it" in result.reason, result.reason
    err = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    assert err["pitch"] < 0.1 and err["roll"] < 0.1, err
    assert err["dist_mm"] / (traj.motion(1).distance * 1e3) < 0.005, err
    assert result.timings["total"] > results[()].timings["total"]  # every attempt counted


def test_level_camera_on_a_bouncing_body_with_vertical_motion():
    # A car whose body heaves by millimetres between frames (the shaking profile: 3 mm here):
    # a level camera's default 7-parameter fit puts the heave into the pitch (0.45° off);
    # with the 8th parameter (``--vertical-motion``) the heave is measured and the pitch holds.
    traj, imgs, cam = _sequence("car", "shaking", 2)
    heave = float(traj.height[1] - traj.height[0])
    errors = {}
    for vertical in (None, True):
        rig = Rig(cam, float(traj.height[0]), PRESETS["car"].pitch_deg)
        result = TwoFrameEstimator(rig, EstimatorConfig(vertical_motion=vertical)).estimate(*imgs)
        assert result.ok, result.reason
        errors[vertical] = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
        if vertical:
            assert result.height_change == pytest.approx(heave, abs=5e-4)
    assert errors[None]["pitch"] > 0.2, errors
    assert errors[True]["pitch"] < 0.05 and errors[True]["roll"] < 0.05, errors


@pytest.mark.parametrize("preset", ["cart", "car"])
def test_rolling_shutter_is_modelled_given_the_readout_time(preset):
    # A CMOS camera reading its rows out over half the frame interval: the bottom rows see the
    # ground later than the top ones, so the near field's patches seem to move further. Left
    # out of the model this is 0.5° (car) to 3.6° (cart) of pitch and 7-12 % of travel; with
    # the readout time (``Rig.readout_s``) the fit gives each patch the motion over its rows' times
    # (0.03-0.10°, 0.6 % and less).
    p = PRESETS[preset]
    traj = make_trajectory("static", 2, preset=p, seed=1)
    tex, cam = preset_texture(p), p.camera()
    fx = Effects(rolling_shutter=0.5)
    imgs = [render_trajectory_frame(tex, cam, traj, k, fx) for k in range(2)]
    interval = float(traj.t[1] - traj.t[0])
    errors = {}
    for readout in (0.0, 0.5 * interval):
        config = EstimatorConfig()
        rig = Rig(cam, p.height_m, p.pitch_deg, readout_s=readout)
        result = TwoFrameEstimator(rig, config).estimate(*imgs, None, interval)
        assert result.ok, result.reason
        errors[readout] = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    distance = traj.motion(1).distance * 1e3
    assert errors[0.0]["pitch"] > 0.3 and errors[0.0]["dist_mm"] > 0.03 * distance, errors
    assert errors[0.5 * interval]["pitch"] < 0.15, errors  # a global shutter's spread
    assert errors[0.5 * interval]["dist_mm"] < 0.01 * distance, errors
    with pytest.raises(ValueError, match="frame interval"):
        rig = Rig(cam, p.height_m, p.pitch_deg, readout_s=readout)
        TwoFrameEstimator(rig, config).estimate(*imgs)


def test_rolling_shutter_of_an_accelerating_vehicle_takes_the_previous_motion():
    # The cart gaining 1 m/s per second at 1.2 m/s (8 % of its speed per frame) under a
    # readout of half the frame interval: the near field's patches are seen later and, the
    # vehicle accelerating, moved further still. A cold pair (constant velocity) is 1-1.4°
    # and 3-4.5 % off; tracked, the previous pair's motion gives the acceleration and the
    # error falls with each pair as that motion improves (0.05° / 0.2 % at the fourth pair).
    p = PRESETS["cart"]
    n, accel, dt = 5, 1.0, 1.0 / p.fps
    t = np.arange(n) * dt
    traj = Trajectory(t, np.full(n, np.radians(p.pitch_deg)), np.zeros(n), np.full(n, p.height_m),
                      np.stack([np.zeros(n), p.speed_mps * t + 0.5 * accel * t * t], axis=1),
                      np.zeros(n), p.speed_mps + accel * t)
    tex, cam = preset_texture(p), p.camera()
    imgs = [render_trajectory_frame(tex, cam, traj, k, Effects(rolling_shutter=0.5))
            for k in range(n)]
    config = EstimatorConfig()
    est = TwoFrameEstimator(Rig(cam, p.height_m, p.pitch_deg, readout_s=0.5 * dt), config)
    result = est.estimate(imgs[0], imgs[1], None, dt)
    for k in range(2, n):
        result = est.estimate(imgs[k - 1], imgs[k], PairGuess.from_previous(result), dt)
        assert result.ok, result.reason
    tracked = _errors(traj, n - 1, result.pose_prev, result.pose_curr, result.motion)
    cold = est.estimate(imgs[n - 2], imgs[n - 1], None, dt)
    cold = _errors(traj, n - 1, cold.pose_prev, cold.pose_curr, cold.motion)
    distance = traj.motion(n - 1).distance * 1e3
    assert cold["pitch"] > 0.5 and cold["dist_mm"] > 0.02 * distance, cold
    assert tracked["pitch"] < 0.1 and tracked["dist_mm"] < 0.005 * distance, tracked


def test_rolling_shutter_rows_of_a_shaking_body_carry_frame_ks_unknown_turning():
    """A shaking cart under a readout of 0.3 of the frame interval: frame k turns during its
    readout at a rate the pair cannot know (docs/shutter.md). The estimates are the same with
    and without the term; with it every tracked pair's σ is wider, by what the running RMS of
    the pair-to-pair change of the (pitch, roll) rate says (weight ``ANGULAR_ACCEL_WEIGHT``,
    this pair's own change included; a cold pair: its own rate)."""
    from vipm_track.stage_context import ANGULAR_ACCEL_WEIGHT

    p = PRESETS["cart"]
    n, dt = 5, 1.0 / p.fps
    traj = make_trajectory("shaking", n, preset=p, seed=201)
    tex, cam = preset_texture(p), p.camera()
    imgs = [render_trajectory_frame(tex, cam, traj, k, Effects(rolling_shutter=0.3))
            for k in range(n)]
    rig = Rig(cam, p.height_m, p.pitch_deg, readout_s=0.3 * dt)
    runs = {}
    for term in (False, True):
        est = TwoFrameEstimator(rig, EstimatorConfig(shutter_rate_covariance=term))
        results = [est.estimate(imgs[0], imgs[1], None, dt)]
        for k in range(2, n):
            results.append(est.estimate(imgs[k - 1], imgs[k],
                                        PairGuess.from_previous(results[-1]), dt))
        assert all(r.ok for r in results), [r.reason for r in results]
        runs[term] = results
    rate = [np.array([r.pose_curr.pitch - r.pose_prev.pitch, r.pose_curr.roll - r.pose_prev.roll])
            for r in runs[True]]
    ms = None
    for k, (off, on) in enumerate(zip(runs[False], runs[True], strict=True)):
        assert on.pose_curr == off.pose_curr and on.motion == off.motion
        if k == 0:
            assert on.angular_accel_ms is None  # cold: no change of rate known
            continue
        change = (rate[k] - rate[k - 1]) ** 2
        w = ANGULAR_ACCEL_WEIGHT
        ms = change if ms is None else (1 - w) * ms + w * change
        np.testing.assert_allclose(on.angular_accel_ms, ms, rtol=1e-9)
        assert on.covariance[2, 2] > 1.5**2 * off.covariance[2, 2]
    # what each pair's term is computed from
    est = TwoFrameEstimator(rig)
    prev, curr = est.prepare(imgs[3], "3"), est.prepare(imgs[4], "4")
    x = dm.pack(runs[True][-1].pose_prev, runs[True][-1].pose_curr, runs[True][-1].motion)
    cold = est.stage_context(prev, curr, None, dt)
    np.testing.assert_allclose(cold.shutter_rate_std(x), np.abs(rate[-1]), rtol=1e-9)
    tracked = est.stage_context(prev, curr, PairGuess.from_previous(runs[True][-2]), dt)
    expected = ((1 - ANGULAR_ACCEL_WEIGHT) * np.asarray(runs[True][-2].angular_accel_ms)
                + ANGULAR_ACCEL_WEIGHT * (rate[-1] - rate[-2]) ** 2)
    np.testing.assert_allclose(tracked.shutter_rate_std(x), np.sqrt(expected), rtol=1e-9)


def test_fast_cart_cold_start_reports_no_wrong_minimum():
    # The cart at 6 m/s and 10 fps from the default 60° start: the frames are half a view
    # apart, and the image-plane cold start of this pair had converged to a wrong minimum
    # (29 % of the patches inliers, travel 89 % short) reported "ok". A steep camera's cold
    # start now needs 40 % of its measured patches as inliers: these pairs fail cold, and
    # say why. (A cold start that solves them should turn this into a check of the answer.)
    p = PRESETS["cart"]
    traj = make_trajectory("gradual", 6, fps=10.0, preset=p, seed=5, speed=6.0)
    tex, cam = preset_texture(p, seed=5), p.camera()  # as `vipm-track simulate --seed 5`
    imgs = [render_trajectory_frame(tex, cam, traj, k) for k in range(6)]
    est = TwoFrameEstimator(Rig(cam, p.height_m, DEFAULT_PITCH_DEG))
    reasons = []
    for k in (4, 5):
        cold = est.estimate(imgs[k - 1], imgs[k])
        assert cold.status == STATUS_FEW_INLIERS, (k, cold.status, cold.reason)
        reasons.append(cold.reason)
    assert any("wrong minimum" in r for r in reasons), reasons
    # The pairs themselves are solvable: tracked from the previous frame's true pose and
    # motion they come out ok and right (measured: pitch <= 0.008°, roll 0.002°, travel
    # 0.04 mm of 588 mm), so an estimator that always fails does not pass this test.
    for k in (4, 5):
        guess = PairGuess(traj.pose(k - 1), traj.pose(k - 1), traj.motion(k - 1))
        tracked = est.estimate(imgs[k - 1], imgs[k], guess)
        assert tracked.ok, (k, tracked.reason)
        err = _errors(traj, k, tracked.pose_prev, tracked.pose_curr, tracked.motion)
        assert err["pitch"] < 0.03 and err["roll"] < 0.01, (k, err)
        assert err["dist_mm"] < 0.2 and err["yaw"] < 0.01, (k, err)


def test_fast_cart_cold_start_on_repeating_texture_is_no_ok():
    # The cart at 8 m/s, 10 fps (0.78 m per frame, beyond its range) as `vipm-track simulate
    # --preset cart --frames 30 --speed 8 --seed 5`: the ground texture tiles one photograph,
    # and these two cold starts converged to a shift by its period that 39-64 % of the
    # correlating patches agree with: `ok` with the travel 0.03 m of 0.78 m. Only 24-25 % of
    # the patches in view correlate there (right steep cold starts: 64-100 %); they now fail.
    p = PRESETS["cart"]
    traj = make_trajectory("static", 30, fps=10.0, preset=p, seed=5, speed=8.0)
    tex, cam = preset_texture(p, seed=5), p.camera()
    est = TwoFrameEstimator(Rig(cam, p.height_m, 45.0))
    reasons = []
    for k in (5, 7):
        cold = est.estimate(render_trajectory_frame(tex, cam, traj, k - 1),
                            render_trajectory_frame(tex, cam, traj, k))
        err = abs(cold.motion.tz - traj.motion(k).tz) if cold.ok else None
        assert not cold.ok, (k, err, cold.reason)
        reasons.append(cold.reason)
    assert any("repeating texture" in r for r in reasons), reasons


def test_fast_car_starts_cold_from_the_whole_plane_shift():
    # 2 m per frame (72 km/h at 10 fps): further than a coarse IPM patch is long, so the
    # patches alone matched nothing (the pair failed, or converged to a steep pitch with no
    # motion); one POC over the whole nominal-pose plane finds the shift first.
    traj, imgs, cam = _sequence("car", "static", 2, fps=10.0, speed=20.0)
    assert traj.motion(1).distance > 1.8
    config = EstimatorConfig()
    rig = Rig(cam, float(traj.height[0]), PRESETS["car"].pitch_deg)
    result = TwoFrameEstimator(rig, config).estimate(imgs[0], imgs[1])
    assert result.ok, result.reason
    err = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    assert err["pitch"] < 0.2 and err["roll"] < 0.2, err
    assert err["dist_mm"] / (traj.motion(1).distance * 1e3) < 0.01, err


def test_car_preset_with_guess_converges():
    traj, imgs, cam = _sequence("car", "static", 2)
    tp, tc, tm = traj.pose(0), traj.pose(1), traj.motion(1)
    off = np.radians(0.5)
    guess = PairGuess(
        geometry.GroundPose(tp.pitch + off, tp.roll - off, tp.height),
        geometry.GroundPose(tc.pitch + off, tc.roll - off, tc.height),
        geometry.PlanarMotion(tm.tx, tm.tz * 1.1, tm.yaw),
    )
    config = EstimatorConfig()
    est = TwoFrameEstimator(Rig(cam, float(traj.height[0]), PRESETS["car"].pitch_deg), config)
    result = est.estimate(imgs[0], imgs[1], guess)
    assert result.ok, result.reason
    err = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    # A forward camera sees pitch far less well than the cart (0.5° off guess to start).
    assert err["pitch"] < 0.25 and err["roll"] < 0.25, err
    assert err["dist_mm"] / (tm.distance * 1e3) < 0.015, err  # under 1.5 % of ~0.6 m
    # Forward cameras report the median of the stages (image stage + 2 refinements).
    stack = np.array([dm.pack(*s) for s in result.stage_estimates])
    assert len(stack) == 3
    reported = dm.pack(result.pose_prev, result.pose_curr, result.motion)
    np.testing.assert_allclose(reported, np.median(stack, axis=0), atol=1e-12)
    last = dataclasses.replace(config, stage_median=False)
    rig = Rig(cam, float(traj.height[0]), PRESETS["car"].pitch_deg)
    single = TwoFrameEstimator(rig, last).estimate(imgs[0], imgs[1], guess)
    np.testing.assert_allclose(dm.pack(single.pose_prev, single.pose_curr, single.motion),
                               stack[-1], atol=1e-12)
    # With one refinement there is no median of two: the refined estimate is reported.
    rig = Rig(cam, float(traj.height[0]), PRESETS["car"].pitch_deg)
    one = TwoFrameEstimator(rig, dataclasses.replace(config, refinements=1))
    r1 = one.estimate(imgs[0], imgs[1], guess)
    assert len(r1.stage_estimates) == 2
    np.testing.assert_allclose(dm.pack(r1.pose_prev, r1.pose_curr, r1.motion),
                               dm.pack(*r1.stage_estimates[-1]), atol=1e-12)


def test_obstacle_patches_are_outliers():
    result, traj, cam = _estimate(obstacle=True)
    assert result.ok, result.reason
    stage = result.stages[0]
    poly = OBSTACLE_POLYGON * [cam.width, cam.height]
    inside = _inside_convex(poly, stage.centres)
    # Patches well inside the obstacle (their whole window on it) must not be inliers.
    deep = inside & _inside_convex(_shrink(poly, 70), stage.centres)
    assert deep.sum() >= 3
    assert not np.any(stage.inliers[deep])
    assert stage.inliers[~inside].mean() > 0.6
    err = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    assert err["pitch"] < 0.1 and err["roll"] < 0.1 and err["dist_mm"] < 0.3, err


# --- failures ----------------------------------------------------------------------------


def _with_hood(images: tuple[np.ndarray, ...], share: float,
               noise: float = 0.0) -> list[np.ndarray]:
    """Dashcam frames: a car hood fixed over the bottom ``share`` of the view (curved edge,
    faint static texture) and a text overlay, the same in every frame; with Gaussian sensor
    noise of ``noise`` grey levels over each frame."""
    h, w = images[0].shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    hood = yy > h * (1 - share) + 0.6 * share * h * ((xx - w / 2) / (w / 2)) ** 2
    rng = np.random.default_rng(0)
    paint = (40 + 20 * rng.random((h // 8, w // 8))).astype(np.uint8)
    paint = cv2.resize(paint, (w, h), interpolation=cv2.INTER_CUBIC)
    out = []
    for image in images:
        frame = image.copy()
        frame[hood] = paint[hood]
        cv2.putText(frame, "2026/11/23 12:00:00  52 km/h", (20, h - 20),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.8, 255, 2)
        if noise > 0:
            frame = np.clip(frame + rng.normal(0.0, noise, frame.shape), 0, 255).astype(np.uint8)
        out.append(frame)
    return out


@pytest.mark.parametrize("noise", [0.0, 2.0])
def test_static_pixels_mark_content_fixed_to_the_camera(noise):
    # with sensor noise (σ 2 grey levels) the hood's frames differ by the noise of both:
    # the noise-free test had marked 7 % of it (the pairs then "no motion" or 99 % short)
    _, imgs, cam = _sequence("car", "static", 2)
    frames = _with_hood(imgs, 0.3, noise)
    static = static_pixels(frames[0].astype(np.float32), frames[1].astype(np.float32))
    h = cam.height
    assert static[int(0.9 * h):].mean() > 0.8  # the hood
    assert static[int(0.55 * h):int(0.7 * h)].mean() < 1e-3  # the road ahead (a few pixels)
    # a standing vehicle: everything is fixed, nothing is marked ("no motion" says it)
    assert not static_pixels(frames[0].astype(np.float32), frames[0].astype(np.float32)).any()


@pytest.mark.parametrize("noise", [0.0, 2.0])
def test_a_hood_over_the_near_road_is_not_taken_for_the_ground(noise):
    # a hood over the bottom 30 % of a dashcam's view (its texture static, POC matches it
    # perfectly at zero shift): the cold start found no travel and tracking locked onto it —
    # every pair "ok" with zero travel (99.9 % distance error); with sensor noise too
    traj, imgs, cam = _sequence("car", "static", 3)
    frames = _with_hood(imgs, 0.3, noise)
    config = EstimatorConfig()
    est = TwoFrameEstimator(Rig(cam, float(traj.height[0]), PRESETS["car"].pitch_deg), config)
    guess = None
    for k in (1, 2):
        result = est.estimate(frames[k - 1], frames[k], guess)
        assert result.ok, result.reason
        err = _errors(traj, k, result.pose_prev, result.pose_curr, result.motion)
        assert err["dist_mm"] / (traj.motion(k).distance * 1e3) < 0.02, err
        assert err["pitch"] < 0.3 and err["roll"] < 0.3, err
        guess = PairGuess.from_previous(result)


def test_noise_sigma_of_white_noise():
    rng = np.random.default_rng(4)
    for sigma in (1.0, 2.0, 5.0):
        image = np.clip(128 + rng.normal(0.0, sigma, (480, 640)), 0, 255).astype(np.uint8)
        assert noise_sigma(image) == pytest.approx(sigma, rel=0.06)
    assert noise_sigma(np.full((480, 640), 90, np.uint8)) == pytest.approx(0.0, abs=1e-3)


def test_weak_moving_texture_under_noise_is_not_static():
    # The corridor floor (contrast 0.12, blurred) under noise σ 2: moved by ~80 px it changes
    # by little more than the noise; the test on the noise alone marked every interest
    # point static (the pair then had no patches), the zero-shift correlation marks none.
    p = PRESETS["cart"]
    traj = make_trajectory("gradual", 2, preset=p, seed=2)
    tex = preset_texture(p, "corridor")
    cam = p.camera()
    frames = [render_trajectory_frame(tex, cam, traj, k, Effects(noise_sigma=2.0, seed=2))
              for k in range(2)]
    est = TwoFrameEstimator(Rig(cam, p.height_m, p.pitch_deg))
    static = static_pixels(frames[0].astype(np.float32), frames[1].astype(np.float32))
    assert static[est.roi].mean() < 0.1
    assert not on_static(static_share(static, est.config.patch_image // 2), est.centres).any()


def test_uniform_images_report_no_texture():
    cam = PRESETS["cart"].camera()
    flat = np.full((cam.height, cam.width), 128, np.uint8)
    result = TwoFrameEstimator(Rig(cam, 0.7, DEFAULT_PITCH_DEG)).estimate(flat, flat.copy())
    assert result.status == STATUS_NO_TEXTURE
    assert result.pose_curr is None
    m = result.to_measurement(3, 0.3)
    assert m.status == STATUS_NO_TEXTURE and not m.ok and np.all(np.isnan(m.z))


def test_identical_frames_report_no_motion():
    _, imgs, cam = _sequence()
    result = TwoFrameEstimator(Rig(cam, 0.7, DEFAULT_PITCH_DEG)).estimate(imgs[0], imgs[0].copy())
    assert result.status == STATUS_NO_MOTION, result.reason
    assert "motion" in result.reason


def test_camera_rotating_on_a_standing_vehicle_reports_no_motion():
    # engine, passengers or wind pitch and roll a standing vehicle's camera: the image moves
    # by pixels, but a pure rotation explains it and the pose against the ground is
    # unobservable (this pair used to come out as "did not converge", or an SVD error)
    p = PRESETS["cart"]
    pitch, roll = np.radians([45.0, 45.4]), np.radians([0.0, 0.3])
    traj = Trajectory(np.array([0.0, 0.1]), pitch, roll, np.full(2, p.height_m),
                      np.zeros((2, 2)), np.array([0.0, 0.002]), np.zeros(2))
    tex, cam = preset_texture(p), p.camera()
    imgs = [render_trajectory_frame(tex, cam, traj, k) for k in range(2)]
    assert np.median(np.abs(imgs[1].astype(float) - imgs[0])) > 5  # the image did move
    result = TwoFrameEstimator(Rig(cam, p.height_m, DEFAULT_PITCH_DEG)).estimate(*imgs)
    assert result.status == STATUS_NO_MOTION, result.reason
    assert "rotation of 0.5" in result.reason


def test_bad_input_is_a_clear_error():
    cam = PRESETS["cart"].camera()
    with pytest.raises(InputError, match="800×600"):
        rig = Rig(cam, 0.7, DEFAULT_PITCH_DEG)
        TwoFrameEstimator(rig).estimate(np.zeros((10, 10), np.uint8), np.zeros((10, 10)))
    with pytest.raises(InputError, match="n_subsets"):
        EstimatorConfig(n_subsets=-1)
    with pytest.raises(InputError, match="height"):
        TwoFrameEstimator(Rig(cam, 0.0, DEFAULT_PITCH_DEG))


# --- covariance and measurement -----------------------------------------------------------


def test_covariance_is_positive_definite_and_in_the_ballpark():
    ratios = []
    for k in (1, 2):
        result, traj, _ = _estimate(profile="gradual", k=k, frames=3)
        assert result.ok, result.reason
        cov = result.covariance
        assert cov.shape == (7, 7)
        np.testing.assert_allclose(cov, cov.T, atol=1e-15)
        assert np.all(np.linalg.eigvalsh(cov) > 0)
        truth = dm.pack(traj.pose(k - 1), traj.pose(k), traj.motion(k))
        est = dm.pack(result.pose_prev, result.pose_curr, result.motion)
        ratios.append(np.abs(est - truth) / result.std)
    ratios = np.concatenate(ratios)
    # |error|/σ of an honest std has a median of 0.67; measured 1.25 over these 14 entries
    # (pitch of both frames ~3σ, the rest 0.2–2.5σ): a std 2× too small or too large fails.
    assert np.median(ratios) < 2.5, ratios
    assert np.median(ratios) > 0.5, ratios


def test_to_measurement_carries_estimate():
    result, _, _ = _estimate()
    m = result.to_measurement(7, 0.7)
    assert isinstance(m, PairMeasurement)
    assert m.ok and m.frame == 7 and m.t == 0.7 and m.height_assumed == pytest.approx(0.7)
    np.testing.assert_allclose(m.z, dm.pack(result.pose_prev, result.pose_curr, result.motion))
    assert m.inliers == result.n_inliers > 12


def test_guess_from_previous_result():
    result, _, _ = _estimate()
    g = PairGuess.from_previous(result)
    assert g.pose_prev == result.pose_curr and g.motion == result.motion
    # the pair's turning, for a rolling shutter's angular acceleration in the next pair
    assert g.angular_rate == pytest.approx(
        (result.pose_curr.pitch - result.pose_prev.pitch,
         result.pose_curr.roll - result.pose_prev.roll))
    assert g.angular_accel_ms is None  # a global shutter keeps no running mean square
    assert PairGuess.from_previous(PairResult(status="no motion")) is None
    twice = predict_guess(dataclasses.replace(result, angular_accel_ms=(1e-4, 4e-6)), 0.1, 0.2)
    assert twice.angular_rate == pytest.approx(2 * np.array(g.angular_rate))
    assert twice.angular_accel_ms == pytest.approx((16e-4, 64e-6))  # rate changes per 2 Δt


# --- helpers ------------------------------------------------------------------------------


def _inside_convex(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    edge = np.roll(poly, -1, axis=0) - poly
    rel = pts[:, None, :] - poly[None]
    cross = edge[None, :, 0] * rel[..., 1] - edge[None, :, 1] * rel[..., 0]
    return np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)


def _shrink(poly: np.ndarray, px: float) -> np.ndarray:
    c = poly.mean(axis=0)
    d = poly - c
    return c + d * np.clip(1 - px / np.linalg.norm(d, axis=1, keepdims=True), 0, None)


# --- region of interest, tracking, baseline, real data --------------------------------------


def test_auto_roi_of_a_forward_camera_keeps_the_near_road():
    cam = PRESETS["car"].camera()
    est = TwoFrameEstimator(Rig(cam, 1.5, 3.0))
    nominal = geometry.GroundPose(np.radians(3.0), 0.0, 1.5)
    ground = geometry.back_project(cam.k, nominal, est.centres)
    assert np.all(np.isfinite(ground))
    assert ground[:, 1].max() <= 15 * 1.5 + 1e-6 and np.abs(ground[:, 0]).max() <= 2.5 * 1.5
    # Patches stay below the horizon.
    horizon = geometry.horizon_row(cam.k, nominal, cam.cx)
    assert np.all(est.centres[:, 1] - est.sizes / 2 > horizon)
    assert est.config.vertical_motion is False
    rig = Rig(PRESETS["cart"].camera(), 0.7, DEFAULT_PITCH_DEG)
    assert TwoFrameEstimator(rig).config.vertical_motion is True


@pytest.mark.parametrize(
    "roi", [(100, 300, 700, 580), np.array([[100, 300], [700, 300], [400, 590]])]
)
def test_user_roi_bounds_the_interest_points(roi):
    cam = PRESETS["cart"].camera()
    est = TwoFrameEstimator(Rig(cam, 0.7, DEFAULT_PITCH_DEG), EstimatorConfig(roi=roi))
    assert len(est.centres) >= 12
    assert np.all(est.roi[est.centres[:, 1].astype(int), est.centres[:, 0].astype(int)])
    assert est.centres[:, 1].min() >= 300
    with pytest.raises(InputError, match="ROI"):
        rig = Rig(cam, 0.7, DEFAULT_PITCH_DEG)
        TwoFrameEstimator(rig, EstimatorConfig(roi=np.zeros((3, 3, 3))))


def test_homography_baseline_decomposition_recovers_pose_and_motion():
    from vipm_track.baseline import decompose

    k = PRESETS["cart"].camera().k
    pp, pc = geometry.GroundPose(0.8, 0.03, 0.7), geometry.GroundPose(0.82, 0.01, 0.7)
    mo = geometry.PlanarMotion(0.01, 0.12, 0.02)
    h = geometry.pair_homography(k, pp, pc, mo)
    pix = np.stack(np.meshgrid(np.linspace(50, 750, 5), np.linspace(50, 550, 4)), -1).reshape(-1, 2)
    out = decompose(h, k, 0.7, geometry.GroundPose(np.radians(60), 0.0, 0.7), pix)
    assert out is not None
    np.testing.assert_allclose(dm.pack(*out), dm.pack(pp, pc, mo), atol=1e-9)


def test_kitti_tracking_pairs():
    import cv2

    from tests.conftest import shared_data
    from vipm_track.camera import load_camera

    root = shared_data("kitti07")
    cam = load_camera(root / "calib.txt")
    poses = np.loadtxt(root / "poses.txt").reshape(-1, 3, 4)
    est = TwoFrameEstimator(Rig(cam, 1.65, 0.0))
    frames = range(100, 105)
    imgs = {i: cv2.imread(str(root / "image_0" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
            for i in frames}
    guess, dist_err, yaw_err = None, [], []
    for i in list(frames)[1:]:
        r = est.estimate(imgs[i - 1], imgs[i], guess)
        assert r.ok, (i, r.reason)
        t0, t1 = np.vstack([poses[i - 1], [0, 0, 0, 1]]), np.vstack([poses[i], [0, 0, 0, 1]])
        rel = np.linalg.inv(t0) @ t1
        dist_err.append(abs(r.motion.distance / np.hypot(rel[0, 3], rel[2, 3]) - 1))
        yaw_err.append(abs(np.degrees(r.motion.yaw - np.arctan2(rel[0, 2], rel[2, 2]))))
        guess = PairGuess.from_previous(r)
    # measured: distance 10.6 % (the cold start), then 1.2 / 0.6 / 1.6 % (median 1.4 %);
    # yaw 0.02–0.06° (median 0.035°)
    assert np.median(dist_err) < 0.04, dist_err
    assert np.median(yaw_err) < 0.1, yaw_err


def test_failed_image_stage_falls_back_to_the_guess():
    # An image stage that cannot pass (absurd inlier threshold): with a guess, the virtual-IPM
    # refinement from the guess, with its wide gate, still lands near the truth.
    traj, imgs, cam = _sequence("car", "static", 2)
    tp, tc, tm = traj.pose(0), traj.pose(1), traj.motion(1)
    config = EstimatorConfig(inlier_px_image=1e-4)
    est = TwoFrameEstimator(Rig(cam, float(traj.height[0]), 3.0), config)
    # Cold start of a forward camera: the nominal-pose IPM translation is the start.
    cold = est.estimate(imgs[0], imgs[1])
    assert cold.ok and "nominal-pose IPM" in cold.reason, cold.reason
    err = _errors(traj, 1, cold.pose_prev, cold.pose_curr, cold.motion)
    assert err["pitch"] < 0.25 and err["roll"] < 0.25, err
    # A steep camera falls back to the nominal-pose IPM start (60° against the cart's 45°)
    cart, cart_imgs, cart_cam = _sequence()
    rig = Rig(cart_cam, 0.7, DEFAULT_PITCH_DEG)
    steep = TwoFrameEstimator(rig, EstimatorConfig(inlier_px_image=1e-4))
    fallback = steep.estimate(*cart_imgs)
    assert fallback.ok and "cold start from the nominal-pose IPM" in fallback.reason
    err = _errors(cart, 1, fallback.pose_prev, fallback.pose_curr, fallback.motion)
    assert err["pitch"] < 0.05 and err["roll"] < 0.05 and err["dist_mm"] < 0.1, err
    # ... and without it has no start to fall to
    alone = dataclasses.replace(steep.config, cold_start_ipm=False)
    rig = Rig(cart_cam, 0.7, DEFAULT_PITCH_DEG)
    assert TwoFrameEstimator(rig, alone).estimate(*cart_imgs).status == (
        "too few inliers")
    off = np.radians(0.3)
    guess = PairGuess(geometry.GroundPose(tp.pitch + off, tp.roll, tp.height),
                      geometry.GroundPose(tc.pitch + off, tc.roll, tc.height),
                      geometry.PlanarMotion(tm.tx, tm.tz * 1.05, tm.yaw))
    result = est.estimate(imgs[0], imgs[1], guess)
    assert result.ok, result.reason
    assert "refined from the guess" in result.reason
    # One refinement more than configured (2 for a forward camera), from the guess.
    assert [s.plane for s in result.stages] == ["image"] + ["ipm"] * (est.config.refinements + 1)
    err = _errors(traj, 1, result.pose_prev, result.pose_curr, result.motion)
    assert err["pitch"] < 0.25 and err["roll"] < 0.25, err


@pytest.mark.parametrize(("preset", "level"), [("car", True), ("cart", False)])
def test_resolve_is_the_config_that_runs(preset, level):
    from vipm_track.estimator_config import camera_kind, resolve

    p = PRESETS[preset]
    config, rig = EstimatorConfig(), Rig(p.camera(), p.height_m, p.pitch_deg)
    assert camera_kind(rig)[1] is level
    resolved = resolve(config, rig)
    assert TwoFrameEstimator(rig, config).config == resolved
    assert resolved.refinements == (2 if level else 1)
    assert resolved.vertical_motion is (not level)
    assert resolve(resolved, rig) == resolved  # nothing left to fill


def test_refinements_on_halved_planes_keep_a_level_camera_accurate(monkeypatch):
    # --refinement-resolution half: the IPM patches correlated at a quarter of the pixels,
    # centred on the halved grid
    from vipm_track import refinement

    calls = []

    def spy(ref, moving, centres, sizes, offsets, recentre=False, level=0, **options):
        calls.append((level, centres))
        return match_grouped(ref, moving, centres, sizes, offsets, recentre, level, **options)

    match_grouped = refinement.match_grouped
    monkeypatch.setattr(refinement, "match_grouped", spy)
    traj, imgs, cam = _sequence("car", "gradual", 3)
    est = TwoFrameEstimator(Rig(cam, float(traj.height[1]), 3.0),
                            EstimatorConfig(ipm_poc_level=1))
    for k in (1, 2):
        result = est.estimate(imgs[k - 1], imgs[k])
        assert result.status == "ok", result.reason
        err = _errors(traj, k, result.pose_prev, result.pose_curr, result.motion)
        # full resolution on these pairs: pitch 0.011-0.033°, roll 0.025-0.036°, 0.3-1.1 mm
        assert err["pitch"] < 0.05 and err["roll"] < 0.08, err
        assert err["dist_mm"] < 2.0 and err["yaw"] < 0.01, err
    assert calls and all(level == 1 and np.all(centres % 2 == 0) for level, centres in calls)


@pytest.mark.parametrize(("inlier_share", "retry", "fails"), [
    (0.2, False, True), (0.5, False, False), (0.5, True, True), (0.7, True, False)])
def test_a_cold_start_with_too_few_inliers_is_a_wrong_minimum(inlier_share, retry, fails):
    """The inlier-share guard on its own: every patch correlates as well as the inliers do
    (so the correlated-share guard passes them), and only the share of inliers among the
    measured patches says the fit is a wrong minimum (40 % cold, 60 % on a retry)."""
    from vipm_track.cold_start import reject_wrong_minimum
    from vipm_track.pair_result import STATUS_OK, PatchField

    n = 100
    inliers = np.arange(n) < round(inlier_share * n)
    stage = PatchField("ipm", np.zeros((n, 2)), np.zeros((n, 2)), np.full(n, 0.5), inliers,
                       np.full(n, 128))
    result = PairResult(STATUS_OK, stages=[stage])
    reject_wrong_minimum(result, steep=True, min_peak=0.1, retry=retry)
    assert (result.status == STATUS_FEW_INLIERS) == fails, result.reason
    if fails:
        assert "a wrong minimum" in result.reason
