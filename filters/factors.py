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
- mount random walks, priors, the wheel speed and the standstill (``standstill_factors``:
  yaw rate, and without wheel speed speed, = 0 where ``model.standstill_states`` says the
  vehicle stands) are gtsam's built-in factors.

Python ``CustomFactor`` callbacks are limited to the three nonlinear or robust pair/process
terms. They must be linearised with Python-owned ``gtsam.Values`` (see ``smoother``): gtsam's
own nonlinear optimisers hand callbacks a copy of every value, which is quadratic in the
drive length.

``stacked_rows`` evaluates the same factors for many consecutive pairs at once in numpy
(whitened, robustly weighted residuals and Jacobians in model coordinates): the sliding-window
smoother (``filters.fixed_lag``) runs on it; a test holds it equal to the gtsam factors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import gtsam
import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

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
#: threshold multipliers that give a loss Cauchy's weight on inliers: Geman–McClure's IRLS
#: weight is 1 − 2r²/k² + O(r⁴), Cauchy's 1 − r²/k², so GM at √2·k weighs the good pairs as
#: Cauchy at k does (at k itself it cost ~1 % pitch / roll RMS on clean drives)
LOSS_K_SCALE: dict[str, float] = {"geman-mcclure": math.sqrt(2.0)}


def robust(base: gtsam.noiseModel.Base, kind: str, k: float) -> gtsam.noiseModel.Base:
    """``base`` wrapped in gtsam's M-estimator ``kind`` (``LOSSES``) of threshold ``k``
    (whitened norm); ``kind='none'`` returns ``base``."""
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


def standstill_factors(
    k: int, states: tuple[int, ...], noise: NoiseParams
) -> list[gtsam.PriorFactorVector]:
    """Standstill pseudo-measurements of frame k (``model.standstill_measurement``): W_k = 0
    (rad/s) and, if ``states`` holds the speed, V_k = 0 (m/s), variances
    ``noise.standstill_var``."""
    letter = {M.SPEED: "V", M.YAW_RATE: "W"}
    return [
        gtsam.PriorFactorVector(
            key(letter[i], k), np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, math.sqrt(var))
        )
        for i, var in zip(states, noise.standstill_var(states), strict=True)
    ]


# --- stacked per-frame rows in numpy (the sliding-window smoother) -----------------------------

#: variables of a frame in the stacked rows, model coordinates (additive, no Pose2 tangent):
#: x, y (m), ψ (rad), v (m/s), ω (rad/s), pitch_m, roll_m (rad), h_m (m), yaw_m, b_pitch,
#: b_roll (rad); the same order as ``smoother._BLOCK``
FRAME_DIM = 11
#: rows of one frame's stack: process 0–4, body 5–6, mount walk 7–10, pose pair 11–14,
#: motion pair 15–17, wheel speed 18, standstill speed 19 and yaw rate 20
PAIR_ROWS = 21
POSE_ROWS, MOTION_ROWS, SPEED_ROW = slice(11, 15), slice(15, 18), 18
STANDSTILL_ROWS = slice(19, 21)


def robust_weight(norm: FloatArray, kind: str, k: float) -> FloatArray:
    """IRLS weight of gtsam's M-estimator ``kind`` of threshold ``k`` at whitened block
    norms ``norm`` (what ``noiseModel.Robust`` multiplies the squared rows by)."""
    r = np.asarray(norm, dtype=float)
    if kind == "none":
        return np.ones_like(r)
    if kind == "huber":
        return np.where(r <= k, 1.0, k / np.maximum(r, 1e-300))
    if kind == "cauchy":
        return k * k / (k * k + r * r)
    if kind == "geman-mcclure":
        return k**4 / (k * k + r * r) ** 2
    if kind == "tukey":
        return np.where(r <= k, (1.0 - (r / k) ** 2) ** 2, 0.0)
    raise ValueError(f"unknown robust loss {kind!r}; expected one of {', '.join(LOSSES)}")


def whitener(cov: FloatArray) -> FloatArray:
    """L⁻¹ of cov = L·Lᵀ (…, n, n): whitened residual = L⁻¹ · residual."""
    return np.linalg.inv(np.linalg.cholesky(np.asarray(cov, dtype=float)))


@lru_cache(maxsize=256)
def _frame_whiteners(dt: float, noise: NoiseParams, cross_track_std_m: float) -> tuple:
    q = process_noise(dt, noise)
    idx = [M.POS_Y, M.POS_X, M.HEADING, M.SPEED, M.YAW_RATE]
    cov = q[np.ix_(idx, idx)].copy()
    cov[1, :] = cov[:, 1] = 0.0
    cov[1, 1] = cross_track_std_m**2
    f, _ = _transition_at_rest(dt, noise)
    walk = 1.0 / np.sqrt(np.diag(q)[[M.MOUNT_PITCH, M.MOUNT_ROLL, M.MOUNT_HEIGHT, M.MOUNT_YAW]])
    body_isig = 1.0 / math.sqrt(q[M.BODY_PITCH, M.BODY_PITCH])
    return whitener(cov), float(f[M.BODY_PITCH, M.BODY_PITCH]), body_isig, walk


