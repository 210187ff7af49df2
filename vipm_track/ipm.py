"""Virtual IPM: bird's-eye images of a frame from a pose *estimate*, and patches on them.

The paper's refinement (section III-C) warps both frames onto ground planes set by the
current estimates Θ̂_p, Θ̂_c (not the true poses), crops square patches centred at the
interest points mapped onto the previous plane, and shrinks those that would leave the
part of the plane the camera sees.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from .compiled import kernel
from .geometry import (
    GroundPose,
    IpmGrid,
    PlanarMotion,
    apply_homography,
    back_project,
    homography_jacobian,
    image_from_ipm_homography,
    ipm_from_image_homography,
    motion_matrix,
    rotation_ground_from_camera,
    transform_ground,
)

FloatArray = NDArray[np.float64]
#: IPM patch sizes are multiples of this (pixels) so that patches batch by size.
SIZE_STEP = 32


def ground_sampling(k: FloatArray, pose: GroundPose, pixels: FloatArray) -> FloatArray:
    """Finest ground sampling distance (N,) at image pixels (N, 2): metres per pixel along
    the ground direction that one image pixel spans least (lateral, for oblique views); NaN
    where the pixel or its neighbours miss the ground (at the horizon)."""
    g0 = back_project(k, pose, pixels)
    gx = back_project(k, pose, pixels + np.array([1.0, 0.0])) - g0
    gy = back_project(k, pose, pixels + np.array([0.0, 1.0])) - g0
    jac = np.stack([gx, gy], axis=-1)  # (N, 2, 2): columns d(ground)/du, d(ground)/dv
    out = np.full(len(jac), np.nan)
    finite = np.all(np.isfinite(jac), axis=(1, 2))
    out[finite] = np.linalg.svd(jac[finite], compute_uv=False)[:, -1]
    return out


def choose_grid(
    k: FloatArray,
    pose_prev: GroundPose,
    motion: PlanarMotion,
    pixels_prev: FloatArray,
    patch: int,
    resolution_scale: float = 1.0,
    max_side: int = 3000,
) -> IpmGrid:
    """IPM grid shared by both frames of a pair.

    Resolution: the median finest ground sampling distance at the interest points times
    ``resolution_scale`` (metres per IPM pixel). Extent: the interest points' ground
    footprint in Ĝ_p and its predicted image in Ĝ_c, plus half a patch, coarsened if a side
    would exceed ``max_side`` pixels.
    """
    ground_p = back_project(k, pose_prev, pixels_prev)
    sampling = ground_sampling(k, pose_prev, pixels_prev)
    ok = np.all(np.isfinite(ground_p), axis=1) & np.isfinite(sampling)
    if not np.any(ok):
        raise ValueError("no interest point meets the ground under the estimated pose")
    ground_p = ground_p[ok]
    mpp = float(np.median(sampling[ok])) * resolution_scale
    ground_c = transform_ground(motion, ground_p)
    pts = np.concatenate([ground_p, ground_c])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    side = max(hi[0] - lo[0], hi[1] - lo[1]) / mpp + patch
    if side > max_side:
        mpp *= side / max_side
    pad = patch / 2 * mpp
    return IpmGrid.from_extent(lo[0] - pad, hi[0] + pad, lo[1] - pad, hi[1] + pad, mpp)


def warp(image: NDArray, k: FloatArray, pose: GroundPose, grid: IpmGrid,
         motion: PlanarMotion | None = None) -> NDArray[np.float32]:
    """Virtual IPM image (grid.height, grid.width) float32 of a grey image for ``pose``.

    With ``motion`` (frame k-1 → k), the image is frame k's and ``grid`` lies on frame
    k-1's ground: each pixel shows the ground point of G_{k-1} moved into G_k, so frame k's
    plane lines up with frame k-1's (no rotation left between them in a turn) wherever
    ``motion`` is right."""
    h = image_from_ipm_homography(k, pose, grid)
    if motion is not None:
        h = h @ moved_pixels_matrix(grid, motion)
    return cv2.warpPerspective(
        image, h, (grid.width, grid.height),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
    )


def moved_pixels_matrix(grid: IpmGrid, motion: PlanarMotion) -> FloatArray:
    """3×3 affine map of IPM pixels of a ground point in G_{k-1} to the IPM pixels of the same
    point in G_k (both on ``grid``)."""
    to_ground = grid.ground_from_pixel_matrix()
    return np.linalg.inv(to_ground) @ motion_matrix(motion) @ to_ground


def visible_polygon(
    k: FloatArray,
    pose: GroundPose,
    grid: IpmGrid,
    image_size: tuple[int, int],
    margin_px: float,
) -> FloatArray:
    """Convex polygon (M, 2), IPM pixels, of the ground the camera sees: the image rectangle
    inset by one pixel, cut ``margin_px`` below the horizon line, mapped onto the IPM grid."""
    w, h = image_size
    poly = np.array([[1.0, 1.0], [w - 2.0, 1.0], [w - 2.0, h - 2.0], [1.0, h - 2.0]])
    # Horizon line n · (u, v, 1) = 0; ground side n · m > 0 (ray's y component in G).
    n = (rotation_ground_from_camera(pose.pitch, pose.roll) @ np.linalg.inv(k))[1]
    delta = margin_px * float(np.hypot(n[0], n[1]))
    poly = _clip_half_plane(poly, n, delta)
    if len(poly) < 3:
        return np.zeros((0, 2))
    return apply_homography(ipm_from_image_homography(k, pose, grid), poly)


def _clip_half_plane(poly: FloatArray, n: FloatArray, delta: float) -> FloatArray:
    """Sutherland-Hodgman: the part of a convex polygon where n·(u, v, 1) ≥ delta."""
    f = poly @ n[:2] + n[2] - delta
    out = []
    for i in range(len(poly)):
        a, b, fa, fb = poly[i], poly[(i + 1) % len(poly)], f[i], f[(i + 1) % len(poly)]
        if fa >= 0:
            out.append(a)
        if (fa >= 0) != (fb >= 0):
            out.append(a + (b - a) * (fa / (fa - fb)))
    return np.array(out).reshape(-1, 2)


def _orientation(polygon: FloatArray) -> float:
    """+1 for a counter-clockwise polygon (M, 2) in (x, y), −1 for a clockwise one (0 if
    degenerate)."""
    if len(polygon) < 3:
        return 0.0
    edge = np.roll(polygon, -1, axis=0) - polygon
    nxt = np.roll(edge, -1, axis=0)
    return float(np.sign(np.sum(edge[:, 0] * nxt[:, 1] - edge[:, 1] * nxt[:, 0])))


@kernel
def _square_fits(polygon: FloatArray, orient: float, cx: float, cy: float, half: float) -> bool:
    """Whether the square of half-side ``half`` centred at (cx, cy) lies in the convex
    ``polygon`` (M, 2) of orientation ``orient`` (:func:`_orientation`)."""
    m = polygon.shape[0]
    if m < 3:
        return False
    for sx, sy in ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)):
        px, py = cx + sx * half, cy + sy * half
        for i in range(m):
            ax, ay = polygon[i, 0], polygon[i, 1]
            ex, ey = polygon[(i + 1) % m, 0] - ax, polygon[(i + 1) % m, 1] - ay
            if not ((ex * (py - ay) - ey * (px - ax)) * orient >= 0):
                return False
    return True


@kernel
def _largest_sizes(polygons: tuple[FloatArray, FloatArray, FloatArray],
                   orients: tuple[float, float, float], centres: FloatArray,
                   moved: FloatArray, candidates: NDArray[np.int64]) -> NDArray[np.int64]:
    """For each centre the first of ``candidates`` (sizes, largest first) whose square lies
    in the grid's box and the previous frame's polygon at ``centres`` and in the box and
    the current frame's polygon at ``moved``; 0 where none does."""
    box, prev, curr = polygons
    o_box, o_prev, o_curr = orients
    sizes = np.zeros(centres.shape[0], np.int64)
    for j in range(centres.shape[0]):
        for s in candidates:
            half = s / 2
            if (_square_fits(prev, o_prev, centres[j, 0], centres[j, 1], half)
                    and _square_fits(box, o_box, centres[j, 0], centres[j, 1], half)
                    and _square_fits(curr, o_curr, moved[j, 0], moved[j, 1], half)
                    and _square_fits(box, o_box, moved[j, 0], moved[j, 1], half)):
                sizes[j] = s
                break
    return sizes


