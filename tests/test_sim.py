"""Synthetic sequences: ground truth consistent with the rendered images, textures,
trajectories, effects and the ``simulate`` writer/CLI."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vipm_track import geometry as g
from vipm_track.camera import CameraModel, load_camera
from vipm_track.cli import main
from vipm_track.render import OBSTACLE_POLYGON, Effects, render_frame
from vipm_track.sim import (
    PRESETS,
    PROFILES,
    make_trajectory,
    preset_texture,
    render_trajectory_frame,
    simulate_sequence,
)
from vipm_track.table import read_table
from vipm_track.texture import GroundTexture, load_texture

WINDOW = 64


def _local_shifts(img0: np.ndarray, img1: np.ndarray, camera: CameraModel, h01: np.ndarray,
                  points: np.ndarray) -> np.ndarray:
    """Residual shift (N, 2) px of frame k's content, brought back into frame k-1 by the
    homography ``h01`` (pixels k-1 → k), against frame k-1 around each point, measured by
    an independent sub-pixel registration (ECC, translation only)."""
    warped = cv2.warpPerspective(img1.astype(np.float32), h01, (camera.width, camera.height),
                                 flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    out = []
    for x, y in np.round(points).astype(int):
        sl = np.s_[y - WINDOW // 2:y + WINDOW // 2, x - WINDOW // 2:x + WINDOW // 2]
        warp = np.eye(2, 3, dtype=np.float32)
        _, warp = cv2.findTransformECC(img0[sl].astype(np.float32), warped[sl], warp,
                                       cv2.MOTION_TRANSLATION, criteria, None, 1)
        out.append(warp[:, 2])
    return np.array(out)


def _test_points(camera: CameraModel, pose0, pose1, motion, top: float) -> np.ndarray:
    """Grid points of frame k-1 whose window stays inside both frames and on the ground."""
    u, v = np.meshgrid(np.linspace(60, camera.width - 60, 8),
                       np.linspace(top, camera.height - 60, 6))
    pts = np.stack([u.ravel(), v.ravel()], axis=1)
    half = WINDOW / 2 + 4
    corners = np.array([[-half, -half], [half, -half], [-half, half], [half, half]])
    keep = []
    for p in pts:
        c0 = p + corners
        c1 = g.predict_pixels(camera.k, pose0, pose1, motion, c0)
        inside = np.all(np.isfinite(c1)) and np.all((c1 > 0) & (c1 < [camera.width - 1,
                                                                         camera.height - 1]))
        keep.append(inside and np.all(g.below_horizon(camera.k, pose0, c0, np.radians(1))))
    return pts[np.array(keep)]


@pytest.mark.parametrize(("preset", "profile", "top"), [
    ("cart", "turn", 80), ("cart", "shaking", 80), ("car", "gradual", 420),
])
def test_ground_truth_motion_matches_image_content(preset, profile, top):
    p = PRESETS[preset]
    camera, tex = p.camera(), preset_texture(p)
    traj = make_trajectory(profile, 3, preset=p, seed=3)
    img0, img1 = (render_trajectory_frame(tex, camera, traj, k) for k in (1, 2))
    pose0, pose1, motion = traj.pose(1), traj.pose(2), traj.motion(2)
    pts = _test_points(camera, pose0, pose1, motion, top)
    assert len(pts) >= 10
    # The content really moved (tens of pixels), and where the GT says, to sub-pixel.
    moved = g.predict_pixels(camera.k, pose0, pose1, motion, pts) - pts
    assert np.median(np.hypot(*moved.T)) > 5
    h01 = g.pair_homography(camera.k, pose0, pose1, motion)
    err = _local_shifts(img0, img1, camera, h01, pts)
    assert np.median(np.hypot(*err.T)) < 0.05
    # The check can fail: 3 % more forward motion is seen as a shift of about the predicted size.
    wrong = g.PlanarMotion(motion.tx, motion.tz * 1.03, motion.yaw)
    err_wrong = _local_shifts(img0, img1, camera,
                              g.pair_homography(camera.k, pose0, pose1, wrong), pts)
    expected = np.hypot(*(g.predict_pixels(camera.k, pose0, pose1, wrong, pts)
                          - g.predict_pixels(camera.k, pose0, pose1, motion, pts)).T)
    assert np.median(np.hypot(*err_wrong.T)) > 0.5 * np.median(expected) > 0.1


def test_rendered_blob_lands_at_projected_pixel():
    # A single Gaussian spot on a black ground at a known world point.
    canvas = np.zeros((4096, 4096), np.float64)
    centre = (2000.0, 1500.0)  # texel (u, v) → world X = u·s, Z = -v·s
    v, u = np.mgrid[1400:1600, 1900:2100]
    canvas[1400:1600, 1900:2100] = 250 * np.exp(-((u - centre[0]) ** 2 + (v - centre[1]) ** 2)
                                                 / (2 * 3.0 ** 2))
    s = 0.001
    tex = GroundTexture(canvas, s)
    p = PRESETS["cart"]
    camera = p.camera()
    pose = g.GroundPose(np.radians(40.0), np.radians(4.0), 0.65)
    world_xz, heading = np.array([1.6, -2.5]), np.radians(20.0)
    img = render_frame(tex, camera, pose, world_xz, heading, supersample=3).astype(float)
    point_w = np.array([centre[0] * s, -centre[1] * s])
    point_g = g.transform_ground(g.PlanarMotion(*world_xz, heading), point_w)
    expected = g.project(camera.k, pose, point_g)
    assert np.all((expected > 40) & (expected < [camera.width - 40, camera.height - 40]))
    x0, y0 = np.round(expected).astype(int)
    patch = img[y0 - 25:y0 + 26, x0 - 25:x0 + 26]
    patch = np.where(patch > 2, patch, 0.0)
    yy, xx = np.mgrid[y0 - 25:y0 + 26, x0 - 25:x0 + 26]
    centroid = np.array([(xx * patch).sum(), (yy * patch).sum()]) / patch.sum()
    assert np.hypot(*(centroid - expected)) < 0.1


def test_car_horizon_sky_above_ground_below():
    p = PRESETS["car"]
    camera, tex = p.camera(), preset_texture(p)
    pose = p.pose()
    img = render_frame(tex, camera, pose, (0.0, 0.0), 0.0).astype(float)
    row = g.horizon_row(camera.k, pose, camera.cx)
    assert 250 < row < 360
    r = int(np.floor(row))
    sky, ground_far = img[: r - 2], img[r + 3: r + 40]
    # Sky is a smooth gradient; the far ground is mip-mapped to the texture's mean (no
    # aliasing noise); the near ground keeps the photo's contrast.
    assert np.std(np.diff(sky, axis=1)) < 0.6
    assert abs(ground_far.mean() - tex.levels[0].mean()) < 6
    assert ground_far.std() < img[-150:].std()
    assert img[-150:].std() > 15


def test_texture_is_seamless_and_not_periodic_at_the_tile_step():
    tex = load_texture("gravel", 0.0015, 0, 24)
    c = tex.levels[0]
    # Across the wrap-around the texture is as continuous as anywhere else.
    inside = np.abs(np.diff(c[:, 1000:1100].astype(float), axis=1)).mean()
    across = np.abs(c[:, 0].astype(float) - c[:, -1]).mean()
    assert across < 1.3 * inside
    c = c[:2048, :2048].astype(float)
    # No exact repetition at the tile step (256 texels) nor anywhere near it.
    a = c[:1024, :1024] - c.mean()
    for shift in (256, 512):
        b = c[:1024, shift:shift + 1024] - c.mean()
        corr = (a * b).mean() / np.sqrt((a * a).mean() * (b * b).mean())
        assert abs(corr) < 0.1
    assert abs(c.std() - 39) < 8  # photo contrast kept by the variance-preserving blend
    again = GroundTexture.from_photo("gravel.png", 0.0015, tiles=4, seed=5)
    assert np.array_equal(again.levels[0], GroundTexture.from_photo("gravel.png", 0.0015,
                                                                    tiles=4, seed=5).levels[0])
    weak = load_texture("corridor", 0.0015, 0, 4).levels[0].astype(float)
    assert weak.std() < 0.15 * c.std()


def test_trajectory_profiles():
    p = PRESETS["cart"]
    for profile in PROFILES:
        traj = make_trajectory(profile, 40, preset=p, seed=1)
        assert len(traj) == 40 and np.allclose(np.diff(traj.t), 1 / p.fps)
        # Motions chain back to the world poses.
        acc = traj.world_pose(0)
        for k in range(1, 40):
            acc = g.compose_motion(acc, traj.motion(k))
        end = traj.world_pose(39)
        assert np.allclose([acc.tx, acc.tz, acc.yaw], [end.tx, end.tz, end.yaw], atol=1e-9)
        dist = np.array([traj.motion(k).distance for k in range(1, 40)])
        assert np.allclose(dist * p.fps, p.speed_mps, rtol=0.08)
    static = make_trajectory("static", 10, preset=p)
    assert np.ptp(static.pitch) == 0 and np.isclose(static.pitch[0], np.radians(45))
    assert all(abs(static.motion(k).tx) < 1e-12 for k in range(1, 10))
    turn = make_trajectory("turn", 10, preset=p)
    assert np.isclose(turn.motion(3).yaw, np.radians(p.turn_rate_dps) / p.fps)
    assert turn.motion(3).tx > 0  # turning right: G_k lies right of straight ahead
    shaking = make_trajectory("shaking", 100, preset=p, seed=2)
    assert np.radians(0.5) < np.std(shaking.pitch) < np.radians(3)
    gradual = make_trajectory("gradual", 100, preset=p, seed=2)
    assert np.max(np.abs(np.diff(gradual.pitch))) < np.radians(0.2) < np.ptp(gradual.pitch)
    height = make_trajectory("height", 100, preset=p, seed=2)
    assert 0.05 < np.ptp(height.height) < 0.2
    again = make_trajectory("shaking", 100, preset=p, seed=2)
    assert np.array_equal(again.pitch, shaking.pitch)
    with pytest.raises(ValueError, match="profile"):
        make_trajectory("loop", 10)


def test_effects():
    p = PRESETS["cart"]
    camera, tex = p.camera(), preset_texture(p)
    pose, xz = p.pose(), (0.3, 1.0)
    clean = render_frame(tex, camera, pose, xz, 0.0).astype(float)
    noisy = render_frame(tex, camera, pose, xz, 0.0, Effects(noise_sigma=4.0)).astype(float)
    assert abs(np.std(noisy - clean) - 4.0) < 0.3
    vig = render_frame(tex, camera, pose, xz, 0.0, Effects(vignetting=1.0)).astype(float)
    corner = (np.hypot(400 / 729, 300 / 729) ** 2 + 1) ** -2
    assert np.isclose(vig[:20, :20].mean() / clean[:20, :20].mean(), corner, atol=0.03)
    drift = Effects(exposure_drift=0.2)
    gains = [render_frame(tex, camera, pose, xz, 0.0, drift, t=t).mean() / clean.mean()
             for t in (0.0, 2.0, 6.0)]
    assert np.ptp(gains) > 0.1
    # Highlights and the obstacle stay put in the image while the ground moves.
    fx = Effects(obstacle=True)
    a = render_frame(tex, camera, pose, xz, 0.0, fx).astype(float)
    b = render_frame(tex, camera, pose, (0.3, 1.2), 0.0, fx).astype(float)
    x, y = (OBSTACLE_POLYGON.mean(axis=0) * [camera.width, camera.height]).astype(int)
    assert np.array_equal(a[y - 20:y + 20, x - 20:x + 20], b[y - 20:y + 20, x - 20:x + 20])
    assert not np.array_equal(a[y - 20:y + 20, x - 20:x + 20], clean[y - 20:y + 20, x - 20:x + 20])
    fx = Effects(highlights=3)
    a = render_frame(tex, camera, pose, xz, 0.0, fx).astype(float) - clean
    b = render_frame(tex, camera, pose, (0.3, 1.2), 0.0, fx).astype(float)
    b -= render_frame(tex, camera, pose, (0.3, 1.2), 0.0).astype(float)
    assert a.max() > 100 and np.mean(np.abs(a - b)) < 0.5  # same blobs, ground moved


def test_motion_blur_follows_each_pixels_image_motion():
    """The blurred frame is the average over its exposure: every frame blurred (the first
    too), more where the ground moves faster in the image, and centred on the frame's pose."""
    p = PRESETS["cart"]
    camera, tex = p.camera(), preset_texture(p)
    traj = make_trajectory("static", 3, None, p, seed=0, speed=0.3)  # 2 cm per frame
    for k in (0, 1):
        sharp = render_trajectory_frame(tex, camera, traj, k).astype(float)
        blurred = render_trajectory_frame(tex, camera, traj, k, Effects(motion_blur=0.5))
        blurred = blurred.astype(float)

        near, far = (np.abs(np.diff(blurred[rows], axis=0)).mean()
                     / np.abs(np.diff(sharp[rows], axis=0)).mean()
                     for rows in (np.s_[450:600], np.s_[0:150]))
        assert near < 0.75 and near < far - 0.1, (k, near, far)
        # Centred: the sharp frame's patches match the blurred frame where they were taken
        # (plain correlation: a box blur's spectrum changes sign, which misleads POC here).
        for x, y in [(200, 300), (400, 450), (600, 500)]:
            scores = cv2.matchTemplate(blurred[y - 28:y + 28, x - 28:x + 28].astype(np.float32),
                                       sharp[y - 24:y + 24, x - 24:x + 24].astype(np.float32),
                                       cv2.TM_CCOEFF_NORMED)
            assert np.unravel_index(np.argmax(scores), scores.shape) == (4, 4), (k, x, y)


