"""Calibration drift monitor: a per-frame verdict on whether the camera still sits where its
nominal calibration says.

States (``STATES``):

- ``UNCALIBRATED``: not enough usable evidence yet (start-up, after INVALID clears);
- ``CALIBRATED``: consistent with the nominal calibration within its tolerances;
- ``DRIFTING``: evidence of a deviation beyond tolerance is accumulating (a test statistic
  above ``warn_enter`` × its threshold);
- ``RECALIBRATE``: a test crossed its threshold; the output carries the new extrinsics and
  their 95 % interval. Left only after ``clear_after_s`` of usable frames with every
  statistic below ``warn_enter`` (hysteresis), or by ``accept`` of a new calibration;
- ``INVALID``: the extrinsics are physically implausible (``NominalCalibration`` limits);
- ``HOLD``: this frame's evidence cannot be trusted (estimator failure, too few inliers,
  standstill, a frame the filter gated); the statistics are frozen.

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
``huber_k``·√S_k (outliers cannot push a statistic far; a real step still can).

Real roads add a slow term g_k to d_k that is not a calibration change either: camber and
slope changes, load, and the front end's tracking correlation (on KITTI 07 the 1 s means of
the measured roll scatter 10–20× more than b + n explain, and the test above, told only of
b + n, flags a correctly mounted camera within seconds). ``road_std_deg`` / ``road_tau_s``
model it as a second Gauss–Markov process whose long-run variance σ_g²(1 + a_g)/(1 − a_g) is
added to w_k (and σ_g² to the clipping variance): slow excursions then count for what they
are worth, at the price of a longer delay for small steps (``scripts/bench_monitor.py``,
"road" rows). The default 0 keeps the flat-ground model.

For each axis, each side (+/−) and each design shift δ of ``MonitorConfig`` a CUSUM of the
log-likelihood ratio of Δ = tol + δ against Δ = tol (tol = the nominal file's tolerance):

    S_k = max(0, S_{k-1} + (δ/w_k)(±u_k − tol − δ/2)),   alarm when S_k ≥ h

so a deviation inside the tolerance drifts the statistic down and is never flagged on
average. The threshold h comes from the requested false-alarm rate: the in-control average
run length of each one-sided CUSUM (Siegmund's approximation for Gaussian increments,
computed at the nominal deviation Δ = 0 and the typical w) is set to
``n_tests × 3600 × fps / false_alarms_per_hour``, a union bound over all tests;
``scripts/bench_monitor.py`` checks the resulting rate by simulation.

The new extrinsics reported with DRIFTING/RECALIBRATE are the nominal plus the median
deviation since the estimated change time (the last time the alarming statistic was zero);
the 95 % interval uses the long-run variance of a mean of n correlated frames (× π/2 for
the median), or the frames' own batch-means scatter (``filters.long_run``) where wider.
INVALID uses a 1 s exponential average of the deviations (and the filter's mount estimate
where given) against the physical limits.

Height is tested only on frames with a metric travel (wheel speed; see
``inputs_from_measurements``): h_k = h_assumed · d_wheel / ‖t_est‖ (CONVENTIONS.md, Scale).
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray
from scipy.optimize import brentq

from vipm_track.errors import InputError

from .body_scale import BodyScale, cautious_std
from .long_run import batch_means
from .model import NoiseParams

FloatArray = NDArray[np.float64]

STATES: tuple[str, ...] = (
    "UNCALIBRATED", "CALIBRATED", "DRIFTING", "RECALIBRATE", "INVALID", "HOLD",
)
UNCALIBRATED, CALIBRATED, DRIFTING, RECALIBRATE, INVALID, HOLD = range(6)
AXES: tuple[str, ...] = ("pitch", "roll", "height")
_SIEGMUND_SHIFT = 1.166  # Siegmund's correction of the CUSUM threshold for the overshoot
#: body std over the configured one (σ/σ₀) at which the thresholds are tabulated for a body
#: std adapted to the data; between them the threshold is interpolated in log σ
_BODY_SCALES = np.array([1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 13.0, 20.0, 35.0, 60.0])


# --- nominal calibration ----------------------------------------------------------------------


@dataclass(frozen=True)
class NominalCalibration:
    """Nominal extrinsics with tolerances and physical limits (degrees / metres, as in files).

    Deviations within ``*_tol`` count as calibrated; beyond ``max_angle_dev_deg`` in pitch or
    roll, or a height off by more than ``max_height_dev_frac`` of nominal (or ≤ 0), the
    extrinsics are INVALID.
    """

    pitch_deg: float
    roll_deg: float
    height_m: float
    pitch_tol_deg: float = 0.1
    roll_tol_deg: float = 0.1
    height_tol_m: float = 0.005
    max_angle_dev_deg: float = 10.0
    max_height_dev_frac: float = 0.5

    def __post_init__(self) -> None:
        for name in ("pitch_deg", "roll_deg", "height_m", "pitch_tol_deg", "roll_tol_deg",
                     "height_tol_m", "max_angle_dev_deg", "max_height_dev_frac"):
            if not math.isfinite(getattr(self, name)):
                raise InputError(f"nominal calibration: {name} must be a finite number")
        if self.height_m <= 0:
            raise InputError(f"nominal calibration: height_m must be > 0, got {self.height_m}")
        if min(self.pitch_tol_deg, self.roll_tol_deg, self.height_tol_m) < 0:
            raise InputError("nominal calibration: tolerances must be >= 0")
        if self.max_angle_dev_deg <= 0 or self.max_height_dev_frac <= 0:
            raise InputError("nominal calibration: limits must be > 0")

    @property
    def values(self) -> FloatArray:
        """(pitch rad, roll rad, height m)."""
        return np.array([math.radians(self.pitch_deg), math.radians(self.roll_deg), self.height_m])

    @property
    def tolerances(self) -> FloatArray:
        """(pitch rad, roll rad, height m)."""
        return np.array([math.radians(self.pitch_tol_deg), math.radians(self.roll_tol_deg),
                         self.height_tol_m])

    @property
    def limits(self) -> FloatArray:
        """Largest plausible |deviation| per axis: (rad, rad, m)."""
        a = math.radians(self.max_angle_dev_deg)
        return np.array([a, a, self.max_height_dev_frac * self.height_m])


def load_nominal(path: str | Path) -> NominalCalibration:
    """Read a nominal-calibration YAML file.

    Keys: ``pitch_deg``, ``roll_deg``, ``height_m`` (required); optional ``tolerances``
    mapping (``pitch_deg``, ``roll_deg``, ``height_m``) and ``limits`` mapping
    (``max_angle_dev_deg``, ``max_height_dev_frac``). Raises :class:`InputError` naming the
    file and the key.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: nominal calibration file not found")
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text file (byte {exc.start}: {exc.reason})") from exc
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a mapping with pitch_deg, roll_deg, height_m")
    known = ("pitch_deg", "roll_deg", "height_m", "tolerances", "limits")
    unknown = sorted(str(k) for k in doc if k not in known)
    if unknown:
        raise InputError(f"{path}: unknown key(s) {unknown}; expected {sorted(known)}")

    def number(section: dict[str, Any], key: str, where: str) -> float:
        try:
            return float(section[key])
        except KeyError as exc:
            raise InputError(f"{path}: missing key '{where}{key}'") from exc
        except (TypeError, ValueError) as exc:
            raise InputError(f"{path}: '{where}{key}' is not a number: {section[key]!r}") from exc

    kwargs = {k: number(doc, k, "") for k in ("pitch_deg", "roll_deg", "height_m")}
    for section, keys in (
        ("tolerances", {"pitch_deg": "pitch_tol_deg", "roll_deg": "roll_tol_deg",
                        "height_m": "height_tol_m"}),
        ("limits", {"max_angle_dev_deg": "max_angle_dev_deg",
                    "max_height_dev_frac": "max_height_dev_frac"}),
    ):
        sub = doc.get(section) or {}
        if not isinstance(sub, dict):
            raise InputError(f"{path}: '{section}' must be a mapping")
        unknown = set(sub) - set(keys)
        if unknown:
            raise InputError(f"{path}: unknown key(s) {sorted(unknown)} in '{section}'; "
                             f"expected {sorted(keys)}")
        for key, attr in keys.items():
            if key in sub:
                kwargs[attr] = number(sub, key, f"{section}.")
    try:
        return NominalCalibration(**kwargs)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from exc


