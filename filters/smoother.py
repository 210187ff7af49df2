"""Factor-graph smoother (gtsam) of the two-frame measurements: the EKF's model, all data.

The graph is the model of ``filters.model`` written as factors (``filters.factors``): per
frame k the vehicle pose X_k (Pose2), speed V_k and yaw rate W_k, mount angles M_k, height
H_k and yaw offset Y_k, body B_k; pair factors (angles, and motion scaled by height),
constant-velocity process factors, Gauss–Markov body factors, mount random walks, wheel-speed
priors, and priors on frame 0 (the EKF's). Pair factors use a redescending robust loss
(Geman–McClure by default, started from the Huber solution), so an outlier pair is
down-weighted instead of pulling the estimate.

- ``smooth_batch``: the whole drive at once (gtsam's iSAM2 relinearising every variable at
  every update: Gauss–Newton, ``optimize``); marginal covariances of the graph linearised at
  the estimate by a block-tridiagonal sweep (``block_marginals``: equal to
  ``gtsam.Marginals``, in O(n)).
- ``FixedLagSmoother`` (``filters.fixed_lag``): the same factors on gtsam's
  ``IncrementalFixedLagSmoother`` over a window of ``lag_s`` seconds; each frame is reported
  once ``lag_s`` of later data is in, with its joint marginal covariance (iSAM2's).
- ``smoothing.smooth``: either, by ``SmootherConfig.lag_s`` (0 = batch).

Every frame gets a :class:`SmoothedFrame` with the fields of ``filters.ekf.FilterState``
(mount, frame pose, metric motion, 16-state and covariance in the model's layout), so the
EKF's metrics and table rows apply unchanged (``smoother_config``; marginals in
``smoother_marginals``); ``drive_summary.summarize_mount`` condenses a drive into the mean
mount with 95 % intervals and its drift.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from . import factors as F
from . import model as M
from .body_scale import BodyScale, pair_change
from .ekf import ExtrinsicsEKF
from .ekf_state import EkfConfig
from .model import NoiseParams
from .mount_change import across_jump, jump_variance
from .mount_steps import MountStep, mount_steps, mount_trend, usable_angles
from .smoother_config import SmoothedFrame, SmootherConfig, chi_norm
from .smoother_marginals import block_marginals, block_norms, state_covariances, states_of

FloatArray = NDArray[np.float64]


# --- shared pieces ----------------------------------------------------------------------------


def _usable_times(measurements: Sequence[PairMeasurement]) -> NDArray[np.bool_]:
    """Frames whose time is finite and after every earlier kept frame's."""
    keep = np.zeros(len(measurements), dtype=bool)
    last = -math.inf
    for i, m in enumerate(measurements):
        if math.isfinite(m.t) and m.t > last:
            keep[i] = True
            last = m.t
    return keep


@dataclass
class _Guess:
    """Initial values of the variables of consecutive frames (model coordinates)."""

    mount: FloatArray  # (2,)
    height: float
    yaw_m: float
    body: FloatArray  # (n, 2)
    speed: FloatArray  # (n,)
    yaw_rate: FloatArray  # (n,)
    pose: FloatArray  # (n, 3) x, y, psi
    wheel_speed: FloatArray  # (n,) the readings as signed speeds (model.signed_speed), NaN: none
    direction: float  # direction of travel at the last frame (model.travel_direction)


def _interp_missing(values: FloatArray, fallback: float = 0.0) -> FloatArray:
    good = np.isfinite(values)
    if not np.any(good):
        return np.full(len(values), fallback)
    idx = np.arange(len(values))
    return np.interp(idx, idx[good], values[good])