def test_rolling_shutter_exposes_each_row_at_its_time():
    """Row v of a rolling-shutter frame k shows the ground from where the vehicle is
    v / rows · readout frame intervals after frame k (row 0 at the frame's time)."""
    p = PRESETS["cart"]
    camera, tex = p.camera(), preset_texture(p)
    traj = make_trajectory("static", 3, None, p, seed=0)  # 12 cm per frame
    readout = 0.5
    rs = render_trajectory_frame(tex, camera, traj, 1, Effects(rolling_shutter=readout))
    rs = rs.astype(float)
    at_frame_time = render_trajectory_frame(tex, camera, traj, 1).astype(float)
    for v in (40, 300, 560):
        u = readout * v / camera.height
        xz = traj.world_xz[1] + u * (traj.world_xz[2] - traj.world_xz[1])
        at_row_time = render_frame(tex, camera, traj.pose(1), xz, 0.0).astype(float)
        rows = np.s_[v - 2:v + 3, 100:700]
        err = np.abs(rs[rows] - at_row_time[rows]).mean()  # bands are timed at their centre
        assert err < 3.0 and np.abs(rs[rows] - at_frame_time[rows]).mean() > 5 * err, v


def test_distorted_camera_renders_what_undistort_recovers():
    p = PRESETS["cart"]
    ideal_cam = p.camera()
    cam = CameraModel(ideal_cam.k, ideal_cam.width, ideal_cam.height, "plumb_bob",
                      np.array([-0.25, 0.08, 0.001, -0.0005, 0.0]))
    tex = preset_texture(p)
    ideal = render_frame(tex, ideal_cam, p.pose(), (0, 0), 0.0).astype(float)
    distorted = render_frame(tex, cam, p.pose(), (0, 0), 0.0)
    back = cam.undistort_image(distorted).astype(float)
    sl = np.s_[100:500, 150:650]
    assert np.mean(np.abs(back[sl] - ideal[sl])) < 0.25 * np.mean(np.abs(distorted[sl] - ideal[sl]))


