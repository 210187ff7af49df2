"""gtsam factors of the smoother: the equations of ``filters.model`` as factor-graph terms.

Variables of frame k (``symbols(k)``; radians, metres, seconds):

    X_k  Pose2   vehicle pose in the world of ``filters.model``: Pose2(x=forward y_w,
                 y=right x_w, θ=ψ), so θ > 0 turns right as in CONVENTIONS.md
    V_k  Vector1 speed v (m/s)          W_k  Vector1 yaw rate ω (rad/s, > 0 right)
    M_k  Vector2 mount (pitch_m, roll_m) H_k  Vector1 mount height h_m (m)
    Y_k  Vector1 mount yaw offset yaw_m  B_k  Vector2 body (b_pitch, b_roll)

(Scalars are 1-vectors: gtsam's Python ``Values.insert`` of a float is ~30× slower.)

Factors, each the model's equation with its noise:

- ``pose_pair_factor``: the four angles of a pair = mount + body of frames k-1 and k
  (``model.pair_measurement`` rows 0–3), correlated 4×4 covariance, robust;
- ``motion_pair_factor``: (tx, tz, yaw) at the assumed height h0 = the displacement in
  G_{k-1} × h0 / h_m (rows 4–6), robust;
- ``process_factor``: constant-velocity planar motion with white acceleration / yaw
  acceleration (``model.propagate_pose`` and the ``model.transition`` noise), the
  displacement along the heading only (no side slip) up to ``cross_track_std_m``;
- ``body_factor``: Gauss–Markov body b_k = a·b_{k-1} + w, a linear factor (no Python);
- mount random walks, priors and the wheel speed are gtsam's built-in factors.

Python ``CustomFactor`` callbacks are limited to the three nonlinear or robust pair/process
terms. They must be linearised with Python-owned ``gtsam.Values`` (see ``smoother``): gtsam's
own nonlinear optimisers hand callbacks a copy of every value, which is quadratic in the
drive length.
"""

from __future__ import annotations

import math
from functools import lru_cache

import gtsam
import numpy as np
from numpy.typing import NDArray

from . import model as M
from .model import NoiseParams

FloatArray = NDArray[np.float64]


def symbols(k: int) -> dict[str, int]:
    """gtsam keys of frame ``k``'s variables by letter (see module doc)."""
    return {c: gtsam.symbol(c, k) for c in "XVWMHYB"}


def key(letter: str, k: int) -> int:
    """gtsam key of variable ``letter`` (one of XVWMHYB) of frame ``k``."""
    return gtsam.symbol(letter, k)


def pose2_from_model(x: float, y: float, psi: float) -> gtsam.Pose2:
    """Pose2 of a vehicle pose (x right, y forward, ψ > 0 right) of ``filters.model``."""
    return gtsam.Pose2(y, x, psi)


def model_from_pose2(p: gtsam.Pose2) -> tuple[float, float, float]:
    """(x right, y forward, ψ) of a Pose2 built by ``pose2_from_model``."""
    return float(p.y()), float(p.x()), float(p.theta())


def tangent_jacobian(psi: float) -> FloatArray:
    """∂(x, y, ψ)/∂(Pose2 tangent) at heading ψ: world position moves by R(θ)·(d1, d2)."""
    s, c = math.sin(psi), math.cos(psi)
    return np.array([[s, c, 0.0], [c, -s, 0.0], [0.0, 0.0, 1.0]])


def wrap(a: float) -> float:
    """Angle wrapped to (-π, π]."""
    return float((a + math.pi) % (2.0 * math.pi) - math.pi)


#: robust losses of the pair factors (gtsam M-estimators), 'none' for plain least squares
LOSSES: tuple[str, ...] = ("huber", "cauchy", "geman-mcclure", "tukey", "none")


