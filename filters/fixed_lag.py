"""Fixed-lag smoother: the smoother's factor graph on gtsam's ``IncrementalFixedLagSmoother``.

The window holds the frames of the last ``lag_s`` seconds plus one anchor frame, with the
batch's factors (``smoother._frame_factors``: the same graph, frame by frame); iSAM2 solves it
incrementally and marginalises the frames that leave (gtsam's fixed-lag smoother). The
window opens on the bootstrap frames solved as the batch solves a drive (a loss that is not
convex started from steps with the Huber loss). Each new frame starts where its pair's
measured motion puts it (``smoother.dead_reckoned``, as the batch's initial guess;
``model.propagate_pose`` without a usable pair), its body where the window has the frame
before moved by the pair's change of pose; the window is updated (one iSAM2 update;
``lag_max_iterations`` allows more while one still predicts more than
``lag_tolerance_chi2``); a frame
is reported once ``lag_s`` of later data is in — up to :data:`MAX_HOLD_S` later while a
change of the mount builds up (:data:`HOLD_AT`) — with its joint marginal covariance with the
previous frame (iSAM2's ``jointMarginalCovariance``), and the frame before it leaves the
window at the next update.

Which frames leave is decided here, not by gtsam's clock: every key's timestamp is 1, and the
frames before the anchor get 0 at the update that should marginalise them (gtsam drops keys
more than its lag, 0.5, older than the newest).
"""

from __future__ import annotations

import math
import time

import gtsam
import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from . import factors as F
from . import model as M
from .body_scale import pairs_to_start
from .mount_change import MountChangeDetector, jump_variance
from .mount_steps import step_onset
from .smoother import (
    BodyTracker,
    _frame_factors,
    _initial_guess,
    _make_frame,
    _prior_factors,
    _skipped,
    _status,
    dead_reckoned,
    held_linearization_point,
    optimize,
    with_pair_loss,
)
from .smoother_config import SmoothedFrame, SmootherConfig
from .smoother_marginals import BLOCK_LETTERS, block_norms, state_covariances
from .step_watch import StepWatch

FloatArray = NDArray[np.float64]

#: a frame's variables as one vector: x, y (m), ψ (rad), v (m/s), ω (rad/s), pitch_m, roll_m
#: (rad), h_m (m), yaw_m, b_pitch, b_roll (rad)
_D = 11
# that vector → index in the model's 16-state
_STATE_OF_VAR = np.array(
    [M.POS_X, M.POS_Y, M.HEADING, M.SPEED, M.YAW_RATE, M.MOUNT_PITCH, M.MOUNT_ROLL,
     M.MOUNT_HEIGHT, M.MOUNT_YAW, M.BODY_PITCH, M.BODY_ROLL]
)
_KEEP, _DROP, _GTSAM_LAG = 1.0, 0.0, 0.5
#: the frames that left the window are marginalised this many at a time: marginalising the
#: oldest frame makes iSAM2 eliminate the whole window again (the oldest and the newest
#: frame are the two ends of its chain), so doing it at every frame costs a window's
#: elimination per frame; until then they stay in the graph, reported, still smoothed
MARGINALIZE_EVERY = 10


class SolveError(RuntimeError):
    """gtsam could not solve the window (a variable lost all constraints, or the numbers
    blew up)."""


def _params() -> gtsam.ISAM2Params:
    """iSAM2 of the window: every update relinearises every variable (the robust losses'
    weights follow the estimate). Thresholds that save callbacks cost accuracy: new data
    moves the mount and height of the whole window, so thresholds below what the pairs
    resolve relinearise nearly all anyway, and 100× larger ones (1e-4 rad on the mount)
    left a car drive's mount roll RMS 2.7 % worse (``docs/filters.md``)."""
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(0.0)
    params.relinearizeSkip = 1
    # QR, not the default Cholesky: marginalising ten frames of a wheel-speed drive (tight
    # height random walk next to metric speed factors) squares a condition number Cholesky
    # could not take ("indeterminate system" near a height, then a restart); its cost is
    # measured in docs/gtsam.md
    params.setFactorization("QR")
    return params


