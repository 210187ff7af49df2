"""Normal equations of the pair's reprojection residuals under a homography, and the pair
homographies themselves, compiled.

The geometric bundle adjustment (``bundle``) maps each patch centre m of frame k-1 through a
pair homography H(x) onto frame k's measurement plane; Levenberg–Marquardt needs, for every
parameter vector x of a batch (one per random subset), the weighted cost Σ w·|r|², JᵀWJ and
JᵀWr over the points. This kernel forms them point by point from H and its parameter
derivatives ∂H/∂x (the division by the third coordinate differentiated exactly), without the
(B, N, 2, n) Jacobian array or the per-point arrays the numpy path builds.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .compiled import kernel

FloatArray = NDArray[np.float64]


@kernel
def _projected(h: FloatArray, ground_w: FloatArray, image_w: FloatArray, u: float, v: float,
               ) -> tuple[bool, float, float, float]:
    """Whether pixel (u, v) is a valid point of homography ``h`` (3, 3) — on the ground of
    frame k-1 (``ground_w`` · m > 0), in front of camera k (``image_w`` · m > 0), not at
    infinity on the plane — its plane position (x, y) there, and the third coordinate of
    ``h`` · m."""
    gw = ground_w[0] * u + ground_w[1] * v + ground_w[2]
    iw = image_w[0] * u + image_w[1] * v + image_w[2]
    p2 = h[2, 0] * u + h[2, 1] * v + h[2, 2]
    if not (gw > 0.0 and iw > 0.0 and p2 != 0.0):
        return False, np.nan, np.nan, p2
    return (True, (h[0, 0] * u + h[0, 1] * v + h[0, 2]) / p2,
            (h[1, 0] * u + h[1, 1] * v + h[1, 2]) / p2, p2)


@kernel
def homography_normal_equations(
    h: FloatArray, dh: FloatArray, ground_w: FloatArray, image_w: FloatArray,
    pixels: FloatArray, targets: FloatArray, whitening: FloatArray, weights: FloatArray,
    invalid: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Cost (B,), JᵀWJ (B, n, n) and JᵀWr (B, n) of the residuals ``W_j·(π(H_b m_j) − t_j)``.

    Parameters
    ----------
    h : (B, 3, 3) plane-from-previous-image homography of each parameter vector.
    dh : (B, n, 3, 3) its derivative with respect to each of the n parameters.
    ground_w, image_w : (B, 3) rows whose product with a homogeneous pixel must be positive
        for the point to be valid (on the ground of frame k-1, in front of camera k).
    pixels, targets : (N, 2) previous-frame pixels and measured plane positions.
    whitening : (N, 2, 2) per-point matrices W, or an empty (0, 2, 2) array for none.
    weights : (B, N) point weights; a zero weight skips the point.
    invalid : residual of each component of an invalid point (its Jacobian is zero).
    """
    n_sets, n_par = dh.shape[0], dh.shape[1]
    whiten = whitening.shape[0] > 0
    cost = np.zeros(n_sets)
    a = np.zeros((n_sets, n_par, n_par))
    g = np.zeros((n_sets, n_par))
    jx = np.empty(n_par)
    jy = np.empty(n_par)
    for b in range(n_sets):
        for j in range(pixels.shape[0]):
            w = weights[b, j]
            if w == 0.0:
                continue
            u, v = pixels[j, 0], pixels[j, 1]
            valid, ox, oy, p2 = _projected(h[b], ground_w[b], image_w[b], u, v)
            if not valid:
                cost[b] += w * 2.0 * invalid * invalid
                continue
            ex, ey = ox - targets[j, 0], oy - targets[j, 1]
            for i in range(n_par):
                d0 = dh[b, i, 0, 0] * u + dh[b, i, 0, 1] * v + dh[b, i, 0, 2]
                d1 = dh[b, i, 1, 0] * u + dh[b, i, 1, 1] * v + dh[b, i, 1, 2]
                d2 = dh[b, i, 2, 0] * u + dh[b, i, 2, 1] * v + dh[b, i, 2, 2]
                jx[i] = (d0 - ox * d2) / p2
                jy[i] = (d1 - oy * d2) / p2
            if whiten:
                w00, w01 = whitening[j, 0, 0], whitening[j, 0, 1]
                w10, w11 = whitening[j, 1, 0], whitening[j, 1, 1]
                ex, ey = w00 * ex + w01 * ey, w10 * ex + w11 * ey
                for i in range(n_par):
                    jx[i], jy[i] = w00 * jx[i] + w01 * jy[i], w10 * jx[i] + w11 * jy[i]
            if not (math.isfinite(ex) and math.isfinite(ey)):
                cost[b] += w * 2.0 * invalid * invalid
                continue
            cost[b] += w * (ex * ex + ey * ey)
            for i in range(n_par):
                g[b, i] += w * (jx[i] * ex + jy[i] * ey)
                for k in range(i + 1):
                    a[b, i, k] += w * (jx[i] * jx[k] + jy[i] * jy[k])
        for i in range(n_par):
            for k in range(i):
                a[b, k, i] = a[b, i, k]
    return cost, a, g


