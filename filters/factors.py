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

Python ``CustomFactor`` callbacks are limited to the terms no built-in factor expresses:
the planar process (pose, speed and yaw rate), the pair's height-scaled motion, and the pair's
four angles (linear, but under a robust loss, which gtsam applies only to a
``NoiseModelFactor``); the process and the motion evaluate in one compiled call each
(``filters.residuals``), the angles' Jacobian is constant. They must be linearised at a
``gtsam.Values`` that has a Python object (``smoother.held_linearization_point``): for any
other pybind11 hands every callback a copy of every value, quadratic in the drive length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import gtsam
import numpy as np
from numpy.typing import NDArray

from . import model as M
from .model import NoiseParams
from .residuals import motion_factor_eval, process_factor_eval

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


#: robust losses of the pair factors (gtsam M-estimators), 'none' for plain least squares
LOSSES: tuple[str, ...] = ("huber", "cauchy", "geman-mcclure", "tukey", "none")
#: threshold multipliers that give a loss Cauchy's weight on inliers: Geman–McClure's IRLS
#: weight is 1 − 2r²/k² + O(r⁴), Cauchy's 1 − r²/k², so GM at √2·k weighs the good pairs as
#: Cauchy at k does (at k itself it cost ~1 % pitch / roll RMS on clean drives)
LOSS_K_SCALE: dict[str, float] = {"geman-mcclure": math.sqrt(2.0)}
#: the losses whose cost is not convex (their influence falls back towards zero far out):
#: started from the Huber solution (``SmootherConfig.convex_start``), as their cost has
#: minima wherever pairs are rejected
NON_CONVEX: tuple[str, ...] = ("cauchy", "geman-mcclure", "tukey")


#: the losses as the compiled code's codes (``residuals.robust_weight``)
LOSS_CODE: dict[str, int] = {"none": 0, "huber": 1, "cauchy": 2, "geman-mcclure": 3, "tukey": 4}


def whitener(cov: FloatArray) -> FloatArray:
    """L⁻¹ of cov = L·Lᵀ (…, n, n): whitened residual = L⁻¹ · residual."""
    return np.linalg.inv(np.linalg.cholesky(np.asarray(cov, dtype=float)))


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
#: the three side by side: ∂(angles)/∂(pitch_m, roll_m, b_{k-1}, b_k)
J_POSE = np.hstack([J_POSE_MOUNT, J_POSE_BPREV, J_POSE_BCURR])


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
    return J_POSE @ np.concatenate([v.atVector(k) for k in keys]) - z4


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
    X_k, H_k, Y_k: ``model.pair_measurement`` rows 4–6 (``residuals.motion_residual``).

    ``metric=False`` (no wheel speed near this frame) drops the derivative w.r.t. the height,
    as the EKF does: scale is then unobservable and the motion prior alone would shrink it
    (smaller motion, smaller accelerations), so the pair must not move h.

    ``given_pose``: the motion given the pair's angles (:class:`GivenPose`): the residual is
    the motion's minus w·A times the pose pair's residual, of covariance ``cov3`` − w·(what the
    angles explain), w the pose block's robust weight at the current values (1: the
    conditional of ``model.motion_given_pose``; 0, angles rejected: the motion's own); the
    factor then also acts on M_k, B_{k-1}, B_k and whitens itself (w held fixed in the
    Jacobian, as IRLS holds a robust weight)."""
    z = np.zeros(7)
    z[4:] = np.asarray(z3, dtype=float)
    cov3 = np.ascontiguousarray(cov3, dtype=float)
    keys = [key("X", k - 1), key("X", k), key("H", k), key("Y", k)]
    given = given_pose is not None
    if given_pose is None:
        noise = robust(_gaussian(cov3), loss, loss_k)
        gain, reduction, pose_whitener = _NO_GAIN, _NO_REDUCTION, _NO_WHITENER
        given_jac = _NO_GIVEN_JAC
        pose_loss, pose_k = 0, 1.0
    else:
        noise = robust(gtsam.noiseModel.Unit.Create(3), loss, loss_k)
        keys += _pose_keys(k)
        z[:4] = given_pose.z4
        gain, reduction = given_pose.gain, given_pose.reduction
        given_jac = np.zeros((3, 14))  # A·∂(angles)/∂(M, B_{k-1}, B_k) in the output's columns
        given_jac[:, 8:] = gain @ J_POSE
        pose_whitener = given_pose.pose_whitener
        pose_loss, pose_k = LOSS_CODE[given_pose.loss], given_pose.loss_k
    h0 = float(height_assumed)
    s = np.zeros(14)
    out = np.empty((3, 15))
    blocks = ((1, 4), (4, 7), (7, 8), (8, 9), (9, 11), (11, 13), (13, 15))[: len(keys)]

    def error(this: gtsam.CustomFactor, v: gtsam.Values, jac: list | None) -> FloatArray:
        p0, p1 = v.atPose2(keys[0]), v.atPose2(keys[1])
        s[0], s[1], s[2] = p0.y(), p0.x(), p0.theta()
        s[3], s[4], s[5] = p1.y(), p1.x(), p1.theta()
        s[6], s[7] = v.atVector(keys[2])[0], v.atVector(keys[3])[0]
        if given:
            s[8:10], s[10:12], s[12:14] = (v.atVector(kk) for kk in keys[4:])
        motion_factor_eval(s, h0, z, metric, cov3, given, gain, reduction, given_jac, J_POSE,
                           pose_whitener, pose_loss, pose_k, out)
        if jac is not None:
            for i, (lo, hi) in enumerate(blocks):
                jac[i] = out[:, lo:hi]
        return out[:, 0].copy()

    return gtsam.CustomFactor(noise, keys, error)


# placeholders of motion_factor_eval's given-pose arguments when there is none
_NO_GAIN, _NO_REDUCTION, _NO_WHITENER = np.zeros((3, 4)), np.zeros((3, 3)), np.zeros((4, 4))
_NO_GIVEN_JAC = np.zeros((3, 14))


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
    expressed along / across the mid-point heading (``residuals.process_residual``; the
    model's noise has no side slip; ``cross_track_std_m`` keeps the factor full rank)."""
    base = _process_noise_model(float(dt), noise, float(cross_track_std_m))
    keys = [key(c, j) for j in (k - 1, k) for c in "XVW"]
    dt = float(dt)
    s = np.zeros(10)
    out = np.empty((5, 11))
    blocks = ((1, 4), (4, 5), (5, 6), (6, 9), (9, 10), (10, 11))

    def error(this: gtsam.CustomFactor, v: gtsam.Values, jac: list | None) -> FloatArray:
        p0, p1 = v.atPose2(keys[0]), v.atPose2(keys[3])
        s[0], s[1], s[2] = p0.y(), p0.x(), p0.theta()
        s[3], s[4] = v.atVector(keys[1])[0], v.atVector(keys[2])[0]
        s[5], s[6], s[7] = p1.y(), p1.x(), p1.theta()
        s[8], s[9] = v.atVector(keys[4])[0], v.atVector(keys[5])[0]
        process_factor_eval(s, dt, out)
        if jac is not None:
            for i, (lo, hi) in enumerate(blocks):
                jac[i] = out[:, lo:hi]
        return out[:, 0].copy()

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


def mount_walk_factors(
    k: int, dt: float, noise: NoiseParams, jump_var: FloatArray | None = None
) -> list[gtsam.NonlinearFactor]:
    """Random walks of the mount angles, height and yaw from frame k-1 to k over ``dt``;
    ``jump_var`` (pitch, roll; rad²) is added to the angles' variance where the mount may
    have stepped (``filters.mount_change``)."""
    models = list(_walk_noise_models(float(dt), noise))
    if jump_var is not None:
        q = process_noise(float(dt), noise)[M.MOUNT_PITCH, M.MOUNT_PITCH]
        models[0] = gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(q + np.asarray(jump_var)))
    return [
        gtsam.BetweenFactorVector(key(c, k - 1), key(c, k), zero, sigma)
        for c, zero, sigma in zip("MHY", (np.zeros(2), np.zeros(1), np.zeros(1)), models,
                                  strict=True)
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
