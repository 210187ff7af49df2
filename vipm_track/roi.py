"""Ground region of interest and the grid of interest points with their patch sizes.

The region is given as a rectangle ``(x0, y0, x1, y1)`` in pixels, a polygon ``(N, 2)`` in
pixels, a boolean mask image ``(H, W)`` or the path of a mask image (non-zero = ground), or
chosen automatically from the nominal pose: image pixels whose ground point lies below the
horizon (with a margin), within a range and a lateral distance of the camera. That rule
takes the whole image for steep cameras and the near road for forward-looking ones.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel
from .errors import InputError
from .geometry import GroundPose, back_project, below_horizon, horizon_row

RoiSpec = tuple[float, float, float, float] | NDArray | str | Path | None

#: Patch sizes are rounded down to multiples of this (pixels), so that patches batch by size.
SIZE_STEP = 16


def roi_mask(
    camera: CameraModel,
    spec: RoiSpec,
    pose: GroundPose,
    max_range: float,
    max_lateral: float,
    horizon_margin: float,
) -> NDArray[np.bool_]:
    """Boolean (H, W) mask of the ground region of interest.

    Parameters
    ----------
    camera : the (undistorted) camera model; the mask has its size.
    spec : user region (see module doc) or None for the automatic one.
    pose : nominal pose used by the automatic region (radians, metres).
    max_range, max_lateral : automatic region limits on the ground point's forward distance
        Z and lateral offset |X|, metres in the frame's ground frame G.
    horizon_margin : automatic region keeps rays at least this far below the horizon, rad.
    """
    w, h = camera.width, camera.height
    if spec is None:
        uu, vv = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        pix = np.stack([uu, vv], axis=-1)
        ground = back_project(camera.k, pose, pix)
        with np.errstate(invalid="ignore"):
            mask = (
                below_horizon(camera.k, pose, pix, horizon_margin)
                & (ground[..., 1] <= max_range)
                & (np.abs(ground[..., 0]) <= max_lateral)
            )
        return mask
    if isinstance(spec, str | Path):
        img = cv2.imread(str(spec), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError(f"{spec}: ROI mask image not found or unreadable")
        if img.shape != (h, w):
            raise InputError(
                f"{spec}: ROI mask is {img.shape[1]}×{img.shape[0]} px but the camera is {w}×{h}"
            )
        return img > 0
    if isinstance(spec, tuple | list) and len(spec) == 4 and np.ndim(spec) == 1:
        x0, y0, x1, y1 = (float(v) for v in spec)
        if not (x1 > x0 and y1 > y0):
            raise InputError(f"ROI rectangle (x0, y0, x1, y1) = {spec} is empty")
        mask = np.zeros((h, w), bool)
        mask[max(0, int(np.ceil(y0))) : min(h, int(y1) + 1),
             max(0, int(np.ceil(x0))) : min(w, int(x1) + 1)] = True
        return mask
    arr = np.asarray(spec)
    if arr.ndim == 2 and arr.shape == (h, w) and arr.dtype != float:
        return arr.astype(bool)
    if arr.ndim == 2 and arr.shape[1] == 2 and arr.shape[0] >= 3:
        mask8 = np.zeros((h, w), np.uint8)
        cv2.fillPoly(mask8, [np.round(arr).astype(np.int32).reshape(-1, 1, 2)], 1)
        return mask8 > 0
    raise InputError(
        f"ROI must be (x0, y0, x1, y1), an (N, 2) polygon, an {h}×{w} mask or a mask image "
        f"path; got an array of shape {arr.shape}"
    )


def interest_points(
    camera: CameraModel,
    mask: NDArray[np.bool_],
    grid: tuple[int, int],
    patch: int,
    min_patch: int,
    pose: GroundPose,
    horizon_margin_px: float,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Grid of interest points over the mask and the patch size of each.

    Points form a ``grid = (nx, ny)`` lattice over the mask's bounding box, inset by half a
    patch where the box allows, and are kept where the mask is set. Each patch is ``patch``
    pixels, shrunk (in steps of :data:`SIZE_STEP`) so that it stays inside the image and at
    least ``horizon_margin_px`` below the horizon of ``pose``; points whose patch would be
    smaller than ``min_patch`` are dropped.

    Returns
    -------
    centres : (N, 2) float pixels (integers), sizes : (N,) int pixels.
    """
    nx, ny = grid
    ys, xs = np.nonzero(mask)
    if xs.size == 0:
        return np.zeros((0, 2)), np.zeros(0, np.int64)
    x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
    # Inset by half a patch where the box has room for two; a thin box (the road band of a
    # forward camera) is spread over, its patches shrinking at the image border instead.
    mx = patch / 2 if x1 - x0 >= 2 * patch else (x1 - x0) / (2 * nx)
    my = patch / 2 if y1 - y0 >= 2 * patch else (y1 - y0) / (2 * ny)
    gx = np.round(np.linspace(x0 + mx, x1 - mx, nx))
    gy = np.round(np.linspace(y0 + my, y1 - my, ny))
    uu, vv = np.meshgrid(gx, gy)
    centres = np.stack([uu.ravel(), vv.ravel()], axis=1)
    keep = mask[centres[:, 1].astype(int), centres[:, 0].astype(int)]
    centres = centres[keep]
    # Half-size limits: image borders and the horizon (a patch above it sees no ground).
    top = np.array([
        max(horizon_row(camera.k, pose, u - patch / 2), horizon_row(camera.k, pose, u + patch / 2))
        for u in centres[:, 0]
    ]) + horizon_margin_px if centres.size else np.zeros(0)
    half = np.minimum.reduce([
        np.full(len(centres), patch / 2),
        centres[:, 0],
        camera.width - 1 - centres[:, 0],
        centres[:, 1] - np.maximum(top, 0.0),
        camera.height - 1 - centres[:, 1],
    ]) if centres.size else np.zeros(0)
    sizes = (np.floor(2 * half / SIZE_STEP) * SIZE_STEP).astype(np.int64)
    sizes = np.minimum(sizes, patch)
    keep = sizes >= min_patch
    return centres[keep], sizes[keep]


def shrink_to_image(
    centres: NDArray[np.float64], sizes: NDArray[np.int64], width: int, height: int,
    min_patch: int,
) -> NDArray[np.int64]:
    """Patch sizes (N,) shrunk (steps of :data:`SIZE_STEP`) so that squares at ``centres``
    (N, 2) stay inside a ``width`` × ``height`` image; 0 where below ``min_patch``."""
    c = np.where(np.isfinite(centres), centres, -1e9)
    half = np.minimum.reduce([
        sizes / 2, c[:, 0], width - 1 - c[:, 0], c[:, 1], height - 1 - c[:, 1],
    ])
    out = np.minimum((np.floor(2 * np.maximum(half, 0) / SIZE_STEP) * SIZE_STEP).astype(np.int64),
                     sizes)
    return np.where(out >= min_patch, out, 0)