def write_nominal(nominal: NominalCalibration, path: str | Path) -> None:
    """Write ``nominal`` in the format ``load_nominal`` reads."""
    doc = {
        "pitch_deg": nominal.pitch_deg, "roll_deg": nominal.roll_deg,
        "height_m": nominal.height_m,
        "tolerances": {"pitch_deg": nominal.pitch_tol_deg, "roll_deg": nominal.roll_tol_deg,
                       "height_m": nominal.height_tol_m},
        "limits": {"max_angle_dev_deg": nominal.max_angle_dev_deg,
                   "max_height_dev_frac": nominal.max_height_dev_frac},
    }
    Path(path).write_text(yaml.safe_dump(doc, sort_keys=False))


# --- configuration ----------------------------------------------------------------------------


@dataclass(frozen=True)
class MonitorConfig:
    """Tuning of the monitor (units in the names; angles in degrees).

    ``fps`` converts ``false_alarms_per_hour`` into an average run length in frames (the CLI
    sets it from the input's timestamps). ``body_*`` must match the filter's body model
    (``MonitorConfig.from_noise(filters.model.NoiseParams())``); ``meas_*`` are the typical
    per-frame measurement standard deviations used for the threshold only (each frame's own
    variance is used in the statistics).
    """

    false_alarms_per_hour: float = 0.1
    fps: float = 10.0
    #: design shifts beyond tolerance, one CUSUM per value and side
    angle_shifts_deg: tuple[float, ...] = (0.15, 0.4, 1.0)
    height_shifts_m: tuple[float, ...] = (0.005, 0.015)
    #: body shaking (the filter model's Gauss–Markov) on pitch, roll; height has none
    body_tau_s: float = 0.3
    body_std_deg: float = 0.2
    #: the body std adapted to the data (``filters.body_scale``, as the filters do) over this
    #: many seconds of usable frames, at least ``body_std_deg``; ``body_std_unknown_deg``
    #: until ``body_window_min_pairs`` frames were seen; 0 keeps ``body_std_deg``. A body
    #: shaking beyond the model would otherwise read as a mount far off nominal
    body_window_s: float = 6.0
    body_window_min_pairs: int = 10
    body_std_unknown_deg: float = 1.5
    #: the measured heights (wheel speed) scatter with the body's heave and the pairs' scale
    #: errors beyond their reported variance: the robust spread of the window's heights less
    #: that variance is added as white noise (none in the model); this share of the nominal
    #: height until measured
    heave_std_unknown_frac: float = 0.02
    #: slow road-relative tilt on pitch and roll that is not a calibration change (road camber
    #: and slope, load, the front end's tracking correlation): Gauss–Markov, added to the
    #: long-run variance of the test. 0 = flat ground (test tracks, renders, the issue's
    #: simulated drives); public roads: see ``scripts/eval_kitti_monitor.py``
    road_std_deg: float = 0.0
    road_tau_s: float = 2.0
    meas_angle_std_deg: float = 0.1
    meas_height_std_m: float = 0.006
    huber_k: float = 3.0
    #: DRIFTING above warn_enter × threshold, back below warn_exit × threshold
    warn_enter: float = 0.5
    warn_exit: float = 0.25
    calibrate_after_s: float = 3.0
    clear_after_s: float = 10.0
    invalid_tau_s: float = 1.0
    #: frames the filter gated feed the test once gating persists this long (a moved camera
    #: is gated on every frame; the monitor must still see it)
    max_gated_run_s: float = 0.3
    #: history kept for the new-extrinsics estimate
    history_s: float = 60.0
    #: a HOLD shorter than this (one failed pair, a short stop) raises no event; the
    #: per-frame state still shows it. A longer one is reported once it has lasted this long,
    #: with the time and frame it began.
    min_hold_event_s: float = 1.0

    def __post_init__(self) -> None:
        if not self.false_alarms_per_hour > 0:
            raise InputError("monitor: false_alarms_per_hour must be > 0")
        if not self.fps > 0:
            raise InputError("monitor: fps must be > 0")
        if not self.angle_shifts_deg or not self.height_shifts_m:
            raise InputError("monitor: at least one design shift per axis is needed")
        if not (self.road_std_deg >= 0 and self.road_tau_s > 0):
            raise InputError("monitor: need road_std_deg >= 0 and road_tau_s > 0")
        if not self.min_hold_event_s >= 0:
            raise InputError("monitor: min_hold_event_s must be >= 0")
        if min(*self.angle_shifts_deg, *self.height_shifts_m) <= 0:
            raise InputError("monitor: design shifts must be > 0")
        if not 0 < self.warn_exit <= self.warn_enter < 1:
            raise InputError("monitor: need 0 < warn_exit <= warn_enter < 1")

    @classmethod
    def from_noise(cls, noise: Any, **overrides: Any) -> MonitorConfig:
        """Config whose body model is that of a ``filters.model.NoiseParams``."""
        return cls(body_tau_s=noise.body_tau_s, body_std_deg=noise.body_std_deg,
                   body_std_unknown_deg=noise.body_std_unknown_deg, **overrides)

    def body_noise(self) -> NoiseParams:
        """The body part of ``filters.model.NoiseParams`` this config describes (what the
        adaptive body std, ``body_scale.BodyScale``, reads)."""
        return NoiseParams(body_tau_s=self.body_tau_s, body_std_deg=self.body_std_deg,
                           body_std_unknown_deg=self.body_std_unknown_deg)


