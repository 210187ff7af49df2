"""Render the camera image of a flat textured ground, with optional photometric effects.

For every output pixel the ground point it sees (``geometry.ground_from_image_homography``
with the frame's pose against the ground) is taken to the world through the frame's world
pose and sampled from a :class:`~vipm_track.texture.GroundTexture`. The whole chain
pixel → G → world → texel is one homography, so OpenCV's ``warpPerspective`` evaluates it
(vectorised, multithreaded). Anti-aliasing: 2× supersampling then ``INTER_AREA``, and a
trilinear mip level chosen per pixel from the homography's local footprint (the far field
of a forward-looking camera shrinks the ground by orders of magnitude).

World pose of G: the ground frame G of a frame sits at ``world_xz`` = (x, z) metres on the
world ground plane W (a frame with the conventions of G) with heading ``world_heading``
radians (> 0 turned right). That is the planar motion W → G, so geometry's
``motion_matrix``/``compose_motion`` relate world poses, and the motion k-1 → k is
``compose_motion(invert_motion(W→G_{k-1}), W→G_k)``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel
from .geometry import (
    GroundPose,
    PlanarMotion,
    apply_homography,
    ground_from_image_homography,
    motion_matrix,
    rotation_ground_from_camera,
)
from .texture import TEXTURES, GroundTexture


@dataclass(frozen=True)
class Effects:
    """Photometric realism switches (all off by default).

    Attributes
    ----------
    noise_sigma : float
        Standard deviation of additive Gaussian sensor noise, grey levels.
    exposure_drift : float
        Relative amplitude of a slow gain drift (e.g. 0.15 = ±15 %), a sum of two
        sinusoids of the frame time with periods 9 s and 3.7 s.
    vignetting : float
        Strength in [0, 1] of cos⁴ falloff (1 = full natural vignetting of the lens).
    highlights : int
        Number of specular blobs fixed in the IMAGE (ceiling lights reflected on a
        polished floor); they do not move with the ground.
    motion_blur : float
        Exposure time as a fraction of the frame interval: the frame is the average of the
        ground rendered at sub-frame poses across an exposure centred on the frame's time
        (needs ``exposure``), so each pixel is blurred along its own image motion.
    rolling_shutter : float
        Readout time (first row's exposure to the last's) as a fraction of the frame
        interval: row v is exposed ``v / rows · rolling_shutter`` intervals after the frame's
        time (row 0), rendered in bands of rows (needs ``exposure``); 0: global shutter.
    obstacle : bool
        A non-ground region (a textured wall/obstacle) fixed in the image's lower right.
    sky_level : float
        Grey level of the sky at the top of the image (a vertical gradient to the horizon).
    seed : int
        Seed of the fixed layout (highlight positions); per-frame noise uses (seed, frame).
    """

    noise_sigma: float = 0.0
    exposure_drift: float = 0.0
    vignetting: float = 0.0
    highlights: int = 0
    motion_blur: float = 0.0
    rolling_shutter: float = 0.0
    obstacle: bool = False
    sky_level: float = 215.0
    seed: int = 0


#: A sub-frame pose for motion blur: pose against the ground, world (x, z) [m], heading [rad].
ExposurePose = tuple[GroundPose, tuple[float, float] | NDArray, float]
#: Image rows [r0, r1) and the sub-frame poses they are exposed over (averaged).
ExposureBand = tuple[int, int, Sequence[ExposurePose]]

#: Obstacle quadrilateral in normalised image coordinates (x/width, y/height).
OBSTACLE_POLYGON = np.array([[0.66, 0.42], [0.94, 0.36], [0.97, 1.0], [0.63, 1.0]])


def render_frame(
    texture: GroundTexture,
    camera: CameraModel,
    pose: GroundPose,
    world_xz: tuple[float, float] | NDArray,
    world_heading: float,
    effects: Effects | None = None,
    *,
    t: float = 0.0,
    frame_index: int = 0,
    exposure: Sequence[ExposureBand] | None = None,
    supersample: int = 2,
    overlay: Callable[[NDArray[np.float32]], NDArray[np.float32]] | None = None,
) -> NDArray[np.uint8]:
    """Grey uint8 image (camera.height × camera.width) of the textured ground.

    Parameters
    ----------
    texture : GroundTexture
        The ground's texture in world coordinates.
    camera : CameraModel
        Intrinsics; the image is rendered as an ideal pinhole image with ``camera.k``
        (distortion, if any, is applied on top, so ``camera.undistort_image`` recovers it).
    pose : GroundPose
        Camera pose against the ground (radians, metres).
    world_xz, world_heading : (x, z) metres and radians
        World pose of this frame's ground frame G (see module doc).
    effects : Effects, optional
        Photometric effects; ``None`` renders the clean image.
    t, frame_index : float, int
        Frame time [s] (exposure drift) and index (noise seed).
    exposure : sequence of (r0, r1, [(GroundPose, world_xz, world_heading), ...]), optional
        Bands of rows covering the image and the sub-frame poses each is exposed over
        (``sim.exposure_bands``), for motion blur and rolling shutter; used where either
        effect is on, else the whole image shows ``pose``.
    supersample : int
        Supersampling factor per axis (≥ 1).
    overlay : callable, optional
        Draws scene content over the ground (e.g. ``traffic.draw_traffic``): takes and
        returns the ideal pinhole grey image (float32), before the photometric effects.
    """
    fx = effects or Effects()
    bands = list(exposure) if (fx.motion_blur > 0 or fx.rolling_shutter > 0) and exposure \
        else [(0, camera.height, [(pose, world_xz, world_heading)])]
    img = np.zeros((camera.height, camera.width), np.float32)
    for r0, r1, poses in bands:
        rows = _rows_camera(camera, r0, r1)
        for sub_pose, sub_xz, sub_heading in poses:
            h_img = _pixel_to_texel_homography(texture, rows, sub_pose, sub_xz, sub_heading)
            img[r0:r1] += _render_ground(texture, rows, h_img, sub_pose, supersample,
                                         fx.sky_level, (r0, camera.height))
        img[r0:r1] /= len(poses)
    if overlay is not None:
        img = overlay(img)
    if fx.obstacle:
        img = _draw_obstacle(img, fx.seed)
    if fx.highlights > 0:
        img = img + _highlight_layer(camera.width, camera.height, fx.highlights, fx.seed)
    gain = np.float32(1.0)
    if fx.exposure_drift:
        gain *= np.float32(1.0 + fx.exposure_drift * (0.7 * np.sin(2 * np.pi * t / 9.0)
                                                      + 0.3 * np.sin(2 * np.pi * t / 3.7 + 1.0)))
    if fx.vignetting > 0:
        img = img * _vignetting(camera, fx.vignetting)
    img = img * gain
    if fx.noise_sigma > 0:
        rng = np.random.default_rng([fx.seed, frame_index, 7919])
        img = img + rng.normal(0.0, fx.noise_sigma, img.shape).astype(np.float32)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if camera.has_distortion:
        out = _distort(out, camera)
    return out


def world_pose_motion(
    world_xz: tuple[float, float] | NDArray, world_heading: float
) -> PlanarMotion:
    """The world pose of G as the planar motion W → G (see module doc)."""
    return PlanarMotion(float(world_xz[0]), float(world_xz[1]), float(world_heading))


def _pixel_to_texel_homography(
    texture: GroundTexture, camera: CameraModel, pose: GroundPose, world_xz, world_heading: float
) -> NDArray:
    """3×3 homography from image pixels to level-0 texels, shifted by whole periods so the
    image's ground lies near the canvas (keeps OpenCV's fixed-point coordinates in range)."""
    ground_from_pixel = ground_from_image_homography(camera.k, pose)
    world_from_ground = np.linalg.inv(motion_matrix(world_pose_motion(world_xz, world_heading)))
    s = texture.metres_per_texel
    texel_from_world = np.array([[1 / s, 0.0, 0.0], [0.0, -1 / s, 0.0], [0.0, 0.0, 1.0]])
    h = texel_from_world @ world_from_ground @ ground_from_pixel
    # Reference: the bottom-centre pixel (ground for any pose that sees the ground at all).
    ref = apply_homography(h, np.array([camera.width / 2.0, camera.height - 1.0]))
    w, hh = texture.size
    if np.all(np.isfinite(ref)):
        shift = np.array([[1, 0, -np.floor(ref[0] / w) * w], [0, 1, -np.floor(ref[1] / hh) * hh],
                          [0, 0, 1.0]])
        h = shift @ h
    return h


def _ground_ray_normal(camera: CameraModel, pose: GroundPose) -> NDArray:
    """n with n·(u, v, 1) = the G-frame y component of pixel (u, v)'s ray (> 0: ground)."""
    r = rotation_ground_from_camera(pose.pitch, pose.roll)
    n = (r @ np.linalg.inv(camera.k))[1]
    return n / np.linalg.norm(n[:2])


