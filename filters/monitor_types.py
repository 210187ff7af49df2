"""The drift monitor's vocabulary: its tuning (``MonitorConfig``), its states, and what goes
in (``MonitorInput``) and comes out (``MonitorOutput``) at each frame.

States (``STATES``; the codes ``UNCALIBRATED`` … ``HOLD`` index it):

- ``UNCALIBRATED``: not enough usable evidence yet (start-up, after INVALID clears), or
  evidence that does not yet put the deviation within the tolerances;
- ``CALIBRATED``: consistent with the nominal calibration: no change found, and the mean
  deviation since the evidence began shown within the tolerance plus the smallest design
  shift (its ``calibrate_within_z``-standard-error interval inside that bound);
- ``DRIFTING``: evidence of a deviation beyond tolerance is accumulating (a test statistic
  above ``warn_enter`` × its threshold);
- ``RECALIBRATE``: a test crossed its threshold; the output carries the new extrinsics and
  their 95 % interval. Left only after ``clear_after_s`` of usable frames with every
  statistic below ``warn_enter`` (hysteresis), or by ``accept`` of a new calibration;
- ``INVALID``: the extrinsics are physically implausible (``NominalCalibration`` limits);
- ``HOLD``: this frame's evidence cannot be trusted (estimator failure, too few inliers,
  standstill, a frame the filter gated); the statistics are frozen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vipm_track.errors import InputError

from .model import NoiseParams

FloatArray = NDArray[np.float64]

STATES: tuple[str, ...] = (
    "UNCALIBRATED", "CALIBRATED", "DRIFTING", "RECALIBRATE", "INVALID", "HOLD",
)
UNCALIBRATED, CALIBRATED, DRIFTING, RECALIBRATE, INVALID, HOLD = range(6)
AXES: tuple[str, ...] = ("pitch", "roll", "height")


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
    #: and over at least this many seconds of frames: 10 pairs of a 20-fps camera are half a
    #: period of a 1-Hz sway, whose calm half taken for the shaking made its other half a
    #: mount change (a correct car camera RECALIBRATE 0.8 s into its drive)
    body_window_min_s: float = 1.0
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
    #: errors that run on from frame to frame (a tracked pair starts from the pose the pair
    #: before found; successive pairs see the same road): the lag-1 autocorrelation ρ of the
    #: whitened innovations over an exponential window of this time constant (s; as many
    #: pairs as a trailing window twice as long), where significant, inflates the long-run
    #: variance by (1+ρ)/(1−ρ) (``filters.row_correlation``, as the filters' σ); ρ is taken as
    #: its cap until ``correlation_min_pairs`` lagged frames were seen, and the factor judged
    #: by is the oldest of the last ``correlation_delay_s`` (a mount change makes the
    #: innovations after it run on: it must not widen its own test). 0: white errors
    correlation_tau_s: float = 3.0
    correlation_min_pairs: int = 10
    correlation_block_s: float = 1.0
    correlation_window_blocks: float = 10.0
    correlation_min_blocks: int = 5
    correlation_delay_s: float = 5.0
    meas_angle_std_deg: float = 0.1
    meas_height_std_m: float = 0.006
    huber_k: float = 3.0
    #: no test crosses its threshold on fewer frames than this (each moves it by at most
    #: 1/min_alarm_frames of it): one outlier is not a change
    min_alarm_frames: int = 3
    #: DRIFTING above warn_enter × threshold, back below warn_exit × threshold
    warn_enter: float = 0.5
    warn_exit: float = 0.25
    calibrate_after_s: float = 3.0
    #: CALIBRATED also needs the mean deviation since the evidence began (the whitened
    #: observations' weighted mean), ± this many standard errors, within the tolerance plus
    #: the smallest design shift: "no change found" alone called a camera 1° off CALIBRATED
    #: until its test caught up, and "not shown beyond" did so wherever the errors were
    #: too correlated to show anything
    calibrate_within_z: float = 1.96
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
        if not self.false_alarms_per_hour <= 3600.0 * self.fps:
            raise InputError(
                f"monitor: false alarms per hour must be at most one per frame (3600 × "
                f"{self.fps:g} fps = {3600.0 * self.fps:g}), got {self.false_alarms_per_hour:g}")
        if not self.angle_shifts_deg or not self.height_shifts_m:
            raise InputError("monitor: at least one design shift per axis is needed")
        if not (self.road_std_deg >= 0 and self.road_tau_s > 0):
            raise InputError("monitor: need road_std_deg >= 0 and road_tau_s > 0")
        if not self.min_hold_event_s >= 0:
            raise InputError("monitor: min_hold_event_s must be >= 0")
        if min(*self.angle_shifts_deg, *self.height_shifts_m) <= 0:
            raise InputError("monitor: design shifts must be > 0")
        if not self.body_window_min_s >= 0:
            raise InputError("monitor: body_window_min_s must be >= 0")
        if not self.calibrate_within_z > 0:
            raise InputError("monitor: calibrate_within_z must be > 0")
        if not 0 < self.warn_exit <= self.warn_enter < 1:
            raise InputError("monitor: need 0 < warn_exit <= warn_enter < 1")

    @classmethod
    def from_noise(cls, noise: Any, **overrides: Any) -> MonitorConfig:
        """Config whose body model is that of a ``filters.model.NoiseParams``."""
        return cls(body_tau_s=noise.body_tau_s, body_std_deg=noise.body_std_deg,
                   body_std_unknown_deg=noise.body_std_unknown_deg, **overrides)

    @property
    def body_min_pairs(self) -> int:
        """Pairs the adaptive body std needs before it is taken as measured: at least
        ``body_window_min_pairs``, and ``body_window_min_s`` of frames."""
        return max(self.body_window_min_pairs, math.ceil(self.body_window_min_s * self.fps))

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
    ``deviation``: 1 s average of pose − nominal (rad, rad, m; NaN on an axis no frame has
    measured yet, e.g. height without wheel speed); ``estimate``/``interval95``:
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


__all__ = [
    "AXES", "CALIBRATED", "DRIFTING", "HOLD", "INVALID", "RECALIBRATE", "STATES", "UNCALIBRATED",
    "MonitorConfig", "MonitorInput", "MonitorOutput",
]