def test_simulate_writes_sequence(tmp_path):
    out = tmp_path / "seq"
    traj = simulate_sequence("cart", 4, out, seed=2, profile="shaking",
                             effects=Effects(noise_sigma=1.0))
    images = sorted((out / "images").glob("*.png"))
    assert [f.name for f in images] == [f"{k:06d}.png" for k in range(4)]
    assert cv2.imread(str(images[0]), cv2.IMREAD_GRAYSCALE).shape == (600, 800)
    cam = load_camera(out / "camera.yaml")
    assert np.allclose(cam.k, PRESETS["cart"].camera().k) and (cam.width, cam.height) == (800, 600)
    assert np.allclose(np.loadtxt(out / "times.txt"), traj.t)
    gt = read_table(out / "gt.csv")
    assert list(gt["status"]) == ["first", "ok", "ok", "ok"]
    assert np.isnan(gt["tz_m"][0])
    assert np.allclose(gt["tz_m"][1:], [traj.motion(k).tz for k in (1, 2, 3)])
    assert np.allclose(gt["pitch_deg"], np.degrees(traj.pitch))
    assert np.allclose(gt["prev_roll_deg"][1:], np.degrees(traj.roll[:-1]))


def test_cli(tmp_path, capsys):
    assert main(["simulate", "--preset", "cart", "--frames", "2", "--out", str(tmp_path / "s"),
                 "--profile", "turn", "--texture", "brick", "--highlights", "--vignetting"]) == 0
    assert len(list((tmp_path / "s" / "images").glob("*.png"))) == 2
    assert main(["simulate", "--frames", "0", "--out", str(tmp_path / "x")]) == 2
    assert "--frames" in capsys.readouterr().err
