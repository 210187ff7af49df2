"""Image content fixed to the camera: the vehicle's hood, a dashcam's text overlay,
reflections on the windshield. POC whitens even a faint texture into a sharp peak, so such
content correlates perfectly at zero shift: where it covers much of the ground, a cold start
finds "no motion" and tracking locks onto it (a hood over the bottom 30 % of a dashcam's view:
every pair "ok" with zero travel).

``static_share`` marks the textured pixels that did not change between two frames while the
rest of the view moved, as a share per patch-sized neighbourhood; the estimator leaves out
the patches on them.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

#: neighbourhood (pixels) over which texture and change are averaged
WINDOW_PX = 5
#: least mean gradient (grey levels per pixel) of a neighbourhood that can be called static
TEXTURE_MIN = 0.1
#: largest mean |change| / mean |gradient| (≈ the normal flow, pixels) of a static pixel
FLOW_MAX_PX = 0.1
#: share of the textured pixels beyond which all content stands still: the vehicle stands
#: (the pair's own checks then say "no motion"), and nothing is marked
STANDSTILL_SHARE = 0.9
#: a patch whose window is more than this share static is left out
PATCH_MAX_SHARE = 0.25


def static_pixels(prev: NDArray, curr: NDArray) -> NDArray[np.bool_]:
    """Pixels (H, W) of two grey images of one size that are textured and did not move
    (normal flow ≤ ``FLOW_MAX_PX``); none where they are ``STANDSTILL_SHARE`` of the
    textured pixels or more."""
    p = np.asarray(prev, np.float32)
    c = np.asarray(curr, np.float32)
    size = (WINDOW_PX, WINDOW_PX)
    grad = cv2.blur(np.abs(cv2.Sobel(p, cv2.CV_32F, 1, 0, ksize=3))
                    + np.abs(cv2.Sobel(p, cv2.CV_32F, 0, 1, ksize=3)), size) / 8.0
    change = cv2.blur(np.abs(c - p), size)
    textured = grad >= TEXTURE_MIN
    static = textured & (change <= FLOW_MAX_PX * grad)
    if static.sum() >= STANDSTILL_SHARE * max(int(textured.sum()), 1):
        return np.zeros(p.shape, bool)
    return static


def static_share(static: NDArray[np.bool_], window: int) -> NDArray[np.float32]:
    """Share (H, W, 0–1) of ``static`` pixels in the ``window``² neighbourhood of each."""
    return cv2.blur(static.astype(np.float32), (window, window))


def on_static(share: NDArray[np.float32], pixels: NDArray) -> NDArray[np.bool_]:
    """Which of the image ``pixels`` (N, 2; x, y, may be NaN or outside) sit on a
    neighbourhood more than ``PATCH_MAX_SHARE`` static."""
    h, w = share.shape
    pix = np.nan_to_num(np.asarray(pixels, dtype=float), nan=-1.0)
    x, y = np.round(pix[:, 0]).astype(int), np.round(pix[:, 1]).astype(int)
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    out = np.zeros(len(pix), bool)
    out[inside] = share[y[inside], x[inside]] > PATCH_MAX_SHARE
    return out