def _initial_guess(
    ms: Sequence[PairMeasurement],
    speeds: FloatArray,
    dts: FloatArray,
    h_nominal: float,
    start: tuple[float, float, float] = (0.0, 0.0, 0.0),
    noise: NoiseParams | None = None,
) -> _Guess:
    """Initial values from the measurements: medians for the mount, dead reckoning for the
    poses (height from the wheel speed where there is one; with ``noise``, speed / yaw rate 0
    where ``model.standstill_states`` says the vehicle stands). ``dts[0]`` is unused."""
    n = len(ms)
    z = np.array([m.z if m.ok else np.full(7, np.nan) for m in ms], dtype=float).reshape(n, 7)
    h0 = np.array([m.height_assumed for m in ms], dtype=float)
    ok = np.all(np.isfinite(z), axis=1)
    if np.any(ok):
        mount = np.array(
            [np.median(0.5 * (z[ok, 0] + z[ok, 2])), np.median(0.5 * (z[ok, 1] + z[ok, 3]))]
        )
    else:
        mount = np.zeros(2)
    travel = np.hypot(z[:, 4], z[:, 5]) / h0  # in heights
    moving = ok & (travel > 1e-3)
    magnitude = np.abs(speeds)
    sel = moving & np.isfinite(speeds) & (magnitude > 0.5)
    sel[0] = False
    height = (float(np.median(magnitude[sel] * dts[sel] / travel[sel])) if sel.sum() >= 3
              else h_nominal)
    if not 0.5 * h_nominal < height < 2.0 * h_nominal:
        height = h_nominal
    # the camera's heading off the axis of travel, either way along it (reversing)
    sign = M.travel_sign(z)
    yaw_m = (float(np.median(np.arctan2(-sign[moving] * z[moving, 4], np.abs(z[moving, 5]))))
             if np.any(moving) else 0.0)
    body = np.where(ok[:, None], z[:, 2:4] - mount, 0.0)
    safe_dt = np.where(dts > 0, dts, np.nan)
    v = _interp_missing(np.where(ok, sign * travel * height / safe_dt, np.nan))
    direction = M.initial_direction(z[ok][:10], speeds[ok][:10])
    wheel = np.empty(n)
    for k, reading in enumerate(speeds):
        direction = M.travel_direction(direction, float(reading), z[k] if ok[k] else None)
        wheel[k] = M.signed_speed(float(reading), direction)
    v = np.where(np.isfinite(wheel), wheel, v)
    w = _interp_missing(np.where(ok, z[:, 6] / safe_dt, np.nan))
    if noise is not None:
        for k, m in enumerate(ms):
            for i in M.standstill_states(float(speeds[k]), m.status, noise):
                (v if i == M.SPEED else w)[k] = 0.0
    # dead reckoning: measured motion where there is a pair, the model's prediction elsewhere
    pose = np.zeros((n, 3))
    pose[0] = start
    for k in range(1, n):
        x, y, psi = pose[k - 1]
        if ok[k]:
            pose[k] = dead_reckoned((x, y, psi), height, yaw_m, ms[k])
        else:
            pose[k] = M.propagate_pose(x, y, psi, v[k - 1], w[k - 1], dts[k])
    return _Guess(mount, height, yaw_m, body, v, w, pose, wheel, direction)


def dead_reckoned(
    pose: tuple[float, float, float], height: float, yaw_m: float, m: PairMeasurement
) -> tuple[float, float, float]:
    """World pose (x, y, ψ) of frame k from frame k-1's ``pose`` and the pair's measured
    motion (tx, tz at h0, yaw) at mount height ``height`` (m) and yaw offset ``yaw_m`` (rad):
    ``model.expected_pair`` solved for frame k's pose."""
    x, y, psi = pose
    scale = height / m.height_assumed
    tx, tz = m.z[4] * scale, m.z[5] * scale
    c, s = math.cos(psi + yaw_m), math.sin(psi + yaw_m)
    return x + c * tx + s * tz, y - s * tx + c * tz, psi + m.z[6]


def _insert_guess(values: gtsam.Values, k: int, guess: _Guess, i: int) -> None:
    """Insert frame k's initial values (row ``i`` of ``guess``)."""
    values.insert(F.key("X", k), F.pose2_from_model(*guess.pose[i]))
    values.insert(F.key("V", k), np.array([guess.speed[i]], dtype=float))
    values.insert(F.key("W", k), np.array([guess.yaw_rate[i]], dtype=float))
    values.insert(F.key("M", k), np.array(guess.mount, dtype=float))
    values.insert(F.key("H", k), np.array([guess.height], dtype=float))
    values.insert(F.key("Y", k), np.array([guess.yaw_m], dtype=float))
    values.insert(F.key("B", k), np.array(guess.body[i], dtype=float))


