"""Extended Kalman filter over the two-frame measurements: mount extrinsics, body shaking and
planar motion (the model of ``filters.model``), on ``filterpy.kalman.ExtendedKalmanFilter``.

Feed it one frame at a time, read estimates back::

    ekf = ExtrinsicsEKF(EkfConfig(height_m=1.5))
    for m, v in zip(measurements, speeds):
        state = ekf.step(m, speed=v)      # FilterState: mount, frame pose, motion, NIS, ...

or ``run_filter(measurements, speed_series, config)`` for a whole sequence.

- Every call predicts to the frame time (stochastic cloning keeps frame k-1 for the pair).
- A wheel speed (m/s, already on the camera clock) updates the speed: h becomes observable.
- A pair whose status is not ``ok`` is skipped (the filter predicts through the gap).
- Standstill (``model.standstill_states``): a wheel speed ≈ 0, or without wheel speed a pair
  reported as "no motion", pins the yaw rate (and without wheel speed the speed) to 0, so the
  heading does not drift with the last yaw rate during a stop (``FilterState.standstill``).
- Mahalanobis gating, as robot_localization's rejection thresholds: the pose block (4 angles)
  and the motion block (tx, tz, yaw) of a pair are each rejected when their normalised
  innovation squared exceeds the chi-square quantile ``gate_probability`` (4 / 3 dof), so an
  unexpected manoeuvre costs the motion only; the same for a speed reading (1 dof). Between
  the gate and ``pose_soft_gate_factor`` / ``motion_soft_gate_factor`` /
  ``speed_soft_gate_factor`` times it a block (or reading) is applied down-weighted
  (covariance × NIS / gate) instead. ``nis`` reports the whole pair's 7-dof value.
- It never diverges silently: after each step the covariance must be finite, symmetric,
  positive semi-definite and its mount angle std below ``max_mount_angle_std_deg``; after
  ``max_consecutive_gated`` pairs in a row gated on pitch/roll the filter no longer agrees with
  the data. Either way it re-initialises from the next good pair (keeping the height estimate)
  and says why in ``reset_reason``. ``max_consecutive_motion_gated`` motion-gated pairs in a
  row restart only the speed, yaw rate, height and mount yaw; ``max_consecutive_speed_gated``
  wheel speeds gated in a row restart the speed at the reading and the height at its prior.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from numpy.typing import NDArray
from scipy.stats import chi2

from vipm_track.measurement import PairMeasurement

from . import model as M
from .body_scale import BodyScale, pair_change, pairs_to_start
from .ekf_state import EkfConfig, FilterState
from .heave import HeaveWidening
from .lever_arm import LeverArm
from .model import NoiseParams
from .mount_change import MountChangeDetector
from .row_correlation import PairErrorCorrelation
from .step_watch import StepWatch
from .wheel_speed import SpeedSource, interpolate_speed

FloatArray = NDArray[np.float64]


class _ClonedEKF(ExtendedKalmanFilter):
    """filterpy's EKF with the nonlinear, cloning transition of ``filters.model``."""

    def __init__(self, noise: NoiseParams) -> None:
        super().__init__(dim_x=M.STATE_DIM, dim_z=7)
        self.x = np.zeros(M.STATE_DIM)
        self._noise = noise
        self._dt = 0.0
        #: stationary body std (pitch, roll), rad: the model's unless adapted to the data
        self.body_std = np.full(2, np.radians(noise.body_std_deg))

    def predict_dt(self, dt: float) -> None:
        x_new, self.F, self.Q = M.transition(self.x, dt, self._noise)
        decay, var = M.body_transition(dt, self._noise, self.body_std)
        for j, i in enumerate((M.BODY_PITCH, M.BODY_ROLL)):
            x_new[i] = decay[j] * self.x[i]
            self.F[i, i] = decay[j]
            self.Q[i, i] = var[j]
        self._x_new = x_new
        self.predict()

    def predict_x(self, u: object = 0) -> None:
        self.x = self._x_new


