"""The drift monitor's statistics and state machine for many streams at once
(``MonitorCore``); ``filters.monitor.DriftMonitor`` wraps one stream with events, reasons and
estimates.

The test and why it runs on the per-frame poses
-----------------------------------------------
The filter's mount state is a random walk with a tiny rate, so a step enters it over tens of
seconds. The monitor instead tests the frame poses the filter is fed (the pair measurements
it gates, with their covariance) against the nominal calibration, treating the body shaking
of the filter's model (``filters.model``: Gauss–Markov, ``body_tau_s``, ``body_std_deg``) as
part of the noise. Per axis j (pitch, roll, height), with d_k = y_k − y_nominal:

    d_k = Δ + b_k + n_k,   b_k = a b_{k-1} + process noise,  a = exp(−dt/τ),  n_k ~ N(0, r_k)

Δ is the mount change under test, b the body (AR(1) at the frame rate), r_k the estimator's
variance. A scalar Kalman filter on b assuming Δ = 0 whitens d into innovations ν_k with
variance S_k. A constant Δ leaves a steady innovation ρΔ with ρ = (1 − a)/(1 − a + aK)
(K the Kalman gain), so u_k = ν_k/ρ is a per-frame observation of Δ with variance
w_k = S_k/ρ², which in steady state is the long-run variance σ_b²(1 + a)/(1 − a) + r:
the test uses all the information the data hold about Δ. Innovations are clipped at
``huber_k``·√S_k, but no lower than the tolerance plus the largest design shift (an offset of
many σ must still count as one), and one frame moves a test by at most
1/``min_alarm_frames`` of its threshold: an outlier cannot push a statistic far on its own; a
real step still can, over a few frames.

Real roads add a slow term g_k to d_k that is not a calibration change either: camber and
slope changes, load, and the front end's tracking correlation (on KITTI 07 the 1 s means of
the measured roll scatter 10–20× more than b + n explain, and the test above, told only of
b + n, flags a correctly mounted camera within seconds). ``road_std_deg`` / ``road_tau_s``
model it as a second Gauss–Markov process whose long-run variance σ_g²(1 + a_g)/(1 − a_g) is
added to w_k (and σ_g² to the clipping variance): slow excursions then count for what they
are worth, at the price of a longer delay for small steps (``scripts/bench_monitor.py``,
"road" rows). The default 0 keeps the flat-ground model.

Errors that run on from frame to frame
--------------------------------------
The front end's errors are not independent: a tracked pair starts from the pose the pair
before found and successive pairs see the same road (lag-1 autocorrelation of the pitch/roll
innovations 0.7–0.8 on KITTI 07). Taken as independent, a few seconds of them look like a
moved camera. The monitor measures their long-run variance on its own normalised innovations
z_k = ν_k/√S_k (1 per frame if the model is right) and multiplies w_k (and the thresholds'
typical w) by its ratio to the expected one, never below 1:

- batch means: the variance of √n × the mean z over blocks of ``correlation_block_s``, from
  successive blocks' differences (a constant offset drops out; one clipped difference holds
  a step), over an exponential window of ``correlation_window_blocks``, taken where it is
  significantly above the expected; judged by as measured ``correlation_delay_s`` earlier, so
  that a mount change, whose innovations run on, does not widen its own test;
- before ``correlation_min_blocks`` blocks, the variance of z × (1+ρ)/(1−ρ) of their lag-1
  autocorrelation ρ over an exponential window of ``correlation_tau_s`` (as the filters'
  ``row_correlation``; where ρ is significant), and before ``correlation_min_pairs`` lagged
  frames the cap (1+0.9)/(1−0.9) = 19.

Differences of 1-s blocks do not see a wander slower than a few seconds: a road whose tilt
wanders over seconds still needs ``road_std_deg`` (below), against which the measured long-run
variance is then judged.

For each axis, each side (+/−) and each design shift δ of ``MonitorConfig`` a CUSUM of the
log-likelihood ratio of Δ = tol + δ against Δ = tol (tol = the nominal file's tolerance):

    S_k = max(0, S_{k-1} + (δ/w_k)(±u_k − tol − δ/2)),   alarm when S_k ≥ h

so a deviation inside the tolerance drifts the statistic down and is never flagged on
average. The threshold h comes from the requested false-alarm rate: the in-control average
run length of each one-sided CUSUM (Siegmund's approximation for Gaussian increments,
computed at the nominal deviation Δ = 0 and the typical w) is set to
``n_tests × 3600 × fps / false_alarms_per_hour``, a union bound over all tests;
``scripts/bench_monitor.py`` checks the resulting rate by simulation.

INVALID uses a 1 s exponential average of the deviations (and the filter's mount estimate
where given) against the physical limits. The new extrinsics reported with DRIFTING and
RECALIBRATE are ``filters.monitor.DriftMonitor``'s, from the last step found in the
whitening filter's innovations (``last_whitening``; ``filters.monitor_segments``), else from
the change time ``change_onset`` estimates. CALIBRATED vouches for the mount: it is entered
where the weighted mean of the u_k since the evidence began, ± ``calibrate_within_z`` of its
standard errors (from the w_k), lies within the tolerance plus the smallest design shift
(``calibrated_bound``).

Height is tested only on frames with a metric travel (wheel speed; see
``inputs_from_measurements``): h_k = h_assumed · d_wheel / ‖t_est‖ (CONVENTIONS.md, Scale).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .monitor_stats import (
    W_SCALES,
    ar1_coefficient,
    cusum_threshold,
    interpolate_thresholds,
    long_run_variance,
)
from .monitor_types import (
    CALIBRATED,
    DRIFTING,
    HOLD,
    INVALID,
    RECALIBRATE,
    UNCALIBRATED,
    MonitorConfig,
)
from .nominal import NominalCalibration
from .row_correlation import MAX_LAG_FRAMES, MAX_RHO, MAX_Z, ar1_variance_factor

FloatArray = NDArray[np.float64]


@dataclass
class _Arrays:
    """Mutable state of ``MonitorCore`` for B streams (leading axis)."""

    body: FloatArray  # (B, 3) body estimate
    body_var: FloatArray  # (B, 3)
    body_std: FloatArray  # (B, 3) stationary body std (rad, rad, m): the model's or adapted
    corr_factor: FloatArray  # (B, 3) long-run variance factor of the errors' correlation
    corr_recent: FloatArray  # (B, 3, K) the factors measured at the last K frames, oldest first
    corr_sums: FloatArray  # (B, 3, 7) weighted sums over lagged innovations (``_correlation``)
    block: FloatArray  # (B, 3, 3) the open block's start time, Σz and frame count
    block_y: FloatArray  # (B, 3) the last closed block's √n × mean z (NaN: none yet)
    block_sums: FloatArray  # (B, 3, 3) Σw, Σw², Σw·d² over successive blocks' differences
    last_z: FloatArray  # (B, 3) the last used frame's normalised innovation
    last_used: NDArray[np.int64]  # (B, 3) ``count`` at that frame
    threshold: FloatArray  # (B, 3, D) CUSUM thresholds at that body std
    invalid_axis: NDArray[np.int64]  # (B,) axis that made the last frame INVALID
    invalid_dev: FloatArray  # (B,) its deviation from nominal (rad or m)
    invalid_mount: NDArray[np.bool_]  # (B,) True: the filter's mount said so, else the frames
    onset: NDArray[np.int64]  # (B,) usable-frame count where the last alarm's change began
    t_last: FloatArray  # (B, 3) time of the last used frame per axis
    cusum: FloatArray  # (B, 3, 2, D)
    zero_count: NDArray[np.int64]  # (B, 3, 2, D) value of ``count`` when the CUSUM was 0
    used: NDArray[np.int64]  # (B, 3) used frames per axis
    count: NDArray[np.int64]  # (B,) usable frames
    ema: FloatArray  # (B, 3)
    base: NDArray[np.int64]  # (B,)
    evidence: NDArray[np.int64]  # (B,) usable frames since UNCALIBRATED began
    info: FloatArray  # (B, 3) Σ 1/w_k over the used frames since then
    info_u: FloatArray  # (B, 3) Σ u_k/w_k (unclipped): with ``info``, the mean deviation
    quiet: NDArray[np.int64]  # (B,) frames below warn_exit while RECALIBRATE / INVALID
    vouched: NDArray[np.bool_]  # (B, 3) axes the mean deviation was last shown within on
    gated_run: NDArray[np.int64]  # (B,)
    alarm_axis: NDArray[np.int64]  # (B,) axis of the last alarm / warning


class MonitorCore:
    """The monitor's statistics and state machine for ``batch`` independent streams at once
    (arrays with a leading batch axis), so Monte Carlo runs share one loop over time.

    ``step`` takes one frame of every stream and returns the state codes (``STATES``
    indices). ``DriftMonitor`` wraps one stream with events, reasons and estimates.
    """

    def __init__(
        self, nominal: NominalCalibration, config: MonitorConfig | None = None, batch: int = 1
    ) -> None:
        self.nominal = nominal
        self.config = cfg = config or MonitorConfig()
        self.batch = batch
        ang = np.radians(np.asarray(cfg.angle_shifts_deg, dtype=float))
        hgt = np.asarray(cfg.height_shifts_m, dtype=float)
        d = max(len(ang), len(hgt))
        # pad the shorter bank by repeating its last shift (an identical, harmless test)
        self.delta = np.stack([_pad(ang, d), _pad(ang, d), _pad(hgt, d)])  # (3, D)
        self.n_tests = 2 * (len(ang) * 2 + len(hgt))
        tol = nominal.tolerances
        self.ref = tol[:, None] + self.delta / 2.0  # (3, D)
        self._clip_floor = tol + self.delta.max(axis=1)  # (3,)
        self.tau = np.array([cfg.body_tau_s, cfg.body_tau_s, 0.0])
        sb = math.radians(cfg.body_std_deg)
        self.body_std = np.array([sb, sb, 0.0])
        sr = math.radians(cfg.road_std_deg)
        self.road_std = np.array([sr, sr, 0.0])
        self._meas_var = np.array([math.radians(cfg.meas_angle_std_deg) ** 2] * 2
                                  + [cfg.meas_height_std_m**2])
        self.w_nominal = self._typical_w(self.body_std)
        self._unknown_factor = (float(ar1_variance_factor(np.float64(MAX_RHO)))
                                if cfg.correlation_tau_s > 0 else 1.0)
        self._corr_delay = max(1, round(cfg.correlation_delay_s * cfg.fps))
        self._arl = self.n_tests * 3600.0 * cfg.fps / cfg.false_alarms_per_hour
        # thresholds (log-likelihood units) at the model's long-run variance and at larger
        # ones (an adapted body std, correlated errors)
        self._threshold_table = np.stack(
            [self._thresholds(self.w_nominal * k) for k in W_SCALES])  # (S, 3, D)
        self.threshold = self._threshold_table[0]
        self.limits = nominal.limits
        self.nominal_values = nominal.values
        self.calib_frames = max(1, round(cfg.calibrate_after_s * cfg.fps))
        self.clear_frames = max(1, round(cfg.clear_after_s * cfg.fps))
        self.max_gated = max(0, round(cfg.max_gated_run_s * cfg.fps))
        self.reset()
        nan = np.full((batch, 3), np.nan)
        self.last_whitening: tuple[FloatArray, ...] = (nan, nan, nan, nan, nan)

    def _typical_w(self, body_std: FloatArray, factor: FloatArray | float = 1.0) -> FloatArray:
        """(..., 3) long-run variance per frame at the configured frame rate and measurement
        noise for a body of stationary std ``body_std`` (..., 3), the errors' correlation
        inflating it by ``factor``."""
        dt = np.full(body_std.shape, 1.0 / self.config.fps)
        a = ar1_coefficient(dt, self.body_tau(body_std))
        return (long_run_variance(body_std, a, self._meas_var) + self._road_lrv(dt)) * factor

    def _thresholds(self, w: FloatArray) -> FloatArray:
        """(3, D) CUSUM thresholds for the requested false-alarm rate at long-run
        variances ``w`` (3,)."""
        out = np.empty(self.delta.shape)
        for j in range(3):
            sd = math.sqrt(w[j])
            for i in range(self.delta.shape[1]):
                b = cusum_threshold(self._arl, -self.ref[j, i] / sd)
                out[j, i] = b * self.delta[j, i] / sd
        return out

    # -- public ---------------------------------------------------------------------------

    def body_tau(self, body_std: FloatArray) -> FloatArray:
        """Body time constants (s) at stationary std ``body_std`` (..., 3): the model's
        τ·(σ₀/σ)², as ``filters.model.body_transition`` (the body's low-frequency power stays
        the model's; the shaking beyond it is fast)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(body_std > 0, self.body_std / body_std, 1.0)
        return self.tau * np.where(self.body_std > 0, ratio, 1.0) ** 2

    def reset(self, streams: NDArray[np.bool_] | None = None) -> None:
        """Start over (UNCALIBRATED, statistics at zero) for ``streams`` (mask), or all."""
        b, d = self.batch, self.delta.shape[1]
        fresh = _Arrays(
            body=np.zeros((b, 3)), body_var=np.tile(self.body_std**2, (b, 1)),
            body_std=np.tile(self.body_std, (b, 1)),
            corr_factor=np.full((b, 3), self._unknown_factor),
            corr_recent=np.full((b, 3, self._corr_delay), np.nan),
            corr_sums=np.zeros((b, 3, 7)),
            block=np.tile([np.nan, 0.0, 0.0], (b, 3, 1)), block_y=np.full((b, 3), np.nan),
            block_sums=np.zeros((b, 3, 3)),
            last_z=np.zeros((b, 3)), last_used=np.full((b, 3), -10, dtype=np.int64),
            threshold=np.tile(self.threshold, (b, 1, 1)),
            invalid_axis=np.zeros(b, dtype=np.int64), invalid_dev=np.zeros(b),
            invalid_mount=np.zeros(b, dtype=bool), onset=np.zeros(b, dtype=np.int64),
            t_last=np.full((b, 3), np.nan), cusum=np.zeros((b, 3, 2, d)),
            zero_count=np.zeros((b, 3, 2, d), dtype=np.int64),
            used=np.zeros((b, 3), dtype=np.int64), count=np.zeros(b, dtype=np.int64),
            ema=np.full((b, 3), np.nan),
            base=np.full(b, UNCALIBRATED, dtype=np.int64), evidence=np.zeros(b, dtype=np.int64),
            info=np.zeros((b, 3)), info_u=np.zeros((b, 3)),
            quiet=np.zeros(b, dtype=np.int64), vouched=np.zeros((b, 3), dtype=bool),
            gated_run=np.zeros(b, dtype=np.int64),
            alarm_axis=np.zeros(b, dtype=np.int64),
        )
        if streams is None or not hasattr(self, "s"):
            self.s = fresh
            return
        for name in fresh.__dataclass_fields__:
            getattr(self.s, name)[streams] = getattr(fresh, name)[streams]

    def change_onset(self, axis: NDArray[np.int64]) -> NDArray[np.int64]:
        """(B,) usable-frame count at which the change on ``axis`` (B,) began: on that axis's
        leading side, the earliest last zero of the tests still above zero (the small design
        shifts keep evidence longer than a large one, whose last zero may be a few frames
        back and would leave a noisy median)."""
        s = self.s
        rows = np.arange(self.batch)
        cus = s.cusum[rows, axis]  # (B, 2, D)
        norm = cus / s.threshold[rows, axis][:, None, :]
        side = np.argmax(norm.max(axis=2), axis=1)
        live = cus[rows, side] > 0  # (B, D)
        zeros = np.where(live, s.zero_count[rows, axis][rows, side], np.iinfo(np.int64).max)
        first = zeros.min(axis=1)
        return np.where(live.any(axis=1), first, s.count)

    def mean_deviation(self) -> tuple[FloatArray, FloatArray]:
        """(B, 3) weighted mean of the whitened deviations u_k since the evidence began
        (rad, rad, m; NaN on an axis without frames) and its standard error: the estimate of
        a constant Δ the CUSUMs test, all of it, not only the part beyond the tolerance."""
        s = self.s
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = np.where(s.info > 0, s.info_u / s.info, np.nan)
            se = np.where(s.info > 0, 1.0 / np.sqrt(s.info), np.nan)
        return mean, se

    def calibrated_bound(self) -> FloatArray:
        """(3,) the deviation CALIBRATED vouches for (rad, rad, m): the tolerance plus the
        smallest change beyond it the test is designed to find."""
        return self.nominal.tolerances + self.delta.min(axis=1)

    def within_tolerance(self, mean: FloatArray, se: FloatArray) -> NDArray[np.bool_]:
        """(B,) the mean deviation since the evidence began (``mean_deviation``'s ``mean``,
        ``se``) is shown within ``calibrated_bound``, its ``calibrate_within_z``-standard-error
        interval inside it, on every axis that has frames."""
        beyond = np.abs(mean) + self.config.calibrate_within_z * se > self.calibrated_bound()
        return ~np.any(np.isfinite(mean) & beyond, axis=1)

    def normalised_statistic(self) -> FloatArray:
        """(B, 3): per axis, the largest CUSUM divided by its threshold (1 = alarm)."""
        return (self.s.cusum / self.s.threshold[:, :, None, :]).max(axis=(2, 3))

    def step(
        self,
        t: FloatArray,
        pose: FloatArray,
        pose_var: FloatArray,
        usable: NDArray[np.bool_],
        gated: NDArray[np.bool_] | None = None,
        mount: FloatArray | None = None,
        body_std: FloatArray | None = None,
    ) -> NDArray[np.int64]:
        """Advance every stream by one frame; return the state codes (B,).

        ``t`` (B,) s; ``pose``/``pose_var`` (B, 3) measured frame pose (rad, rad, m; NaN =
        no information on that axis) and its variance; ``usable`` (B,); ``gated`` (B,) the
        filter rejected the frame; ``mount`` (B, 3) the filter's mount estimate or NaN;
        ``body_std`` (B, 2) the body's stationary std (pitch, roll, rad) adapted to the data,
        or (B, 3) with the height's heave (m) (None: keep the current one; never below the
        configured ``body_std_deg``).
        """
        s, cfg = self.s, self.config
        if body_std is not None:
            self._set_body_std(np.asarray(body_std, dtype=float).reshape(self.batch, -1))
        usable = np.asarray(usable, dtype=bool)
        if gated is not None:
            gated = np.asarray(gated, dtype=bool) & usable
            s.gated_run = np.where(gated, s.gated_run + 1, 0)
            usable = usable & ~(gated & (s.gated_run <= self.max_gated))
        dev = np.asarray(pose, dtype=float) - self.nominal_values
        var = np.asarray(pose_var, dtype=float)
        use = usable[:, None] & np.isfinite(dev) & np.isfinite(var)  # (B, 3)
        dev0 = np.where(use, dev, 0.0)
        var0 = np.where(use, var, 1.0)

        # whitening Kalman filter on the body (Δ = 0), then the offset observation u
        dt = np.where(np.isfinite(s.t_last), t[:, None] - s.t_last, np.inf)
        dt = np.where(dt > 0, dt, 1.0 / cfg.fps)
        a = ar1_coefficient(dt, self.body_tau(s.body_std))
        x_pred = a * s.body
        p_pred = a * a * s.body_var + s.body_std**2 * (1.0 - a * a)
        nu = dev0 - x_pred
        sv = p_pred + var0
        gain = p_pred / sv
        rho = (1.0 - a) / (1.0 - a + a * gain)
        road_lrv = self._road_lrv(dt)
        # the innovations' long-run variance the model expects (the road's, where modelled,
        # runs on in them): the measured one is judged against it
        expected = 1.0 + road_lrv * rho * rho / sv
        self._correlation(t, np.clip(nu / np.sqrt(sv), -MAX_Z, MAX_Z), use, dt, expected)
        s.threshold = interpolate_thresholds(
            self._threshold_table, self._typical_w(s.body_std, s.corr_factor) / self.w_nominal)
        road_var = self.road_std**2
        # clipped (outliers), but never below what the largest design shift beyond the
        # tolerance leaves: heights measured to a millimetre clipped a 2-cm offset to its
        # 5-mm tolerance, which no test then saw (one frame's push is capped below)
        lim = np.maximum(cfg.huber_k * np.sqrt(sv + road_var), self._clip_floor)
        nu_c = np.clip(nu, -lim, lim)
        u = nu_c / rho
        # the whitening filter's innovations, their variance, AR(1) coefficient, gain and the
        # long-run variance factor the road's wander gives them (NaN where unused):
        # ``filters.monitor_segments`` finds steps in them
        self.last_whitening = (np.where(use, nu_c, np.nan), sv, a, gain, expected)
        w = (sv / (rho * rho) + road_lrv) * s.corr_factor
        s.body = np.where(use, x_pred + gain * nu_c, s.body)
        s.body_var = np.where(use, (1.0 - gain) * p_pred, s.body_var)
        s.t_last = np.where(use, t[:, None], s.t_last)
        s.used = s.used + use
        s.count = s.count + usable
        s.info = np.where(use, s.info + 1.0 / w, s.info)
        s.info_u = np.where(use, s.info_u + nu / rho / w, s.info_u)  # the mean: unclipped

        # CUSUM bank: (B, 3, side, D)
        signed = np.stack([u, -u], axis=2)[..., None]  # (B, 3, 2, 1)
        inc = (self.delta / w[..., None])[:, :, None, :] * (signed - self.ref[None, :, None, :])
        # one frame moves a test by at most 1/``min_alarm_frames`` of its threshold: an
        # outlier the clip above lets through does not raise an alarm on its own
        cap = s.threshold[:, :, None, :] / cfg.min_alarm_frames
        new = np.maximum(0.0, s.cusum + np.minimum(inc, cap))
        use4 = use[:, :, None, None]
        s.cusum = np.where(use4, new, s.cusum)
        s.zero_count = np.where(use4 & (new <= 0.0), s.count[:, None, None, None], s.zero_count)

        # short average of the deviation (INVALID check)
        alpha = 1.0 - np.exp(-np.minimum(dt, 1e6) / cfg.invalid_tau_s)
        first = use & (s.used == 1)
        s.ema = np.where(first, dev0, np.where(use, s.ema + alpha * (dev0 - s.ema), s.ema))
        settled = s.used >= max(1, round(cfg.invalid_tau_s * cfg.fps))
        bad = settled & (np.abs(s.ema) > self.limits)
        bad[:, 2] |= settled[:, 2] & (self.nominal_values[2] + s.ema[:, 2] <= 0.0)
        # which axis and which source (frames or the filter's mount) is furthest out
        excess = np.where(bad, np.abs(s.ema) / self.limits, -np.inf)
        source_dev = np.where(bad, s.ema, 0.0)
        from_mount = np.zeros_like(bad)
        if mount is not None:
            mdev = np.asarray(mount, dtype=float) - self.nominal_values
            mbad = np.isfinite(mdev) & (np.abs(mdev) > self.limits)
            mexcess = np.where(mbad, np.abs(mdev) / self.limits, -np.inf)
            from_mount = mexcess > excess
            excess = np.maximum(excess, mexcess)
            source_dev = np.where(from_mount, mdev, source_dev)
            bad |= mbad
        invalid_now = bad.any(axis=1)
        worst = np.argmax(excess, axis=1)
        rows = np.arange(self.batch)
        s.invalid_axis = np.where(invalid_now, worst, s.invalid_axis)
        s.invalid_dev = np.where(invalid_now, source_dev[rows, worst], s.invalid_dev)
        s.invalid_mount = np.where(invalid_now, from_mount[rows, worst], s.invalid_mount)

        return self._transition(usable, invalid_now)

    # -- internals --------------------------------------------------------------------------

    def _road_lrv(self, dt: FloatArray) -> FloatArray:
        """Long-run variance per frame of the road tilt (Gauss–Markov, ``road_*``) at frame
        spacing ``dt`` (per axis; 0 where the road term is off)."""
        a = np.exp(-np.minimum(dt, 1e6) / self.config.road_tau_s)
        return long_run_variance(self.road_std, a, 0.0)

    def _set_body_std(self, body_std: FloatArray) -> None:
        """Adopt body stds (B, 2) for pitch and roll (floored at the configured one) or (B, 3)
        with the height's heave too (m; none in the model: white, at least 0)."""
        n = body_std.shape[1]
        self.s.body_std[:, :n] = np.maximum(body_std, self.body_std[:n])

    def _correlation(self, t: FloatArray, z: FloatArray, use: NDArray[np.bool_],
                     dt: FloatArray, expected: FloatArray) -> None:
        """Update the long-run variance factor ``corr_factor`` (B, 3) from the normalised
        innovations ``z`` (B, 3) at times ``t`` (B,): their long-run variance over the
        ``expected`` one (B, 3), at least 1 (module doc)."""
        s, cfg = self.s, self.config
        if cfg.correlation_tau_s <= 0:
            return
        lag1 = self._lag1_lrv(z, use, dt)
        block, n_blocks = self._block_lrv(t, z, use)
        block_known = n_blocks >= cfg.correlation_min_blocks
        with np.errstate(divide="ignore", invalid="ignore"):
            # batch means where significantly above the expected (2 σ of a χ² estimate)
            block_excess = block > expected * (1.0 + 2.0 * np.sqrt(2.0 / n_blocks))
        block_factor = np.where(block_known, np.maximum(
            np.where(block_excess, block, expected) / expected, 1.0), np.nan)
        # batch means are judged by as measured ``correlation_delay_s`` ago (a mount change
        # makes the innovations after it run on, and must not widen its own test); until
        # then as measured, before them the lag-1 estimate, before that ``_unknown_factor``
        s.corr_recent = np.concatenate([s.corr_recent[..., 1:], block_factor[..., None]],
                                       axis=-1)
        early = np.where(np.isfinite(lag1), np.maximum(lag1 / expected, 1.0),
                         self._unknown_factor)
        s.corr_factor = np.where(np.isfinite(s.corr_recent[..., 0]), s.corr_recent[..., 0],
                                 np.where(block_known, block_factor, early))

    def _lag1_lrv(self, z: FloatArray, use: NDArray[np.bool_], dt: FloatArray) -> FloatArray:
        """The long-run variance of ``z`` as their variance × (1+ρ)/(1−ρ), ρ their lag-1
        autocorrelation over the exponential window (1 where ρ is not significant), and where
        ``correlation_min_pairs`` lagged frames were seen (before, from three on, the variance
        × the cap's factor; NaN before that): the first estimate, an upper one for a smooth
        sway (whose long-run variance is small)."""
        s, cfg = self.s, self.config
        decay = np.where(use, np.exp(-np.minimum(dt, 1e6) / cfg.correlation_tau_s), 1.0)
        lagged = use & (s.count[:, None] - s.last_used <= MAX_LAG_FRAMES)
        prev = s.last_z
        sums = s.corr_sums
        sums *= decay[..., None]
        sums[..., 1] *= decay  # Σw² decays by the square
        add = np.stack([np.ones_like(z), np.ones_like(z), prev, z, prev * prev, z * z,
                        prev * z], axis=-1)
        sums += np.where(lagged[..., None], add, 0.0)
        s.last_z = np.where(use, z, s.last_z)
        s.last_used = np.where(use, s.count[:, None], s.last_used)
        with np.errstate(divide="ignore", invalid="ignore"):
            n = sums[..., 0]
            n_eff = n * n / sums[..., 1]
            ma, mb = sums[..., 2] / n, sums[..., 3] / n
            va = sums[..., 4] / n - ma * ma
            vb = sums[..., 5] / n - mb * mb
            r = (sums[..., 6] / n - ma * mb) / np.sqrt(np.maximum(va * vb, 1e-12))
            sig = 2.0 / np.sqrt(n_eff)
        # the variance is 1 if the model is right, far less where the errors are far below it
        # (a still camera's); with too few lagged frames for ρ, taken at its cap
        var = np.nan_to_num(vb)
        lrv = var * ar1_variance_factor(np.nan_to_num(r))
        known = np.nan_to_num(n_eff) >= cfg.correlation_min_pairs
        return np.where(known, np.where(np.nan_to_num(r) > sig, lrv, 1.0),
                        np.where(n >= 3, var * self._unknown_factor, np.nan))

    def _block_lrv(self, t: FloatArray, z: FloatArray, use: NDArray[np.bool_]
                   ) -> tuple[FloatArray, FloatArray]:
        """Batch means: the variance of √n × the mean of ``z`` over blocks of
        ``correlation_block_s`` (1 for white innovations, less for a sway that averages out
        within a block), from successive blocks' differences (a constant offset does not
        count, a step only in one difference of many) over an exponential window of
        ``correlation_window_blocks``, and the number of differences it rests on."""
        s, cfg = self.s, self.config
        blk, last, sums = s.block, s.block_y, s.block_sums
        tt = np.broadcast_to(t[:, None], z.shape)
        blk[..., 0] = np.where(use & np.isnan(blk[..., 0]), tt, blk[..., 0])
        blk[..., 1] += np.where(use, z, 0.0)
        blk[..., 2] += use
        closed = use & (tt - blk[..., 0] >= cfg.correlation_block_s - 0.5 / cfg.fps)
        with np.errstate(divide="ignore", invalid="ignore"):
            y = blk[..., 1] / np.sqrt(blk[..., 2])
        diff = closed & np.isfinite(last)
        with np.errstate(divide="ignore", invalid="ignore"):
            # one difference counts for at most 9 × the estimate so far (before it): a step
            # is in one
            current = np.where(sums[..., 0] > 0, sums[..., 2] / sums[..., 0], np.inf)
        decay = np.where(closed, math.exp(-1.0 / cfg.correlation_window_blocks), 1.0)
        sums[..., 0] = sums[..., 0] * decay + diff
        sums[..., 1] = sums[..., 1] * decay * decay + diff
        d2 = np.minimum(0.5 * (y - np.nan_to_num(last)) ** 2, 9.0 * np.maximum(current, 1.0))
        sums[..., 2] = sums[..., 2] * decay + np.where(diff, d2, 0.0)
        s.block_y = np.where(closed, y, last)
        blk[closed] = [np.nan, 0.0, 0.0]
        with np.errstate(divide="ignore", invalid="ignore"):
            f = sums[..., 2] / sums[..., 0]
            n_eff = np.nan_to_num(sums[..., 0] ** 2 / sums[..., 1])
        return f, n_eff

    def _transition(
        self, usable: NDArray[np.bool_], invalid_now: NDArray[np.bool_]
    ) -> NDArray[np.int64]:
        s, cfg = self.s, self.config
        stat = self.normalised_statistic()
        self.last_statistic = stat  # before any alarm restarts the statistics
        top = stat.max(axis=1)
        axis = stat.argmax(axis=1)
        base = s.base.copy()
        alarm = usable & (top >= 1.0) & ~invalid_now
        warn = top >= cfg.warn_enter
        calm = top < cfg.warn_exit

        # INVALID: enter at once, leave after clear_after_s of plausible frames
        entering_invalid = usable & invalid_now
        s.quiet = np.where(entering_invalid, 0, s.quiet)
        base = np.where(entering_invalid, INVALID, base)
        in_invalid = usable & ~invalid_now & (base == INVALID)
        s.quiet = np.where(in_invalid, s.quiet + 1, s.quiet)
        cleared = in_invalid & (s.quiet >= self.clear_frames)
        if cleared.any():
            self.reset(cleared)
            base = np.where(cleared, UNCALIBRATED, base)
        # alarm: RECALIBRATE (latched); restart the statistics so persistence re-alarms
        was_recal = base == RECALIBRATE
        base = np.where(alarm, RECALIBRATE, base)
        s.alarm_axis = np.where(alarm | (warn & usable & (base != RECALIBRATE)), axis, s.alarm_axis)
        s.quiet = np.where(alarm, 0, s.quiet)
        if alarm.any():
            s.onset = np.where(alarm, self.change_onset(axis), s.onset)
            s.cusum[alarm] = 0.0
            s.zero_count[alarm] = s.count[alarm][:, None, None, None]
        # RECALIBRATE → CALIBRATED after clear_after_s of frames without a warning
        recal = usable & was_recal & ~alarm & (base == RECALIBRATE)
        s.quiet = np.where(recal, np.where(warn, 0, s.quiet + 1), s.quiet)
        # the mean deviation restarts with the calm run that clears RECALIBRATE: after it,
        # CALIBRATED's reason gave the mean since the drive began, the change included
        # (+0.40° ± 0.05° against a tolerance of 0.1°)
        restart = (alarm | (recal & warn))[:, None]
        s.info, s.info_u = np.where(restart, 0.0, s.info), np.where(restart, 0.0, s.info_u)
        base = np.where(recal & (s.quiet >= self.clear_frames), CALIBRATED, base)
        # UNCALIBRATED / CALIBRATED / DRIFTING
        normal = usable & ~alarm & np.isin(base, (UNCALIBRATED, CALIBRATED, DRIFTING))
        s.evidence = np.where(normal, s.evidence + 1, s.evidence)
        enough = s.evidence >= self.calib_frames
        # entering CALIBRATED takes a mean deviation within the tolerance as well; once
        # there, the CUSUMs alone judge (a later change would be diluted in the mean)
        # (an axis tested only since, the height once a wheel speed gives one, is judged
        # so before CALIBRATED goes on)
        mean, se = self.mean_deviation()
        tested = np.isfinite(mean)
        within = self.within_tolerance(mean, se)
        # (judged in those states only: in RECALIBRATE the mean restarts and has no axis)
        s.vouched = np.where((normal & enough & within)[:, None], tested, s.vouched)
        kept = (base == CALIBRATED) & ~np.any(tested & ~s.vouched, axis=1)
        settled = enough & (kept | within)
        nxt = np.where(
            warn & enough, DRIFTING,
            np.where(
                base == DRIFTING,
                np.where(calm, np.where(settled, CALIBRATED, UNCALIBRATED), DRIFTING),
                np.where(settled, CALIBRATED, UNCALIBRATED),
            ),
        )
        base = np.where(normal, nxt, base)
        # implausible extrinsics say nothing about a small change: the test restarts after
        inv = base == INVALID
        if inv.any():
            s.cusum[inv] = 0.0
            s.zero_count[inv] = s.count[inv][:, None, None, None]
        s.base = base
        return np.where(usable, base, HOLD)


def _pad(x: FloatArray, n: int) -> FloatArray:
    return np.concatenate([x, np.full(n - len(x), x[-1])])


__all__ = ["MonitorCore"]
