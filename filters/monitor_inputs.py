"""Per-frame monitor inputs (``filters.monitor_types.MonitorInput``) from the filter pipeline: the
pair measurements the filter is fed, wheel speed, and the filter's states.

- pitch, roll: the measured pose of frame k (``z[2:4]`` of its pair) and its variance;
- height: with wheel speed, h_k = h_assumed · d_wheel / ‖t_est‖ (CONVENTIONS.md, Scale), where
  d_wheel is the wheel-speed distance travelled between frames k−1 and k (trapezoidal
  integral of the samples, so every sample counts once); its variance combines the
  translation covariance and the speed noise. Without speed, or across a gap of more than
  ``max_speed_gap_s`` in the speed samples, the height is NaN (untested);
- HOLD reasons: the estimator's status when not ``ok``; ``inconsistent with neighbouring
  pairs`` (an outlier: see ``inconsistent_pairs``); ``too few inliers`` below
  ``min_inliers``; ``standstill`` where the wheel speed is at most ``min_speed_mps`` (a
  stop, as the filters' zero-velocity update), or without wheel speed where the pair's
  travel is below ``min_travel_frac`` of the camera height (the scale of the ground's image
  motion: the same rule for a 0.2 m/s robot and a 40 m/s car); ``slow for a forward
  camera`` where a level camera's pair travels less than ``min_travel_frac_forward`` of its
  height (:func:`forward_camera_options`): its pitch reads low and its travel long, pair
  after pair (docs/kitti.md, "Slow driving"), which the test would take for a changed mount;
- mount / covariance / gated: from the filter's per-frame states where given.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from .body_scale import pair_change
from .ekf import ExtrinsicsEKF, speed_at
from .ekf_state import EkfConfig
from .forward_slow import (
    MIN_TRAVEL_FRAC_FORWARD,
    SLOW_FORWARD,
    is_level,
    level_pitches,
    slow_pairs,
)
from .monitor import DriftMonitor
from .monitor_types import MonitorConfig, MonitorInput, MonitorOutput
from .nominal import NominalCalibration
from .pair_height import MIN_SPEED_MPS, MIN_TRAVEL_FRAC, pair_heights, pair_spans

FloatArray = NDArray[np.float64]


def forward_camera_options(nominal: NominalCalibration) -> dict[str, float]:
    """The input options for a camera at ``nominal``: a level camera is not judged on slow
    pairs (``forward_slow``)."""
    if is_level(nominal.pitch_deg):
        return {"min_travel_frac_forward": MIN_TRAVEL_FRAC_FORWARD}
    return {}


@dataclass(frozen=True)
class InputArrays:
    """Monitor inputs of n frames as arrays: ``pose``/``pose_var`` (n, 3) (rad, rad, m;
    NaN = no information), ``reason`` (n,) the HOLD reason or '' for a usable frame."""

    frame: NDArray[np.int64]
    t: FloatArray
    pose: FloatArray
    pose_var: FloatArray
    reason: NDArray[np.object_]

    @property
    def usable(self) -> NDArray[np.bool_]:
        return self.reason == ""


def input_arrays(
    frame: NDArray[np.int64],
    t: FloatArray,
    z: FloatArray,
    cov: FloatArray,
    height_assumed: FloatArray,
    status: Sequence[str],
    inliers: NDArray[np.int64] | None = None,
    speed: Any | None = None,
    *,
    clock_offset_s: float = 0.0,
    min_speed_mps: float = MIN_SPEED_MPS,
    min_travel_frac: float = MIN_TRAVEL_FRAC,
    min_inliers: int = 0,
    speed_std_rel: float = 0.005,
    speed_std_abs_mps: float = 0.002,
    consistency_gate: float = 5.0,
    max_speed_gap_s: float = 0.5,
    min_travel_frac_forward: float = 0.0,
) -> InputArrays:
    """Vectorised core of ``inputs_from_measurements`` on the measurement arrays: ``z`` (n, 7)
    and ``cov`` (n, 7, 7) in the order of ``vipm_track.measurement``, ``status`` per frame."""
    frame = np.asarray(frame)
    t = np.asarray(t, dtype=float)
    z = np.asarray(z, dtype=float)
    cov = np.asarray(cov, dtype=float)
    n = len(t)
    h0 = np.broadcast_to(np.asarray(height_assumed, dtype=float), (n,))
    status = np.asarray(status, dtype=object)
    ok = (status == "ok") & np.all(np.isfinite(z), axis=1)
    travel = np.hypot(z[:, 4], z[:, 5])
    dt = pair_spans(frame, t)
    height = np.full(n, np.nan)
    height_var = np.full(n, np.nan)
    if speed is not None:
        height, height_var, v_now = pair_heights(
            t, dt, z, cov, h0, np.asarray(speed.t, dtype=float) + clock_offset_s,
            np.asarray(speed.speed_mps, dtype=float), min_speed_mps=min_speed_mps,
            min_travel_frac=min_travel_frac, speed_std_rel=speed_std_rel,
            speed_std_abs_mps=speed_std_abs_mps, max_speed_gap_s=max_speed_gap_s)
    else:
        v_now = np.full(n, np.nan)
    # standstill: from the wheel speed where it covers the frame, else from the pair's travel
    # in camera heights (travel at the assumed height over that height: the scale cancels)
    still = np.where(np.isfinite(v_now), v_now <= min_speed_mps,
                     travel < min_travel_frac * h0)
    reason = np.full(n, "", dtype=object)
    if consistency_gate > 0:
        reason[inconsistent_pairs(frame, z, cov, consistency_gate)] = (
            "inconsistent with neighbouring pairs")
    if min_inliers > 0 and inliers is not None:
        inl = np.asarray(inliers)
        reason[(inl > 0) & (inl < min_inliers)] = "too few inliers"
    reason[still & (reason == "")] = "standstill"
    # judged by the pair's own pitch, not the nominal's: a camera tens of degrees from a
    # level nominal (another camera's file) is no slow forward camera but a wrong mount
    slow = slow_pairs(z, h0, min_travel_frac_forward) & level_pitches(np.degrees(z[:, 2]))
    reason[slow & (reason == "")] = SLOW_FORWARD
    failed = ~ok
    reason[failed] = np.where(status[failed] == "ok", "no estimate", status[failed])
    pose = np.stack([z[:, 2], z[:, 3], height], axis=1)
    pose_var = np.stack([cov[:, 2, 2], cov[:, 3, 3], height_var], axis=1)
    return InputArrays(frame, t, pose, pose_var, reason)


def inconsistent_pairs(
    frame: NDArray[np.int64], z: FloatArray, cov: FloatArray, gate: float = 5.0
) -> NDArray[np.bool_]:
    """Pairs whose angles disagree with a neighbouring pair (outliers), (n,) bool.

    Pair k measures frames k−1 and k; pair k+1 measures frames k and k+1: both measure the
    pose of frame k, so ``z[k, 2:4]`` and ``z[k+1, 0:2]`` agree within their noise whatever
    the mount does (a mount step shifts both). When they differ by more than ``gate``
    standard deviations one of the two is wrong and neither is trusted (two outliers in a row
    can agree with each other, so requiring both sides would let them through). Needs one
    frame of look-ahead.
    """
    n = len(frame)
    bad_next = np.zeros(n, dtype=bool)
    if n > 1:
        adjacent = np.asarray(frame)[1:] == np.asarray(frame)[:-1] + 1
        diff = z[:-1, 2:4] - z[1:, 0:2]
        var = np.stack([cov[:-1, 2, 2] + cov[1:, 0, 0], cov[:-1, 3, 3] + cov[1:, 1, 1]], axis=1)
        with np.errstate(invalid="ignore"):
            big = np.abs(diff) > gate * np.sqrt(var)
        known = adjacent & np.all(np.isfinite(diff), axis=1)
        bad_next[:-1] = known & big.any(axis=1)
    return bad_next | np.concatenate([[False], bad_next[:-1]])


def inputs_from_measurements(
    measurements: Sequence[PairMeasurement],
    speed: Any | None = None,
    states: Sequence[Any] | None = None,
    **options: Any,
) -> list[MonitorInput]:
    """Monitor inputs, one per measurement (see module doc).

    ``speed``: anything with ``t`` (s, speed clock) and ``speed_mps`` arrays (a
    ``filters.wheel_speed.SpeedSeries`` or ``filters.drive_sim.SpeedSamples``);
    ``states``: the filter's per-frame states aligned with ``measurements`` (read through
    ``mount_from_state``), or None. ``options``: those of ``input_arrays``
    (``clock_offset_s`` added to the speed times to reach the camera clock, ``min_speed_mps``,
    ``min_inliers``, ``speed_std_rel``/``speed_std_abs_mps`` the noise of one speed sample).
    """
    n = len(measurements)
    if states is not None and len(states) != n:
        raise ValueError(f"{len(states)} filter states for {n} measurements")
    if n == 0:
        return []
    arr = input_arrays(
        np.array([m.frame for m in measurements]), np.array([m.t for m in measurements]),
        np.array([m.z for m in measurements]), np.array([m.covariance for m in measurements]),
        np.array([m.height_assumed for m in measurements]),
        [m.status for m in measurements], np.array([m.inliers for m in measurements]),
        speed, **options,
    )
    change, change_var = pair_change(np.array([m.z for m in measurements]),
                                     np.array([m.covariance for m in measurements]))
    dt = np.concatenate([[np.nan], np.diff(arr.t)])
    out = []
    for k in range(n):
        mount = mount_cov = None
        gated = False
        if states is not None:
            mount, mount_cov, gated = mount_from_state(states[k])
        reason = str(arr.reason[k])
        out.append(MonitorInput(
            frame=int(arr.frame[k]), t=float(arr.t[k]), pose=arr.pose[k],
            pose_var=arr.pose_var[k], usable=not reason, hold_reason=reason, gated=gated,
            mount=mount, mount_cov=mount_cov, change=change[k], change_var=change_var[k],
            dt=float(dt[k]),
        ))
    return out


def mount_from_state(state: Any) -> tuple[FloatArray | None, FloatArray | None, bool]:
    """(mount (3,), covariance (3, 3), pose gated) of a filter state; None where absent.

    Reads ``mount`` (or ``mount_pitch``, ``mount_roll``, ``mount_height``), ``mount_cov`` and
    ``gated`` (``filters.ekf.FilterState``: '', 'pose', 'motion', 'pose+motion'; only a
    gated *pose* concerns the monitor; a bool is taken as is). A state whose ``status`` is
    ``waiting`` (filter not initialised) has no mount."""
    if state is None or getattr(state, "status", "") == "waiting":
        return None, None, False
    mount = getattr(state, "mount", None)
    if mount is None and hasattr(state, "mount_pitch"):
        mount = [state.mount_pitch, state.mount_roll, state.mount_height]
    cov = getattr(state, "mount_cov", None)
    g = getattr(state, "gated", False)
    gated = "pose" in g if isinstance(g, str) else bool(g)
    return (
        None if mount is None else np.asarray(mount, dtype=float).reshape(3),
        None if cov is None else np.asarray(cov, dtype=float).reshape(3, 3),
        gated,
    )


def monitor_measurements(
    measurements: Sequence[PairMeasurement],
    nominal: NominalCalibration,
    speed: Any | None = None,
    config: MonitorConfig | None = None,
    ekf_config: Any | None = None,
    progress: bool = False,
    **options: Any,
) -> tuple[list[Any], list[MonitorOutput]]:
    """The filter pipeline then the monitor over a whole sequence (``monitor_frames``).
    Returns (filter states, monitor outputs), one of each per measurement."""
    frames = list(monitor_frames(measurements, nominal, speed, config, ekf_config, progress,
                                 **options))
    return [s for _, s, _ in frames], [o for _, _, o in frames]


def monitor_frames(
    measurements: Sequence[PairMeasurement],
    nominal: NominalCalibration,
    speed: Any | None = None,
    config: MonitorConfig | None = None,
    ekf_config: Any | None = None,
    progress: bool = False,
    **options: Any,
) -> Iterator[tuple[PairMeasurement, Any, MonitorOutput]]:
    """(measurement, EKF state, monitor output) of every frame, each as soon as it is
    decided: the measurements' monitor inputs (they compare a pair with its neighbours) for
    the whole list at once, then the EKF (``filters.ekf``, with ``speed`` on the camera
    clock) steps frame by frame and ``DriftMonitor`` judges each frame with the filter's
    mount and gating. ``config`` defaults to the EKF model's body noise at the
    measurements' median frame rate; ``options``: those of ``input_arrays``."""
    ekf_config = ekf_config or EkfConfig(height_m=nominal.height_m)
    if config is None:
        config = MonitorConfig.from_noise(ekf_config.noise, fps=frame_rate(measurements))
    ekf = ExtrinsicsEKF(ekf_config)
    mon = DriftMonitor(nominal, config)
    inputs = inputs_from_measurements(measurements, speed,
                                      **(forward_camera_options(nominal) | options))
    times = np.array([m.t for m in measurements], dtype=float)
    speeds = speed_at(speed, times) if speed is not None else np.full(len(times), np.nan)
    it: Any = zip(measurements, speeds, inputs, strict=True)
    if progress:
        from vipm_track.progress import progress_bar

        it = progress_bar(it, total=len(measurements), desc="monitor", unit="frame")
    for m, v, frame_input in it:
        state = ekf.step(m, m.t, float(v), m.frame)
        mount, mount_cov, gated = mount_from_state(state)
        judged = replace(frame_input, mount=mount, mount_cov=mount_cov, gated=gated)
        yield m, state, mon.update(judged)


def frame_rate(measurements: Sequence[PairMeasurement], default: float = 10.0) -> float:
    """Median frame rate (Hz) of consecutive measurements, ``default`` if unknown."""
    t = np.array([m.t for m in measurements], dtype=float)
    f = np.array([m.frame for m in measurements])
    if len(t) < 2:
        return default
    dt = np.diff(t) / np.maximum(np.diff(f), 1)
    dt = dt[np.isfinite(dt) & (dt > 0)]
    return float(1.0 / np.median(dt)) if len(dt) else default