# --- per-frame input and output ---------------------------------------------------------------


@dataclass(frozen=True)
class MonitorInput:
    """What the monitor sees at one frame.

    ``pose``: the frame's measured pose (pitch rad, roll rad, height m; NaN where the frame
    says nothing about an axis, e.g. height without wheel speed) and ``pose_var`` its
    measurement variance (rad², rad², m²), body shaking excluded. ``mount``/``mount_cov``:
    the filter's mount estimate (same units) and 3×3 covariance, or None. ``usable`` False
    with a ``hold_reason`` puts the frame on HOLD; ``gated``: the filter rejected the frame.
    ``change``/``change_var``: the pair's measured change of (pitch, roll) since the frame
    before, ``dt`` s earlier (rad, rad²; ``body_scale.pair_change``), from which the body's
    shaking is measured; None: the body std stays the model's.
    """

    frame: int
    t: float
    pose: FloatArray
    pose_var: FloatArray
    usable: bool = True
    hold_reason: str = ""
    gated: bool = False
    mount: FloatArray | None = None
    mount_cov: FloatArray | None = None
    change: FloatArray | None = None
    change_var: FloatArray | None = None
    dt: float = math.nan


@dataclass(frozen=True)
class MonitorOutput:
    """The monitor's verdict at one frame.

    ``statistic``: per axis, the largest CUSUM over its threshold (1 = alarm);
    ``deviation``: 1 s average of pose − nominal (rad, rad, m); ``estimate``/``interval95``:
    new extrinsics (rad, rad, m) and their 95 % interval ((3, 2): low, high) while DRIFTING
    or RECALIBRATE, else None; ``event``: a JSON-ready dict when the state changed.
    """

    frame: int
    t: float
    state: str
    reason: str
    statistic: FloatArray
    deviation: FloatArray
    estimate: FloatArray | None = None
    interval95: FloatArray | None = None
    event: dict[str, Any] | None = None
    mount: FloatArray | None = None


