"""The renderer against a second, separately written projection.

Ground truth here does not come from ``vipm_track.geometry``: the camera pose is built with
``cv2.Rodrigues`` from the text of CONVENTIONS.md (R_GC = Rx(−pitch)·Rz(roll), camera
centre at (0, −h, 0) in G, a world point reaching G_k through Ry(heading)ᵀ(P − (x, 0, z)))
and points are projected with ``cv2.projectPoints`` (lens distortion included). The scene
is a ground texture of small Gaussian dots at known texels (texel (u, v) ↔ world
X = u·mpt, Z = −v·mpt, the texture's own convention); each dot's centroid in the rendered
frame must land where the independent projection puts it. A rolling shutter's row v is
exposed v/rows · readout frame intervals after the frame's time: the dot is seen at the
row where the camera, moved along the known constant-velocity drive, projects it to that
row (solved here by fixed-point iteration).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vipm_track.camera import CameraModel
from vipm_track.geometry import GroundPose  # the renderer's input type; no projection
from vipm_track.render import Effects, render_frame
from vipm_track.sim import PRESETS, Trajectory, render_trajectory_frame
from vipm_track.texture import GroundTexture

CANVAS = 2048
BACKGROUND, PEAK = 30.0, 220.0


def _dot_texture(metres_per_texel: float, spacing: int, sigma: float) -> tuple[GroundTexture,
                                                                             np.ndarray]:
    """A canvas of Gaussian dots on a jittered grid; returns the texture and the dots'
    texel centres (N, 2) as (u, v)."""
    rng = np.random.default_rng(11)
    g = np.arange(spacing // 2, CANVAS, spacing, dtype=float)
    uu, vv = np.meshgrid(g, g)
    centres = np.stack([uu.ravel(), vv.ravel()], axis=1)
    centres += rng.uniform(-0.3, 0.3, centres.shape) * spacing
    canvas = np.full((CANVAS, CANVAS), BACKGROUND)
    half = int(np.ceil(4 * sigma))
    for cu, cv in centres:
        u0, v0 = int(np.rint(cu)), int(np.rint(cv))
        us = np.arange(u0 - half, u0 + half + 1)
        vs = np.arange(v0 - half, v0 + half + 1)
        blob = np.exp(-0.5 * (((us[None, :] - cu) ** 2 + (vs[:, None] - cv) ** 2) / sigma**2))
        canvas[np.ix_(vs % CANVAS, us % CANVAS)] += (PEAK - BACKGROUND) * blob
    return GroundTexture(canvas, metres_per_texel, "dots"), centres


def _camera_from_world(pitch: float, roll: float, height: float, world_xz, heading: float):
    """(rvec, tvec) of world → camera, written from CONVENTIONS.md with cv2.Rodrigues."""
    r_gc = cv2.Rodrigues(np.array([-pitch, 0.0, 0.0]))[0] @ cv2.Rodrigues(
        np.array([0.0, 0.0, roll]))[0]
    r_wg = cv2.Rodrigues(np.array([0.0, heading, 0.0]))[0]  # Ry(heading): columns = G in W
    origin_g = np.array([world_xz[0], 0.0, world_xz[1]])
    centre_g = np.array([0.0, -height, 0.0])
    # P_C = R_GCᵀ (R_WGᵀ (P_W − o) − c)
    r_cw = r_gc.T @ r_wg.T
    t_cw = -r_gc.T @ (r_wg.T @ origin_g) - r_gc.T @ centre_g
    return cv2.Rodrigues(r_cw)[0], t_cw, r_cw


def _visible_dots(centres, mpt: float, camera: CameraModel, pose, world_xz, heading,
                  max_range_m: float, sigma_texels: float, radius_px: int):
    """World points (M, 3) of the periodic copies of the dots in front of the camera within
    ``max_range_m`` of it that the image resolves (the dot ≥ 1 px across both ways, no
    other dot within 2.5 window radii), with their projections (M, 2)."""
    period = CANVAS * mpt
    shifts = np.arange(-3, 4) * period
    pts = []
    for sx in shifts:
        for sz in shifts:
            pts.append(np.column_stack([centres[:, 0] * mpt + sx, np.zeros(len(centres)),
                                        -centres[:, 1] * mpt + sz]))
    pts = np.concatenate(pts)
    rvec, tvec, r_cw = _camera_from_world(*pose, world_xz, heading)
    cam_pts = pts @ r_cw.T + tvec
    pts = pts[(cam_pts[:, 2] > 0.05) & (np.linalg.norm(cam_pts, axis=1) < max_range_m)]
    dist = camera.distortion if camera.distortion.size else np.zeros(5)

    def project(p):
        return cv2.projectPoints(p, rvec, tvec, camera.k, dist)[0].reshape(-1, 2)

    uv = project(pts)
    dx, dz = np.array([sigma_texels * mpt, 0.0, 0.0]), np.array([0.0, 0.0, sigma_texels * mpt])
    size_x = np.linalg.norm(project(pts + dx) - project(pts - dx), axis=1)
    size_z = np.linalg.norm(project(pts + dz) - project(pts - dz), axis=1)
    gap = np.linalg.norm(uv[:, None] - uv[None], axis=2)
    np.fill_diagonal(gap, np.inf)
    resolved = (np.minimum(size_x, size_z) >= 2.0) & (gap.min(axis=1) > 2.5 * radius_px)
    return pts[resolved], uv[resolved]


def _centroid(img: np.ndarray, uv: np.ndarray, radius: int) -> np.ndarray | None:
    """Intensity-weighted centroid (background removed) of the dot near ``uv``; None where
    the window leaves the image or holds more than one dot."""
    u0, v0 = int(np.rint(uv[0])), int(np.rint(uv[1]))
    h, w = img.shape
    if not (radius <= u0 < w - radius and radius <= v0 < h - radius):
        return None
    win = img[v0 - radius:v0 + radius + 1, u0 - radius:u0 + radius + 1].astype(float)
    wgt = np.clip(win - BACKGROUND - 8.0, 0.0, None)
    # a clean dot: bright centre, dark rim (no neighbour cut by the window)
    rim = np.concatenate([wgt[0], wgt[-1], wgt[:, 0], wgt[:, -1]])
    if wgt.max() < 60.0 or rim.max() > 2.0:
        return None
    ys, xs = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    return np.array([u0 + (wgt * xs).sum() / wgt.sum(), v0 + (wgt * ys).sum() / wgt.sum()])


def _offsets(img, uv, radius: int) -> np.ndarray:
    found = [(c, p) for p in uv if (c := _centroid(img, p, radius)) is not None]
    return np.array([c - p for c, p in found]).reshape(-1, 2)


# (preset, pitch°, roll°, height m, world x/z m, heading°, range m, dot spacing/σ texels,
# window radius px, bound px)
CASES = {
    "cart-nominal": ("cart", 45.0, 0.0, 0.7, (0.4, -1.3), 0.0, 3.0, 64, 3.0, 9, 0.1),
    "cart-pitched-rolled-turned": ("cart", 38.0, 4.0, 0.65, (-1.7, 2.2), 25.0, 3.0, 64, 3.0,
                                   9, 0.1),
    "cart-steep-rolled-left": ("cart", 70.0, -6.0, 0.8, (0.9, 0.3), -140.0, 3.0, 64, 3.0, 9,
                               0.1),
    "car-forward": ("car", 3.0, 1.5, 1.5, (3.0, -5.0), 10.0, 12.0, 48, 1.5, 8, 0.1),
}


@pytest.mark.parametrize("case", list(CASES))
def test_dots_land_where_an_independent_projection_puts_them(case: str) -> None:
    (preset, pitch, roll, height, world_xz, heading, max_range, spacing, sigma, radius,
     bound) = CASES[case]
    p = PRESETS[preset]
    camera = p.camera()
    mpt = p.metres_per_texel
    texture, centres = _dot_texture(mpt, spacing, sigma)
    pose = (np.radians(pitch), np.radians(roll), height)
    img = render_frame(texture, camera, GroundPose(*pose), np.array(world_xz),
                       np.radians(heading))
    _, uv = _visible_dots(centres, mpt, camera, pose, world_xz, np.radians(heading),
                          max_range, sigma, radius)
    off = _offsets(img, uv, radius)
    assert len(off) >= 15, f"only {len(off)} clean dots checked"
    # measured: worst 0.02–0.03 px, medians ≤ 0.014 px (32–106 dots per case)
    assert np.abs(off).max() < bound, np.abs(off).max(axis=0)
    assert np.abs(np.median(off, axis=0)).max() < 0.04


def test_dots_through_a_distorted_lens() -> None:
    # Lens distortion is applied on top of the pinhole render; cv2.projectPoints with the
    # same coefficients is the independent truth.
    p = PRESETS["cart"]
    pin = p.camera()
    camera = CameraModel(pin.k, pin.width, pin.height, "plumb_bob",
                         np.array([-0.25, 0.08, 0.001, -0.0005, 0.0]))
    texture, centres = _dot_texture(p.metres_per_texel, 64, 3.0)
    pose = (np.radians(45.0), np.radians(2.0), 0.7)
    img = render_frame(texture, camera, GroundPose(*pose), np.array([0.2, 0.1]), 0.3)
    pts, uv = _visible_dots(centres, p.metres_per_texel, camera, pose, (0.2, 0.1), 0.3, 3.0,
                            3.0, 9)
    off = _offsets(img, uv, 9)
    assert len(off) >= 15
    # measured worst 0.04 px
    assert np.abs(off).max() < 0.1, np.abs(off).max(axis=0)
    # the lens matters here: the same dots through the pinhole land tens of pixels away
    rvec, tvec, _ = _camera_from_world(*pose, (0.2, 0.1), 0.3)
    uv_pinhole = cv2.projectPoints(pts, rvec, tvec, pin.k, np.zeros(5))[0].reshape(-1, 2)
    inside = (uv[:, 0] > 0) & (uv[:, 0] < pin.width) & (uv[:, 1] > 0) & (uv[:, 1] < pin.height)
    assert np.abs(uv_pinhole - uv)[inside].max() > 20


def _drive(preset: str, n: int, speed: float, yaw_rate: float, pitch_rate: float):
    """A constant-velocity drive (straight or a constant turn) with the pitch changing at a
    constant rate: every sub-frame pose is known in closed form."""
    p = PRESETS[preset]
    dt = 1.0 / p.fps
    t = np.arange(n) * dt
    heading = yaw_rate * t
    if yaw_rate:
        x = speed / yaw_rate * (1.0 - np.cos(heading))
        z = speed / yaw_rate * np.sin(heading)
    else:
        x, z = np.zeros(n), speed * t
    pitch = np.radians(p.pitch_deg) + pitch_rate * t
    traj = Trajectory(t, pitch, np.full(n, np.radians(1.0)), np.full(n, p.height_m),
                      np.stack([x, z], axis=1), heading, np.full(n, speed))

    def at(time: float):
        h = yaw_rate * time
        if yaw_rate:
            xz = (speed / yaw_rate * (1.0 - np.cos(h)), speed / yaw_rate * np.sin(h))
        else:
            xz = (0.0, speed * time)
        return (np.radians(p.pitch_deg) + pitch_rate * time, np.radians(1.0), p.height_m), xz, h

    return traj, at


@pytest.mark.parametrize(("preset", "speed", "yaw_rate", "pitch_rate", "readout"), [
    ("cart", 1.5, 0.0, 0.0, 0.5),
    ("cart", 1.2, 0.6, 0.05, 0.8),
    ("car", 15.0, 0.15, 0.0, 0.4),
])
def test_rolling_shutter_rows_against_an_independent_projection(
        preset: str, speed: float, yaw_rate: float, pitch_rate: float, readout: float) -> None:
    p = PRESETS[preset]
    camera = p.camera()
    mpt = p.metres_per_texel
    spacing, sigma, max_range, radius = ((64, 3.0, 3.0, 9) if preset == "cart"
                                         else (48, 1.5, 12.0, 8))
    texture, centres = _dot_texture(mpt, spacing, sigma)
    traj, at = _drive(preset, 3, speed, yaw_rate, pitch_rate)
    k, dt = 1, 1.0 / p.fps
    img = render_trajectory_frame(texture, camera, traj, k, Effects(rolling_shutter=readout))
    t_k = traj.t[k]
    pose0, xz0, h0 = at(t_k)
    pts, uv = _visible_dots(centres, mpt, camera, pose0, xz0, h0, max_range, sigma, radius)
    # each dot's row: v = projection at time t_k + v / rows · readout · dt
    shutter_uv = uv.copy()
    for _ in range(20):
        for i, (pt, (_, v)) in enumerate(zip(pts, shutter_uv, strict=True)):
            pose, xz, h = at(t_k + np.clip(v, 0, camera.height - 1) / camera.height
                             * readout * dt)
            rvec, tvec, _ = _camera_from_world(*pose, xz, h)
            shutter_uv[i] = cv2.projectPoints(pt[None], rvec, tvec, camera.k,
                                              np.zeros(5))[0].reshape(2)
    off = _offsets(img, shutter_uv, radius)
    assert len(off) >= 15, f"only {len(off)} clean dots checked"
    # the shutter moves the dots by 11–30 px (median; up to 87 px), so the check has teeth
    inside = ((shutter_uv[:, 0] > 0) & (shutter_uv[:, 0] < camera.width)
              & (shutter_uv[:, 1] > 0) & (shutter_uv[:, 1] < camera.height))
    moved = np.linalg.norm(shutter_uv - uv, axis=1)[inside]
    assert np.median(moved) > 5.0, np.median(moved)
    # measured worst 0.02–0.12 px (bands of rows share one time, ≤ 0.5 px of ground motion
    # between neighbours by design), medians ≤ 0.02 px
    assert np.abs(off).max() < 0.3, np.abs(off).max(axis=0)
    assert np.abs(np.median(off, axis=0)).max() < 0.06
