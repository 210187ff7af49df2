"""Image content fixed to the camera: the vehicle's hood, a dashcam's text overlay,
reflections on the windshield. POC whitens even a faint texture into a sharp peak, so such
content correlates perfectly at zero shift: where it covers much of the ground, a cold start
finds "no motion" and tracking locks onto it (a hood over the bottom 30 % of a dashcam's view:
every pair "ok" with zero travel).

``static_share`` marks the textured pixels that did not change between two frames while the
rest of the view moved, as a share per patch-sized neighbourhood; the estimator leaves out
the patches on them.

"Did not change" allows for sensor noise: two frames of a static hood differ by the noise
of both (mean |change| 1.13 σ), which a noise-free test (normal flow ≤ 0.1 px) took for
motion at σ = 1 grey level already, so the hood won every pair again ("no motion", or 99 %
short). The noise σ is measured on each frame's flattest parts (``noise_sigma``); a pixel
whose change noise explains counts as static only where the two frames also correlate at
zero shift (weak texture that moved by pixels changes by little more than the noise, but no
longer correlates with itself).
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
#: mean gradient (as measured for ``TEXTURE_MIN``) of white noise of unit σ: |Sobel| of it
#: has mean 0.798·√12, two of them over 8
NOISE_GRADIENT = 0.798 * 12 ** 0.5 / 4.0
#: a patch whose window is more than this share static is left out
PATCH_MAX_SHARE = 0.25
#: a static pixel's mean |change| may exceed what the noise alone gives (1.128 σ) by this
#: factor (the spread of a 5×5 mean of noise is about ±0.17 σ)
NOISE_MARGIN = 1.3
#: neighbourhood (pixels) of the two frames' zero-shift correlation
CORRELATION_WINDOW_PX = 9
#: least zero-shift correlation of a pixel whose change the noise explains, for it to count
#: as static (a static texture of variance s² under noise σ² correlates at s²/(s² + σ²))
MIN_CORRELATION = 0.3
#: Immerkær's noise mask ("Fast noise variance estimation", 1996), scaled to unit noise gain:
#: it cancels the image's linear structure and passes white noise of σ as σ
NOISE_MASK = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32) / 6.0
#: neighbourhood (pixels) of the local mean |mask response| behind the noise estimate
NOISE_WINDOW_PX = 7
#: percentile of those local means taken for the noise: the flattest parts of the view
NOISE_PERCENTILE = 5.0
#: that percentile for white noise of unit σ: E|N(0, 1)| = 0.798 times 0.7145, the 5th
#: percentile of 7×7 means of it relative to their mean (measured on 1280×720 noise)
NOISE_PERCENTILE_UNIT = 0.7979 * 0.7145


def noise_sigma(image: NDArray) -> float:
    """Standard deviation of a grey image's sensor noise, grey levels, from its flattest
    parts (``NOISE_PERCENTILE`` of the local mean response to ``NOISE_MASK``); texture
    raises it, so it is an upper bound where no part of the view is flat."""
    response = np.abs(cv2.filter2D(np.asarray(image, np.float32), cv2.CV_32F, NOISE_MASK))
    r = NOISE_WINDOW_PX // 2
    local = cv2.blur(response, (NOISE_WINDOW_PX, NOISE_WINDOW_PX))[r:-r, r:-r]
    if local.size == 0:
        return 0.0
    return float(np.percentile(local, NOISE_PERCENTILE)) / NOISE_PERCENTILE_UNIT


def static_pixels(prev: NDArray, curr: NDArray,
                  noise: tuple[float, float] | None = None) -> NDArray[np.bool_]:
    """Pixels (H, W) of two grey images of one size that are textured and did not move:
    mean |change| within the normal flow ``FLOW_MAX_PX`` plus what the frames' noise
    explains, and where noise explains some of it, a zero-shift correlation of at least
    ``MIN_CORRELATION``; none where the vehicle stands (``stands_still``). ``noise``: the two
    frames' ``noise_sigma`` where the caller has them already (a sequence's frame is the
    current one of a pair and the previous one of the next)."""
    static, clearly_textured = _static_and_textured(prev, curr, noise)
    if _still(static, clearly_textured):
        return np.zeros(static.shape, bool)
    return static


def stands_still(prev: NDArray, curr: NDArray,
                 noise: tuple[float, float] | None = None) -> bool:
    """Whether all content of two grey images stood still between them: ``STANDSTILL_SHARE``
    of the pixels textured clearly above the noise are static (a standing vehicle; a passing
    car or pedestrian is the rest). Unlike a pair's "no motion", which asks whether its
    patches moved, this asks every pixel: a level camera's sky or a far field that the
    patches of a wrong nominal pose sit on stands still while the ground below moves."""
    return _still(*_static_and_textured(prev, curr, noise))


def _still(static: NDArray[np.bool_], clearly_textured: NDArray[np.bool_]) -> bool:
    return bool((static & clearly_textured).sum()
                >= STANDSTILL_SHARE * max(int(clearly_textured.sum()), 1))


def _static_and_textured(
    prev: NDArray, curr: NDArray, noise: tuple[float, float] | None,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """The static pixels (module doc) and the pixels textured clearly above the noise (the
    mean gradient of white noise σ alone is ``NOISE_GRADIENT`` σ: flat parts of a noisy
    frame would count as texture that "moved", since noise does not correlate)."""
    p = np.asarray(prev, np.float32)
    c = np.asarray(curr, np.float32)
    size = (WINDOW_PX, WINDOW_PX)
    grad = cv2.blur(np.abs(cv2.Sobel(p, cv2.CV_32F, 1, 0, ksize=3))
                    + np.abs(cv2.Sobel(p, cv2.CV_32F, 0, 1, ksize=3)), size) / 8.0
    change = cv2.blur(np.abs(c - p), size)
    sigma_p, sigma_c = noise if noise is not None else (noise_sigma(p), noise_sigma(c))
    sigma = 0.5 * (sigma_p + sigma_c)
    textured = grad >= TEXTURE_MIN
    # the change of pure noise in both frames: |N(0, 2σ²)| has mean 2σ/√π = 1.128 σ
    static = textured & (change <= FLOW_MAX_PX * grad + NOISE_MARGIN * 1.128 * sigma)
    if sigma > 0:
        static &= _zero_shift_correlation(p, c, CORRELATION_WINDOW_PX) >= MIN_CORRELATION
    return static, grad >= TEXTURE_MIN + 2.0 * NOISE_GRADIENT * sigma


def _zero_shift_correlation(p: NDArray[np.float32], c: NDArray[np.float32],
                            window: int) -> NDArray[np.float32]:
    """Normalised cross-correlation (H, W) of two images at zero shift over the ``window``²
    neighbourhood of each pixel."""
    size = (window, window)
    mp, mc = cv2.blur(p, size), cv2.blur(c, size)
    var_p = cv2.blur(p * p, size) - mp * mp
    var_c = cv2.blur(c * c, size) - mc * mc
    cov = cv2.blur(p * c, size) - mp * mc
    return cov / np.sqrt(np.maximum(var_p * var_c, 1e-6))


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