# --- thresholds -------------------------------------------------------------------------------


def cusum_log_arl(b: float, drift: float) -> float:
    """Natural log of the average run length (samples) of a CUSUM of unit-variance Gaussian
    increments with mean ``drift`` and threshold ``b`` (both in standard deviations),
    Siegmund's approximation ARL = (exp(−2μb') + 2μb' − 1)/(2μ²), b' = b + 1.166."""
    bb = b + _SIEGMUND_SHIFT
    if abs(drift) < 1e-9:
        return 2.0 * math.log(bb)
    x = 2.0 * drift * bb
    if -x > 30.0:  # exp(-x) dominates; stay in log space
        return -x + math.log1p((x - 1.0) * math.exp(x)) - math.log(2.0 * drift * drift)
    return math.log(math.exp(-x) + x - 1.0) - math.log(2.0 * drift * drift)


def cusum_threshold(arl: float, drift: float) -> float:
    """Threshold b (standard deviations of the increment) whose in-control ARL is ``arl``
    samples, for increments of mean ``drift`` < 0 (``cusum_log_arl`` inverted)."""
    if arl <= 1.0:
        raise ValueError(f"ARL must exceed one sample, got {arl}")
    target = math.log(arl)
    return float(brentq(lambda b: cusum_log_arl(b, drift) - target, 0.0, 1e3 + target))


def long_run_variance(body_std: float, a: float, meas_var: float) -> float:
    """Variance per frame of the information about a constant offset in AR(1) body
    (stationary std ``body_std``, coefficient ``a``) plus white noise ``meas_var``."""
    return body_std**2 * (1.0 + a) / (1.0 - a) + meas_var


def mean_variance(body_std: float, a: float, meas_var: float, n: int) -> float:
    """Variance of the mean of ``n`` consecutive frames of AR(1) body + white noise."""
    if n <= 0:
        return math.inf
    if a <= 0.0:
        return (body_std**2 + meas_var) / n
    corr = (1.0 + a) / (1.0 - a) - 2.0 * a * (1.0 - a**n) / (n * (1.0 - a) ** 2)
    return body_std**2 * corr / n + meas_var / n


# --- batched core -----------------------------------------------------------------------------


