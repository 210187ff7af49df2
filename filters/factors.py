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
- ``body_factor``: Gauss–Markov body b_k = a·b_{k-1} + w, a linear factor (no Python), its
  std per frame (``body_scale``: adapted to the measured shaking);
- mount random walks, priors, the wheel speed and the standstill (``standstill_factors``:
  yaw rate, and without wheel speed speed, = 0 where ``model.standstill_states`` says the
  vehicle stands) are gtsam's built-in factors.

Python ``CustomFactor`` callbacks are limited to the three nonlinear or robust pair/process
terms. They must be linearised with Python-owned ``gtsam.Values`` (see ``smoother``): gtsam's
own nonlinear optimisers hand callbacks a copy of every value, which is quadratic in the
drive length.

``filters.window_rows`` evaluates the same factors for many consecutive pairs at once
(whitened, robustly weighted residuals and Jacobians in model coordinates): the sliding-window
smoother (``filters.fixed_lag``) runs on it; a test holds it equal to these gtsam factors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import gtsam
import numpy as np
from numpy.typing import NDArray

from . import model as M
from .compiled import kernel
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


#: the losses as the compiled code's codes (``robust_weight``, ``window_rows``)
LOSS_CODE: dict[str, int] = {"none": 0, "huber": 1, "cauchy": 2, "geman-mcclure": 3, "tukey": 4}


@kernel
def robust_weight(norm: float, code: int, k: float) -> float:
    """IRLS weight of gtsam's M-estimator (``LOSS_CODE``) of threshold ``k`` at a whitened
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


def whitener(cov: FloatArray) -> FloatArray:
    """L⁻¹ of cov = L·Lᵀ (…, n, n): whitened residual = L⁻¹ · residual."""
    return np.linalg.inv(np.linalg.cholesky(np.asarray(cov, dtype=float)))


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
J_POSE_MOUNT = _H_PAIR[0:4][:, [M.MOUNT_PITCH, M.MOUNT_ROLL]].copy()
J_POSE_BPREV = _H_PAIR[0:4][:, [M.PREV_BODY_PITCH, M.PREV_BODY_ROLL]].copy()
J_POSE_BCURR = _H_PAIR[0:4][:, [M.BODY_PITCH, M.BODY_ROLL]].copy()


def pose_pair_factor(
    k: int, z4: FloatArray, cov4: FloatArray, loss: str = "huber", loss_k: float = 3.0
) -> gtsam.CustomFactor:
    """Factor of the pair's angles (pitch_prev, roll_prev, pitch, roll) (rad) on M_k, B_{k-1},
    B_k: z4 = (m + b_{k-1}, m + b_k) + noise of covariance ``cov4``."""
    z4 = np.asarray(z4, dtype=float).copy()
    noise = robust(_gaussian(cov4), loss, loss_k)
    keys = _pose_keys(k)

    def error(this: gtsam.CustomFactor, v: gtsam.Values, jac: list | None) -> FloatArray:
        if jac is not None:
            jac[0], jac[1], jac[2] = J_POSE_MOUNT, J_POSE_BPREV, J_POSE_BCURR
        return _pose_residual(v, keys, z4)

    return gtsam.CustomFactor(noise, keys, error)


def _pose_keys(k: int) -> list[int]:
    """Keys the pair's four angles depend on: M_k, B_{k-1}, B_k."""
    return [key("M", k), key("B", k - 1), key("B", k)]


def _pose_residual(v: gtsam.Values, keys: list[int], z4: FloatArray) -> FloatArray:
    """The pair's angles (m + b_{k-1}, m + b_k) at ``v`` (``keys``: ``_pose_keys``) minus z4."""
    return (J_POSE_MOUNT @ v.atVector(keys[0]) + J_POSE_BPREV @ v.atVector(keys[1])
            + J_POSE_BCURR @ v.atVector(keys[2]) - z4)