@kernel
def pair_homography_factors(k: FloatArray, height: float, xs: FloatArray,
                            ) -> tuple[FloatArray, FloatArray]:
    """``ground_from_image(Θ_p)`` (B, 3, 3) and ``image_from_ground(Θ_c) · T(Ψ)`` (B, 3, 3)
    of parameter vectors ``xs`` (B, 7 or 8): R_GC = Rx(−pitch)·Rz(roll), ground (X, Z) lifted
    to (X, h, Z), frame k at ``height + xs[7]`` for 8-vectors (``displacement_model``)."""
    n_sets, n_par = xs.shape
    kinv = np.linalg.inv(k)
    g_from_i = np.empty((n_sets, 3, 3))
    out_from_g = np.empty((n_sets, 3, 3))
    r = np.empty((3, 3))
    m = np.empty((3, 3))
    for b in range(n_sets):
        _rotation(xs[b, 0], xs[b, 1], r)
        # lift⁻¹ · R_GC(Θ_p): rows x, z, y/h of R
        for j in range(3):
            m[0, j], m[1, j], m[2, j] = r[0, j], r[2, j], r[1, j] / height
        g_from_i[b] = m @ kinv
        _rotation(xs[b, 2], xs[b, 3], r)
        h_c = height + (xs[b, 7] if n_par > 7 else 0.0)
        cy, sy = math.cos(xs[b, 6]), math.sin(xs[b, 6])
        tx = -(cy * xs[b, 4] - sy * xs[b, 5])
        tz = -(sy * xs[b, 4] + cy * xs[b, 5])
        # R_GCᵀ(Θ_c) · lift · T(Ψ): lift · T = rows (cy, −sy, tx), (0, 0, h_c), (sy, cy, tz)
        for i in range(3):
            a0, a1, a2 = r[0, i], r[1, i] * h_c, r[2, i]
            m[i, 0] = a0 * cy + a2 * sy
            m[i, 1] = -a0 * sy + a2 * cy
            m[i, 2] = a0 * tx + a1 + a2 * tz
        out_from_g[b] = k @ m
    return g_from_i, out_from_g


@kernel
def _rotation(pitch: float, roll: float, out: FloatArray) -> None:
    """R_GC = Rx(−pitch) · Rz(roll) into ``out`` (3, 3), as
    ``geometry.rotation_ground_from_camera``."""
    c, s, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    out[0, 0], out[0, 1], out[0, 2] = cr, -sr, 0.0
    out[1, 0], out[1, 1], out[1, 2] = c * sr, c * cr, s
    out[2, 0], out[2, 1], out[2, 2] = -s * sr, -s * cr, c


@kernel
def project_points(h: FloatArray, ground_w: FloatArray, image_w: FloatArray,
                   pixels: FloatArray) -> FloatArray:
    """``π(H_b m_j)`` (B, N, 2) of previous-frame pixels ``pixels`` (N, 2) through each
    homography ``h`` (B, 3, 3); NaN where the point is invalid (``ground_w``, ``image_w`` as
    :func:`homography_normal_equations`) or maps to infinity on the plane."""
    n_sets, n_points = h.shape[0], pixels.shape[0]
    out = np.empty((n_sets, n_points, 2))
    for b in range(n_sets):
        for j in range(n_points):
            valid, ox, oy, _ = _projected(h[b], ground_w[b], image_w[b], pixels[j, 0],
                                          pixels[j, 1])
            out[b, j, 0], out[b, j, 1] = (ox, oy) if valid else (np.nan, np.nan)
    return out


#: central-difference step of the parameters, radians / metres (here and in
#: ``displacement_model``)
FD_STEP = 1e-6


