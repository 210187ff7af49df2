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


def tangent_jacobian(psi: float | FloatArray) -> FloatArray:
    """∂(x, y, ψ)/∂(Pose2 tangent) at heading ψ: world position moves by R(θ)·(d1, d2).
    An array of headings (...) gives (..., 3, 3)."""
    s, c = np.sin(psi), np.cos(psi)
    t = np.zeros((*np.shape(psi), 3, 3))
    t[..., 0, 0], t[..., 0, 1], t[..., 1, 0], t[..., 1, 1], t[..., 2, 2] = s, c, c, -s, 1.0
    return t


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
    jm, jbp, jbc = _J_POSE_MOUNT, _J_POSE_BPREV, _J_POSE_BCURR

    def error(this: gtsam.CustomFactor, v: gtsam.Values, jac: list | None) -> FloatArray:
        if jac is not None:
            jac[0], jac[1], jac[2] = jm, jbp, jbc
        return jm @ v.atVector(keys[0]) + jbp @ v.atVector(keys[1]) + jbc @ v.atVector(keys[2]) - z4

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
    zero31 = np.zeros((3, 1))

    def error(this: gtsam.CustomFactor, v: gtsam.Values, jac: list | None) -> FloatArray:
        # model.expected_pair rows 4-6 written out with scalars (a test holds them equal): the
        # Python callback runs for every frame and iteration
        p0, p1 = v.atPose2(keys[0]), v.atPose2(keys[1])
        psi0, psi1 = p0.theta(), p1.theta()
        dx, dy = p1.y() - p0.y(), p1.x() - p0.x()
        h = float(v.atVector(keys[2])[0])
        g = psi0 + float(v.atVector(keys[3])[0])
        c, s = math.cos(g), math.sin(g)
        sc = h0 / h
        tx, tz = sc * (c * dx - s * dy), sc * (s * dx + c * dy)
        e = np.array([tx - z3[0], tz - z3[1], wrap(psi1 - psi0 - z3[2])])
        if jac is not None:
            # ∂/∂(x, y, ψ) of (tx, tz, yaw) times the Pose2 tangent Jacobian (tangent_jacobian)
            # of either frame; the heading enters tx, tz through g = ψ_{k-1} + yaw_m
            tg_x, tg_z = -tz, tx
            s0, c0 = math.sin(psi0), math.cos(psi0)
            s1, c1 = math.sin(psi1), math.cos(psi1)
            # rows of ∂(tx, tz)/∂(x, y) = sc · [[c, -s], [s, c]] times [[s_, c_], [c_, -s_]]
            a00, a01 = sc * (c * s1 - s * c1), sc * (c * c1 + s * s1)
            a10, a11 = sc * (s * s1 + c * c1), sc * (s * c1 - c * s1)
            b00, b01 = sc * (c * s0 - s * c0), sc * (c * c0 + s * s0)
            b10, b11 = sc * (s * s0 + c * c0), sc * (s * c0 - c * s0)
            jac[0] = np.array([[-b00, -b01, tg_x], [-b10, -b11, tg_z], [0.0, 0.0, -1.0]])
            jac[1] = np.array([[a00, a01, 0.0], [a10, a11, 0.0], [0.0, 0.0, 1.0]])
            jac[2] = np.array([[-tx / h], [-tz / h], [0.0]]) if metric else zero31
            jac[3] = np.array([[tg_x], [tg_z], [0.0]])
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


def _process_covariance(dt: float, noise: NoiseParams, cross_track_std_m: float) -> FloatArray:
    """Covariance of the process factor's residual (along, cross, heading, Δv, Δω) over ``dt``:
    ``model.transition``'s noise at heading 0, the cross-track axis replaced by
    ``cross_track_std_m`` (the model has no side slip)."""
    q = process_noise(dt, noise)
    idx = [M.POS_Y, M.POS_X, M.HEADING, M.SPEED, M.YAW_RATE]
    cov = q[np.ix_(idx, idx)].copy()
    cov[1, :] = cov[:, 1] = 0.0
    cov[1, 1] = cross_track_std_m**2
    return cov