def _first_line(exc: Exception) -> str:
    """The first non-blank line of ``exc``'s message (gtsam's start with a newline), or its
    type's name."""
    return next((ln.strip() for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)


def _frame_vector(values: gtsam.Values, k: int) -> FloatArray:
    """Frame ``k``'s variables as the ``_D``-vector (module constants) from ``values``."""
    x, y, psi = F.model_from_pose2(values.atPose2(F.key("X", k)))
    out = np.empty(_D)
    out[0:3] = x, y, psi
    out[3] = values.atVector(F.key("V", k))[0]
    out[4] = values.atVector(F.key("W", k))[0]
    out[5:7] = values.atVector(F.key("M", k))
    out[7] = values.atVector(F.key("H", k))[0]
    out[8] = values.atVector(F.key("Y", k))[0]
    out[9:11] = values.atVector(F.key("B", k))
    return out


def _insert(values: gtsam.Values, k: int, x: FloatArray) -> None:
    """Insert frame ``k``'s variables from the ``_D``-vector ``x``."""
    values.insert(F.key("X", k), F.pose2_from_model(x[0], x[1], x[2]))
    for letter, part in (("V", x[3:4]), ("W", x[4:5]), ("M", x[5:7]), ("H", x[7:8]),
                         ("Y", x[8:9]), ("B", x[9:11])):
        values.insert(F.key(letter, k), np.array(part, dtype=float))


def _keys(k: int) -> list[int]:
    """Frame ``k``'s keys in the marginals' block order (``smoother_marginals``)."""
    return [F.key(c, k) for c in BLOCK_LETTERS]


def restart_pose(last: SmoothedFrame, m: PairMeasurement) -> tuple[float, float, float]:
    """World pose (x, y, ψ) at which a restarted window's first frame ``m`` starts: the last
    reported frame moved by ``m``'s pair where that agrees with the last speed and yaw rate
    (within 3σ of the pair's travel plus a fifth of the step), else moved by those: the pair
    has not been through the robust loss, and an outlier would shift the track for good."""
    pose = (float(last.position[0]), float(last.position[1]), float(last.heading))
    propagated = M.propagate_pose(*pose, last.speed, last.yaw_rate, m.t - last.t)
    if not m.ok:
        return propagated
    height = float(last.mount[2])
    paired = dead_reckoned(pose, height, last.mount_yaw, m)
    step = math.hypot(propagated[0] - pose[0], propagated[1] - pose[1])
    travel_std = float(np.hypot(*m.std[4:6])) * height / m.height_assumed
    gap = math.hypot(paired[0] - propagated[0], paired[1] - propagated[1])
    return paired if gap <= 3.0 * travel_std + 0.2 * step else propagated


#: while the mount-change test's statistic is past this share of its threshold (a change
#: building up, not yet called), frames are held up to ``MAX_HOLD_S`` [s] longer than the
#: lag: reported before the call, a knock's frames and those up to a lag before it had the
#: new mount taken for the old (a shaken car's 1° knock, called 3 s late: 0.2–0.3° off at
#: z 2–4 before it, 0.7° at z 13 after it). Where the test calls no change, a held frame
#: is reported as it was when due (with more look-ahead than its neighbours, the frames
#: where a hold began stepped by a knock the test never called, which the drive's summary
#: then took for a step of the mount)
HOLD_AT = 0.15
MAX_HOLD_S = 5.0


class FixedLagSmoother:
    """Sliding-window smoother over ``config.lag_s`` seconds. Feed frames with ``step``; it
    returns the frames that have ``lag_s`` of later data (smoothed with it; held up to
    :data:`MAX_HOLD_S` longer while a change of the mount builds up), oldest first;
    ``finish`` returns the rest, smoothed with the data there is."""

    def __init__(self, config: SmootherConfig | None = None) -> None:
        cfg = config or SmootherConfig(lag_s=2.0)
        if cfg.lag_s <= 0:
            raise ValueError("FixedLagSmoother needs lag_s > 0 (use smooth_batch for 0)")
        self._cfg = cfg
        self._start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._reset: tuple[int, str] | None = None
        #: frames before the window starts: (pair, wheel speed, body std)
        self._boot: list[tuple[PairMeasurement, float, FloatArray]] = []
        self._body = BodyTracker(cfg)
        self._start_pairs = pairs_to_start(cfg.init_pairs, cfg.body_window_s,
                                           cfg.body_window_min_pairs)
        self._mount_change = MountChangeDetector(cfg.mount_change)
        self._steps = StepWatch(cfg.mount_steps)
        #: the mount's jumps so far: (time s of the frame it jumped into, axis 0 pitch /
        #: 1 roll, step rad), as the EKF's ``mount_changes``
        self.mount_changes: list[tuple[float, int, float]] = []
        self._started = False
        self._t_last = -math.inf
        self._last_speed_t = -math.inf
        self._direction = 1.0  # of travel, model.travel_direction
        self._still: dict[int, bool] = {}  # frame → standstill, until the frame is emitted
        self._next_key = 0  # key index of the next frame (unique over restarts)
        #: seconds spent so far: "update" (iSAM2 updates, the factors' callbacks included),
        #: "marginals" (joint marginal covariances), "output" (the rest of reporting frames)
        self.timings: dict[str, float] = {"update": 0.0, "marginals": 0.0, "output": 0.0}
        self._clear()

    # --- public ------------------------------------------------------------------------------

    def step(self, m: PairMeasurement, speed: float = float("nan")) -> list[SmoothedFrame]:
        """Add frame ``m`` (with the wheel speed at its time, m/s, NaN if none); return the
        frames that are now final."""
        if not (math.isfinite(m.t) and m.t > self._t_last):
            return [_skipped(m, f"time {m.t} not after the previous frame's")]
        self._t_last = m.t
        self._still[m.frame] = bool(M.standstill_states(speed, m.status, self._cfg.noise))
        body_std = self._body.observe(m)
        if not self._started:
            self._boot.append((m, speed, body_std))
            if sum(b.ok for b, _, _ in self._boot[1:]) < self._start_pairs:
                return []
            boot, self._boot = self._boot, []
            return self._start(boot)
        graph, values, k = self._append(m, speed, body_std)
        try:
            self._solve(graph, values, [k], self._cfg.lag_max_iterations)
        except SolveError as exc:
            return self._restart(m, speed, body_std, exc)
        return self._emit(final=False)

    def finish(self) -> list[SmoothedFrame]:
        """Frames still in the window (and any never started), smoothed with the data there is."""
        if not self._started:
            if not self._boot:
                return []
            boot, self._boot = self._boot, []
            return self._start(boot, final=True)
        # the step watch tests once per block: its last test may have missed the last one
        jumped = sorted(set(self._watched_jumps(self._t_last, last=True)))
        if jumped:
            self._held.clear()
            graph = [(k, f) for k in jumped for f in self._frame_graph(k, self._added[k][0])]
            try:
                self._solve(graph, gtsam.Values(), [], self._cfg.lag_max_iterations)
            except SolveError:  # the window as last solved, as a restart reports it
                return self._emit(final=True, marginals=False)
        return self._emit(final=True)

    # --- window ------------------------------------------------------------------------------

    def _clear(self) -> None:
        self._smoother = gtsam.IncrementalFixedLagSmoother(_GTSAM_LAG, _params())
        self._ms: list[PairMeasurement] = []  # frames of the window, oldest first
        self._k: list[int] = []  # their key indices
        self._est = gtsam.Values()  # the window's estimate after the last solve
        self._newest = np.zeros(_D)  # the newest frame's variables in it
        #: key index → the factors its frame added (for a mount jump: removed, added again)
        #: as (inputs of smoother._frame_factors, factor indices in gtsam's graph)
        self._added: dict[int, tuple[tuple, list[int]]] = {}
        self._pairs: dict[int, tuple[gtsam.CustomFactor, gtsam.CustomFactor]] = {}
        self._emitted = 0  # frames of the window already reported (the anchor, if 1)
        self._drop: list[int] = []  # key indices to marginalise at the next update
        self._removed: list[int] = []  # factor indices to remove at the next update
        #: key index → a held frame as it was due to be reported (``HOLD_AT``)
        self._held: dict[int, SmoothedFrame] = {}

    def _frame_graph(self, k: int, args: tuple) -> list[gtsam.NonlinearFactor]:
        """``smoother._frame_factors`` of key index ``k`` with ``args``, its pair factors kept
        for the block norms."""
        fs = _frame_factors(k, *args)
        m, first = args[0], args[4]
        if not first and m.ok:
            self._pairs[k] = (fs[5], fs[6])
        return fs

    def _append(
        self, m: PairMeasurement, speed: float, body_std: FloatArray
    ) -> tuple[list[tuple[int, gtsam.NonlinearFactor]], gtsam.Values, int]:
        """Frame ``m``'s factors (tagged with its key index) and initial values, started from
        the newest frame moved by its pair (by the motion model without a usable pair);
        ``body_std``: its body std, rad."""
        prev_m, prev = self._ms[-1], self._newest
        dt = m.t - prev_m.t
        if math.isfinite(speed):
            self._last_speed_t = m.t
        metric = m.t - self._last_speed_t <= self._cfg.speed_timeout_s
        new = prev.copy()
        if m.ok:
            # the pair's own motion, as the batch's initial guess: a prediction from the last
            # speed and yaw rate can be so far off after a manoeuvre that the robust loss
            # rejects the pair, and every later one (the estimate locks onto the old motion)
            new[0:3] = dead_reckoned((prev[0], prev[1], prev[2]), prev[7], prev[8], m)
            new[3:5] = M.pair_rates(m.z, prev[7], m.height_assumed, dt)
            # the body moved by the pair's change of pose (what it measures best) from where
            # the window has frame k-1: set to the pair's own pose of frame k instead, the
            # change would miss by the two pairs' disagreement on frame k-1, and a
            # redescending loss would reject the pair at its first linearisation
            new[9:11] = prev[9:11] + (m.z[2:4] - m.z[0:2])
        else:
            new[0:3] = M.propagate_pose(prev[0], prev[1], prev[2], prev[3], prev[4], dt)
            new[9:11] = 0.0
        self._direction = M.travel_direction(self._direction, speed, m.z if m.ok else None)
        speed = M.signed_speed(speed, self._direction)
        if math.isfinite(speed):
            new[3] = speed
        for i in M.standstill_states(speed, m.status, self._cfg.noise):
            new[3 if i == M.SPEED else 4] = 0.0  # standing: start from the pseudo-measurement
        k = self._next_key
        self._next_key += 1
        args = (m, float(speed), float(dt), self._cfg, False, bool(metric), body_std, None)
        self._added[k] = (args, [])
        self._ms.append(m)
        self._k.append(k)
        jumped = self._watch_mount(m, dt, prev, body_std) if m.ok else []
        graph = [(j, f) for j in sorted({*jumped, k}) for f in self._frame_graph(
            j, self._added[j][0])]
        values = gtsam.Values()
        _insert(values, k, new)
        return graph, values, k

    def _watch_mount(
        self, m: PairMeasurement, dt: float, prev: FloatArray, body_std: FloatArray
    ) -> list[int]:
        """Feed the mount-change test (``filters.mount_change``) the newest pair's angles
        against the window's prediction (the newest frame's mount plus its decayed body), and
        the step test (``filters.step_watch``: a knock the first test missed) its angles; on
        a step, let the mount jump into the frame where it began (or the window's oldest
        pair, if that frame is final already): the key indices of the frames whose factors
        are to be added again with the jump (their old ones go at the next update)."""
        decay, _ = M.body_transition(dt, self._cfg.noise, body_std)
        cov = self._cfg.noise.pair_covariance(m.covariance, m.z[6])
        innovation = m.z[2:4] - (prev[5:7] + decay * prev[9:11])
        step = self._mount_change.update(m.t, innovation, body_std**2 + np.diag(cov)[2:4])
        out: list[int] = []
        for j in np.flatnonzero(np.isfinite(step)):
            # from lag_s before the test's evidence began: its start lags a step where the
            # window's mount and body took part of it up first (0.35 s on a shaken car)
            since = self._mount_change.onset[j]
            onset = self._step_onset(j, since - self._cfg.lag_s, since)
            self._steps.followed(onset, int(j))
            out.append(self._jump(int(j), onset, float(step[j])))
        self._steps.add(m.t, float(m.z[2]), float(m.z[3]))
        out += self._watched_jumps(m.t)
        if out:  # the held frames are reported as the window has them after the jump
            self._held.clear()
        return out

    def _watched_jumps(self, t: float, last: bool = False) -> list[int]:
        """Jumps at the steps the step watch finds at time ``t`` [s] (``StepWatch.due``):
        their frames' key indices."""
        out = []
        for j, onset, s in self._steps.due(t, last):
            # within the window: its least squares, as for the online test's (the split of
            # the test's partial sums can miss by a frame: 0.05° more error)
            if len(self._ms) > 1 and onset > self._ms[1].t:
                near = onset - self._cfg.mount_steps.min_segment_s
                onset = self._step_onset(j, max(near, self._ms[1].t), onset)
            out.append(self._jump(j, onset, s))
        return out

    def _jump(self, axis: int, onset: float, step: float) -> int:
        """Let the mount jump by ``step`` [rad] on ``axis`` into the frame at ``onset`` [s]
        (the window's oldest pair if that frame is final already): its key index."""
        # the frame's factors join it to the one before, which must still be in the window
        i = next((i for i in range(1, len(self._ms)) if self._ms[i].t >= onset),
                 len(self._ms) - 1)
        k = self._k[i]
        self.mount_changes.append((float(self._ms[i].t), axis, float(step)))
        args, indices = self._added[k]
        jump = np.zeros(2) if args[-1] is None else args[-1].copy()
        jump[axis] += jump_variance(step)
        self._removed.extend(indices)
        self._added[k] = ((*args[:-1], jump), [])
        return k

    def _step_onset(self, axis: int, after: float, fallback: float) -> float:
        """When the mount stepped on ``axis`` (0 pitch, 1 roll): the least-squares step of
        the window's pairs' angle among the cuts from ``after`` [s] on; ``fallback`` [s]
        where the window holds too few pairs or no such cut."""
        usable = [m for m in self._ms if m.ok and math.isfinite(m.z[2 + axis])]
        if len(usable) < 3:
            return fallback
        onset = step_onset(np.array([m.t for m in usable]),
                           np.array([m.z[2 + axis] for m in usable]), after)
        return onset if math.isfinite(onset) else fallback

    # --- start / restart -----------------------------------------------------------------------

    def _start(
        self, boot: list[tuple[PairMeasurement, float, FloatArray]], final: bool = False
    ) -> list[SmoothedFrame]:
        """Open a window on the bootstrap frames (the batch's initial guess), solve it (first
        with the Huber loss where the pair loss is not convex, as the batch)."""
        cfg = self._cfg
        ms = [b for b, _, _ in boot]
        sp = np.array([s for _, s, _ in boot], dtype=float)
        t = np.array([b.t for b in ms])
        dts = np.concatenate([[0.0], np.diff(t)])
        g = _initial_guess(ms, sp, dts, cfg.height_m, self._start_pose, cfg.noise)
        sp, self._direction = g.wheel_speed, g.direction
        self._clear()
        self._started = True
        graph: list[tuple[int, gtsam.NonlinearFactor]] = []
        values = gtsam.Values()
        keys = []
        for i, m in enumerate(ms):
            k = self._next_key
            self._next_key += 1
            x = np.concatenate([g.pose[i], [g.speed[i], g.yaw_rate[i]], g.mount,
                                [g.height, g.yaw_m], g.body[i]])
            _insert(values, k, x)
            if i == 0:
                graph += [(k, f) for f in _prior_factors(k, g, cfg, self._start_pose)]
            if math.isfinite(sp[i]):
                self._last_speed_t = float(t[i])
            metric = t[i] - self._last_speed_t <= cfg.speed_timeout_s
            # the bootstrap frames with the shaking all of them showed
            args = (m, float(sp[i]), float(dts[i]), cfg, i == 0, bool(metric), boot[-1][2],
                    None)
            graph += [(k, f) for f in self._frame_graph(k, args)]
            self._added[k] = (args, [])
            keys.append(k)
        self._ms, self._k = list(ms), keys
        for m in ms:  # the step watch's series starts with the drive, not the window
            if m.ok:
                self._steps.add(m.t, float(m.z[2]), float(m.z[3]))
        convex = cfg.convex_start()
        try:
            if convex is not None:
                t0 = time.perf_counter()
                paired = {id(f) for fs in self._pairs.values() for f in fs}
                boot_graph = with_pair_loss(
                    (f for _, f in graph if id(f) not in paired),
                    ((k, a[0], a[5], a[7]) for k, (a, _) in self._added.items() if not a[4]),
                    convex)
                try:
                    values = optimize(boot_graph, values, convex)[0]
                except RuntimeError as exc:  # as _solve: gtsam's indeterminate system
                    raise SolveError(_first_line(exc)) from None
                finally:
                    self.timings["update"] += time.perf_counter() - t0
            self._solve(graph, values, keys, cfg.max_iterations)
        except SolveError as exc:  # nothing to fall back on: report the frames as skipped
            self._started = False
            why = f"smoother could not start: {exc}"
            return [_skipped(b, why) for b in ms]
        return self._emit(final=final)

    def _restart(
        self, m: PairMeasurement, speed: float, body_std: FloatArray, exc: Exception
    ) -> list[SmoothedFrame]:
        """Emit the window from the last good solution (without covariances: gtsam's state
        after a failed update is not trusted), then start a new window at ``m``
        (bootstrapped again, continuing the trajectory), as the EKF resets."""
        why = f"smoother restarted: {exc}"
        self._ms.pop()  # m: its update failed
        self._k.pop()
        out = self._emit(final=True, marginals=False)
        good = [f for f in out if np.all(np.isfinite(f.position))]
        if good:
            self._start_pose = restart_pose(good[-1], m)
        self._reset = (m.frame, why)
        self._started = False
        self._boot = [(m, speed, body_std)]
        self._clear()
        return out

    # --- solving -------------------------------------------------------------------------------

    def _solve(
        self, tagged: list[tuple[int, gtsam.NonlinearFactor]], values: gtsam.Values,
        new_keys: list[int], max_iterations: int,
    ) -> None:
        """Add the ``tagged`` factors (key index of the frame that added each) and the new
        frames' ``values``, marginalise the frames before the anchor, and take iSAM2 steps
        until one predicts a decrease below ``lag_tolerance_chi2`` (at most
        ``max_iterations``)."""
        graph = gtsam.NonlinearFactorGraph()
        for _, f in tagged:
            graph.add(f)
        stamps = {key: _KEEP for k in new_keys for key in _keys(k)}
        drop = self._drop if len(self._drop) >= MARGINALIZE_EVERY else []
        stamps.update({key: _DROP for k in drop for key in _keys(k)})
        removed, self._removed = self._removed, []
        sm = self._smoother
        t0 = time.perf_counter()
        try:
            with held_linearization_point(sm):
                sm.update(graph, values, stamps, removed)
                indices = sm.getISAM2Result().getNewFactorsIndices()
                for _ in range(max_iterations - 1):
                    # the decrease the last update's linear step predicts: 0.5·|d|² of its
                    # Bayes tree R·δ = d, the tree's error at δ = 0
                    isam = sm.getISAM2()
                    if (float(isam.error(gtsam.VectorValues.Zero(isam.getDelta())))
                            <= self._cfg.lag_tolerance_chi2):
                        break
                    sm.update()
                self._est = sm.calculateEstimate()
        except RuntimeError as exc:  # gtsam's IndeterminantLinearSystemException and kin
            raise SolveError(_first_line(exc)) from None
        finally:
            self.timings["update"] += time.perf_counter() - t0
        for (k, _), index in zip(tagged, indices, strict=True):
            self._added[k][1].append(int(index))
        for k in drop:
            self._added.pop(k, None)
            self._pairs.pop(k, None)
        self._drop = self._drop[len(drop):]
        self._newest = _frame_vector(self._est, self._k[-1])

    def _joint_marginal(self, ks: list[int]) -> FloatArray:
        """Joint marginal covariance of the frames ``ks`` (key indices; blocks in the order of
        ``smoother_marginals``, Pose2 tangents)."""
        t0 = time.perf_counter()
        try:
            keys = [key for k in ks for key in _keys(k)]
            return np.asarray(self._smoother.getISAM2().jointMarginalCovariance(keys)
                              .fullMatrix())
        except RuntimeError as exc:
            raise SolveError(f"no marginal: {_first_line(exc)}") from None
        finally:
            self.timings["marginals"] += time.perf_counter() - t0

    # --- output --------------------------------------------------------------------------------

    def _emit(self, final: bool, marginals: bool = True) -> list[SmoothedFrame]:
        """Frames with ≥ ``lag_s`` of later data (all if ``final``), oldest first; the frames
        before the newest reported one leave the window at the next update (it stays as the
        anchor)."""
        t0 = time.perf_counter()
        marginals_before = self.timings["marginals"]
        out: list[SmoothedFrame] = []
        t_new = self._ms[-1].t if self._ms else -math.inf
        lag = self._cfg.lag_s
        holding = math.isfinite(self._mount_change.pending_since(HOLD_AT))
        while self._emitted < len(self._ms):
            i = self._emitted
            m = self._ms[i]
            if not final and t_new - m.t < lag:
                break
            if not final and holding and t_new - m.t < lag + MAX_HOLD_S:
                # held: as it would be reported now, should the test not call a change
                for j in range(i, len(self._ms)):
                    if t_new - self._ms[j].t < lag:
                        break
                    if self._k[j] not in self._held:
                        self._held[self._k[j]] = self._report(j, marginals)
                break
            held = self._held.pop(self._k[i], None)
            out.append(held if held is not None else self._report(i, marginals))
            self._emitted += 1
        # frames before the anchor (the newest reported one) leave at the next update
        anchor = self._emitted - 1
        if anchor > 0:
            self._drop += self._k[:anchor]
            del self._ms[:anchor], self._k[:anchor]
            self._emitted -= anchor
        self.timings["output"] += (time.perf_counter() - t0
                                   - (self.timings["marginals"] - marginals_before))
        return out

    def _report(self, i: int, marginals: bool) -> SmoothedFrame:
        """The window's frame ``i`` as the window's estimate has it now."""
        m = self._ms[i]
        ks = self._k[max(i - 1, 0) : i + 1]
        x = np.array([_frame_vector(self._est, k) for k in ks])
        states = np.full((len(ks), M.STATE_DIM), np.nan)
        states[:, _STATE_OF_VAR] = x
        if len(ks) == 2:
            states[1, M.PREV_POSE] = states[0, M.POSE]
            states[1, M.PREV_BODY] = states[0, M.BODY]
        cov, note = self._covariance(ks, states, marginals)
        k = ks[-1]
        if k in self._pairs and len(ks) == 2:
            norms = block_norms({k: self._pairs[k]}, self._est)[k]
        else:
            norms = None
        return self._frame(m, states[-1], cov, norms, note)

    def _covariance(
        self, ks: list[int], states: FloatArray, marginals: bool
    ) -> tuple[FloatArray, str]:
        """The 16×16 covariance (model layout) of the last of frames ``ks`` (itself, or its
        previous frame and itself) and an empty note, or NaN and a note saying why there is
        none."""
        nan = np.full((M.STATE_DIM, M.STATE_DIM), np.nan)
        if not (marginals and self._cfg.marginals):
            return nan, ""
        try:
            joint = self._joint_marginal(ks)
        except SolveError as exc:
            return nan, f"no covariance: {exc}"
        d = _D
        n = len(ks)
        sigma = np.array([joint[i * d:(i + 1) * d, i * d:(i + 1) * d] for i in range(n)])
        cross = joint[None, :d, d:] if n == 2 else np.zeros((0, d, d))
        return state_covariances(states, sigma, cross)[-1], ""

    def _frame(
        self,
        m: PairMeasurement,
        state: FloatArray,
        cov: FloatArray,
        norms: tuple[float, float] | None,
        note: str = "",
    ) -> SmoothedFrame:
        pair = norms if m.ok else None
        status, gated = _status(m, pair, self._cfg)
        reason = "" if pair else m.status
        if self._reset is not None and self._reset[0] == m.frame:
            status, reason = "reset", self._reset[1]
        if note:
            reason = f"{reason}; {note}" if reason else note
        return _make_frame(m, state, cov, status, gated, reason,
                           self._still.pop(m.frame, False))
