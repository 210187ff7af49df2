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
def _row_time_excess(k: FloatArray, pose: FloatArray, rate: FloatArray, x: float, z: float,
                     motion: FloatArray, change: FloatArray, a: float, b: float,
                     per_row: float) -> tuple[float, float, float, float]:
    """(v·per_row − b, u, v, w): frame k's homogeneous pixel (u, v, w) of ground point (x, z)
    of frame k-1 seen at time a, moved to time b (pose (pitch, roll, height) of frame k at
    row 0 plus ``rate`` per frame interval), and how far b is from its row's time. Scalar
    arithmetic (no arrays made per call)."""
    s = 1.0 + b - a
    c = 0.5 * (b * b - a * a + a + b)
    tx = s * motion[0] + c * change[0]
    tz = s * motion[1] + c * change[1]
    yaw = s * motion[2] + c * change[2]
    cy, sy = math.cos(yaw), math.sin(yaw)
    dx, dz = x - tx, z - tz
    gx, gy, gz = cy * dx - sy * dz, pose[2] + b * rate[2], sy * dx + cy * dz
    cp, sp = math.cos(pose[0] + b * rate[0]), math.sin(pose[0] + b * rate[0])
    cr, sr = math.cos(pose[1] + b * rate[1]), math.sin(pose[1] + b * rate[1])
    # camera = R_GCᵀ · ground, R_GC = Rx(−pitch)·Rz(roll) (geometry's convention)
    cx_ = cr * gx + cp * sr * gy - sp * sr * gz
    cy_ = -sr * gx + cp * cr * gy - sp * cr * gz
    cz_ = sp * gy + cp * gz
    u = k[0, 0] * cx_ + k[0, 1] * cy_ + k[0, 2] * cz_
    v = k[1, 0] * cx_ + k[1, 1] * cy_ + k[1, 2] * cz_
    w = k[2, 0] * cx_ + k[2, 1] * cy_ + k[2, 2] * cz_
    return v / w * per_row - b, u, v, w


@kernel
def moved_pixels(k: FloatArray, params: FloatArray, height: float, pixels_prev: FloatArray,
                 change: FloatArray, per_row: float, readout: float, start: FloatArray,
                 active: NDArray[np.bool_]) -> tuple[FloatArray, FloatArray]:
    """Homogeneous frame-k pixels (B, n, 3) of the ground seen at ``pixels_prev`` (n, 2) in
    frame k-1, each row exposed at its own time.

    ``params`` (B, 8): pitch and roll of frames k-1 and k (at their row 0), tx, tz, yaw over
    the frame interval and the height change dh [m] (frame k-1 at ``height``); the poses
    change at the pair's own rate within a frame (constant angular and vertical velocity),
    or (B, 12) with four more: frame k-1's and frame k's pitch and roll rate off the pair's,
    radians per frame interval (``bundle.shutter_rate_covariance``'s omitted parameters);
    the travel at a constant acceleration (``change`` (B, 3): the motion's change from the
    interval before; zeros: constant velocity). Times in frame intervals; ``per_row``:
    frame intervals per row; ``readout``: first row to last. The row time b of each point
    in frame k solves ``b = v(b)·per_row`` (secant steps from its row in frame k-1); NaN
    where it has no solution within two readouts of it (the point outruns the shutter out of
    the frame) or the point is above frame k-1's horizon.

    ``start`` (B, n): where each point's secant steps start (NaN: its row time in frame k-1);
    a solution for nearby parameters (a central difference's base) saves most of the steps.
    ``active`` (B, n): the points solved; the others stay NaN (a subset's unused points).
    Returns the pixels and the row times b (B, n) they were solved at (NaN where none)."""
    n_b, n_p = params.shape[0], pixels_prev.shape[0]
    n_rate = params.shape[1] - 8
    kinv = np.linalg.inv(k)
    out = np.full((n_b, n_p, 3), np.nan)
    times = np.full((n_b, n_p), np.nan)
    for i in range(n_b):
        p = params[i]
        rate = np.array([p[2] - p[0], p[3] - p[1], p[7]])
        rate_p, rate_c = rate.copy(), rate.copy()
        if n_rate > 0:  # each frame's angular rate off the pair's by an omitted parameter
            rate_p[0] += p[8]
            rate_p[1] += p[9]
            rate_c[0] += p[10]
            rate_c[1] += p[11]
        pose_c = np.array([p[2], p[3], height + p[7]])
        for j in range(n_p):
            if not active[i, j]:
                continue
            a = pixels_prev[j, 1] * per_row
            # frame k-1's ground point, back-projected with its pose at time a:
            # ray = R_GC · K⁻¹ · (u, v, 1), R_GC = Rx(−pitch)·Rz(roll)
            mu, mv = pixels_prev[j, 0], pixels_prev[j, 1]
            qx = kinv[0, 0] * mu + kinv[0, 1] * mv + kinv[0, 2]
            qy = kinv[1, 0] * mu + kinv[1, 1] * mv + kinv[1, 2]
            qz = kinv[2, 0] * mu + kinv[2, 1] * mv + kinv[2, 2]
            cp, sp = math.cos(p[0] + a * rate_p[0]), math.sin(p[0] + a * rate_p[0])
            cr, sr = math.cos(p[1] + a * rate_p[1]), math.sin(p[1] + a * rate_p[1])
            rx = cr * qx - sr * qy
            ry = cp * sr * qx + cp * cr * qy + sp * qz
            rz = -sp * sr * qx - sp * cr * qy + cp * qz
            if not ry > 0:
                continue
            h_a = height + a * rate[2]
            x, z = h_a * rx / ry, h_a * rz / ry
            low, high = a - 2.0 * readout, a + 2.0 * readout
            b_old = a if math.isnan(start[i, j]) else min(max(start[i, j], low), high)
            f_old, u, v, w = _row_time_excess(k, pose_c, rate_c, x, z, p[4:7], change[i], a,
                                              b_old, per_row)
            if not math.isfinite(f_old):
                continue
            b = min(max(b_old + f_old, low), high)  # a fixed-point step, then secant steps
            f, b_f = f_old, b_old  # b_f: the row time that (f, u, v, w) belong to
            for _ in range(MAX_STEPS):
                f, u, v, w = _row_time_excess(k, pose_c, rate_c, x, z, p[4:7], change[i], a, b,
                                              per_row)
                b_f = b
                if not math.isfinite(f) or f == f_old:
                    break
                step = -f * (b - b_old) / (f - f_old)
                b_old, f_old = b, f
                b = min(max(b + step, low), high)
                if abs(b - b_old) < TOLERANCE:
                    f, u, v, w = _row_time_excess(k, pose_c, rate_c, x, z, p[4:7], change[i], a,
                                                  b, per_row)
                    b_f = b
                    break
            if math.isfinite(f) and abs(f) < 1e-9:
                out[i, j, 0], out[i, j, 1], out[i, j, 2] = u, v, w
                times[i, j] = b_f
    return out, times