@dataclass
class _Arrays:
    """Mutable state of ``MonitorCore`` for B streams (leading axis)."""

    body: FloatArray  # (B, 3) body estimate
    body_var: FloatArray  # (B, 3)
    body_std: FloatArray  # (B, 3) stationary body std (rad, rad, m): the model's or adapted
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
    quiet: NDArray[np.int64]  # (B,) frames below warn_exit while RECALIBRATE / INVALID
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
        self.tau = np.array([cfg.body_tau_s, cfg.body_tau_s, 0.0])
        sb = math.radians(cfg.body_std_deg)
        self.body_std = np.array([sb, sb, 0.0])
        sr = math.radians(cfg.road_std_deg)
        self.road_std = np.array([sr, sr, 0.0])
        self._meas_var = np.array([math.radians(cfg.meas_angle_std_deg) ** 2] * 2
                                  + [cfg.meas_height_std_m**2])
        self.w_nominal = self._typical_w(self.body_std)
        self._arl = self.n_tests * 3600.0 * cfg.fps / cfg.false_alarms_per_hour
        # thresholds (log-likelihood units) at the model's body std and at larger adapted ones:
        # angles at k × the model's std, height (no body in the model) where its long-run
        # variance is k² × the measurement's alone
        meas_h = math.sqrt(self._meas_var[2])
        self._threshold_table = np.stack([
            self._thresholds(self._typical_w(
                np.array([sb * k, sb * k, meas_h * math.sqrt(k * k - 1.0)])))
            for k in _BODY_SCALES
        ])  # (S, 3, D)
        self.threshold = self._threshold_table[0]
        self.limits = nominal.limits
        self.nominal_values = nominal.values
        self.calib_frames = max(1, round(cfg.calibrate_after_s * cfg.fps))
        self.clear_frames = max(1, round(cfg.clear_after_s * cfg.fps))
        self.max_gated = max(0, round(cfg.max_gated_run_s * cfg.fps))
        self.reset()

    def _typical_w(self, body_std: FloatArray) -> FloatArray:
        """(3,) long-run variance per frame at the configured frame rate and measurement
        noise for a body of stationary std ``body_std`` (3,)."""
        dt = np.full(3, 1.0 / self.config.fps)
        a = self._decay(dt, self._tau_of(body_std))
        return np.array([long_run_variance(body_std[j], a[j], self._meas_var[j])
                         for j in range(3)]) + self._road_lrv(dt)

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

    def _tau_of(self, body_std: FloatArray) -> FloatArray:
        """Body time constants (s) at stationary std ``body_std`` (..., 3): the model's
        τ·(σ₀/σ)², as ``filters.model.body_transition`` (the body's low-frequency power stays
        the model's; the shaking beyond it is fast)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(body_std > 0, self.body_std / body_std, 1.0)
        return self.tau * np.where(self.body_std > 0, ratio, 1.0) ** 2

    # -- public ---------------------------------------------------------------------------

    def reset(self, streams: NDArray[np.bool_] | None = None) -> None:
        """Start over (UNCALIBRATED, statistics at zero) for ``streams`` (mask), or all."""
        b, d = self.batch, self.delta.shape[1]
        fresh = _Arrays(
            body=np.zeros((b, 3)), body_var=np.tile(self.body_std**2, (b, 1)),
            body_std=np.tile(self.body_std, (b, 1)),
            threshold=np.tile(self.threshold, (b, 1, 1)),
            invalid_axis=np.zeros(b, dtype=np.int64), invalid_dev=np.zeros(b),
            invalid_mount=np.zeros(b, dtype=bool), onset=np.zeros(b, dtype=np.int64),
            t_last=np.full((b, 3), np.nan), cusum=np.zeros((b, 3, 2, d)),
            zero_count=np.zeros((b, 3, 2, d), dtype=np.int64),
            used=np.zeros((b, 3), dtype=np.int64), count=np.zeros(b, dtype=np.int64),
            ema=np.zeros((b, 3)),
            base=np.full(b, UNCALIBRATED, dtype=np.int64), evidence=np.zeros(b, dtype=np.int64),
            quiet=np.zeros(b, dtype=np.int64), gated_run=np.zeros(b, dtype=np.int64),
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
        a = self._decay(dt, self._tau_of(s.body_std))
        x_pred = a * s.body
        p_pred = a * a * s.body_var + s.body_std**2 * (1.0 - a * a)
        nu = dev0 - x_pred
        sv = p_pred + var0
        road_var = self.road_std**2
        lim = cfg.huber_k * np.sqrt(sv + road_var)
        nu_c = np.clip(nu, -lim, lim)
        gain = p_pred / sv
        rho = (1.0 - a) / (1.0 - a + a * gain)
        u = nu_c / rho
        w = sv / (rho * rho) + self._road_lrv(dt)
        s.body = np.where(use, x_pred + gain * nu_c, s.body)
        s.body_var = np.where(use, (1.0 - gain) * p_pred, s.body_var)
        s.t_last = np.where(use, t[:, None], s.t_last)
        s.used = s.used + use
        s.count = s.count + usable

        # CUSUM bank: (B, 3, side, D)
        signed = np.stack([u, -u], axis=2)[..., None]  # (B, 3, 2, 1)
        inc = (self.delta / w[..., None])[:, :, None, :] * (signed - self.ref[None, :, None, :])
        new = np.maximum(0.0, s.cusum + inc)
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

    @staticmethod
    def _decay(dt: FloatArray, tau: FloatArray) -> FloatArray:
        """AR(1) coefficient of the body over ``dt`` at time constants ``tau`` (0: white)."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            a = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
        return a

    def _set_body_std(self, body_std: FloatArray) -> None:
        """Adopt body stds (B, 2) for pitch and roll (floored at the configured one) or (B, 3)
        with the height's heave too (m; none in the model: white, at least 0) and the
        thresholds that go with them."""
        s = self.s
        n = body_std.shape[1]
        std = np.maximum(body_std, self.body_std[:n])
        s.body_std[:, :n] = std
        scale = np.empty_like(std)
        scale[:, :2] = std[:, :2] / self.body_std[:2]
        if n == 3:  # the height's long-run variance over its measurement's alone, rooted
            scale[:, 2] = np.sqrt(1.0 + std[:, 2] ** 2 / self._meas_var[2])
        # log-linear interpolation of the threshold table (clamped at its ends)
        x = np.log(np.clip(scale, _BODY_SCALES[0], _BODY_SCALES[-1]))
        grid = np.log(_BODY_SCALES)
        hi = np.clip(np.searchsorted(grid, x, side="right"), 1, len(grid) - 1)  # (B, n)
        lo = hi - 1
        f = ((x - grid[lo]) / (grid[hi] - grid[lo]))[..., None]  # (B, n, 1)
        table = self._threshold_table  # (S, 3, D)
        for j in range(n):
            s.threshold[:, j] = (1 - f[:, j]) * table[lo[:, j], j] + f[:, j] * table[hi[:, j], j]

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
        base = np.where(recal & (s.quiet >= self.clear_frames), CALIBRATED, base)
        # UNCALIBRATED / CALIBRATED / DRIFTING
        normal = usable & ~alarm & np.isin(base, (UNCALIBRATED, CALIBRATED, DRIFTING))
        s.evidence = np.where(normal, s.evidence + 1, s.evidence)
        enough = s.evidence >= self.calib_frames
        nxt = np.where(
            warn & enough, DRIFTING,
            np.where(
                base == DRIFTING,
                np.where(calm, np.where(enough, CALIBRATED, UNCALIBRATED), DRIFTING),
                np.where(enough, CALIBRATED, UNCALIBRATED),
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


class _HeaveScale:
    """Trailing-window robust spread (m) of the measured heights beyond their reported
    variance, for the monitor's height test (``MonitorConfig.heave_std_unknown_frac``); the
    same start rule as ``body_scale.BodyScale``: ``unknown`` below three heights, then the
    spread's upper 95 % bound until ``min_pairs``."""

    def __init__(self, window_s: float, min_pairs: int, unknown: float) -> None:
        self._window_s, self._min_pairs, self._unknown = window_s, min_pairs, unknown
        self._seen: deque[tuple[float, float, float]] = deque()

    def add(self, t: float, height: float, var: float) -> None:
        if math.isfinite(height) and math.isfinite(var):
            self._seen.append((t, height, var))
        while self._seen and self._seen[0][0] < t - self._window_s:
            self._seen.popleft()

    def std(self) -> float:
        n = len(self._seen)
        std = 0.0
        if n:
            h = np.array([x[1] for x in self._seen])
            mad = float(np.median(np.abs(h - np.median(h))))
            var = (1.4826 * mad) ** 2 - float(np.median([x[2] for x in self._seen]))
            std = math.sqrt(max(0.0, var))
        return float(cautious_std(std, n, self._min_pairs, self._unknown))


def _pad(x: FloatArray, n: int) -> FloatArray:
    return np.concatenate([x, np.full(n - len(x), x[-1])])


# --- one stream: events, reasons, estimates ---------------------------------------------------


class DriftMonitor:
    """Streaming monitor of one camera: ``update(MonitorInput) -> MonitorOutput``.

    Example::

        mon = DriftMonitor(load_nominal("data/nominal_car.yaml"), MonitorConfig(fps=10))
        for inp in inputs:
            out = mon.update(inp)
            if out.event:
                print(json.dumps(out.event))
    """

    def __init__(self, nominal: NominalCalibration, config: MonitorConfig | None = None) -> None:
        self.core = MonitorCore(nominal, config, batch=1)
        self.nominal = nominal
        self.config = self.core.config
        n_hist = max(1, round(self.config.history_s * self.config.fps))
        self._history: deque[tuple[int, FloatArray, FloatArray]] = deque(maxlen=n_hist)
        self._state: str | None = None
        self._reported: str | None = None  # the state the last event announced
        self._hold_event: dict[str, Any] | None = None  # a HOLD not yet long enough to report
        self._change_at: int | None = None
        self._held = 0
        cfg = self.config
        self._body = BodyScale(cfg.body_noise(), cfg.body_window_s, cfg.body_window_min_pairs)
        self._heave = _HeaveScale(cfg.body_window_s, cfg.body_window_min_pairs,
                                  cfg.heave_std_unknown_frac * nominal.height_m)

    @property
    def thresholds(self) -> FloatArray:
        """(3, D) CUSUM thresholds (log-likelihood units) per axis and design shift, at the
        current body std."""
        return self.core.s.threshold[0].copy()

    def accept(self, nominal: NominalCalibration) -> None:
        """Adopt a new nominal calibration (after a recalibration) and start over."""
        self.__init__(nominal, self.config)  # type: ignore[misc]

    def update(self, inp: MonitorInput) -> MonitorOutput:
        """Judge one frame (see ``MonitorOutput``)."""
        core = self.core
        pose = np.asarray(inp.pose, dtype=float).reshape(3)
        var = np.asarray(inp.pose_var, dtype=float).reshape(3)
        mount = None if inp.mount is None else np.asarray(inp.mount, dtype=float).reshape(1, 3)
        before = core.s.base[0]
        body_std = None
        if inp.usable and inp.change is not None and self.config.body_window_s > 0:
            change_var = np.full(2, np.nan) if inp.change_var is None else inp.change_var
            self._body.add(float(inp.t), pose[:2], var[:2], np.asarray(inp.change, dtype=float),
                           np.asarray(change_var, dtype=float), float(inp.dt))
            self._heave.add(float(inp.t), float(pose[2]), float(var[2]))
            body_std = np.append(self._body.std(), self._heave.std())[None]
        code = int(core.step(
            np.array([float(inp.t)]), pose[None], var[None], np.array([bool(inp.usable)]),
            np.array([bool(inp.gated)]), mount, body_std,
        )[0])
        base = int(core.s.base[0])
        used = int(core.s.count[0])
        if inp.usable:
            self._history.append((used, pose - core.nominal_values, var))
        if base == RECALIBRATE and before != RECALIBRATE:
            self._change_at = int(core.s.onset[0])  # the statistics restarted at the alarm
        elif base not in (RECALIBRATE, DRIFTING):
            self._change_at = None
        state = STATES[code]
        stat = core.last_statistic[0].copy()
        estimate = interval = None
        if code in (DRIFTING, RECALIBRATE) or (code == HOLD and base in (DRIFTING, RECALIBRATE)):
            start = self._change_at if base == RECALIBRATE else self._change_start()
            estimate, interval = self._estimate(start)
        reason = self._reason(code, base, inp, stat, estimate, interval)
        event = self._debounced_event(inp, state, reason, estimate, interval)
        self._state = state
        return MonitorOutput(
            frame=inp.frame, t=float(inp.t), state=state, reason=reason, statistic=stat,
            deviation=core.s.ema[0].copy(), estimate=estimate, interval95=interval, event=event,
            mount=None if inp.mount is None else np.asarray(inp.mount, dtype=float),
        )

    # -- internals --------------------------------------------------------------------------

    def _debounced_event(self, inp: MonitorInput, state: str, reason: str,
                         estimate: FloatArray | None, interval: FloatArray | None,
                         ) -> dict[str, Any] | None:
        """The event of this frame, if any: a change of the announced state, where a HOLD
        counts only once it has lasted ``min_hold_event_s`` (see MonitorConfig)."""
        if state == "HOLD":
            if self._state != "HOLD":
                self._hold_event = self._event(inp, state, reason, estimate, interval)
            pending = self._hold_event
            if (pending is not None and self._reported != "HOLD"
                    and float(inp.t) - pending["t"] >= self.config.min_hold_event_s - 1e-9):
                self._reported = "HOLD"
                return pending
            return None
        self._hold_event = None
        if state == self._reported:
            return None
        self._reported = state
        return self._event(inp, state, reason, estimate, interval)

    def _change_start(self) -> int:
        """Used-frame count at which the change under way began (``MonitorCore.change_onset``
        on the leading axis)."""
        core = self.core
        return int(core.change_onset(core.s.alarm_axis[:1])[0])

    def _estimate(self, start: int | None) -> tuple[FloatArray, FloatArray]:
        core, cfg = self.core, self.config
        hist = [h for h in self._history if start is None or h[0] > start]
        min_n = max(3, round(0.5 * cfg.fps))
        if len(hist) < min_n:
            hist = list(self._history)[-min_n:]
        dev = np.array([h[1] for h in hist])
        var = np.array([h[2] for h in hist])
        est = np.full(3, np.nan)
        half = np.full(3, np.nan)
        body_std = core.s.body_std[0]
        a = core._decay(np.full(3, 1.0 / cfg.fps), core._tau_of(body_std))
        a_road = math.exp(-1.0 / (cfg.fps * cfg.road_tau_s))
        for j in range(3):
            ok = np.isfinite(dev[:, j])
            n = int(ok.sum())
            if n == 0:
                continue
            est[j] = float(np.median(dev[ok, j]))
            mv = (mean_variance(body_std[j], a[j], float(np.mean(var[ok, j])), n)
                  + mean_variance(core.road_std[j], a_road, 0.0, n))
            half[j] = 1.96 * math.sqrt(math.pi / 2.0 * mv)
            data = batch_means(dev[ok, j])  # the data's own scatter, where wider
            if data is not None:
                half[j] = max(half[j], math.sqrt(math.pi / 2.0) * data.half_width95)
        value = core.nominal_values + est
        return value, np.stack([value - half, value + half], axis=1)

    def _reason(self, code: int, base: int, inp: MonitorInput, stat: FloatArray,
                estimate: FloatArray | None, interval: FloatArray | None) -> str:
        core = self.core
        if code == HOLD:
            return inp.hold_reason or ("gated by the filter" if inp.gated else "unusable frame")
        if code == INVALID:
            j = int(core.s.invalid_axis[0])
            limit = _fmt_dev(j, core.limits[j], sign=False)
            source = "filter's mount" if core.s.invalid_mount[0] else "1 s mean of the frames"
            return (f"{AXES[j]} {_fmt_dev(j, float(core.s.invalid_dev[0]))} from nominal "
                    f"({source}) exceeds the limit {limit}")
        if code == UNCALIBRATED:
            return (f"collecting evidence ({int(core.s.evidence[0])}/{core.calib_frames} "
                    "usable frames)")
        if code == CALIBRATED:
            return "consistent with nominal within tolerance"
        j = int(core.s.alarm_axis[0])
        tol = _fmt_dev(j, core.nominal.tolerances[j], sign=False)
        dev = (estimate - core.nominal_values)[j] if estimate is not None else core.s.ema[0, j]
        if code == RECALIBRATE:
            span = ""
            if interval is not None:
                lo, hi = interval[j] - core.nominal_values[j]
                span = f", 95 % {_fmt_dev(j, lo)} … {_fmt_dev(j, hi)}"
            return (f"{AXES[j]} changed: {_fmt_dev(j, dev)} from nominal (median since the "
                    f"change{span}), beyond the tolerance {tol}: the test crossed its "
                    "threshold")
        return (f"{AXES[j]} drifting: the test stands at {stat[j]:.0%} of its threshold "
                f"(DRIFTING from {self.config.warn_enter:.0%}); median deviation since it "
                f"began {_fmt_dev(j, dev)}, tolerance {tol}")

    def _event(self, inp: MonitorInput, state: str, reason: str, estimate: FloatArray | None,
               interval: FloatArray | None) -> dict[str, Any]:
        ev: dict[str, Any] = {"t": float(inp.t), "frame": int(inp.frame), "state": state}
        ev["estimate"] = None if estimate is None else _pose_dict(estimate)
        ev["interval95"] = None if interval is None else {
            k: [v0, v1] for (k, v0), (_, v1) in zip(
                _pose_dict(interval[:, 0]).items(), _pose_dict(interval[:, 1]).items(), strict=True)
        }
        if inp.mount is not None:
            ev["filter_mount"] = _pose_dict(np.asarray(inp.mount, dtype=float))
        ev["reason"] = reason
        return ev


def _pose_dict(v: FloatArray) -> dict[str, float | None]:
    out = {"pitch_deg": math.degrees(v[0]), "roll_deg": math.degrees(v[1]), "height_m": v[2]}
    return {k: (round(float(x), 6) if math.isfinite(x) else None) for k, x in out.items()}


def _fmt_dev(axis: int, value: float, sign: bool = True) -> str:
    if not math.isfinite(value):
        return "?"
    if axis < 2:
        return f"{math.degrees(value):+.2f}°" if sign else f"{math.degrees(value):.2f}°"
    return f"{value * 100:+.1f} cm" if sign else f"{value * 100:.1f} cm"


def run_monitor(
    inputs: Iterable[MonitorInput], nominal: NominalCalibration, config: MonitorConfig | None = None
) -> list[MonitorOutput]:
    """Monitor a whole sequence; one output per input."""
    mon = DriftMonitor(nominal, config)
    return [mon.update(i) for i in inputs]


def write_events(outputs: Sequence[MonitorOutput], path: str | Path) -> int:
    """Write the events of ``outputs`` as JSON lines; return how many."""
    n = 0
    with Path(path).open("w") as f:
        for o in outputs:
            if o.event is not None:
                f.write(json.dumps(o.event) + "\n")
                n += 1
    return n


__all__ = [
    "STATES", "DriftMonitor", "MonitorConfig", "MonitorCore", "MonitorInput", "MonitorOutput",
    "NominalCalibration", "cusum_threshold", "load_nominal", "run_monitor", "write_events",
    "write_nominal",
]