def _prior_factors(
    k: int, guess: _Guess, cfg: SmootherConfig, pose: tuple[float, float, float] = (0, 0, 0)
) -> list[gtsam.NonlinearFactor]:
    """Priors of the first frame: the EKF's initial covariance around the initial guess
    (mount angles, speed, yaw rate), the nominal height and a zero yaw offset; the world
    frame is the first vehicle pose."""
    nz = cfg.noise
    iso = gtsam.noiseModel.Isotropic.Sigma
    return [
        gtsam.PriorFactorPose2(F.key("X", k), F.pose2_from_model(*pose), iso(3, 1e-3)),
        gtsam.PriorFactorVector(
            F.key("M", k), np.array(guess.mount), iso(2, math.radians(nz.prior_mount_angle_std_deg))
        ),
        gtsam.PriorFactorVector(
            F.key("H", k), np.array([cfg.height_m]), iso(1, nz.prior_height_std_rel * cfg.height_m)
        ),
        gtsam.PriorFactorVector(
            F.key("Y", k), np.zeros(1), iso(1, math.radians(nz.prior_mount_yaw_std_deg))
        ),
        gtsam.PriorFactorVector(
            F.key("B", k), np.zeros(2), iso(2, math.radians(nz.initial_body_std_deg))
        ),
        gtsam.PriorFactorVector(
            F.key("V", k), np.array([guess.speed[0]]), iso(1, nz.prior_speed_std_mps)
        ),
        gtsam.PriorFactorVector(
            F.key("W", k),
            np.array([guess.yaw_rate[0]]),
            iso(1, math.radians(nz.prior_yaw_rate_std_dps)),
        ),
    ]


def _frame_factors(
    k: int,
    m: PairMeasurement,
    speed: float,
    dt: float,
    cfg: SmootherConfig,
    first: bool,
    metric: bool = True,
    body_std: FloatArray | None = None,
    mount_jump_var: FloatArray | None = None,
    with_pair: bool = True,
) -> list[gtsam.NonlinearFactor]:
    """Factors that frame k (key index) adds: process, body (std ``body_std``, rad; None: the
    model's), mount walk (unless ``first``; ``mount_jump_var``: see ``mount_walk_factors``),
    the pair (``pair_factors``; at 5 and 6, if usable, not ``first`` and ``with_pair``), the
    wheel speed (if finite) and the standstill (``model.standstill_states``)."""
    nz = cfg.noise
    out: list[gtsam.NonlinearFactor] = []
    if not first:
        out.append(F.process_factor(k, dt, nz, cfg.cross_track_std_m))
        out.append(F.body_factor(k, dt, nz, body_std))
        out.extend(F.mount_walk_factors(k, dt, nz, mount_jump_var))
        if with_pair:
            out.extend(pair_factors(k, m, cfg, metric, mount_jump_var))
    if math.isfinite(speed):
        out.append(F.speed_factor(k, speed, nz, cfg.speed_loss, cfg.loss_k(1)))
    out.extend(F.standstill_factors(k, M.standstill_states(speed, m.status, nz), nz))
    return out


def pair_factors(
    k: int, m: PairMeasurement, cfg: SmootherConfig, metric: bool = True,
    mount_jump_var: FloatArray | None = None,
) -> list[gtsam.NonlinearFactor]:
    """Pair ``m``'s angle and motion factors at key index ``k`` under ``cfg.loss`` (none if the
    pair is not usable); ``metric``: see ``motion_pair_factor``; ``mount_jump_var``: the
    mount's jump variance within the pair (``across_jump``), None if none."""
    if not m.ok:
        return []
    cov = cfg.noise.pair_covariance(m.covariance, m.z[6])
    if mount_jump_var is not None:
        cov = across_jump(cov, mount_jump_var)
    given = None
    if cfg.motion_given_pose:
        given = F.GivenPose.of_pair(cov, m.z[:4], cfg.loss, cfg.pair_loss_k(4))
    return [
        F.pose_pair_factor(k, m.z[:4], cov[:4, :4], cfg.loss, cfg.pair_loss_k(4)),
        F.motion_pair_factor(k, m.z[4:7], cov[4:7, 4:7], m.height_assumed, cfg.loss,
                             cfg.pair_loss_k(3), metric, given),
    ]