class ExtrinsicsEKF:
    """Recursive estimate of mount extrinsics, body shaking and planar motion (module doc)."""

    def __init__(self, config: EkfConfig | None = None, widen_pose: bool = True,
                 speed_series: SpeedSource | None = None, clock_offset_s: float = 0.0) -> None:
        """``widen_pose``: widen each state's pose σ by the pairs' error correlation and its
        height σ by the body's heave, and add the camera's lever arms to its lateral motion
        (:meth:`step`); off where only the mount is read (it costs a sixth of a step).
        ``speed_series`` (camera clock after ``clock_offset_s``): the wheel speed the speeds
        given to :meth:`step` come from, whose distance between a pair's frames measures the
        heave (``heave.HeaveWidening``); None: the speeds given with the frames."""
        self._cfg = config or EkfConfig()
        if self._cfg.height_m <= 0:
            raise ValueError(f"nominal height must be > 0, got {self._cfg.height_m}")
        self._gate_pose = float(chi2.ppf(self._cfg.gate_probability, 4))
        self._gate_motion = float(chi2.ppf(self._cfg.gate_probability, 3))
        self._speed_gate = float(chi2.ppf(self._cfg.speed_gate_probability, 1))
        self._kf: _ClonedEKF | None = None
        self._t: float | None = None
        self._pose_gated_run = 0
        self._motion_gated_run = 0
        self._speed_gated_run = 0
        self._direction = 1.0  # of travel, model.travel_direction
        self._motion_note = ""
        self._pending_reset = ""
        #: bootstrap frames: (usable pair or None, wheel speed, dt, pair status)
        self._boot: list[tuple[PairMeasurement | None, float | None, float, str]] = []
        self._last_speed_t: float | None = None
        self._still = False  # the last _advance applied the standstill
        #: the body's shaking measured on recent ok pairs (``body_scale``)
        cfg = self._cfg
        self._body = BodyScale(cfg.noise, cfg.body_window_s, cfg.body_window_min_pairs)
        self._start_pairs = pairs_to_start(cfg.init_pairs, cfg.body_window_s,
                                           cfg.body_window_min_pairs)
        #: pairs up to this time are in the body window already (the bootstrap's)
        self._body_seen_t = -math.inf
        self._mount_change = MountChangeDetector(cfg.mount_change)
        self._steps = StepWatch(cfg.mount_steps)
        self._correlation = PairErrorCorrelation() if widen_pose else None
        self._heave = (HeaveWidening(self._cfg, speed_series, clock_offset_s) if widen_pose
                       else None)
        self._lever = LeverArm(self._cfg.noise.lever_arm_std_m) if widen_pose else None
        #: mount steps found so far: (onset time s, axis 0 pitch / 1 roll, step rad)
        self.mount_changes: list[tuple[float, int, float]] = []
        h0 = self._cfg.height_m
        self._height = (h0, (self._cfg.noise.prior_height_std_rel * h0) ** 2)

    @property
    def config(self) -> EkfConfig:
        return self._cfg

    @property
    def initialised(self) -> bool:
        return self._kf is not None

    def step(
        self,
        measurement: PairMeasurement | None,
        t: float | None = None,
        speed: float | None = None,
        frame: int | None = None,
    ) -> FilterState:
        """Advance to frame time ``t`` (default: the measurement's) and apply the pair
        ``measurement`` (skipped unless ok) and the wheel ``speed`` (m/s; None/NaN: none).
        The state's lateral motion takes the camera's lever arms (``lever_arm``), its pose and
        motion σ are widened by the pairs' error correlation (``row_correlation``) and its
        height σ by the body's heave (``heave``; the filter's own covariance is not), unless
        the filter was made without."""
        state = self._step(measurement, t, speed, frame)
        if self._correlation is None or self._heave is None or self._lever is None:
            return state
        state = self._lever.corrected(state, measurement)
        state = self._correlation.widened(state, measurement)
        return self._heave.widened(state, measurement,
                                   math.nan if speed is None else float(speed))

    def _step(self, measurement: PairMeasurement | None, t: float | None, speed: float | None,
              frame: int | None) -> FilterState:
        """:meth:`step`, before the pose σ is widened."""
        if t is None:
            if measurement is None:
                raise ValueError("step needs a time t when there is no measurement")
            t = measurement.t
        frame = measurement.frame if frame is None and measurement is not None else frame
        frame = -1 if frame is None else frame
        t = float(t)
        usable = measurement is not None and measurement.ok
        pair_status = "" if measurement is None else measurement.status
        if self._t is not None and t <= self._t:
            # a frame out of order: report it, change nothing
            return self._state(frame, t, "predicted" if self._kf else "waiting",
                               reset_reason="", note=f"time {t} not after {self._t}")
        dt = t - self._t if self._t is not None else self._cfg.default_dt_s
        self._t = t

        reason = ""
        if self._kf is None:
            # bootstrap: collect init_pairs good pairs (and enough to measure the body's
            # shaking), start from their medians (robust to an outlier among them), then run
            # them through the filter like any other frame, with the shaking they showed
            if not usable and not self._boot:
                return self._state(frame, t, "waiting")
            self._boot.append((measurement if usable else None, speed, dt, pair_status))
            if sum(b[0] is not None for b in self._boot) < self._start_pairs:
                return self._state(frame, t, "waiting")
            if self._pending_reset:
                reason = f"re-initialised after {self._pending_reset}"
            self._pending_reset = ""
            boot, self._boot = self._boot, []
            self._initialise(boot)
            for m, v, d, st in boot[:-1]:
                self._advance(m, v, d, st)
            if self._pending_reset:  # the start itself failed: try again on the next pairs
                problem = self._pending_reset
                self._reset(problem)
                return self._state(frame, t, "waiting", reset_reason=problem)
        status, nis, gated, speed_nis, speed_gated = self._advance(
            measurement if usable else None, speed, dt, pair_status
        )
        still = self._still
        if self._motion_note:
            reason = "; ".join(r for r in (reason, self._motion_note) if r)
            self._motion_note = ""

        problem = self._check()
        if problem:
            state = self._state(frame, t, "reset", nis=nis, gated=gated, speed_nis=speed_nis,
                                speed_gated=speed_gated, reset_reason=problem, standstill=still)
            self._reset(problem)
            return state
        return self._state(frame, t, status, nis=nis, gated=gated, speed_nis=speed_nis,
                           speed_gated=speed_gated, reset_reason=reason, standstill=still)

    def _advance(
        self, m: PairMeasurement | None, speed: float | None, dt: float, pair_status: str = ""
    ) -> tuple[str, float, str, float, bool]:
        """Predict over ``dt`` and apply the speed, the standstill (if the speed, or the pair
        status ``pair_status`` without one, says so) and the pair: (status, nis, gated blocks,
        speed NIS, speed gated)."""
        assert self._kf is not None
        self._kf.predict_dt(dt)
        speed_nis, speed_gated = float("nan"), False
        if speed is not None and np.isfinite(speed):
            self._direction = M.travel_direction(self._direction, float(speed),
                                                 None if m is None else m.z)
            speed = M.signed_speed(float(speed), self._direction)
            speed_nis, speed_gated = self._update_speed(speed)
        # a gated wheel speed says nothing, about standstill either
        still = M.standstill_states(
            None if speed_gated else speed, pair_status, self._cfg.noise
        )
        self._still = bool(still)
        if still:
            self._update_standstill(still)
        if m is None:
            return "predicted", float("nan"), "", speed_nis, speed_gated
        nis, gated = self._update_pair(m, dt)
        status = {"": "ok", "pose+motion": "gated"}.get(gated, "partial")
        return status, nis, gated, speed_nis, speed_gated

    # --- internals --------------------------------------------------------------------------

    def _initialise(
        self, boot: list[tuple[PairMeasurement | None, float | None, float, str]]
    ) -> None:
        """Start, at the frame before the first of ``boot`` (pairs, speeds, intervals), from
        the prior and the medians of the pairs' angles, speed and yaw rate."""
        nz = self._cfg.noise
        h_mean, h_var = self._height
        pairs = [(m, d) for m, _, d, _ in boot if m is not None]
        for m, d in pairs:
            self._body.add(m.t, *self._body_change(m), d)
        self._body_seen_t = pairs[-1][0].t
        zs = np.array([m.z for m, _ in pairs])
        dts = np.array([d for _, d in pairs])
        h0s = np.array([m.height_assumed for m, _ in pairs])
        travel = M.travel_sign(zs) * np.hypot(zs[:, 4], zs[:, 5]) * h_mean / h0s
        self._direction = M.initial_direction(
            zs, np.array([np.nan if v is None else v for m, v, _, _ in boot if m is not None],
                         dtype=float))
        speeds = np.array([M.signed_speed(v, self._direction)
                           for _, v, _, _ in boot if v is not None and np.isfinite(v)])
        x = np.zeros(M.STATE_DIM)
        x[M.MOUNT_PITCH] = float(np.median(0.5 * (zs[:, 0] + zs[:, 2])))
        x[M.MOUNT_ROLL] = float(np.median(0.5 * (zs[:, 1] + zs[:, 3])))
        x[M.MOUNT_HEIGHT] = h_mean
        x[M.SPEED] = float(np.median(speeds)) if len(speeds) else float(np.median(travel / dts))
        x[M.YAW_RATE] = float(np.median(zs[:, 6] / dts))
        p = np.zeros((M.STATE_DIM, M.STATE_DIM))
        ang = np.radians(nz.prior_mount_angle_std_deg) ** 2
        p[M.MOUNT_PITCH, M.MOUNT_PITCH] = p[M.MOUNT_ROLL, M.MOUNT_ROLL] = ang
        p[M.MOUNT_HEIGHT, M.MOUNT_HEIGHT] = h_var
        p[M.MOUNT_YAW, M.MOUNT_YAW] = np.radians(nz.prior_mount_yaw_std_deg) ** 2
        body = self._body.std() ** 2
        for j, i in enumerate((M.BODY_PITCH, M.BODY_ROLL)):
            p[i, i] = p[i + 2, i + 2] = body[j]
        cfg = self._cfg
        p[M.SPEED, M.SPEED] = _spread(
            speeds if len(speeds) else travel / dts, cfg.init_speed_std_min_mps,
            nz.prior_speed_std_mps) ** 2
        p[M.YAW_RATE, M.YAW_RATE] = _spread(
            zs[:, 6] / dts, np.radians(cfg.init_yaw_rate_std_min_dps),
            np.radians(nz.prior_yaw_rate_std_dps)) ** 2
        kf = _ClonedEKF(nz)
        kf.x, kf.P = x, p
        kf.body_std = self._body.std()
        self._kf = kf
        self._pose_gated_run = self._motion_gated_run = self._speed_gated_run = 0

    def _update_pair(self, m: PairMeasurement, dt: float) -> tuple[float, str]:
        """Gate and apply a pair; returns its 7-dof NIS and the rejected blocks
        ('' / 'pose' / 'motion' / 'pose+motion').

        The pose block (4 angles) and the motion block (tx, tz, yaw) are gated separately, so a
        manoeuvre the motion model did not expect costs the motion only, not the calibration.
        """
        kf = self._kf
        assert kf is not None
        zp, h = M.pair_measurement(kf.x, m.height_assumed)
        if not self._metric():
            # no metric speed lately: scale (h with v and the poses) is unobservable, and an
            # EKF would invent information along it from its moving linearisation point;
            # hold h where it is (its prior) instead
            h[:, M.MOUNT_HEIGHT] = 0.0
        r = self._cfg.noise.pair_covariance(m.covariance, m.z[6])
        # without the angle-motion correlations: the filter's predicted frame pose (body
        # predicted to decay) is no better than the pair's own, so correcting the motion by it
        # only adds the prediction's error (KITTI 07, distance error median 3.09 % without,
        # 4.26 % with, bias −2.0 % / −3.5 %); the smoothers, which know each frame's pose from
        # the pairs on both sides, use them (``model.motion_given_pose``)
        r[:4, 4:] = 0.0
        r[4:, :4] = 0.0
        y = m.z - zp
        y[6] = M.wrap_angle(y[6])
        s = h @ kf.P @ h.T + r
        step = self._mount_change.update(m.t, y[2:4], np.diag(s)[2:4])
        onset = self._mount_change.onset.copy()
        for j in np.flatnonzero(np.isfinite(step)):
            self._steps.followed(float(onset[j]), int(j))
        # a knock the online test missed (before it was armed, the body took it up): the
        # offline test on the pairs so far finds it, and the mount is re-opened as for a call
        self._steps.add(m.t, float(m.z[2]), float(m.z[3]))
        for j, at, d in self._steps.due(m.t):
            step[j], onset[j] = d, at
        if np.isfinite(step).any():
            self._reopen_mount(step, onset)
            s = h @ kf.P @ h.T + r
        nis = _mahalanobis(y, s)
        keep = []
        r = r.copy()
        cfg = self._cfg
        for block, gate, soft in ((_POSE_ROWS, self._gate_pose, cfg.pose_soft_gate_factor),
                                  (_MOTION_ROWS, self._gate_motion, cfg.motion_soft_gate_factor)):
            d2 = _mahalanobis(y[block], s[np.ix_(block, block)])
            if d2 <= gate:
                keep.extend(block)
            elif d2 <= soft * gate:
                # shaking or a manoeuvre (or an optimistic covariance) beyond the model, not an
                # outlier: down-weight rather than drop, or the estimate falls back on the
                # prediction
                r[np.ix_(block, block)] *= d2 / gate
                keep.extend(block)
        self._observe_body(m, dt)
        self._pose_gated_run = 0 if 0 in keep else self._pose_gated_run + 1
        self._motion_gated_run = 0 if 4 in keep else self._motion_gated_run + 1
        if keep:
            rows = np.array(keep)
            hk, zk, rk = h[rows], zp[rows], r[np.ix_(rows, rows)]
            residual = _pair_residual if 6 in keep else np.subtract
            kf.update(m.z[rows], lambda _x: hk, lambda _x: zk, R=rk, residual=residual)
        n = self._cfg.max_consecutive_gated
        if self._pose_gated_run >= n:
            self._pending_reset = f"{self._pose_gated_run} pairs in a row gated on pitch/roll"
        elif self._motion_gated_run >= self._cfg.max_consecutive_motion_gated:
            self._restart_motion(m, dt)
        rejected = [name for name, rows in (("pose", 0), ("motion", 4)) if rows not in keep]
        return nis, "+".join(rejected)

    def _reopen_mount(self, step: FloatArray, onset: FloatArray) -> None:
        """Re-open the mount angles for the found steps (pitch, roll; rad, NaN: none; begun at
        ``onset`` [s]), and say so in the frame's reason.

        The step's variance d² is added to the mount and to both bodies, each alone: whether
        the bodies took the step so far (the pairs' angles fitted) or the gate held it out,
        the next pairs set the frames' angles and the bodies' decay to zero then moves the
        mount (along (mount, −bodies) alone the frames' angles would stay pinned where a gate
        left them)."""
        kf = self._kf
        assert kf is not None
        notes = []
        axes = ((M.MOUNT_PITCH, M.BODY_PITCH, M.PREV_BODY_PITCH),
                (M.MOUNT_ROLL, M.BODY_ROLL, M.PREV_BODY_ROLL))
        for j, ((mount, body, prev), d) in enumerate(zip(axes, step, strict=True)):
            if np.isfinite(d):
                self.mount_changes.append((float(onset[j]), j, float(d)))
                kf.P[[mount, body, prev], [mount, body, prev]] += d * d
                notes.append(f"{('pitch', 'roll')[j]} {math.degrees(d):+.2f}°")
        self._add_motion_note("mount re-opened after a step of " + ", ".join(notes))

    def _body_change(self, m: PairMeasurement) -> tuple[FloatArray, ...]:
        """The pair's current-frame pitch/roll (rad), their variances, its change of them and
        the change's variances (rad², with the filters' floors: ``pair_covariance``)."""
        cov = self._cfg.noise.pair_covariance(m.covariance, m.z[6])
        return (m.z[2:4], np.diag(cov)[2:4], *pair_change(m.z, cov))

    def _observe_body(self, m: PairMeasurement, dt: float) -> None:
        """Add the pair's change of pitch/roll over ``dt`` s to the body window (unless the
        bootstrap put it there) and re-adapt the body std."""
        kf = self._kf
        assert kf is not None
        if m.t > self._body_seen_t:
            self._body.add(m.t, *self._body_change(m), dt)
        kf.body_std = self._body.std()

    def _restart_motion(self, m: PairMeasurement, dt: float) -> None:
        """Re-initialise speed and yaw rate from this pair after the motion model lost track."""
        kf = self._kf
        assert kf is not None
        nz = self._cfg.noise
        speed, yaw_rate = M.pair_rates(m.z, kf.x[M.MOUNT_HEIGHT], m.height_assumed, dt)
        h_prior = (nz.prior_height_std_rel * self._cfg.height_m) ** 2
        yaw_prior = np.radians(nz.prior_mount_yaw_std_deg) ** 2
        # a wrong height or mount yaw also makes every translation disagree (the yaw turns
        # the predicted (tx, tz) off the measured direction): let the next pairs move them
        values = {M.YAW_RATE: yaw_rate}
        variances = {
            M.YAW_RATE: np.radians(nz.prior_yaw_rate_std_dps) ** 2,
            M.MOUNT_HEIGHT: max(h_prior, float(kf.P[M.MOUNT_HEIGHT, M.MOUNT_HEIGHT])),
            M.MOUNT_YAW: max(yaw_prior, float(kf.P[M.MOUNT_YAW, M.MOUNT_YAW])),
        }
        if not self._metric():
            # with a wheel speed the wheel says the speed, not pairs the model could not
            # follow (travel beyond the estimator's range aliases backwards: a car at 30 m/s
            # was restarted at -18 m/s every few pairs)
            values[M.SPEED] = speed
            variances[M.SPEED] = nz.prior_speed_std_mps**2
        _reopen(kf, values, variances)
        opened = "speed/yaw rate" if M.SPEED in values else "yaw rate"
        self._add_motion_note(f"{opened}/height/mount yaw re-opened after "
                              f"{self._motion_gated_run} pairs gated on motion")
        self._motion_gated_run = 0

    def _add_motion_note(self, note: str) -> None:
        """Add ``note`` to this frame's ``reset_reason`` (a speed and a motion restart can
        both happen within one frame)."""
        self._motion_note = "; ".join(r for r in (self._motion_note, note) if r)

    def _update_speed(self, speed: float) -> tuple[float, bool]:
        kf = self._kf
        assert kf is not None
        zp, h = M.speed_measurement(kf.x)
        r = np.array([[self._cfg.noise.speed_meas_var(speed)]])
        s = (h @ kf.P @ h.T + r).item()
        nis = float((speed - zp[0]) ** 2 / s)
        if self._speed_gate < nis <= self._cfg.speed_soft_gate_factor * self._speed_gate:
            r *= nis / self._speed_gate  # braking/accelerating beyond the model: down-weight
        elif nis > self._speed_gate:
            self._speed_gated_run += 1
            if self._speed_gated_run < self._cfg.max_consecutive_speed_gated:
                return nis, True
            self._restart_speed(speed)
        self._speed_gated_run = 0
        kf.update(np.array([speed]), lambda _x: h, lambda _x: zp, R=r)
        self._last_speed_t = self._t
        return nis, False

    def _restart_speed(self, speed: float) -> None:
        """Restart the speed at the wheels' reading ``speed`` (m/s, with its noise) and the
        height at its prior: pairs fused against the lost speed have bent it."""
        kf = self._kf
        assert kf is not None
        nz = self._cfg.noise
        h = self._cfg.height_m
        _reopen(kf, {M.SPEED: speed, M.MOUNT_HEIGHT: h}, {
            M.SPEED: nz.speed_meas_var(speed),
            M.MOUNT_HEIGHT: (nz.prior_height_std_rel * h) ** 2,
        })
        self._add_motion_note(
            f"speed/height re-opened after {self._speed_gated_run} wheel speeds gated")

    def _update_standstill(self, states: tuple[int, ...]) -> None:
        """Apply the standstill pseudo-measurement (``states`` = 0); no gate: the wheel speed
        (itself gated) or the image pair decided that the vehicle stands."""
        kf = self._kf
        assert kf is not None
        zp, h = M.standstill_measurement(kf.x, states)
        r = np.diag(self._cfg.noise.standstill_var(states))
        kf.update(np.zeros(len(states)), lambda _x: h, lambda _x: zp, R=r)

    def _metric(self) -> bool:
        """Whether a wheel speed was applied within ``speed_timeout_s``."""
        return (
            self._last_speed_t is not None and self._t is not None
            and self._t - self._last_speed_t <= self._cfg.speed_timeout_s
        )

    def _check(self) -> str:
        """Why the filter can no longer be trusted, or ''."""
        if self._pending_reset:
            return self._pending_reset
        kf = self._kf
        if kf is None:
            return ""
        p = kf.P
        if not (np.all(np.isfinite(kf.x)) and np.all(np.isfinite(p))):
            return "state or covariance not finite"
        kf.P = p = 0.5 * (p + p.T)
        scale = max(float(np.max(np.abs(np.diag(p)))), 1e-300)
        if float(np.linalg.eigvalsh(p)[0]) < -1e-9 * scale:
            return "covariance not positive semi-definite"
        lim = np.radians(self._cfg.max_mount_angle_std_deg) ** 2
        if p[M.MOUNT_PITCH, M.MOUNT_PITCH] > lim or p[M.MOUNT_ROLL, M.MOUNT_ROLL] > lim:
            return f"mount angle std above {self._cfg.max_mount_angle_std_deg}°"
        if not kf.x[M.MOUNT_HEIGHT] > 0:
            return "height estimate not positive"
        return ""

    def _reset(self, reason: str) -> None:
        """Drop the state (keeping a sane height estimate) until the next good pair."""
        kf = self._kf
        if kf is not None and np.isfinite(kf.x[M.MOUNT_HEIGHT]) and kf.x[M.MOUNT_HEIGHT] > 0:
            var = float(kf.P[M.MOUNT_HEIGHT, M.MOUNT_HEIGHT])
            prior = (self._cfg.noise.prior_height_std_rel * self._cfg.height_m) ** 2
            self._height = (float(kf.x[M.MOUNT_HEIGHT]), var if 0 < var < prior else prior)
        self._kf = None
        self._pose_gated_run = self._motion_gated_run = self._speed_gated_run = 0
        self._pending_reset = reason
        self._mount_change.reset()

    def _state(
        self, frame: int, t: float, status: str, nis: float = float("nan"), gated: str = "",
        speed_nis: float = float("nan"), speed_gated: bool = False, reset_reason: str = "",
        note: str = "", standstill: bool = False,
    ) -> FilterState:
        kf = self._kf
        if kf is None:
            nan3, nan33 = np.full(3, np.nan), np.full((3, 3), np.nan)
            return FilterState(
                frame, t, "waiting", nan3, nan33, float("nan"), nan3, nan33, nan3, nan33,
                float("nan"), float("nan"), np.full(2, np.nan), float("nan"),
                np.full(M.STATE_DIM, np.nan), np.full((M.STATE_DIM, M.STATE_DIM), np.nan),
                reset_reason=reset_reason or note,
            )
        x, p = kf.x.copy(), kf.P.copy()
        pose, jp = M.frame_pose(x)
        motion, jm = M.metric_motion(x)
        return FilterState(
            frame=frame, t=t, status=status, mount=x[M.MOUNT].copy(),
            mount_cov=p[M.MOUNT, M.MOUNT].copy(), mount_yaw=float(x[M.MOUNT_YAW]),
            pose=pose, pose_cov=jp @ p @ jp.T, motion=motion, motion_cov=jm @ p @ jm.T,
            speed=float(x[M.SPEED]), yaw_rate=float(x[M.YAW_RATE]),
            position=x[[M.POS_X, M.POS_Y]].copy(), heading=float(x[M.HEADING]), state=x,
            covariance=p, nis=nis, gated=gated, speed_nis=speed_nis, speed_gated=speed_gated,
            reset_reason=reset_reason or note, standstill=standstill,
        )