def robust(base: gtsam.noiseModel.Base, kind: str, k: float) -> gtsam.noiseModel.Base:
    """``base`` wrapped in a Huber / Cauchy M-estimator of threshold ``k`` (whitened norm);
    ``kind='none'`` returns ``base``."""
    if kind == "none":
        return base
    if kind == "huber":
        est = gtsam.noiseModel.mEstimator.Huber.Create(k)
    elif kind == "cauchy":
        est = gtsam.noiseModel.mEstimator.Cauchy.Create(k)
    elif kind == "geman-mcclure":
        est = gtsam.noiseModel.mEstimator.GemanMcClure.Create(k)
    elif kind == "tukey":
        est = gtsam.noiseModel.mEstimator.Tukey.Create(k)
    else:
        raise ValueError(f"unknown robust loss {kind!r}; expected one of {', '.join(LOSSES)}")
    return gtsam.noiseModel.Robust.Create(est, base)


def _gaussian(cov: FloatArray) -> gtsam.noiseModel.Gaussian:
    return gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov, dtype=float))


# --- pair factors ---------------------------------------------------------------------------

# Jacobian of the pair's four angles w.r.t. (pitch_m, roll_m, b_prev (2), b_curr (2)): constant
# (the model is linear there), read once from the model itself.
_PROBE = np.zeros(M.STATE_DIM)
_PROBE[M.MOUNT_HEIGHT] = 1.0
_H_PAIR = M.pair_measurement(_PROBE, 1.0)[1]
_J_POSE_MOUNT = _H_PAIR[0:4][:, [M.MOUNT_PITCH, M.MOUNT_ROLL]].copy()
_J_POSE_BPREV = _H_PAIR[0:4][:, [M.PREV_BODY_PITCH, M.PREV_BODY_ROLL]].copy()
_J_POSE_BCURR = _H_PAIR[0:4][:, [M.BODY_PITCH, M.BODY_ROLL]].copy()


def pose_pair_factor(
    k: int, z4: FloatArray, cov4: FloatArray, loss: str = "huber", loss_k: float = 3.0
) -> gtsam.CustomFactor:
    """Factor of the pair's angles (pitch_prev, roll_prev, pitch, roll) (rad) on M_k, B_{k-1},
    B_k: z4 = (m + b_{k-1}, m + b_k) + noise of covariance ``cov4``."""
    z4 = np.asarray(z4, dtype=float).copy()
    noise = robust(_gaussian(cov4), loss, loss_k)
    keys = [key("M", k), key("B", k - 1), key("B", k)]

    def error(this: gtsam.CustomFactor, v: gtsam.Values, jac: list | None) -> FloatArray:
        m, bp, bc = v.atVector(keys[0]), v.atVector(keys[1]), v.atVector(keys[2])
        e = _J_POSE_MOUNT @ m + _J_POSE_BPREV @ bp + _J_POSE_BCURR @ bc - z4
        if jac is not None:
            jac[0], jac[1], jac[2] = _J_POSE_MOUNT, _J_POSE_BPREV, _J_POSE_BCURR
        return e

    return gtsam.CustomFactor(noise, keys, error)


