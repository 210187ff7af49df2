"""Rolling shutter: where a ground point lands in frame k when each row is exposed at its
own time (the residual model's part, ``bundle`` module doc), compiled per point."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .compiled import kernel

FloatArray = NDArray[np.float64]

#: Most secant steps per point, and the tolerance on the row time [frame intervals].
MAX_STEPS = 30
TOLERANCE = 1e-12


@kernel
def _row_time_excess(h: FloatArray, x: float, z: float, psi: FloatArray, change: FloatArray,
                     a: float, b: float, per_row: float) -> tuple[float, float, float, float]:
    """(v·per_row − b, u, v, w): frame k's homogeneous pixel (u, v, w) of ground point (x, z)
    of frame k-1 seen at time a, moved to time b, and how far b is from its row's time."""
    s = 1.0 + b - a
    c = 0.5 * (b * b - a * a + a + b)
    tx = s * psi[0] + c * change[0]
    tz = s * psi[1] + c * change[1]
    yaw = s * psi[2] + c * change[2]
    cy, sy = math.cos(yaw), math.sin(yaw)
    dx, dz = x - tx, z - tz
    mx, mz = cy * dx - sy * dz, sy * dx + cy * dz
    u = h[0, 0] * mx + h[0, 1] * mz + h[0, 2]
    v = h[1, 0] * mx + h[1, 1] * mz + h[1, 2]
    w = h[2, 0] * mx + h[2, 1] * mz + h[2, 2]
    return v / w * per_row - b, u, v, w


@kernel
def moved_pixels(image_from_ground: FloatArray, ground_x: FloatArray, ground_z: FloatArray,
                 motion: FloatArray, change: FloatArray, time_prev: FloatArray,
                 per_row: float, readout: float) -> FloatArray:
    """Homogeneous frame-k pixels (B, n, 3) of ground points (``ground_x``/``ground_z``,
    (B, n), metres in frame k-1's G) seen at times ``time_prev`` (n,) after frame k-1's
    row 0, each moved over the time to its own row's exposure in frame k.

    ``image_from_ground`` (B, 3, 3): frame k's ground → image homography per parameter
    vector; ``motion`` (B, 3): (tx, tz, yaw) over the frame interval; ``change`` (B, 3): its
    change from the interval before (constant acceleration; zeros: constant velocity);
    times in frame intervals; ``per_row``: frame intervals per row; ``readout``: first row to
    last. The row time b solves ``b = v(b)·per_row`` (secant steps from the global
    shutter's row); NaN where it has no solution within two readouts of ``time_prev`` (the
    point outruns the shutter out of the frame) or the point is undefined."""
    n_b, n_p = ground_x.shape
    out = np.full((n_b, n_p, 3), np.nan)
    for i in range(n_b):
        h = image_from_ground[i]
        for j in range(n_p):
            x, z, a = ground_x[i, j], ground_z[i, j], time_prev[j]
            if not (math.isfinite(x) and math.isfinite(z)):
                continue
            low, high = a - 2.0 * readout, a + 2.0 * readout
            b_old = a
            f_old, u, v, w = _row_time_excess(h, x, z, motion[i], change[i], a, b_old, per_row)
            if not math.isfinite(f_old):
                continue
            b = min(max(b_old + f_old, low), high)  # a fixed-point step, then secant steps
            f = f_old
            for _ in range(MAX_STEPS):
                f, u, v, w = _row_time_excess(h, x, z, motion[i], change[i], a, b, per_row)
                if not math.isfinite(f) or f == f_old:
                    break
                step = -f * (b - b_old) / (f - f_old)
                b_old, f_old = b, f
                b = min(max(b + step, low), high)
                if abs(b - b_old) < TOLERANCE:
                    f, u, v, w = _row_time_excess(h, x, z, motion[i], change[i], a, b, per_row)
                    break
            if math.isfinite(f) and abs(f) < 1e-9:
                out[i, j, 0], out[i, j, 1], out[i, j, 2] = u, v, w
    return out