#: an offline step this close to a change the EKF's test found [s] is that change (the
#: CUSUM alarms a little after it)
SAME_CHANGE_S = 2.0


def mount_jumps(
    ms: Sequence[PairMeasurement], speeds: FloatArray, cfg: SmootherConfig,
    offline: list[list[MountStep]] | None = None,
) -> dict[int, FloatArray]:
    """Where the mount stepped (a knocked camera): the EKF's mount-change test
    (``filters.mount_change``) run over the drive, and the offline test on the pairs' angles
    (``offline``: :func:`offline_steps`, found here where not given) for steps the EKF's
    body took up before its test saw them; key index → variance (pitch, roll; rad²) to add
    to the mount's walk into that frame (``mount_change.jump_variance``) on the axis that
    stepped."""
    t = np.array([m.t for m in ms])
    changes: list[tuple[float, int, float]] = []
    if cfg.mount_change.enabled:
        ekf = ExtrinsicsEKF(EkfConfig(height_m=cfg.height_m, noise=cfg.noise,
                                      mount_change=cfg.mount_change,
                                      mount_steps=cfg.mount_steps), widen_pose=False)
        for m, v in zip(ms, speeds, strict=True):
            ekf.step(m, m.t, float(v), m.frame)
        changes = persistent_changes(ekf.mount_changes, cfg.mount_change_persist_s)
    for axis, found in enumerate(offline_steps(ms, cfg) if offline is None else offline):
        near = [onset for onset, a, _ in changes if a == axis]
        changes += [(s.onset_s, axis, s.step) for s in found
                    if all(abs(s.onset_s - o) > SAME_CHANGE_S for o in near)]
    out: dict[int, FloatArray] = {}
    for onset, axis, step in changes:
        k = max(1, int(np.searchsorted(t, onset)))
        out.setdefault(k, np.zeros(2))[axis] += jump_variance(step)
    return out


def mount_creep(ms: Sequence[PairMeasurement], cfg: SmootherConfig,
                offline: list[list[MountStep]]) -> FloatArray:
    """(n, 2) variance (pitch, roll; rad²) to add to the mount's walk into each frame where
    the pairs' angle drifts (``mount_steps.mount_trend``, within the segments the steps
    ``offline`` found leave): the drift over ``trend_walk_s`` per that time, so that the
    walk can follow a creeping mount; zero elsewhere."""
    out = np.zeros((len(ms), 2))
    if not cfg.mount_steps.enabled:
        return out
    t_usable, angles = usable_angles(ms)
    t = np.array([m.t for m in ms])
    for axis, found in enumerate(offline):
        slope = mount_trend(t_usable, angles[:, axis], found, cfg.mount_steps)
        if slope is not None:
            out[1:, axis] = slope ** 2 * cfg.mount_steps.trend_walk_s * np.diff(t)
    return out


def offline_steps(ms: Sequence[PairMeasurement], cfg: SmootherConfig) -> list[list[MountStep]]:
    """Per axis (pitch, roll) the steps ``mount_steps`` finds in the usable pairs' angle of
    their current frame (none where the test is off or fewer than 3 pairs are usable)."""
    t, angles = usable_angles(ms)
    if not cfg.mount_steps.enabled or len(t) < 3:
        return [[], []]
    return [mount_steps(t, angles[:, axis], cfg.mount_steps) for axis in (0, 1)]