_POSE_ROWS = [0, 1, 2, 3]
_MOTION_ROWS = [4, 5, 6]


def _mahalanobis(y: FloatArray, s: FloatArray) -> float:
    """yᵀ S⁻¹ y, inf where S is singular or the result not finite."""
    try:
        d = float(y @ np.linalg.solve(s, y))
    except np.linalg.LinAlgError:
        return float("inf")
    return d if np.isfinite(d) else float("inf")


def _spread(values: FloatArray, floor: float, cap: float) -> float:
    """Robust std (1.4826 · MAD) of ``values``, clipped to [floor, cap]."""
    mad = float(np.median(np.abs(values - np.median(values))))
    return float(np.clip(1.4826 * mad, floor, cap))


def _pair_residual(z: FloatArray, zp: FloatArray) -> FloatArray:
    """z - zp with the yaw (always the last row when present) wrapped to (-π, π]."""
    y = np.asarray(z, dtype=float) - zp
    y[-1] = M.wrap_angle(y[-1])
    return y


def speed_at(series: SpeedSource, times: FloatArray, clock_offset_s: float = 0.0) -> FloatArray:
    """Wheel speed (m/s) at camera ``times``: linear interpolation of ``series`` whose clock
    is the camera's minus ``clock_offset_s``; NaN outside the samples or across gaps > 0.5 s
    (``wheel_speed.interpolate_speed``)."""
    return interpolate_speed(series.t, series.speed_mps,
                             np.asarray(times, dtype=float) - clock_offset_s)