def motion_pair_factor(
    k: int,
    z3: FloatArray,
    cov3: FloatArray,
    height_assumed: float,
    loss: str = "huber",
    loss_k: float = 3.0,
    metric: bool = True,
) -> gtsam.CustomFactor:
    """Factor of the pair's motion (tx, tz at the assumed height, m; yaw, rad) on X_{k-1},
    X_k, H_k, Y_k: ``model.pair_measurement`` rows 4–6.

    ``metric=False`` (no wheel speed near this frame) drops the derivative w.r.t. the height,
    as the EKF does: scale is then unobservable and the motion prior alone would shrink it
    (smaller motion, smaller accelerations), so the pair must not move h."""
    z3 = np.asarray(z3, dtype=float).copy()
    noise = robust(_gaussian(cov3), loss, loss_k)
    keys = [key("X", k - 1), key("X", k), key("H", k), key("Y", k)]
    h0 = float(height_assumed)

    def error(this: gtsam.CustomFactor, v: gtsam.Values, jac: list | None) -> FloatArray:
        # model.expected_pair rows 4-6 written out (a test holds them equal): the Python
        # callback runs for every frame and iteration
        p0, p1 = v.atPose2(keys[0]), v.atPose2(keys[1])
        y0, x0, psi0 = p0.x(), p0.y(), p0.theta()
        y1, x1, psi1 = p1.x(), p1.y(), p1.theta()
        h = v.atVector(keys[2])[0]
        g = psi0 + v.atVector(keys[3])[0]
        c, s = math.cos(g), math.sin(g)
        sc = h0 / h
        dx, dy = x1 - x0, y1 - y0
        tx, tz = sc * (c * dx - s * dy), sc * (s * dx + c * dy)
        e = np.array([tx - z3[0], tz - z3[1], wrap(psi1 - psi0 - z3[2])])
        if jac is not None:
            a = np.array([[sc * c, -sc * s, 0.0], [sc * s, sc * c, 0.0], [0.0, 0.0, 1.0]])
            d_g = np.array([[sc * (-s * dx - c * dy)], [sc * (c * dx - s * dy)], [0.0]])
            a_prev = -a
            a_prev[:, 2:3] += d_g
            jac[0] = a_prev @ tangent_jacobian(psi0)
            jac[1] = a @ tangent_jacobian(psi1)
            jac[2] = np.array([[-tx / h], [-tz / h], [0.0]]) if metric else np.zeros((3, 1))
            jac[3] = d_g
        return e

    return gtsam.CustomFactor(noise, keys, error)


# --- process factors ------------------------------------------------------------------------


@lru_cache(maxsize=256)
def _transition_at_rest(dt: float, noise: NoiseParams) -> tuple[FloatArray, FloatArray]:
    s = np.zeros(M.STATE_DIM)
    s[M.MOUNT_HEIGHT] = 1.0
    _, f, q = M.transition(s, dt, noise)
    f.setflags(write=False)
    q.setflags(write=False)
    return f, q


def process_noise(dt: float, noise: NoiseParams) -> FloatArray:
    """Full 16×16 process noise of ``model.transition`` over ``dt`` at heading 0 (so the
    along-track axis is y and the cross-track axis x). Read-only (cached per dt)."""
    return _transition_at_rest(float(dt), noise)[1]


def process_factor(
    k: int, dt: float, noise: NoiseParams, cross_track_std_m: float
) -> gtsam.CustomFactor:
    """Factor of the planar motion from frame k-1 to k over ``dt`` s: X_k, V_k, W_k against
    ``model.propagate_pose`` of X_{k-1}, V_{k-1}, W_{k-1}, with the residual position
    expressed along / across the mid-point heading (the model's noise has no side slip;
    ``cross_track_std_m`` keeps the factor full rank)."""
    q = process_noise(dt, noise)
    # residual order: along, cross, heading, speed, yaw rate
    idx = [M.POS_Y, M.POS_X, M.HEADING, M.SPEED, M.YAW_RATE]
    cov = q[np.ix_(idx, idx)].copy()
    cov[1, :] = cov[:, 1] = 0.0
    cov[1, 1] = cross_track_std_m**2
    base = gtsam.noiseModel.Gaussian.Covariance(cov)
    keys = [key(c, j) for j in (k - 1, k) for c in "XVW"]

    def error(this: gtsam.CustomFactor, v: gtsam.Values, jac: list | None) -> FloatArray:
        p0, p1 = v.atPose2(keys[0]), v.atPose2(keys[3])
        y0, x0, psi0 = p0.x(), p0.y(), p0.theta()
        y1, x1, psi1 = p1.x(), p1.y(), p1.theta()
        v0, w0 = v.atVector(keys[1])[0], v.atVector(keys[2])[0]
        v1, w1 = v.atVector(keys[4])[0], v.atVector(keys[5])[0]
        # model.propagate_pose, inlined (a test holds them equal)
        a = psi0 + 0.5 * w0 * dt
        sa, ca = math.sin(a), math.cos(a)
        xp, yp, psip = x0 + v0 * dt * sa, y0 + v0 * dt * ca, psi0 + w0 * dt
        dx, dy = x1 - xp, y1 - yp
        along = sa * dx + ca * dy
        cross = ca * dx - sa * dy
        e = np.array([along, cross, wrap(psi1 - psip), v1 - v0, w1 - w0])
        if jac is not None:
            # ∂/∂(x0, y0, ψ0, v0, ω0) and ∂/∂(x1, y1, ψ1) of (along, cross, heading)
            d_a = np.array([cross, -along - v0 * dt, 0.0])
            j_prev = np.zeros((5, 3))
            j_prev[0:2, 0:2] = -np.array([[sa, ca], [ca, -sa]])
            j_prev[0:3, 2] = d_a + np.array([0.0, 0.0, -1.0])
            j_v0 = np.array([[-dt], [0.0], [0.0], [-1.0], [0.0]])
            j_w0 = np.zeros((5, 1))
            j_w0[0:3, 0] = 0.5 * dt * d_a
            j_w0[2, 0] -= dt
            j_w0[4, 0] = -1.0
            j_curr = np.zeros((5, 3))
            j_curr[0:2, 0:2] = np.array([[sa, ca], [ca, -sa]])
            j_curr[2, 2] = 1.0
            jac[0] = j_prev @ tangent_jacobian(psi0)
            jac[1], jac[2] = j_v0, j_w0
            jac[3] = j_curr @ tangent_jacobian(psi1)
            jac[4] = np.array([[0.0], [0.0], [0.0], [1.0], [0.0]])
            jac[5] = np.array([[0.0], [0.0], [0.0], [0.0], [1.0]])
        return e

    return gtsam.CustomFactor(base, keys, error)