def persistent_changes(
    changes: list[tuple[float, int, float]], persist_s: float
) -> list[tuple[float, int, float]]:
    """The mount changes (onset s, axis, step rad) that last: a change undone on its axis by
    one of the other sign within ``persist_s`` seconds was a burst of bad pairs, not a
    knock, and both are dropped (offline, the batch can see that; the EKF cannot)."""
    keep = list(changes)
    i = 0
    while i < len(keep):
        t0, axis, step = keep[i]
        back = next((j for j in range(i + 1, len(keep)) if keep[j][1] == axis), None)
        if (back is not None and keep[back][0] - t0 <= persist_s
                and np.sign(keep[back][2]) == -np.sign(step)):
            del keep[back], keep[i]
            continue
        i += 1
    return keep


class BodyTracker:
    """The smoothers' adaptive body std (``body_scale.BodyScale`` on the pairs' pitch/roll,
    their changes and variances): feed every frame in time order."""

    def __init__(self, cfg: SmootherConfig) -> None:
        self._noise = cfg.noise
        self._scale = BodyScale(cfg.noise, cfg.body_window_s, cfg.body_window_min_pairs)
        self._min_pairs = cfg.body_window_min_pairs if cfg.body_window_s > 0 else 0
        self._t_last = math.nan  # time of the frame before (pairs join consecutive frames)

    def observe(self, m: PairMeasurement) -> FloatArray:
        """Add frame ``m``'s pair (if usable); the body std (pitch, roll, rad) at its time."""
        if m.ok:
            cov = self._noise.pair_covariance(m.covariance, m.z[6])
            self._scale.add(m.t, m.z[2:4], np.diag(cov)[2:4], *pair_change(m.z, cov),
                            m.t - self._t_last)
        self._t_last = m.t
        return self._scale.std()

    def stds(self, measurements: Sequence[PairMeasurement]) -> FloatArray:
        """(n, 2) body std of every frame of a whole drive (rad): the trailing window's, and
        for the frames before the window first held enough pairs to measure the shaking,
        the std at that point (a batch may look ahead; ``observe`` alone would give them the
        'unknown' std)."""
        out = np.empty((len(measurements), 2))
        counts = np.empty(len(measurements), dtype=np.int64)
        for k, m in enumerate(measurements):
            out[k] = self.observe(m)
            counts[k] = self._scale.pairs
        known = np.flatnonzero(counts >= self._min_pairs)
        if len(known):
            out[: known[0]] = out[known[0]]
        return out


def _metric_frames(t: FloatArray, speeds: FloatArray, timeout_s: float) -> NDArray[np.bool_]:
    """Frames with a wheel speed within ``timeout_s`` (either side): their pairs move h."""
    ts = t[np.isfinite(speeds)]
    if len(ts) == 0:
        return np.zeros(len(t), dtype=bool)
    j = np.clip(np.searchsorted(ts, t), 1, max(len(ts) - 1, 1))
    near = np.minimum(np.abs(t - ts[j - 1]), np.abs(ts[np.minimum(j, len(ts) - 1)] - t))
    return near <= timeout_s


def _make_frames(
    ms: Sequence[PairMeasurement],
    states: FloatArray,
    covs: FloatArray,
    statuses: Sequence[str],
    gated: Sequence[str] | None = None,
    reasons: Sequence[str] | None = None,
    standstill: Sequence[bool] | None = None,
) -> list[SmoothedFrame]:
    """Frames from n states (n, 16) and covariances (n, 16, 16) in the model's layout (NaN
    where unknown: a frame without a previous one has NaN prev slots), vectorised."""
    n = len(ms)
    states = np.asarray(states, dtype=float).reshape(n, M.STATE_DIM)
    covs = np.asarray(covs, dtype=float).reshape(n, M.STATE_DIM, M.STATE_DIM)
    finite_cov = np.isfinite(covs)
    cov0 = np.where(finite_cov, covs, 0.0)
    state0 = np.where(np.isfinite(states), states, 0.0)
    pose, jp = M.frame_pose(state0)
    pose = np.where(np.isfinite(states[:, [0, 1, 2]]), pose, np.nan)
    pose_ok = finite_cov[:, :6, :6].all(axis=(1, 2))
    pose_cov = np.where(pose_ok[:, None, None], jp @ cov0 @ jp.T, np.nan)
    has_prev = np.isfinite(states[:, M.PREV_POSE]).all(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):  # frames without a state: masked below
        motion, jm = M.metric_motion(state0)
    motion_cov = jm @ cov0 @ np.swapaxes(jm, 1, 2)
    motion[~has_prev] = np.nan
    motion_cov[~has_prev] = np.nan
    gated = gated if gated is not None else [""] * n
    reasons = reasons if reasons is not None else [""] * n
    standstill = standstill if standstill is not None else [False] * n
    return [
        SmoothedFrame(
            frame=m.frame,
            t=m.t,
            status=statuses[i],
            mount=states[i, M.MOUNT].copy(),
            mount_cov=covs[i, M.MOUNT, M.MOUNT].copy(),
            mount_yaw=float(states[i, M.MOUNT_YAW]),
            pose=pose[i],
            pose_cov=pose_cov[i],
            motion=motion[i],
            motion_cov=motion_cov[i],
            speed=float(states[i, M.SPEED]),
            yaw_rate=float(states[i, M.YAW_RATE]),
            position=states[i, [M.POS_X, M.POS_Y]],
            heading=float(states[i, M.HEADING]),
            state=states[i],
            covariance=covs[i],
            gated=gated[i],
            reason=reasons[i],
            standstill=bool(standstill[i]),
        )
        for i, m in enumerate(ms)
    ]