def _reopen(kf: _ClonedEKF, values: dict[int, float], variances: dict[int, float]) -> None:
    """Restart part of ``kf``'s state: the states of ``values`` take those values, those of
    ``variances`` that variance, uncorrelated with the rest (indices of ``filters.model``)."""
    x, p = kf.x.copy(), kf.P.copy()
    for i, value in values.items():
        x[i] = value
    for i, var in variances.items():
        p[i, :] = p[:, i] = 0.0
        p[i, i] = var
    kf.x, kf.P = x, p


def run_filter(
    measurements: Sequence[PairMeasurement],
    speed_series: SpeedSource | None = None,
    config: EkfConfig | None = None,
    clock_offset_s: float = 0.0,
    progress: bool = False,
    ekf: ExtrinsicsEKF | None = None,
) -> list[FilterState]:
    """Filter a whole sequence (one measurement per frame, failed ones included); with
    ``speed_series`` the wheel speed at each frame time is applied too. Returns one
    ``FilterState`` per measurement. ``ekf``: the filter to run (its ``mount_changes`` are
    then the caller's to read), else one made from ``config``."""
    ekf = ekf or ExtrinsicsEKF(config, speed_series=speed_series, clock_offset_s=clock_offset_s)
    times = np.array([m.t for m in measurements], dtype=float)
    speeds = (
        speed_at(speed_series, times, clock_offset_s) if speed_series is not None
        else np.full(len(times), np.nan)
    )
    it = zip(measurements, speeds, strict=True)
    if progress:
        from vipm_track.progress import progress_bar

        it = progress_bar(it, total=len(measurements), desc="ekf", unit="frame")
    return [ekf.step(m, m.t, float(v), m.frame) for m, v in it]
