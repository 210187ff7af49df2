"""Geometry round trips and sign conventions (CONVENTIONS.md)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vipm_track import geometry as g
from vipm_track import ipm

K = np.array([[729.0, 0.0, 400.0], [0.0, 729.0, 300.0], [0.0, 0.0, 1.0]])

poses = st.builds(
    g.GroundPose,
    pitch=st.floats(np.radians(5), np.radians(90)),
    roll=st.floats(np.radians(-20), np.radians(20)),
    height=st.floats(0.2, 3.0),
)
motions = st.builds(
    g.PlanarMotion,
    tx=st.floats(-2, 2),
    tz=st.floats(-3, 3),
    yaw=st.floats(-0.5, 0.5),
)


def _ground_pixels(pose: g.GroundPose, n: int = 50) -> np.ndarray:
    rng = np.random.default_rng(0)
    px = rng.uniform([0, 0], [800, 600], size=(n, 2))
    return px[g.below_horizon(K, pose, px, margin=np.radians(2))]


@settings(max_examples=200, deadline=None)
@given(poses)
def test_projection_inverts_back_projection(pose):
    px = _ground_pixels(pose)
    again = g.project(K, pose, g.back_project(K, pose, px))
    np.testing.assert_allclose(again, px, atol=1e-7)


@settings(max_examples=200, deadline=None)
@given(motions)
def test_motion_inverse_composes_to_identity(motion):
    np.testing.assert_allclose(
        g.motion_matrix(g.invert_motion(motion)) @ g.motion_matrix(motion), np.eye(3), atol=1e-12
    )
    ident = g.compose_motion(motion, g.invert_motion(motion))
    np.testing.assert_allclose([ident.tx, ident.tz, ident.yaw], 0.0, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(motions, motions)
def test_composition_matches_matrix_product(a, b):
    ab = g.compose_motion(a, b)
    np.testing.assert_allclose(
        g.motion_matrix(ab), g.motion_matrix(b) @ g.motion_matrix(a), atol=1e-12
    )


@settings(max_examples=200, deadline=None)
@given(motions, st.floats(0.002, 0.05))
def test_moved_ipm_pixels_follow_the_ground_motion(motion, mpp):
    grid = g.IpmGrid.from_extent(-4.0, 4.0, 1.0, 9.0, mpp)
    q = np.random.default_rng(1).uniform(0, [grid.width, grid.height], size=(20, 2))
    moved = g.apply_homography(ipm.moved_pixels_matrix(grid, motion), q)
    pointwise = grid.pixel_from_ground(g.transform_ground(motion, grid.ground_from_pixel(q)))
    np.testing.assert_allclose(moved, pointwise, atol=1e-7)
    # the rigid map of transform_ground, written out
    c, s = np.cos(motion.yaw), np.sin(motion.yaw)
    x, z = grid.ground_from_pixel(q).T
    dx, dz = x - motion.tx, z - motion.tz
    np.testing.assert_allclose(g.transform_ground(motion, grid.ground_from_pixel(q)),
                               np.stack([c * dx - s * dz, s * dx + c * dz], axis=1), atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(poses, motions)
def test_homographies_agree_with_pointwise_maps(pose, motion):
    px = _ground_pixels(pose)
    ground = g.back_project(K, pose, px)
    np.testing.assert_allclose(
        g.apply_homography(g.ground_from_image_homography(K, pose), px),
        ground,
        rtol=1e-9,
        atol=1e-9,
    )
    np.testing.assert_allclose(
        g.apply_homography(g.image_from_ground_homography(K, pose), ground),
        px,
        rtol=1e-9,
        atol=1e-9,
    )
    pose2 = g.GroundPose(pose.pitch * 0.98, pose.roll * 0.9, pose.height)
    expected = g.predict_pixels(K, pose, pose2, motion, px)
    got = g.apply_homography(g.pair_homography(K, pose, pose2, motion), px)
    ok = np.all(np.isfinite(expected), axis=1)
    np.testing.assert_allclose(got[ok], expected[ok], rtol=1e-9, atol=1e-9)
    grid = g.IpmGrid.from_extent(-2, 2, 0.5, 6, 0.01)
    ipm_px = grid.pixel_from_ground(ground)
    np.testing.assert_allclose(
        g.apply_homography(g.image_from_ipm_homography(K, pose, grid), ipm_px),
        px,
        rtol=1e-9,
        atol=1e-9,
    )


@settings(max_examples=200, deadline=None)
@given(poses, st.floats(-0.05, 0.05), st.floats(-0.05, 0.05))
def test_rotation_parallax_vanishes_without_translation(pose, d_pitch, d_roll):
    # a camera turning in place: a pure rotation maps every pixel, with no parallax
    px = _ground_pixels(pose)
    if len(px) < 3:
        return
    pose2 = g.GroundPose(pose.pitch + d_pitch, pose.roll + d_roll, pose.height)
    moved = g.predict_pixels(K, pose, pose2, g.PlanarMotion(0.0, 0.0, 0.0), px)
    ok = np.all(np.isfinite(moved), axis=1)
    residual, angle = g.rotation_parallax(K, px[ok], moved[ok])
    assert np.max(residual) < 1e-6
    r1 = g.rotation_ground_from_camera(pose.pitch, pose.roll)
    r2 = g.rotation_ground_from_camera(pose2.pitch, pose2.roll)
    expected = np.arccos(np.clip(0.5 * (np.trace(r1.T @ r2) - 1.0), -1.0, 1.0))
    assert abs(angle - expected) < 1e-6


def test_rotation_parallax_shows_translation():
    pose = g.GroundPose(np.radians(45.0), 0.0, 0.7)
    px = _ground_pixels(pose)
    for step, low, high in ((0.001, 0.05, 1.0), (0.05, 5.0, 100.0)):  # metres: px of parallax
        moved = g.predict_pixels(K, pose, pose, g.PlanarMotion(0.0, step, 0.01), px)
        residual, _ = g.rotation_parallax(K, px, moved)
        assert low < np.median(residual) < high


def test_signs_follow_conventions():
    # Straight down: the principal point sees the ground point under the camera.
    down = g.GroundPose(np.pi / 2, 0.0, 1.0)
    np.testing.assert_allclose(g.back_project(K, down, [[400.0, 300.0]]), [[0.0, 0.0]], atol=1e-12)
    # pitch > 0 looks down: the principal point sees ground ahead at h / tan(pitch).
    pose = g.GroundPose(np.radians(30), 0.0, 1.5)
    np.testing.assert_allclose(
        g.back_project(K, pose, [[400.0, 300.0]]), [[0.0, 1.5 / np.tan(np.radians(30))]], atol=1e-9
    )
    # roll > 0 dips the image's right edge toward the ground: the right side of the image
    # sees nearer ground than the left side on the same row.
    rolled = g.GroundPose(np.radians(30), np.radians(5), 1.5)
    left, right = g.back_project(K, rolled, [[100.0, 300.0], [700.0, 300.0]])
    assert right[1] < left[1]
    # Pixels above the horizon have no ground point.
    assert np.all(np.isnan(g.back_project(K, pose, [[400.0, -2000.0]])))
    assert not g.below_horizon(K, pose, [[400.0, -2000.0]])[0]
    # yaw > 0 turns right: a point straight ahead ends up on the left (x < 0).
    ahead = g.transform_ground(g.PlanarMotion(0, 0, np.radians(10)), [[0.0, 10.0]])
    assert ahead[0, 0] < 0
    # Forward motion: ground ahead comes closer by tz.
    np.testing.assert_allclose(
        g.transform_ground(g.PlanarMotion(0, 1.0, 0), [[0.0, 5.0]]), [[0.0, 4.0]]
    )


def test_pose_from_rotation_round_trip():
    for pitch, roll in [(0.3, 0.1), (1.2, -0.3), (0.05, 0.0)]:
        r = g.rotation_ground_from_camera(pitch, roll)
        np.testing.assert_allclose(g.pose_from_rotation(r), (pitch, roll), atol=1e-12)


def test_horizon_row_separates_ground_from_sky():
    pose = g.GroundPose(np.radians(3), np.radians(2), 1.5)
    v = g.horizon_row(K, pose, 400.0)
    assert g.below_horizon(K, pose, [[400.0, v + 1.0]])[0]
    assert not g.below_horizon(K, pose, [[400.0, v - 1.0]])[0]


@settings(max_examples=100, deadline=None)
@given(poses)
def test_homography_jacobian_matches_finite_differences(pose):
    h = g.ground_from_image_homography(K, pose)
    px = _ground_pixels(pose)
    if len(px) == 0:
        return
    jac = g.homography_jacobian(h, px)
    eps = 1e-3
    for axis in range(2):
        step = np.zeros(2)
        step[axis] = eps
        fd = (g.apply_homography(h, px + step) - g.apply_homography(h, px - step)) / (2 * eps)
        np.testing.assert_allclose(jac[:, :, axis], fd, rtol=1e-5, atol=1e-9)