@kernel
def _product(a: FloatArray, b: FloatArray) -> FloatArray:
    """The 3 × 3 product ``a · b``."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


@kernel
def pair_normal_equations(
    x: FloatArray, weights: FloatArray, k: FloatArray, height: float, plane: FloatArray,
    pixels: FloatArray, targets: FloatArray, whitening: FloatArray, full_index: NDArray,
    prior_mean: FloatArray, prior_scale: FloatArray, invalid: float,
) -> tuple[float, FloatArray, FloatArray]:
    """Cost, JᵀWJ (n, n) and JᵀWr (n,) of one parameter vector ``x`` (n,) over the points
    weighted by ``weights`` (N,), as ``DisplacementModel.normal_equations`` under a global
    shutter: the model's full parameters are ``x[full_index]``, ``plane`` maps frame k's
    image onto the measurement plane, the prior (``prior_scale`` (4,) or empty) adds
    ``prior_scale · (full[:4] − prior_mean)``; ∂H/∂x by central differences."""
    n = x.shape[0]
    xs = np.empty((1 + 2 * n, full_index.shape[0]))
    for r in range(1 + 2 * n):
        for c in range(full_index.shape[0]):
            i = full_index[c]
            xs[r, c] = x[i] + (FD_STEP if r == 1 + i else -FD_STEP if r == 1 + n + i else 0.0)
    g_from_i, out_from_g = pair_homography_factors(k, height, xs)
    h = np.empty((1 + 2 * n, 3, 3))
    image_w = np.empty((1, 3))
    for r in range(1 + 2 * n):
        image_from_prev = _product(out_from_g[r], g_from_i[r])
        h[r] = _product(plane, image_from_prev)
        if r == 0:
            image_w[0] = image_from_prev[2]
    dh = np.empty((1, n, 3, 3))
    for i in range(n):
        dh[0, i] = (h[1 + i] - h[1 + n + i]) / (2 * FD_STEP)
    cost, a, g = homography_normal_equations(h[:1], dh, g_from_i[:1, 2].copy(), image_w,
                                             pixels, targets, whitening,
                                             weights.reshape(1, -1), invalid)
    total, jtj, jtr = cost[0], a[0], g[0]
    for q in range(prior_scale.shape[0]):  # ∂p_q/∂x_i = prior_scale[q] where x_i is full[q]
        i = full_index[q]
        p = prior_scale[q] * (x[i] - prior_mean[q])
        total += p * p
        jtr[i] += prior_scale[q] * p
        jtj[i, i] += prior_scale[q] * prior_scale[q]
    return total, jtj, jtr


@kernel
def pair_lm(
    x0: FloatArray, weights: FloatArray, k: FloatArray, height: float, plane: FloatArray,
    pixels: FloatArray, targets: FloatArray, whitening: FloatArray, full_index: NDArray,
    prior_mean: FloatArray, prior_scale: FloatArray, invalid: float, max_iterations: int,
    tolerance: float, x_tolerance: float,
) -> tuple[FloatArray, NDArray[np.bool_], int]:
    """Levenberg–Marquardt from ``x0`` (S, n) for each row of point weights ``weights``
    (S, N), the model as :func:`pair_normal_equations`: Marquardt's diagonal damping
    (``bundle.lm_batch``, whose steps these are, subset by subset); a subset stops once its
    relative cost decrease falls below ``tolerance``, its step below 1e-12, or (with
    ``x_tolerance`` > 0, as MINPACK's ``xtol``) a rejected step below ``x_tolerance`` of
    ``|x|``: the central-difference gradient is not exactly zero at the minimum, so its last
    steps never lower the cost; else once its damping passes 1e9 or after
    ``max_iterations`` steps (neither converged).
    Returns the solutions (S, n), whether each converged, and the evaluations made."""
    n_sets, n = x0.shape
    x_out = x0.copy()
    converged = np.zeros(n_sets, np.bool_)
    evaluations = 0
    damped = np.empty((n, n))
    for s in range(n_sets):
        x = x0[s].copy()
        c, a, g = pair_normal_equations(x, weights[s], k, height, plane, pixels, targets,
                                        whitening, full_index, prior_mean, prior_scale,
                                        invalid)
        evaluations += 1
        lam = 1e-3
        for _ in range(max_iterations):
            largest = 0.0
            for i in range(n):
                largest = max(largest, a[i, i])
            damped[:] = a
            for i in range(n):
                damped[i, i] += lam * (a[i, i] + 1e-9 * largest + 1e-12)
            step = -np.linalg.solve(damped, g)
            x_new = x + step
            c_new, a_new, g_new = pair_normal_equations(
                x_new, weights[s], k, height, plane, pixels, targets, whitening, full_index,
                prior_mean, prior_scale, invalid)
            evaluations += 1
            better = c_new < c
            rel = (c - c_new) / max(c, 1e-300)
            if better:
                x, c, a, g = x_new, c_new, a_new, g_new
                lam = max(lam / 3.0, 1e-9)
            else:
                lam *= 4.0
            small = np.sqrt(np.sum(step**2)) <= x_tolerance * (np.sqrt(np.sum(x**2))
                                                               + x_tolerance)
            if ((better and rel < tolerance) or lam > 1e9 or np.max(np.abs(step)) < 1e-12
                    or (small and not better)):
                converged[s] = lam <= 1e9
                break
        x_out[s] = x
    return x_out, converged, evaluations