def _rows_camera(camera: CameraModel, r0: int, r1: int) -> CameraModel:
    """The ideal pinhole camera whose image is rows [r0, r1) of ``camera``'s."""
    if (r0, r1) == (0, camera.height):
        return camera
    k = camera.k.copy()
    k[1, 2] -= r0
    return CameraModel(k, camera.width, r1 - r0)


def _render_ground(
    texture: GroundTexture, camera: CameraModel, h: NDArray, pose: GroundPose, ss: int,
    sky: float, rows: tuple[int, int] = (0, 0),
) -> NDArray[np.float32]:
    """The ground (and sky) in ``camera``'s image through the pixel → texel homography ``h``;
    ``rows``: (first row, rows of the whole image) where ``camera`` images a band of rows
    (for the sky's gradient)."""
    width, height = camera.width, camera.height
    ss = max(1, int(ss))
    # Supersampled pixel p_s → output pixel (p_s + 0.5)/ss - 0.5 (INTER_AREA's pixel centres).
    sub = _scale_about_centres(1.0 / ss)
    h_ss = h @ sub
    level = _mip_level(h_ss, width, height, ss, texture.n_levels)
    n = _ground_ray_normal(camera, pose)
    us = (np.arange(width * ss, dtype=np.float32) + 0.5) / ss - 0.5
    vs = (np.arange(height * ss, dtype=np.float32) + 0.5) / ss - 0.5
    # Ray elevation is linear in (u, v): the horizon is in view if a top corner sees sky.
    horizon_visible = min(n[0] * u + n[1] * vs[0] + n[2] for u in (us[0], us[-1])) <= 1e-9
    # Rows that see any ground (the ray elevation is linear along a row: test both ends,
    # one output row of margin for the supersamples); rows of pure sky are not warped.
    v_out = np.arange(height, dtype=np.float64)
    sees_ground = np.maximum(n[0] * 0 + n[1] * (v_out + 0.5) + n[2],
                             n[0] * (width - 1) + n[1] * (v_out + 0.5) + n[2]) > 0
    out = np.zeros((height, width), np.float32)
    for lev in range(texture.n_levels):
        weight = np.clip(1.0 - np.abs(level - lev), 0.0, 1.0)
        used = np.flatnonzero((weight.max(axis=1) > 0) & sees_ground)
        if used.size == 0:
            continue
        r0, r1 = int(used[0]), int(used[-1]) + 1
        band_shift = np.array([[1, 0, 0], [0, 1, r0 * ss], [0, 0, 1.0]])
        hl = _scale_about_centres(2.0**-lev) @ h_ss @ band_shift
        band = cv2.warpPerspective(
            texture.levels[lev], hl, (width * ss, (r1 - r0) * ss),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_WRAP,
        ).astype(np.float32)
        if horizon_visible:
            band *= (n[0] * us[None, :] + n[1] * vs[r0 * ss:r1 * ss, None] + n[2]) > 1e-9
        if ss > 1:
            band = cv2.resize(band, (width, r1 - r0), interpolation=cv2.INTER_AREA)
        out[r0:r1] += weight[r0:r1] * band
    if horizon_visible:
        mask = ((n[0] * us[None, :] + n[1] * vs[:, None] + n[2]) > 1e-9).astype(np.float32)
        alpha = cv2.resize(mask, (width, height), interpolation=cv2.INTER_AREA) if ss > 1 else mask
        row0, total = rows if rows[1] else (0, height)
        sky_col = (sky - 35.0 * (row0 + np.arange(height, dtype=np.float32)) / total)[:, None]
        out += (1.0 - alpha) * sky_col
    return out