def _make_frame(
    m: PairMeasurement,
    state: FloatArray,
    cov: FloatArray,
    status: str,
    gated: str = "",
    reason: str = "",
    standstill: bool = False,
) -> SmoothedFrame:
    """One frame of ``_make_frames``."""
    return _make_frames([m], state, cov, [status], [gated], [reason], [standstill])[0]


def _skipped(m: PairMeasurement, why: str) -> SmoothedFrame:
    nan = np.full(M.STATE_DIM, np.nan)
    return _make_frame(m, nan, np.full((M.STATE_DIM, M.STATE_DIM), np.nan), "skipped", reason=why)


def _status(
    m: PairMeasurement, norms: tuple[float, float] | None, cfg: SmootherConfig
) -> tuple[str, str]:
    """(status, gated blocks) of a frame from its pair blocks' whitened norms."""
    if norms is None:
        return "predicted", ""
    gates = (chi_norm(cfg.report_probability, 4), chi_norm(cfg.report_probability, 3))
    rejected = [
        name for name, nrm, g in zip(("pose", "motion"), norms, gates, strict=True) if nrm > g
    ]
    status = {0: "ok", 1: "partial", 2: "gated"}[len(rejected)]
    return status, "+".join(rejected)


# --- batch ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class BatchInfo:
    """How a batch solve went: Gauss–Newton iterations (of both solves where the loss is
    started from the convex solution), the graph's error where its solve began (the
    initial guess, or the convex solution) and at the estimate, seconds per stage."""

    iterations: int
    initial_error: float
    final_error: float
    timings: dict[str, float]
    #: an interrupt came while the marginals were computed: the frames are the converged
    #: estimate without their covariances
    marginals_interrupted: bool = False