@dataclass(frozen=True)
class GivenPose:
    """What the motion-given-angles form of ``motion_pair_factor`` needs of its pair: the
    angles z4 (rad), A and the covariance A·Σ_angles,motion they explain
    (``model.motion_given_pose``), the angles' whitener and the pose factor's robust loss."""

    z4: FloatArray
    gain: FloatArray  # (3, 4)
    reduction: FloatArray  # (3, 3)
    pose_whitener: FloatArray  # (4, 4)
    loss: str
    loss_k: float

    @classmethod
    def of_pair(cls, cov: FloatArray, z4: FloatArray, loss: str, loss_k: float) -> GivenPose:
        """From a pair's 7×7 covariance (``pair_covariance``) and angles."""
        gain, conditional = M.motion_given_pose(cov)
        return cls(np.asarray(z4, dtype=float).copy(), gain, cov[4:, 4:] - conditional,
                   whitener(cov[:4, :4]), loss, float(loss_k))


def motion_pair_factor(
    k: int,
    z3: FloatArray,
    cov3: FloatArray,
    height_assumed: float,
    loss: str = "huber",
    loss_k: float = 3.0,
    metric: bool = True,
    given_pose: GivenPose | None = None,
) -> gtsam.CustomFactor:
    """Factor of the pair's motion (tx, tz at the assumed height, m; yaw, rad) on X_{k-1},
    X_k, H_k, Y_k: ``model.pair_measurement`` rows 4–6.

    ``metric=False`` (no wheel speed near this frame) drops the derivative w.r.t. the height,
    as the EKF does: scale is then unobservable and the motion prior alone would shrink it
    (smaller motion, smaller accelerations), so the pair must not move h.

    ``given_pose``: the motion given the pair's angles (:class:`GivenPose`): the residual is
    the motion's minus w·A times the pose pair's residual, of covariance ``cov3`` − w·(what the
    angles explain), w the pose block's robust weight at the current values (1: the
    conditional of ``model.motion_given_pose``; 0, angles rejected: the motion's own); the
    factor then also acts on M_k, B_{k-1}, B_k and whitens itself (w held fixed in the
    Jacobian, as IRLS holds a robust weight)."""
    z3 = np.asarray(z3, dtype=float).copy()
    cov3 = np.asarray(cov3, dtype=float)
    keys = [key("X", k - 1), key("X", k), key("H", k), key("Y", k)]
    if given_pose is None:
        noise = robust(_gaussian(cov3), loss, loss_k)
    else:
        noise = robust(gtsam.noiseModel.Unit.Create(3), loss, loss_k)
        gp = given_pose
        keys += _pose_keys(k)
        j_pose = [gp.gain @ J_POSE_MOUNT, gp.gain @ J_POSE_BPREV, gp.gain @ J_POSE_BCURR]
        pose_loss = LOSS_CODE[gp.loss]
        wm = np.empty((3, 3))  # the whitener at the current pose weight
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
        if given_pose is not None:
            pose_res = _pose_residual(v, keys[4:], gp.z4)
            w = robust_weight(float(np.linalg.norm(gp.pose_whitener @ pose_res)), pose_loss,
                              gp.loss_k)
            lower_inverse_cholesky(cov3 - w * gp.reduction, wm)
            e = wm @ (e - w * gp.gain @ pose_res)
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
            if given_pose is not None:
                for i in range(4):
                    jac[i] = wm @ jac[i]
                jac[4], jac[5], jac[6] = (-w * wm @ j for j in j_pose)
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


def process_covariance(dt: float, noise: NoiseParams, cross_track_std_m: float) -> FloatArray:
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
    return gtsam.noiseModel.Gaussian.Covariance(process_covariance(dt, noise, cross_track_std_m))


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


def body_factor(
    k: int, dt: float, noise: NoiseParams, std: FloatArray | None = None
) -> gtsam.LinearContainerFactor:
    """Gauss–Markov body b_k = a·b_{k-1} + w over ``dt`` with stationary std ``std`` (rad,
    pitch and roll; None: the model's; ``model.body_transition``'s decay and variance):
    an exactly linear factor, so gtsam evaluates it without Python."""
    decay, var = M.body_transition(float(dt), noise, std)
    kp, kc = key("B", k - 1), key("B", k)
    jf = gtsam.JacobianFactor(
        kp, -np.diag(decay), kc, np.eye(2), np.zeros(2),
        gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(var)),
    )
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
