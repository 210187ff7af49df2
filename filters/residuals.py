"""The smoother's two nonlinear equations, compiled: the planar process and the pair's motion.

One implementation of each residual and its Jacobian in model coordinates (x right, y
forward, ψ > 0 right; ``filters.model``), called by the gtsam factors (``filters.factors``,
through ``process_factor_eval`` / ``motion_factor_eval``, which also apply the Pose2
tangent and, for the motion given the angles, the pose block's weight and the whitening).
The Python factor callbacks run for every frame and relinearisation, so each is one
compiled call. The robust weight and the 3×3 whitener they use are here too.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from vipm_track.compiled import kernel

FloatArray = NDArray[np.float64]


@kernel
def robust_weight(norm: float, code: int, k: float) -> float:
    """IRLS weight of gtsam's M-estimator (``factors.LOSS_CODE``) of threshold ``k`` at a whitened
    block norm (what ``noiseModel.Robust`` multiplies the squared rows by)."""
    if code == 1:
        return 1.0 if norm <= k else k / max(norm, 1e-300)
    if code == 2:
        return k * k / (k * k + norm * norm)
    if code == 3:
        return k**4 / (k * k + norm * norm) ** 2
    if code == 4:
        return (1.0 - (norm / k) ** 2) ** 2 if norm <= k else 0.0
    return 1.0


@kernel
def lower_inverse_cholesky(cov: FloatArray, out: FloatArray) -> None:
    """out = L⁻¹ for a 3×3 ``cov`` = L·Lᵀ: ``whitener`` of a 3×3 covariance, compiled (the
    motion blocks' whitener in the compiled rows and the motion factor)."""
    l00 = math.sqrt(cov[0, 0])
    l10 = cov[1, 0] / l00
    l20 = cov[2, 0] / l00
    l11 = math.sqrt(cov[1, 1] - l10 * l10)
    l21 = (cov[2, 1] - l20 * l10) / l11
    l22 = math.sqrt(cov[2, 2] - l20 * l20 - l21 * l21)
    out[0, 0], out[0, 1], out[0, 2] = 1.0 / l00, 0.0, 0.0
    out[1, 0], out[1, 1], out[1, 2] = -l10 / (l00 * l11), 1.0 / l11, 0.0
    out[2, 1] = -l21 / (l11 * l22)
    out[2, 0] = -(l20 * out[0, 0] + l21 * out[1, 0]) / l22
    out[2, 2] = 1.0 / l22


@kernel
def wrap(a: float) -> float:
    """Angle (rad) wrapped to [-π, π)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@kernel
def process_residual(x0, y0, psi0, v0, w0, x1, y1, psi1, v1, w1, dt, e, dyn):  # pragma: no cover
    """Constant-velocity process from frame k-1 to k over ``dt`` s (``model.propagate_pose``)
    into ``e`` (5,): the position residual along / across the mid-point heading (m), the
    heading's (rad), Δv (m/s), Δω (rad/s); into ``dyn`` (2, 6): ∂(along, cross)/∂(x0, y0, ψ0,
    ω0, x1, y1). The rest of the Jacobian is constant: ``process_constant_jacobian``."""
    a = psi0 + 0.5 * w0 * dt
    sa, ca = math.sin(a), math.cos(a)
    dx = x1 - (x0 + v0 * dt * sa)
    dy = y1 - (y0 + v0 * dt * ca)
    along, cross = sa * dx + ca * dy, ca * dx - sa * dy
    d_psi = -along - v0 * dt  # ∂cross/∂(mid-point heading); ∂along/∂ it is cross
    e[0], e[1], e[2] = along, cross, wrap(psi1 - psi0 - w0 * dt)
    e[3], e[4] = v1 - v0, w1 - w0
    hdt = 0.5 * dt
    dyn[0, 0], dyn[0, 1], dyn[0, 2], dyn[0, 3], dyn[0, 4], dyn[0, 5] = (
        -sa, -ca, cross, hdt * cross, sa, ca)
    dyn[1, 0], dyn[1, 1], dyn[1, 2], dyn[1, 3], dyn[1, 4], dyn[1, 5] = (
        -ca, sa, d_psi, hdt * d_psi, ca, -sa)


@kernel
def process_constant_jacobian(dt, out):  # pragma: no cover
    """The part of ``process_residual``'s Jacobian that does not depend on the state, into
    ``out`` (5, 10) over (x0, y0, ψ0, v0, ω0, x1, y1, ψ1, v1, ω1): ∂along/∂v0 = −dt; heading:
    −1 (ψ0), −dt (ω0), +1 (ψ1); Δv, Δω: ∓1. ``dyn`` adds to along / cross."""
    out[:, :] = 0.0
    out[0, 3] = -dt
    out[2, 2], out[2, 4], out[2, 7] = -1.0, -dt, 1.0
    out[3, 3], out[3, 8], out[4, 4], out[4, 9] = -1.0, 1.0, -1.0, 1.0


@kernel
def motion_residual(x0, y0, psi0, x1, y1, psi1, h, yaw_m, h0, z, metric, e, j):  # pragma: no cover
    """The pair's motion (``model.pair_measurement`` rows 4–6): the displacement in
    G_{k-1} (heading ψ0 + yaw_m) scaled by h0 / h, minus z[4:7] (tx, tz at h0, m; yaw, rad),
    into ``e`` (3,); ∂/∂(x0, y0, ψ0, x1, y1, ψ1, h, yaw_m) into ``j`` (3, 8). Without
    ``metric`` (no wheel speed nearby) the height column is 0, as in the EKF: scale is then
    unobservable and the pair must not move h."""
    g = psi0 + yaw_m
    sc = h0 / h
    scg, ssg = sc * math.cos(g), sc * math.sin(g)
    dx, dy = x1 - x0, y1 - y0
    tx, tz = scg * dx - ssg * dy, ssg * dx + scg * dy
    e[0], e[1], e[2] = tx - z[4], tz - z[5], wrap(psi1 - psi0 - z[6])
    dh = 1.0 / h if metric else 0.0
    j[0, 0], j[0, 1], j[0, 2], j[0, 3], j[0, 4], j[0, 5] = -scg, ssg, -tz, scg, -ssg, 0.0
    j[1, 0], j[1, 1], j[1, 2], j[1, 3], j[1, 4], j[1, 5] = -ssg, -scg, tx, ssg, scg, 0.0
    j[2, 0], j[2, 1], j[2, 2], j[2, 3], j[2, 4], j[2, 5] = 0.0, 0.0, -1.0, 0.0, 0.0, 1.0
    j[0, 6], j[1, 6], j[2, 6] = -tx * dh, -tz * dh, 0.0
    j[0, 7], j[1, 7], j[2, 7] = -tz, tx, 0.0


@kernel
def _to_tangent(jm, col, psi, out, out_col):  # pragma: no cover
    """out[:, out_col:out_col+3] = jm[:, col:col+3] · ∂(x, y, ψ)/∂(Pose2 tangent) at ψ
    (``factors.tangent_jacobian``)."""
    s, c = math.sin(psi), math.cos(psi)
    for i in range(jm.shape[0]):
        jx, jy = jm[i, col], jm[i, col + 1]
        out[i, out_col] = jx * s + jy * c
        out[i, out_col + 1] = jx * c - jy * s
        out[i, out_col + 2] = jm[i, col + 2]


@kernel
def process_factor_eval(s, dt, out):  # pragma: no cover
    """``factors.process_factor`` at s = (x0, y0, ψ0, v0, ω0, x1, y1, ψ1, v1, ω1): out (5, 11)
    = [residual | ∂/∂ X_{k-1} (Pose2 tangent) | V_{k-1} | W_{k-1} | X_k | V_k | W_k]."""
    e = np.empty(5)
    dyn = np.empty((2, 6))
    process_residual(s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8], s[9], dt, e, dyn)
    jm = np.empty((5, 10))  # model coordinates, columns as s
    process_constant_jacobian(dt, jm)
    for i in range(2):
        for j, col in enumerate((0, 1, 2, 4, 5, 6)):
            jm[i, col] += dyn[i, j]
    out[:, 0] = e
    _to_tangent(jm, 0, s[2], out, 1)
    out[:, 4], out[:, 5] = jm[:, 3], jm[:, 4]
    _to_tangent(jm, 5, s[7], out, 6)
    out[:, 9], out[:, 10] = jm[:, 8], jm[:, 9]


@kernel
def whiten_motion_given_pose(  # pragma: no cover (compiled)
    e, jm, a_res, a_jac, w, cov3, reduction, r_out, j_out
):
    """The motion rows given the angles as far as the pose block is trusted
    (``factors.GivenPose``): r_out (3,) = L⁻¹·(e − w·a_res), j_out (3, n) = L⁻¹·(jm − w·a_jac),
    L·Lᵀ = cov3 − w·reduction. ``e``, ``jm``: the motion's residual and Jacobian; ``a_res``,
    ``a_jac``: A times the pose residual and its Jacobian (same columns); w: the pose block's
    robust weight (its 1/w inflation of the angles' covariance scales A and what A explains by
    w; reduction 0: the motion's own rows, whitened). ``j_out`` may be ``jm``."""
    cov = np.empty((3, 3))
    for i in range(3):
        for c in range(3):
            cov[i, c] = cov3[i, c] - w * reduction[i, c]
    wm = np.empty((3, 3))
    lower_inverse_cholesky(cov, wm)
    for i in range(2, -1, -1):  # wm is lower triangular: rows j > i are written first
        acc = 0.0
        for j in range(i + 1):
            acc += wm[i, j] * (e[j] - w * a_res[j])
        r_out[i] = acc
        for c in range(jm.shape[1]):
            acc = 0.0
            for j in range(i + 1):
                acc += wm[i, j] * (jm[j, c] - w * a_jac[j, c])
            j_out[i, c] = acc


@kernel
def motion_factor_eval(s, h0, z, metric, cov3, given, gain, reduction, given_jac, j_pose,
                       pose_whitener, pose_loss, pose_k, out):  # pragma: no cover
    """``factors.motion_pair_factor`` at s = (x0, y0, ψ0, x1, y1, ψ1, h, yaw_m, then the pose
    block's variables: pitch_m, roll_m, b_{k-1} (2), b_k (2)): out (3, 15) = [residual |
    X_{k-1} (tangent) | X_k | H | Y | M | B_{k-1} | B_k].

    Without ``given`` the residual is the motion's (gtsam whitens it with ``cov3``); with
    it, the motion given the angles (``whiten_motion_given_pose``; ``gain`` A, ``given_jac``
    A·∂(angles) in out's columns 1–14, the pose block's robust weight from ``pose_loss`` /
    ``pose_k`` at its norm whitened by ``pose_whitener``)."""
    e = np.empty(3)
    jm = np.empty((3, 8))
    motion_residual(s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], h0, z, metric, e, jm)
    out[:, :] = 0.0
    out[:, 0] = e
    _to_tangent(jm, 0, s[2], out, 1)
    _to_tangent(jm, 3, s[5], out, 4)
    for i in range(3):
        out[i, 7], out[i, 8] = jm[i, 6], jm[i, 7]
    if not given:
        return
    pose_res = np.empty(4)
    for i in range(4):
        acc = -z[i]
        for c in range(6):
            acc += j_pose[i, c] * s[8 + c]
        pose_res[i] = acc
    sq = 0.0
    for i in range(4):
        acc = 0.0
        for c in range(4):
            acc += pose_whitener[i, c] * pose_res[c]
        sq += acc * acc
    w = robust_weight(math.sqrt(sq), pose_loss, pose_k)
    a_res = np.empty(3)
    for i in range(3):
        acc = 0.0
        for c in range(4):
            acc += gain[i, c] * pose_res[c]
        a_res[i] = acc
    whiten_motion_given_pose(e, out[:, 1:], a_res, given_jac, w, cov3, reduction, out[:, 0],
                             out[:, 1:])