def _batch_graph(
    inputs: Sequence[tuple], guess: _Guess, cfg: SmootherConfig, progress: bool = False
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values,
           dict[int, tuple[gtsam.CustomFactor, gtsam.CustomFactor]],
           list[gtsam.NonlinearFactor]]:
    """The drive's graph, its initial values (``guess``), each pair's factors (key index →
    angle and motion factors) and every other factor; ``inputs`` per frame: (measurement,
    wheel speed, dt, first, metric, body std, mount jump variance), as ``_frame_factors``
    takes them."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    pairs: dict[int, tuple[gtsam.CustomFactor, gtsam.CustomFactor]] = {}
    shared: list[gtsam.NonlinearFactor] = []
    frames: Iterable[tuple[int, tuple]] = enumerate(inputs)
    if progress:
        from vipm_track.progress import progress_bar

        frames = progress_bar(frames, total=len(inputs), desc="smoother: graph", unit="frame")
    for k, (m, speed, dt, first, metric, body_std, jump) in frames:
        _insert_guess(values, k, guess, k)
        fs = _frame_factors(k, m, speed, dt, cfg, first, metric, body_std, jump,
                            with_pair=False)
        if first:
            fs = _prior_factors(k, guess, cfg) + fs
        own = [] if first else pair_factors(k, m, cfg, metric, jump)
        if own:
            pairs[k] = (own[0], own[1])
        shared.extend(fs)
        for f in fs + own:
            graph.add(f)
    return graph, values, pairs, shared


def with_pair_loss(
    shared: Iterable[gtsam.NonlinearFactor],
    pairs: Iterable[tuple[int, PairMeasurement, bool, FloatArray | None]],
    cfg: SmootherConfig,
) -> gtsam.NonlinearFactorGraph:
    """The graph of the ``shared`` factors and the ``pairs`` (key index, measurement,
    metric, mount jump variance: ``pair_factors``' arguments) under ``cfg.loss``."""
    graph = gtsam.NonlinearFactorGraph()
    for f in shared:
        graph.add(f)
    for k, m, metric, jump in pairs:
        for f in pair_factors(k, m, cfg, metric, jump):
            graph.add(f)
    return graph


def smooth_batch(
    measurements: Sequence[PairMeasurement],
    speeds: FloatArray | None = None,
    config: SmootherConfig | None = None,
    progress: bool = False,
) -> tuple[list[SmoothedFrame], BatchInfo]:
    """Smooth a whole drive: one :class:`SmoothedFrame` per measurement (in order). A pair
    loss that is not convex is started from Gauss–Newton steps with the Huber loss
    (``SmootherConfig.convex_start``).

    ``speeds``: wheel speed (m/s) at each measurement's time, NaN where none (see
    ``speeds_at_frames``)."""
    import time

    cfg = config or SmootherConfig()
    n_all = len(measurements)
    speeds_all = np.full(n_all, np.nan) if speeds is None else np.asarray(speeds, dtype=float)
    if len(speeds_all) != n_all:
        raise ValueError(f"{len(speeds_all)} speeds for {n_all} measurements")
    keep = _usable_times(measurements)
    idx = np.flatnonzero(keep)
    if len(idx) == 0:
        return [_skipped(m, "time not usable") for m in measurements], BatchInfo(0, 0.0, 0.0, {})
    ms = [measurements[i] for i in idx]
    sp = speeds_all[idx]
    t = np.array([m.t for m in ms])
    dts = np.concatenate([[0.0], np.diff(t)])
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    guess = _initial_guess(ms, sp, dts, cfg.height_m, noise=cfg.noise)
    sp = guess.wheel_speed
    metric = _metric_frames(t, sp, cfg.speed_timeout_s)
    body_std = BodyTracker(cfg).stds(ms)
    offline = offline_steps(ms, cfg)
    walk = mount_creep(ms, cfg, offline)
    for k, jump in mount_jumps(ms, sp, cfg, offline).items():
        walk[k] += jump
    inputs = [(m, float(sp[k]), float(dts[k]), k == 0, bool(metric[k]), body_std[k],
               walk[k] if walk[k].any() else None) for k, m in enumerate(ms)]
    graph, values, pairs, shared = _batch_graph(inputs, guess, cfg, progress)
    stages = [(graph, cfg)]
    convex = cfg.convex_start()
    if convex is not None:
        frame_pairs = [(k, m, metric, jump) for k, (m, _, _, first, metric, _, jump)
                       in enumerate(inputs) if not first]
        stages.insert(0, (with_pair_loss(shared, frame_pairs, convex), convex))
    timings["build"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    bar = None
    if progress:
        from vipm_track.progress import progress_bar

        bar = progress_bar(total=cfg.max_iterations * len(stages),
                           desc="smoother: Gauss-Newton", unit="step")
    try:
        on_step = None if bar is None else lambda: bar.update(1)
        iters = 0
        for stage_graph, c in stages:
            values, n, e0, e1 = optimize(stage_graph, values, c, on_step)
            iters += n
    finally:
        if bar is not None:  # converged: the bar ends full
            bar.total = bar.n
            bar.refresh()
            bar.close()
    timings["optimize"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    n_kept = len(ms)
    states = states_of(values, n_kept)
    covs = np.full((n_kept, M.STATE_DIM, M.STATE_DIM), np.nan)
    interrupted = False
    if cfg.marginals:
        try:
            # the marginals are those of the graph linearised at the estimate
            # (gtsam.Marginals' definition; ``block_marginals`` reads them in O(n))
            sigma, cross = block_marginals(graph.linearize(values), len(ms))
            covs = state_covariances(states, sigma, cross)
        except KeyboardInterrupt:  # the estimate has converged: it is kept, without its σ
            interrupted = True
    norms = block_norms(pairs, values)
    statuses, gated, reasons, stills = [], [], [], []
    for k, m in enumerate(ms):
        status, g = _status(m, norms.get(k), cfg)
        statuses.append(status)
        gated.append(g)
        reasons.append("" if status != "predicted" else m.status)
        stills.append(bool(M.standstill_states(float(sp[k]), m.status, cfg.noise)))
    frames_kept = _make_frames(ms, states, covs, statuses, gated, reasons, stills)
    timings["output"] = time.perf_counter() - t0

    out: list[SmoothedFrame] = []
    j = 0
    for i, m in enumerate(measurements):
        if keep[i]:
            out.append(frames_kept[j])
            j += 1
        else:
            out.append(_skipped(m, f"time {m.t} not after the previous frame's"))
    return out, BatchInfo(iters, e0, e1, timings, interrupted)


def optimize(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    cfg: SmootherConfig,
    on_step: Callable[[], None] | None = None,
) -> tuple[gtsam.Values, int, float, float]:
    """``graph`` minimised from ``values`` by gtsam's iSAM2 (relinearising every variable at
    every update: Gauss–Newton steps, the robust losses by the noise models' reweighting):
    (values, iterations, initial and final error). It stops when a step's predicted decrease
    of the error is below ``cfg.tolerance`` relative or ``cfg.tolerance_chi2`` in χ² units,
    or after ``cfg.max_iterations``; ``on_step`` is called after every step (progress).

    Why iSAM2 and not gtsam's ``LevenbergMarquardtOptimizer``: those hand each Python
    ``CustomFactor`` callback a copy of every value of the graph (pybind11 copies a C++
    ``Values`` it has no Python object for), quadratic in the drive length
    (``scripts/results/bench_smoother.md``); iSAM2 linearises at one ``Values`` it keeps,
    and ``held_linearization_point`` gives that a Python object, so callbacks see it by
    reference."""
    isam = gtsam.ISAM2(_batch_params())
    err0 = float(graph.error(values))
    err = err0  # as the steps' linear models predict it (the graph's error costs a callback each)
    with held_linearization_point(isam):
        isam.update(graph, values)
        it = 1
        while True:
            if on_step is not None:
                on_step()
            decrease = float(isam.error(gtsam.VectorValues.Zero(isam.getDelta())))
            if (it >= cfg.max_iterations
                    or decrease <= max(cfg.tolerance * err, cfg.tolerance_chi2)):
                break
            isam.update()
            err -= decrease
            it += 1
    out = isam.calculateEstimate()
    return out, it, err0, float(graph.error(out))


def _batch_params() -> gtsam.ISAM2Params:
    """iSAM2 as a batch Gauss–Newton solver: every update relinearises every variable; QR
    elimination (Cholesky of the normal equations found a 2400-frame drive with
    ``motion_given_pose`` indeterminate: its pivots lose definiteness numerically)."""
    params = gtsam.ISAM2Params()
    params.setFactorization("QR")
    params.setRelinearizeThreshold(0.0)
    params.relinearizeSkip = 1
    return params


@contextmanager
def held_linearization_point(solver: gtsam.ISAM2 | gtsam.IncrementalFixedLagSmoother
                             ) -> Iterator[None]:
    """Hold a Python reference to ``solver``'s linearisation point while the block runs:
    pybind11 then passes that object to the ``CustomFactor`` callbacks instead of copying
    every value for each call (the point is one ``Values`` iSAM2 updates in place)."""
    ref = solver.getLinearizationPoint()
    try:
        yield
    finally:
        del ref