def body_factor(k: int, dt: float, noise: NoiseParams) -> gtsam.LinearContainerFactor:
    """Gauss–Markov body b_k = a·b_{k-1} + w over ``dt`` (``model.transition``'s decay and
    variance): an exactly linear factor, so gtsam evaluates it without Python."""
    f, q = _transition_at_rest(float(dt), noise)
    a = f[M.BODY_PITCH, M.BODY_PITCH]
    sigma = math.sqrt(q[M.BODY_PITCH, M.BODY_PITCH])
    kp, kc = key("B", k - 1), key("B", k)
    jf = gtsam.JacobianFactor(
        kp, -a * np.eye(2), kc, np.eye(2), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, sigma)
    )
    lin = gtsam.Values()
    lin.insert(kp, np.zeros(2))
    lin.insert(kc, np.zeros(2))
    return gtsam.LinearContainerFactor(jf, lin)


def mount_walk_factors(k: int, dt: float, noise: NoiseParams) -> list[gtsam.NonlinearFactor]:
    """Random walks of the mount angles, height and yaw from frame k-1 to k over ``dt``."""
    q = process_noise(dt, noise)
    ang = math.sqrt(q[M.MOUNT_PITCH, M.MOUNT_PITCH])
    return [
        gtsam.BetweenFactorVector(
            key("M", k - 1), key("M", k), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, ang)
        ),
        gtsam.BetweenFactorVector(
            key("H", k - 1),
            key("H", k),
            np.zeros(1),
            gtsam.noiseModel.Isotropic.Sigma(1, math.sqrt(q[M.MOUNT_HEIGHT, M.MOUNT_HEIGHT])),
        ),
        gtsam.BetweenFactorVector(
            key("Y", k - 1),
            key("Y", k),
            np.zeros(1),
            gtsam.noiseModel.Isotropic.Sigma(1, math.sqrt(q[M.MOUNT_YAW, M.MOUNT_YAW])),
        ),
    ]


def speed_factor(
    k: int, speed_mps: float, noise: NoiseParams, loss: str = "none", loss_k: float = 3.0
) -> gtsam.PriorFactorVector:
    """Wheel speed (m/s) at frame k's time on V_k, variance ``noise.speed_meas_var``."""
    sigma = math.sqrt(noise.speed_meas_var(speed_mps))
    noise_model = robust(gtsam.noiseModel.Isotropic.Sigma(1, sigma), loss, loss_k)
    return gtsam.PriorFactorVector(key("V", k), np.array([float(speed_mps)]), noise_model)