def patch_sizes(
    grid: IpmGrid,
    polygon_prev: FloatArray,
    polygon_curr: FloatArray,
    centres: FloatArray,
    offsets: FloatArray,
    patch: int,
    min_patch: int,
    step: int = SIZE_STEP,
) -> NDArray[np.int64]:
    """Largest size (N,) ≤ ``patch`` (multiples of ``step``) whose square at ``centres``
    stays in the previous frame's visible polygon and, moved by ``offsets``, in the current
    one's, both inside the grid; 0 where even ``min_patch`` does not fit."""
    box = np.array([[0.0, 0.0], [grid.width - 1.0, 0.0], [grid.width - 1.0, grid.height - 1.0],
                    [0.0, grid.height - 1.0]])
    top = int(patch // step * step) if patch >= step else patch
    candidates = list(range(top, min_patch - 1, -step)) or [patch]
    polygons = tuple(np.ascontiguousarray(p, dtype=float).reshape(-1, 2)
                     for p in (box, polygon_prev, polygon_curr))
    centres = np.ascontiguousarray(centres, dtype=float)
    return _largest_sizes(polygons, tuple(_orientation(p) for p in polygons), centres,
                          np.ascontiguousarray(centres + offsets), np.array(candidates))


#: Exponent of the area-magnification term of :func:`patch_noise_whitening`. On rendered
#: cart pairs (``scripts/fit_patch_noise.py``) the far-field / near-field ratio of the
#: residuals at the true parameters is 8.6 unweighted, 2.5 with p = 1, 1.8 with 1.5 and 1.3
#: with 2; pose accuracy is the same for 1.5 and 2 (`bench_accuracy`-style check, 30 pairs).
NOISE_AREA_POWER = 1.5


def patch_noise_whitening(
    plane_from_image: FloatArray,
    targets: FloatArray,
    sizes: NDArray[np.int64],
    patch: int,
    area_power: float = NOISE_AREA_POWER,
) -> FloatArray:
    """Whitening matrices (N, 2, 2) of IPM patch displacements, relative to a typical patch.

    A patch's POC displacement is noisier where the virtual IPM magnifies the image (the far
    field: one image pixel spans several IPM pixels and fewer image pixels fill the patch)
    and where the patch was shrunk. The covariance, in IPM pixels², is modelled as

        Σ = (I + J Jᵀ · max(1, det J)^p) · (patch / size)²

    with J the 2×2 Jacobian of image → IPM at the patch's position in frame k (``targets``,
    IPM pixels) and p = ``area_power``. W = Σ^(-1/2), scaled so that the median
    patch keeps unit weight (thresholds stay in typical IPM pixels). Patches with size 0 or
    undefined positions get W = I (they are not used).
    """
    n = len(targets)
    out = np.tile(np.eye(2), (n, 1, 1))
    ok = (np.asarray(sizes) > 0) & np.all(np.isfinite(targets), axis=1)
    if not ok.any():
        return out
    image_pts = apply_homography(np.linalg.inv(plane_from_image), targets[ok])
    jac = homography_jacobian(plane_from_image, image_pts)
    area = np.maximum(1.0, np.abs(np.linalg.det(jac))) ** area_power
    cov = np.eye(2) + jac @ np.swapaxes(jac, 1, 2) * area[:, None, None]
    cov *= ((patch / np.asarray(sizes)[ok]) ** 2)[:, None, None]
    vals, vecs = np.linalg.eigh(cov)
    scale = np.sqrt(vals.mean(axis=1))
    w = vecs @ (vecs.transpose(0, 2, 1) / np.sqrt(vals)[:, :, None])
    good = np.all(np.isfinite(w), axis=(1, 2))
    idx = np.flatnonzero(ok)[good]
    out[idx] = w[good] * float(np.median(scale[good]))
    return out