def _scale_about_centres(scale: float) -> NDArray:
    """Map pixel-centre coordinates of one grid to a grid ``scale`` times as fine/coarse:
    c' = (c + 0.5)·scale − 0.5."""
    return np.array([[scale, 0, 0.5 * scale - 0.5], [0, scale, 0.5 * scale - 0.5], [0, 0, 1.0]])


def _mip_level(h_ss: NDArray, width: int, height: int, ss: int, n_levels: int) -> NDArray:
    """Per output pixel mip level log2(texels per supersample), from the homography's
    Jacobian on a coarse grid (the footprint varies smoothly), clipped to the pyramid."""
    step = 8
    gu = np.arange(0, width + step, step, dtype=float)
    gv = np.arange(0, height + step, step, dtype=float)
    u, v = np.meshgrid((gu + 0.5) * ss - 0.5, (gv + 0.5) * ss - 0.5)
    w = h_ss[2, 0] * u + h_ss[2, 1] * v + h_ss[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (h_ss[0, 0] * u + h_ss[0, 1] * v + h_ss[0, 2]) / w
        y = (h_ss[1, 0] * u + h_ss[1, 1] * v + h_ss[1, 2]) / w
        dxu, dyu = (h_ss[0, 0] - x * h_ss[2, 0]) / w, (h_ss[1, 0] - y * h_ss[2, 0]) / w
        dxv, dyv = (h_ss[0, 1] - x * h_ss[2, 1]) / w, (h_ss[1, 1] - y * h_ss[2, 1]) / w
        foot = np.maximum(np.hypot(dxu, dyu), np.hypot(dxv, dyv))
        level = np.log2(foot)
    level[~np.isfinite(level) | (w <= 0)] = n_levels - 1
    level = np.clip(level, 0.0, n_levels - 1).astype(np.float32)
    coarse = cv2.resize(level, (level.shape[1] * step, level.shape[0] * step),
                        interpolation=cv2.INTER_LINEAR)
    off = step // 2
    return coarse[off:off + height, off:off + width]


def _draw_obstacle(img: NDArray[np.float32], seed: int) -> NDArray[np.float32]:
    """Fill the obstacle polygon with a fixed brick texture (a wall that does not move like
    the ground), with an anti-aliased edge."""
    alpha, wall = _obstacle_layer(img.shape[1], img.shape[0], seed)
    return (1 - alpha) * img + alpha * wall


@functools.lru_cache(maxsize=4)
def _obstacle_layer(width: int, height: int, seed: int) -> tuple[NDArray, NDArray]:
    ss = 4
    poly = np.round(OBSTACLE_POLYGON * [width * ss, height * ss]).astype(np.int32)
    mask = np.zeros((height * ss, width * ss), np.uint8)
    cv2.fillPoly(mask, [poly], 255)
    alpha = cv2.resize(mask, (width, height), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    wall = GroundTexture.from_photo(TEXTURES["brick"].photo, 1.0, tiles=4, seed=seed,
                                    recipe=TEXTURES["brick"]).levels[1]
    reps = (int(np.ceil(height / wall.shape[0])), int(np.ceil(width / wall.shape[1])))
    wall = np.tile(wall, reps)[:height, :width].astype(np.float32) * 0.8 + 20
    return alpha, wall


@functools.lru_cache(maxsize=4)
def _highlight_layer(width: int, height: int, n: int, seed: int) -> NDArray[np.float32]:
    """Additive specular blobs (grey levels) at seeded positions in the lower image half."""
    rng = np.random.default_rng([seed, 104729])
    u = np.arange(width, dtype=np.float32)
    v = np.arange(height, dtype=np.float32)
    layer = np.zeros((height, width), np.float32)
    for _ in range(n):
        cx, cy = rng.uniform(0.1, 0.9) * width, rng.uniform(0.5, 0.95) * height
        sx, sy = rng.uniform(0.02, 0.05) * width, rng.uniform(0.01, 0.03) * height
        # Separable Gaussian: an outer product of two 1-D profiles.
        layer += 140.0 * np.outer(np.exp(-0.5 * ((v - cy) / sy) ** 2),
                                  np.exp(-0.5 * ((u - cx) / sx) ** 2))
    return layer


def _vignetting(camera: CameraModel, strength: float) -> NDArray[np.float32]:
    return _vignetting_map(camera.width, camera.height, camera.fx, camera.fy, camera.cx,
                           camera.cy, strength)


@functools.lru_cache(maxsize=4)
def _vignetting_map(width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                    strength: float) -> NDArray[np.float32]:
    u = (np.arange(width, dtype=np.float32) - cx) / fx
    v = (np.arange(height, dtype=np.float32) - cy) / fy
    cos4 = 1.0 / (1.0 + v[:, None] ** 2 + u[None, :] ** 2) ** 2
    return (1.0 - strength * (1.0 - cos4)).astype(np.float32)


def _distort(img: NDArray[np.uint8], camera: CameraModel) -> NDArray[np.uint8]:
    """Distorted image from the ideal pinhole one: each distorted pixel samples the ideal
    image where its undistorted position lies."""
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    ideal = camera.undistort_points(np.stack([u, v], axis=-1)).astype(np.float32)
    return cv2.remap(img, ideal[..., 0], ideal[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