@lru_cache(maxsize=256)
def _process_noise_model(
    dt: float, noise: NoiseParams, cross_track_std_m: float
) -> gtsam.noiseModel.Gaussian:
    return gtsam.noiseModel.Gaussian.Covariance(_process_covariance(dt, noise, cross_track_std_m))


def process_factor(
    k: int, dt: float, noise: NoiseParams, cross_track_std_m: float
) -> gtsam.CustomFactor:
    """Factor of the planar motion from frame k-1 to k over ``dt`` s: X_k, V_k, W_k against
    ``model.propagate_pose`` of X_{k-1}, V_{k-1}, W_{k-1}, with the residual position
    expressed along / across the mid-point heading (the model's noise has no side slip;
    ``cross_track_std_m`` keeps the factor full rank)."""
    base = _process_noise_model(float(dt), noise, float(cross_track_std_m))
    keys = [key(c, j) for j in (k - 1, k) for c in "XVW"]

    j_v0 = np.array([[-dt], [0.0], [0.0], [-1.0], [0.0]])
    j_v1 = np.array([[0.0], [0.0], [0.0], [1.0], [0.0]])
    j_w1 = np.array([[0.0], [0.0], [0.0], [0.0], [1.0]])

    def error(this: gtsam.CustomFactor, v: gtsam.Values, jac: list | None) -> FloatArray:
        p0, p1 = v.atPose2(keys[0]), v.atPose2(keys[3])
        y0, x0, psi0 = p0.x(), p0.y(), p0.theta()
        y1, x1, psi1 = p1.x(), p1.y(), p1.theta()
        v0, w0 = float(v.atVector(keys[1])[0]), float(v.atVector(keys[2])[0])
        v1, w1 = float(v.atVector(keys[4])[0]), float(v.atVector(keys[5])[0])
        # model.propagate_pose, inlined with scalars (a test holds them equal)
        a = psi0 + 0.5 * w0 * dt
        sa, ca = math.sin(a), math.cos(a)
        dx, dy = x1 - (x0 + v0 * dt * sa), y1 - (y0 + v0 * dt * ca)
        along = sa * dx + ca * dy
        cross = ca * dx - sa * dy
        e = np.array([along, cross, wrap(psi1 - psi0 - w0 * dt), v1 - v0, w1 - w0])
        if jac is not None:
            # ∂(along, cross, heading)/∂(x, y, ψ) of either frame times the Pose2 tangent
            # Jacobian (tangent_jacobian); the mid-point heading a moves with ψ0 and ω0
            d_psi = -along - v0 * dt  # ∂cross/∂a (∂along/∂a = cross)
            s0, c0 = math.sin(psi0), math.cos(psi0)
            s1, c1 = math.sin(psi1), math.cos(psi1)
            jac[0] = np.array([
                [-(sa * s0 + ca * c0), ca * s0 - sa * c0, cross],
                [sa * c0 - ca * s0, -(ca * c0 + sa * s0), d_psi],
                [0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
            ])
            jac[1] = j_v0
            jac[2] = np.array([[0.5 * dt * cross], [0.5 * dt * d_psi], [-dt], [0.0], [-1.0]])
            jac[3] = np.array([
                [sa * s1 + ca * c1, sa * c1 - ca * s1, 0.0],
                [ca * s1 - sa * c1, ca * c1 + sa * s1, 0.0],
                [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
            ])
            jac[4], jac[5] = j_v1, j_w1
        return e

    return gtsam.CustomFactor(base, keys, error)


@lru_cache(maxsize=256)
def _body_terms(dt: float, noise: NoiseParams) -> tuple:
    f, q = _transition_at_rest(dt, noise)
    a = f[M.BODY_PITCH, M.BODY_PITCH]
    sigma = math.sqrt(q[M.BODY_PITCH, M.BODY_PITCH])
    return -a * np.eye(2), np.eye(2), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, sigma)


def body_factor(k: int, dt: float, noise: NoiseParams) -> gtsam.LinearContainerFactor:
    """Gauss–Markov body b_k = a·b_{k-1} + w over ``dt`` (``model.transition``'s decay and
    variance): an exactly linear factor, so gtsam evaluates it without Python."""
    a_prev, eye, zero, sigma = _body_terms(float(dt), noise)
    kp, kc = key("B", k - 1), key("B", k)
    jf = gtsam.JacobianFactor(kp, a_prev, kc, eye, zero, sigma)
    lin = gtsam.Values()
    lin.insert(kp, np.zeros(2))
    lin.insert(kc, np.zeros(2))
    return gtsam.LinearContainerFactor(jf, lin)


def mount_walk_factors(k: int, dt: float, noise: NoiseParams) -> list[gtsam.NonlinearFactor]:
    """Random walks of the mount angles, height and yaw from frame k-1 to k over ``dt``."""
    return [
        gtsam.BetweenFactorVector(key(c, k - 1), key(c, k), zero, sigma)
        for c, zero, sigma in zip("MHY", (np.zeros(2), np.zeros(1), np.zeros(1)),
                                  _walk_noise_models(float(dt), noise), strict=True)
    ]


@lru_cache(maxsize=256)
def _walk_noise_models(dt: float, noise: NoiseParams) -> tuple:
    """Isotropic noise of the mount angles', height's and yaw offset's random walks over dt."""
    q = process_noise(dt, noise)
    return tuple(
        gtsam.noiseModel.Isotropic.Sigma(dim, math.sqrt(q[i, i]))
        for dim, i in ((2, M.MOUNT_PITCH), (1, M.MOUNT_HEIGHT), (1, M.MOUNT_YAW))
    )


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


# first column of frame k in the stacked rows (frame k-1's start at 0)
_CURR = FRAME_DIM
# process rows (along, cross, heading, Δv, Δω): the Jacobian entries that do not depend on the
# state, and those of (along, cross) that do (set per call in ``stacked_rows``)
_PROCESS_DYN_COLS = np.array([0, 1, 2, 4, _CURR, _CURR + 1])


@lru_cache(maxsize=256)
def _frame_constants(dt: float, noise: NoiseParams, cross_track_std_m: float) -> tuple:
    """Per-dt constants of the stacked rows: the process whitener (5, 5), its product with
    the process rows' constant Jacobian (5, 22), and the whitened Jacobian (21, 22) of the
    body and mount-walk rows (5–10) (read-only)."""
    d = FRAME_DIM
    q = process_noise(dt, noise)
    w = whitener(_process_covariance(dt, noise, cross_track_std_m))
    static = np.zeros((5, 2 * d))
    static[0, 3] = -dt  # along: -v0·dt
    static[2, 2], static[2, 4], static[2, d + 2] = -1.0, -dt, 1.0
    static[3, 3], static[3, d + 3], static[4, 4], static[4, d + 4] = -1.0, 1.0, -1.0, 1.0
    f, _ = _transition_at_rest(dt, noise)
    body_a = float(f[M.BODY_PITCH, M.BODY_PITCH])
    body_isig = 1.0 / math.sqrt(q[M.BODY_PITCH, M.BODY_PITCH])
    walk = 1.0 / np.sqrt(np.diag(q)[[M.MOUNT_PITCH, M.MOUNT_ROLL, M.MOUNT_HEIGHT, M.MOUNT_YAW]])
    lin = np.zeros((PAIR_ROWS, 2 * d))
    for i, col in enumerate((9, 10)):  # body: b_k − a·b_{k-1}
        lin[5 + i, col], lin[5 + i, d + col] = -body_isig * body_a, body_isig
    for i, col in enumerate((5, 6, 7, 8)):  # mount walks: m_k − m_{k-1}
        lin[7 + i, col], lin[7 + i, d + col] = -walk[i], walk[i]
    out = (w, w @ static, lin)
    for arr in out:
        arr.setflags(write=False)
    return out


# (row, column) of the motion pair's state-dependent Jacobian entries, in ``stacked_rows``'
# order: ∂(tx, tz)/∂(x_k, y_k), ∂/∂(x_{k-1}, y_{k-1}), ∂/∂ψ_{k-1} and ∂/∂yaw_m, ∂/∂h_m
_MOTION_JAC_ROWS = np.array([0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1, 1, 0, 1])
_MOTION_JAC_COLS = np.array([
    _CURR, _CURR + 1, _CURR, _CURR + 1, 0, 1, 0, 1, 2, _CURR + 8, 2, _CURR + 8, _CURR + 7,
    _CURR + 7,
])

# the pose pair's Jacobian (m + b_{k-1}, m + b_k) w.r.t. (frame k-1, frame k): the model's
# blocks (read above) at the mount and body columns of the FRAME_DIM layout
_J_POSE_STACKED = np.zeros((4, 2 * FRAME_DIM))
_J_POSE_STACKED[:, _CURR + 5 : _CURR + 7] = _J_POSE_MOUNT
_J_POSE_STACKED[:, 9:11] = _J_POSE_BPREV
_J_POSE_STACKED[:, _CURR + 9 : _CURR + 11] = _J_POSE_BCURR


@dataclass
class StackedPairs:
    """Constants of the factors that join frames k-1 and k, for n consecutive pairs (arrays
    with a leading axis n). Missing pieces have zero rows (no pair / no speed)."""

    dt: FloatArray  # (n,) s
    z: FloatArray  # (n, 7) pair measurement, rad / m at h0
    h0: FloatArray  # (n,) assumed height of the pair, m
    w_motion: FloatArray  # (n, 3, 3) whitener of the pair motion (0 without a pair)
    metric: NDArray[np.bool_]  # (n,) the pair's motion moves h_m (wheel speed nearby)
    w_process: FloatArray  # (n, 5, 5) whitener of (along, cross, heading, Δv, Δω)
    process_jac: FloatArray  # (n, 5, 22) whitened state-independent process Jacobian
    #: (n, 21, 22), (n, 21): the rows that are linear in the state (body, mount walks, pose
    #: pair, wheel speed, standstill), whitened: r = lin_jac · (x_{k-1}, x_k) − lin_b
    lin_jac: FloatArray
    lin_b: FloatArray


def pair_constants(
    m: PairMeasurement,
    dt: float,
    speed: float,
    noise: NoiseParams,
    cross_track_std_m: float,
    metric: bool,
) -> dict[str, object]:
    """One pair's entries of :class:`StackedPairs` (a row of each field)."""
    d = FRAME_DIM
    wq, process_jac, lin_static = _frame_constants(float(dt), noise, float(cross_track_std_m))
    lin = lin_static.copy()
    b = np.zeros(PAIR_ROWS)
    ok = bool(m.ok)
    z = np.asarray(m.z, dtype=float) if ok else np.zeros(7)
    if ok:
        cov = noise.pair_covariance(m.covariance)
        w_pose = whitener(cov[:4, :4])
        lin[POSE_ROWS] = w_pose @ _J_POSE_STACKED
        b[POSE_ROWS] = w_pose @ z[:4]
    if math.isfinite(speed):
        isig = 1.0 / math.sqrt(noise.speed_meas_var(speed))
        lin[SPEED_ROW, d + 3], b[SPEED_ROW] = isig, isig * speed
    still = M.standstill_states(speed, m.status, noise)
    for i, var in zip(still, noise.standstill_var(still), strict=True):
        row = STANDSTILL_ROWS.start + (M.SPEED, M.YAW_RATE).index(i)
        lin[row, d + (3 if i == M.SPEED else 4)] = 1.0 / math.sqrt(var)
    return {
        "dt": dt,
        "z": z,
        "h0": float(m.height_assumed) if ok else 1.0,
        "w_motion": whitener(cov[4:7, 4:7]) if ok else np.zeros((3, 3)),
        "metric": metric,
        "w_process": wq,
        "process_jac": process_jac,
        "lin_jac": lin,
        "lin_b": b,
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
    ``standstill_factors`` (a test holds them equal), evaluated for all pairs at once; the
    linear rows come whitened from ``pair_constants``. ``loss`` = (kind, threshold of the
    4-dof pose block, threshold of the 3-dof motion block); ``speed_loss`` = (kind,
    threshold)."""
    n = len(prev)
    both = np.concatenate([prev, curr], axis=1)
    r = np.matmul(c.lin_jac, both[..., None])[..., 0] - c.lin_b
    jac = c.lin_jac.copy()
    # (few, large numpy operations: the sliding window calls this for a few dozen pairs)
    x0, y0, psi0, v0, w0, _, _, _, _, _, _ = prev.T
    x1, y1, psi1, v1, w1, _, _, h, yaw_m, _, _ = curr.T
    dt = c.dt
    # process: model.propagate_pose, residual along / across the mid-point heading
    a = psi0 + 0.5 * w0 * dt
    sa, ca = np.sin(a), np.cos(a)
    dx = x1 - (x0 + v0 * dt * sa)
    dy = y1 - (y0 + v0 * dt * ca)
    along, cross = sa * dx + ca * dy, ca * dx - sa * dy
    d_psi = -along - v0 * dt  # ∂cross/∂(mid-point heading); ∂along/∂ it is cross
    # the two angle differences wrapped at once: process heading, pair yaw
    turn = _wrap(np.array([psi1 - psi0 - w0 * dt, psi1 - psi0 - c.z[:, 6]]))
    e5 = np.array([along, cross, turn[0], v1 - v0, w1 - w0]).T
    r[:, 0:5] = np.matmul(c.w_process, e5[..., None])[..., 0]
    # ∂(along, cross)/∂ columns _PROCESS_DYN_COLS (x0, y0, ψ0, ω0, x1, y1)
    hdt = 0.5 * dt
    dyn = np.array(
        [-sa, -ca, cross, hdt * cross, sa, ca, -ca, sa, d_psi, hdt * d_psi, ca, -sa]
    ).T.reshape(n, 2, 6)
    jac[:, 0:5] = c.process_jac
    jac[:, 0:5, _PROCESS_DYN_COLS] += np.matmul(c.w_process[:, :, 0:2], dyn)
    # motion pair: displacement in G_{k-1} scaled by h0 / h_m
    g = psi0 + yaw_m
    sc = c.h0 / h
    scg, ssg = sc * np.cos(g), sc * np.sin(g)
    ddx, ddy = x1 - x0, y1 - y0
    tx, tz = scg * ddx - ssg * ddy, ssg * ddx + scg * ddy
    e3 = np.array([tx - c.z[:, 4], tz - c.z[:, 5], turn[1]]).T
    dh = np.where(c.metric, 1.0 / h, 0.0)  # the EKF's rule: without wheel speed, h stays
    j3 = np.zeros((n, 3, 2 * FRAME_DIM))
    j3[:, _MOTION_JAC_ROWS, _MOTION_JAC_COLS] = np.array(
        [scg, -ssg, ssg, scg, -scg, ssg, -ssg, -scg, -tz, -tz, tx, tx, -tx * dh, -tz * dh]
    ).T
    j3[:, 2, 2], j3[:, 2, _CURR + 2] = -1.0, 1.0
    r[:, MOTION_ROWS] = np.matmul(c.w_motion, e3[..., None])[..., 0]
    jac[:, MOTION_ROWS] = np.matmul(c.w_motion, j3)
    # robust weights (IRLS, as gtsam's noiseModel.Robust) of the pair blocks and the speed
    sq = r * r
    norms = np.sqrt(np.array([sq[:, POSE_ROWS].sum(axis=1), sq[:, MOTION_ROWS].sum(axis=1)]).T)
    kind, k4, k3 = loss
    scale = np.ones((n, PAIR_ROWS))
    if kind != "none":
        scale[:, POSE_ROWS] = np.sqrt(robust_weight(norms[:, 0], kind, k4))[:, None]
        scale[:, MOTION_ROWS] = np.sqrt(robust_weight(norms[:, 1], kind, k3))[:, None]
    if speed_loss[0] != "none":
        scale[:, SPEED_ROW] = np.sqrt(robust_weight(np.abs(r[:, SPEED_ROW]), *speed_loss))
    r *= scale
    jac *= scale[..., None]
    return r, jac, norms


def _wrap(a: FloatArray) -> FloatArray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi
