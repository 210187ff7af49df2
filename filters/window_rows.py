"""The smoother's factors for many consecutive frame pairs at once (the sliding window's rows).

``stacked_rows`` evaluates, for n pairs (k-1, k), every factor of ``filters.factors`` that
joins the two frames — process, body, mount walks, pose pair, motion pair, wheel speed,
standstill — as whitened, robustly weighted residuals (n, 21) and Jacobians (n, 21, 22) in
model coordinates (additive, no Pose2 tangent); a test holds them equal to the gtsam factors.
The rows that are linear in the state come whitened from ``pair_constants`` (once per pair);
the rest are evaluated per call by one compiled loop (numba; the process and motion residuals
are ``filters.residuals``', as in the gtsam factors): the sliding window calls this
twice per frame on a few dozen pairs, where numpy's per-operation cost dominated.

Variables of a frame (``FRAME_DIM``): x, y (m), ψ (rad), v (m/s), ω (rad/s), pitch_m,
roll_m (rad), h_m (m), yaw_m, b_pitch, b_roll (rad); a pair's 22 columns are frame k-1's
then frame k's. Rows (``PAIR_ROWS``): process 0–4, body 5–6, mount walk 7–10, pose pair
11–14, motion pair 15–17, wheel speed 18, standstill speed 19 and yaw rate 20.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from vipm_track.compiled import kernel
from vipm_track.measurement import PairMeasurement

from . import factors as F
from . import model as M
from .model import NoiseParams
from .mount_change import across_jump
from .residuals import (
    motion_residual,
    process_constant_jacobian,
    process_residual,
    robust_weight,
    whiten_motion_given_pose,
)

FloatArray = NDArray[np.float64]

FRAME_DIM = 11
PAIR_ROWS = 21
POSE_ROWS, MOTION_ROWS, SPEED_ROW = slice(11, 15), slice(15, 18), 18
STANDSTILL_ROWS = slice(19, 21)

# first column of frame k in a pair's columns (frame k-1's start at 0)
_CURR = FRAME_DIM
def _loss_code(kind: str) -> int:
    if kind not in F.LOSS_CODE:
        raise ValueError(f"unknown robust loss {kind!r}; expected one of {', '.join(F.LOSSES)}")
    return F.LOSS_CODE[kind]


@lru_cache(maxsize=256)
def _frame_constants(dt: float, noise: NoiseParams, cross_track_std_m: float) -> tuple:
    """Per-dt constants of the rows: the process whitener (5, 5), its product with the
    process rows' constant Jacobian (5, 22), and the whitened Jacobian (21, 22) of the
    mount-walk rows (7–10) (read-only; the body rows 5–6 depend on the frame's body std)."""
    d = FRAME_DIM
    q = F.process_noise(dt, noise)
    w = F.whitener(F.process_covariance(dt, noise, cross_track_std_m))
    const = np.empty((5, 10))  # over (x, y, ψ, v, ω) of frame k-1, then of frame k
    process_constant_jacobian(dt, const)
    static = np.zeros((5, 2 * d))
    static[:, :5], static[:, d : d + 5] = const[:, :5], const[:, 5:]
    walk = 1.0 / np.sqrt(np.diag(q)[[M.MOUNT_PITCH, M.MOUNT_ROLL, M.MOUNT_HEIGHT, M.MOUNT_YAW]])
    lin = np.zeros((PAIR_ROWS, 2 * d))
    for i, col in enumerate((5, 6, 7, 8)):  # mount walks: m_k − m_{k-1}
        lin[7 + i, col], lin[7 + i, d + col] = -walk[i], walk[i]
    out = (w, w @ static, lin)
    for arr in out:
        arr.setflags(write=False)
    return out


# the pose pair's Jacobian (m + b_{k-1}, m + b_k) w.r.t. (frame k-1, frame k): the model's
# blocks (``factors``) at the mount and body columns
_J_POSE = np.zeros((4, 2 * FRAME_DIM))
_J_POSE[:, _CURR + 5 : _CURR + 7] = F.J_POSE_MOUNT
_J_POSE[:, 9:11] = F.J_POSE_BPREV
_J_POSE[:, _CURR + 9 : _CURR + 11] = F.J_POSE_BCURR


@dataclass
class StackedPairs:
    """Constants of the factors that join frames k-1 and k, for n consecutive pairs (arrays
    with a leading axis n). Missing pieces have zero rows (no pair / no speed)."""

    dt: FloatArray  # (n,) s
    z: FloatArray  # (n, 7) pair measurement, rad / m at h0
    h0: FloatArray  # (n,) assumed height of the pair, m
    #: (n, 3, 3) covariance of the pair's motion (zeros where there is no pair: no rows)
    motion_cov: FloatArray
    #: (n, 3, 3), (n, 3, 22), (n, 3): the motion given the angles (``model.motion_given_pose``,
    #: zeros without it): of covariance motion_cov − w·given_red, it subtracts w·A·(pose
    #: residual) = w·(given_jac · (x_{k-1}, x_k) − given_b), w the pose block's robust weight
    given_red: FloatArray
    given_jac: FloatArray
    given_b: FloatArray
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
    given_pose: bool = False,
    body_std: FloatArray | None = None,
) -> dict[str, object]:
    """One pair's entries of :class:`StackedPairs` (a row of each field); ``given_pose``: the
    motion rows are the motion given the pair's angles (``SmootherConfig.motion_given_pose``),
    else its own (marginal) covariance; ``body_std``: frame k's body std (pitch, roll, rad;
    None: the model's)."""
    d = FRAME_DIM
    wq, process_jac, lin_static = _frame_constants(float(dt), noise, float(cross_track_std_m))
    lin = lin_static.copy()
    decay, var = M.body_transition(float(dt), noise, body_std)
    for i, col in enumerate((9, 10)):  # body: b_k − a·b_{k-1}
        isig = 1.0 / math.sqrt(var[i])
        lin[5 + i, col], lin[5 + i, d + col] = -isig * decay[i], isig
    b = np.zeros(PAIR_ROWS)
    ok = bool(m.ok)
    z = np.asarray(m.z, dtype=float) if ok else np.zeros(7)
    motion_cov, given_red = np.zeros((3, 3)), np.zeros((3, 3))
    given_jac, given_b = np.zeros((3, 2 * d)), np.zeros(3)
    if ok:
        cov = noise.pair_covariance(m.covariance, m.z[6])
        w_pose = F.whitener(cov[:4, :4])
        lin[POSE_ROWS] = w_pose @ _J_POSE
        b[POSE_ROWS] = w_pose @ z[:4]
        motion_cov = cov[4:7, 4:7]
        if given_pose:
            gain, conditional = M.motion_given_pose(cov)
            given_red = motion_cov - conditional
            given_jac, given_b = gain @ _J_POSE, gain @ z[:4]
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
        "motion_cov": motion_cov,
        "given_red": given_red,
        "given_jac": given_jac,
        "given_b": given_b,
        "metric": metric,
        "w_process": wq,
        "process_jac": process_jac,
        "lin_jac": lin,
        "lin_b": b,
    }


def apply_mount_jump(
    lin_jac: FloatArray, lin_b: FloatArray, m: PairMeasurement, dt: float, noise: NoiseParams,
    jump_var: FloatArray,
) -> None:
    """Let the mount step by variance ``jump_var`` (pitch, roll; rad²) into the frame of a
    stored pair's rows (``pair_constants``'s ``lin_jac`` (21, 22) and ``lin_b`` (21,), changed
    in place): its mount-walk rows and the doubt of its previous frame's angles, as
    ``smoother._frame_factors`` does for the batch."""
    q = np.diag(F.process_noise(float(dt), noise))[[M.MOUNT_PITCH, M.MOUNT_ROLL]]
    for i in range(2):  # mount walks: 1/√q → 1/√(q + jump)
        lin_jac[7 + i] *= math.sqrt(q[i] / (q[i] + jump_var[i]))
    if m.ok:
        cov = across_jump(noise.pair_covariance(m.covariance, m.z[6]), jump_var)
        w_pose = F.whitener(cov[:4, :4])
        lin_jac[POSE_ROWS] = w_pose @ _J_POSE
        lin_b[POSE_ROWS] = w_pose @ np.asarray(m.z, dtype=float)[:4]


def stacked_rows(
    prev: FloatArray,
    curr: FloatArray,
    c: StackedPairs,
    loss: tuple[str, float, float] = ("none", 1.0, 1.0),
    speed_loss: tuple[str, float] = ("none", 1.0),
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Whitened, robustly weighted residuals (n, 21) and Jacobians (n, 21, 22) w.r.t.
    (prev, curr) of every factor joining frames k-1 and k (rows as ``PAIR_ROWS``), and the
    Gaussian whitened norms (n, 2) of the pose / motion pair blocks.

    The same equations as ``factors.process_factor``, ``body_factor``,
    ``mount_walk_factors``, ``pose_pair_factor``, ``motion_pair_factor``, ``speed_factor``
    and ``standstill_factors``. ``loss`` = (kind, threshold of the 4-dof pose block,
    threshold of the 3-dof motion block); ``speed_loss`` = (kind, threshold)."""
    n = len(prev)
    r = np.empty((n, PAIR_ROWS))
    jac = np.empty((n, PAIR_ROWS, 2 * FRAME_DIM))
    norms = np.empty((n, 2))
    _rows(
        np.ascontiguousarray(prev, dtype=float), np.ascontiguousarray(curr, dtype=float),
        c.dt, c.z, c.h0, c.motion_cov, c.given_red, c.given_jac, c.given_b, c.metric,
        c.w_process,
        c.process_jac, c.lin_jac, c.lin_b, _loss_code(loss[0]), float(loss[1]), float(loss[2]),
        _loss_code(speed_loss[0]), float(speed_loss[1]), r, jac, norms,
    )
    return r, jac, norms


@kernel
def _rows(  # pragma: no cover (compiled)
    prev, curr, dt_, z, h0, motion_cov, given_red, given_jac, given_b, metric, w_process,
    process_jac, lin_jac, lin_b, loss, k4, k3, speed_loss, k_speed, r, jac, norms,
):
    """``stacked_rows``' loop over the pairs: fills r, jac, norms."""
    d = FRAME_DIM
    cols = 2 * d
    dyn_cols = (0, 1, 2, 4, _CURR, _CURR + 1)
    motion_cols = (0, 1, 2, _CURR, _CURR + 1, _CURR + 2, _CURR + 7, _CURR + 8)
    jm = np.empty((3, 8))
    both = np.empty(cols)
    dyn = np.empty((2, 6))
    e = np.empty(5)
    j3 = np.zeros((3, cols))
    given = np.empty(3)
    for k in range(prev.shape[0]):
        both[:d] = prev[k]
        both[d:] = curr[k]
        # the linear rows (whitened once in pair_constants)
        for i in range(PAIR_ROWS):
            acc = -lin_b[k, i]
            for c in range(cols):
                jac[k, i, c] = lin_jac[k, i, c]
                acc += lin_jac[k, i, c] * both[c]
            r[k, i] = acc
        # process: model.propagate_pose, residual along / across the mid-point heading
        process_residual(prev[k, 0], prev[k, 1], prev[k, 2], prev[k, 3], prev[k, 4],
                         curr[k, 0], curr[k, 1], curr[k, 2], curr[k, 3], curr[k, 4], dt_[k],
                         e, dyn)
        for i in range(5):
            acc = 0.0
            for j in range(5):
                acc += w_process[k, i, j] * e[j]
            r[k, i] = acc
            for c in range(cols):
                jac[k, i, c] = process_jac[k, i, c]
            for j in range(6):
                jac[k, i, dyn_cols[j]] += (
                    w_process[k, i, 0] * dyn[0, j] + w_process[k, i, 1] * dyn[1, j]
                )
        # motion pair: displacement in G_{k-1} scaled by h0 / h_m
        motion_residual(prev[k, 0], prev[k, 1], prev[k, 2], curr[k, 0], curr[k, 1], curr[k, 2],
                        curr[k, 7], curr[k, 8], h0[k], z[k], metric[k], e, jm)
        for i in range(3):
            for j in range(8):
                j3[i, motion_cols[j]] = jm[i, j]
        # the motion given the angles as far as the pose block is trusted: its robust weight w
        # inflates the angles' covariance by 1/w, which scales A by w and gives back w·(the
        # covariance the angles explained)
        pose_sq = 0.0
        for i in range(11, 15):
            pose_sq += r[k, i] * r[k, i]
        norms[k, 0] = math.sqrt(pose_sq)
        w_pose = robust_weight(norms[k, 0], loss, k4)
        if motion_cov[k, 0, 0] > 0.0:
            for i in range(3):
                acc = -given_b[k, i]
                for c in range(cols):
                    acc += given_jac[k, i, c] * both[c]
                given[i] = acc
            whiten_motion_given_pose(e, j3, given, given_jac[k], w_pose, motion_cov[k],
                                     given_red[k], r[k, 15:18], jac[k, 15:18])
        else:  # no pair: no rows
            r[k, 15:18] = 0.0
            jac[k, 15:18] = 0.0
        # robust weights (IRLS, as gtsam's noiseModel.Robust) of the pair blocks and the speed
        motion_sq = r[k, 15] ** 2 + r[k, 16] ** 2 + r[k, 17] ** 2
        norms[k, 1] = math.sqrt(motion_sq)
        s_pose = math.sqrt(w_pose)
        s_motion = math.sqrt(robust_weight(norms[k, 1], loss, k3))
        s_speed = math.sqrt(robust_weight(abs(r[k, SPEED_ROW]), speed_loss, k_speed))
        for i in range(11, 19):
            s = s_pose if i < 15 else (s_motion if i < 18 else s_speed)
            r[k, i] *= s
            for c in range(cols):
                jac[k, i, c] *= s