@dataclass
class StackedPairs:
    """Constants of the factors that join frames k-1 and k, for n consecutive pairs (arrays
    with a leading axis n). Missing pieces have zero whiteners (no pair / no speed)."""

    dt: FloatArray  # (n,) s
    z: FloatArray  # (n, 7) pair measurement, rad / m at h0
    h0: FloatArray  # (n,) assumed height of the pair, m
    w_pose: FloatArray  # (n, 4, 4) whitener of the pair angles (0 without a pair)
    w_motion: FloatArray  # (n, 3, 3) whitener of the pair motion (0 without a pair)
    metric: NDArray[np.bool_]  # (n,) the pair's motion moves h_m (wheel speed nearby)
    w_process: FloatArray  # (n, 5, 5) whitener of (along, cross, heading, Δv, Δω)
    body_a: FloatArray  # (n,) Gauss–Markov decay
    body_isig: FloatArray  # (n,) 1 / σ of the body step
    walk_isig: FloatArray  # (n, 4) 1 / σ of the mount walks (pitch, roll, h, yaw)
    speed: FloatArray  # (n,) wheel speed m/s (0 where none)
    speed_isig: FloatArray  # (n,) 1 / σ of the wheel speed (0 where none)
    still_isig: FloatArray  # (n, 2) 1 / σ of the standstill speed, yaw rate (0 where none)


def pair_constants(
    m: PairMeasurement,
    dt: float,
    speed: float,
    noise: NoiseParams,
    cross_track_std_m: float,
    metric: bool,
) -> dict[str, object]:
    """One pair's entries of :class:`StackedPairs` (a row of each field)."""
    wq, a, bis, walk = _frame_whiteners(float(dt), noise, float(cross_track_std_m))
    ok = bool(m.ok)
    cov = noise.pair_covariance(m.covariance) if ok else None
    has_speed = math.isfinite(speed)
    still = M.standstill_states(speed, m.status, noise)
    still_isig = np.zeros(2)
    for i, var in zip(still, noise.standstill_var(still), strict=True):
        still_isig[(M.SPEED, M.YAW_RATE).index(i)] = 1.0 / math.sqrt(var)
    return {
        "dt": dt,
        "z": np.asarray(m.z, dtype=float) if ok else np.zeros(7),
        "h0": float(m.height_assumed) if ok else 1.0,
        "w_pose": whitener(cov[:4, :4]) if ok else np.zeros((4, 4)),
        "w_motion": whitener(cov[4:7, 4:7]) if ok else np.zeros((3, 3)),
        "metric": metric,
        "w_process": wq,
        "body_a": a,
        "body_isig": bis,
        "walk_isig": walk,
        "speed": speed if has_speed else 0.0,
        "speed_isig": 1.0 / math.sqrt(noise.speed_meas_var(speed)) if has_speed else 0.0,
        "still_isig": still_isig,
    }


def stacked_rows(
    prev: FloatArray,
    curr: FloatArray,
    c: StackedPairs,
    loss: tuple[str, float, float] = ("none", 1.0, 1.0),
    speed_loss: tuple[str, float] = ("none", 1.0),
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Whitened, robustly weighted residuals (n, 21) and Jacobians (n, 21, 22) w.r.t.
    (prev, curr) of every factor joining frames k-1 and k (``FRAME_DIM`` layout, rows as
    ``PAIR_ROWS``), and the Gaussian whitened norms (n, 2) of the pose / motion pair blocks.

    The same equations as ``process_factor``, ``body_factor``, ``mount_walk_factors``,
    ``pose_pair_factor``, ``motion_pair_factor``, ``speed_factor`` and
    ``standstill_factors`` (a test holds them
    equal), evaluated for all pairs at once. ``loss`` = (kind, threshold of the 4-dof pose
    block, threshold of the 3-dof motion block); ``speed_loss`` = (kind, threshold)."""
    n = len(prev)
    d = FRAME_DIM
    r = np.zeros((n, PAIR_ROWS))
    jac = np.zeros((n, PAIR_ROWS, 2 * d))
    x0, y0, psi0, v0, w0 = (prev[:, i] for i in range(5))
    x1, y1, psi1, v1, w1 = (curr[:, i] for i in range(5))
    dt = c.dt
    # process: model.propagate_pose, residual along / across the mid-point heading
    a = psi0 + 0.5 * w0 * dt
    sa, ca = np.sin(a), np.cos(a)
    dx = x1 - (x0 + v0 * dt * sa)
    dy = y1 - (y0 + v0 * dt * ca)
    along, cross = sa * dx + ca * dy, ca * dx - sa * dy
    r[:, 0], r[:, 1] = along, cross
    r[:, 2] = _wrap(psi1 - psi0 - w0 * dt)
    r[:, 3], r[:, 4] = v1 - v0, w1 - w0
    jac[:, 0, 0], jac[:, 0, 1], jac[:, 1, 0], jac[:, 1, 1] = -sa, -ca, -ca, sa
    jac[:, 0, d], jac[:, 0, d + 1], jac[:, 1, d], jac[:, 1, d + 1] = sa, ca, ca, -sa
    jac[:, 0, 2], jac[:, 1, 2] = cross, -along - v0 * dt
    jac[:, 0, 4], jac[:, 1, 4] = 0.5 * dt * cross, 0.5 * dt * (-along - v0 * dt)
    jac[:, 0, 3] = -dt
    jac[:, 2, 2], jac[:, 2, 4], jac[:, 2, d + 2] = -1.0, -dt, 1.0
    jac[:, 3, 3], jac[:, 3, d + 3], jac[:, 4, 4], jac[:, 4, d + 4] = -1.0, 1.0, -1.0, 1.0
    r[:, 0:5] = np.matmul(c.w_process, r[:, 0:5, None])[..., 0]
    jac[:, 0:5] = np.matmul(c.w_process, jac[:, 0:5])
    # body (Gauss–Markov) and mount random walks: linear
    for i, col in enumerate((9, 10)):
        r[:, 5 + i] = c.body_isig * (curr[:, col] - c.body_a * prev[:, col])
        jac[:, 5 + i, col], jac[:, 5 + i, d + col] = -c.body_isig * c.body_a, c.body_isig
    for i, col in enumerate((5, 6, 7, 8)):
        r[:, 7 + i] = c.walk_isig[:, i] * (curr[:, col] - prev[:, col])
        jac[:, 7 + i, col], jac[:, 7 + i, d + col] = -c.walk_isig[:, i], c.walk_isig[:, i]
    # pose pair: (m + b_{k-1}, m + b_k) on the current mount
    e4 = np.stack(
        [curr[:, 5] + prev[:, 9], curr[:, 6] + prev[:, 10], curr[:, 5] + curr[:, 9],
         curr[:, 6] + curr[:, 10]], axis=1,
    ) - c.z[:, :4]
    j4 = np.zeros((n, 4, 2 * d))
    j4[:, 0, d + 5] = j4[:, 2, d + 5] = j4[:, 1, d + 6] = j4[:, 3, d + 6] = 1.0
    j4[:, 0, 9] = j4[:, 1, 10] = j4[:, 2, d + 9] = j4[:, 3, d + 10] = 1.0
    # motion pair: displacement in G_{k-1} scaled by h0 / h_m
    g = psi0 + curr[:, 8]
    cg, sg = np.cos(g), np.sin(g)
    sc = c.h0 / curr[:, 7]
    ddx, ddy = x1 - x0, y1 - y0
    tx, tz = sc * (cg * ddx - sg * ddy), sc * (sg * ddx + cg * ddy)
    e3 = np.stack([tx - c.z[:, 4], tz - c.z[:, 5], _wrap(psi1 - psi0 - c.z[:, 6])], axis=1)
    j3 = np.zeros((n, 3, 2 * d))
    j3[:, 0, d], j3[:, 0, d + 1], j3[:, 1, d], j3[:, 1, d + 1] = sc * cg, -sc * sg, sc * sg, sc * cg
    j3[:, 0:2, 0:2] = -j3[:, 0:2, d : d + 2]
    tx_g, tz_g = sc * (-sg * ddx - cg * ddy), sc * (cg * ddx - sg * ddy)
    j3[:, 0, 2] = j3[:, 0, d + 8] = tx_g
    j3[:, 1, 2] = j3[:, 1, d + 8] = tz_g
    j3[:, 0, d + 7] = np.where(c.metric, -tx / curr[:, 7], 0.0)
    j3[:, 1, d + 7] = np.where(c.metric, -tz / curr[:, 7], 0.0)
    j3[:, 2, 2], j3[:, 2, d + 2] = -1.0, 1.0
    norms = np.zeros((n, 2))
    kind, k4, k3 = loss
    for rows, e, j, w, kk, col in (
        (POSE_ROWS, e4, j4, c.w_pose, k4, 0), (MOTION_ROWS, e3, j3, c.w_motion, k3, 1)
    ):
        ew = np.matmul(w, e[..., None])[..., 0]
        norms[:, col] = np.linalg.norm(ew, axis=1)
        s = np.sqrt(robust_weight(norms[:, col], kind, kk))
        r[:, rows] = s[:, None] * ew
        jac[:, rows] = s[:, None, None] * np.matmul(w, j)
    # wheel speed on the current frame
    es = c.speed_isig * (v1 - c.speed)
    s = np.sqrt(robust_weight(np.abs(es), *speed_loss))
    r[:, SPEED_ROW] = s * es
    jac[:, SPEED_ROW, d + 3] = s * c.speed_isig
    # standstill: speed and yaw rate of the current frame measured as 0
    r[:, STANDSTILL_ROWS] = c.still_isig * curr[:, 3:5]
    jac[:, 19, d + 3], jac[:, 20, d + 4] = c.still_isig[:, 0], c.still_isig[:, 1]
    return r, jac, norms


def _wrap(a: FloatArray) -> FloatArray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi
