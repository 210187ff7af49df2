"""Track tables: the EKF's per-frame output in the conventions' format.

One row per frame. The base columns (``CONVENTIONS.md``) hold the *filtered* frame pose
(pitch/roll = mount + body, height = mount height) and the filtered motion from frame k-1
(metric, at the estimated height); ``status`` is ``ok`` whenever the filter has an estimate
and ``waiting for first pairs`` before it starts (numbers empty). Then, in this order:

- ``pitch_std_deg, roll_std_deg, height_std_m``: 1-σ of the filtered frame pose (pitch
  and roll widened by the pairs' error correlation: ``row_correlation``);
- ``tx_std_m, tz_std_m, yaw_std_deg``: 1-σ of the filtered motion;
- ``mount_pitch_deg, mount_pitch_std_deg, mount_roll_deg, mount_roll_std_deg,
  mount_height_m, mount_height_std_m``: the slow mount part, i.e. the calibration;
- ``mount_yaw_deg``: heading of the camera's ground frame right of the direction of travel;
- ``speed_mps, yaw_rate_dps``: filtered speed (m/s), yaw rate (deg/s, > 0 turning right);
- ``x_m, y_m, heading_deg``: vehicle pose in the first frame's planar frame (x right,
  y forward, heading > 0 turning right);
- ``filter_status``: ``ok`` pair applied, ``partial`` pose or motion block gated, ``gated``,
  ``predicted`` (no usable pair), ``reset``, ``waiting``;
- ``meas_status, meas_pitch_deg, meas_roll_deg, meas_tx_m, meas_tz_m, meas_yaw_deg``: the raw
  pair measurement (tx/tz at the assumed height);
- ``wheel_speed_mps``: wheel speed applied at this frame (empty: none);
- ``nis``: 7-dof normalised innovation squared of the pair (empty: none);
- ``gated``: blocks the Mahalanobis gate rejected: ``pose``, ``motion``, ``pose+motion``;
- ``reset_reason``: why the filter was reset or re-initialised at this frame.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from vipm_track.measurement import PairMeasurement
from vipm_track.table import CONCISE, ColumnChoice, TableColumns, TableWriter, choose_columns

from .ekf import ExtrinsicsEKF, SpeedSource, speed_at
from .ekf_state import EkfConfig, FilterState

TRACK_COLUMNS: tuple[str, ...] = (
    "pitch_std_deg", "roll_std_deg", "height_std_m", "tx_std_m", "tz_std_m", "yaw_std_deg",
    "mount_pitch_deg", "mount_pitch_std_deg", "mount_roll_deg", "mount_roll_std_deg",
    "mount_height_m", "mount_height_std_m", "mount_yaw_deg",
    "speed_mps", "yaw_rate_dps", "x_m", "y_m", "heading_deg", "filter_status",
    "meas_status", "meas_pitch_deg", "meas_roll_deg", "meas_tx_m", "meas_tz_m", "meas_yaw_deg",
    "wheel_speed_mps", "nis", "gated", "standstill", "reset_reason",
)

#: The concise track table: pose and motion with their 1-σ, the mount (the calibration),
#: speed, yaw rate, the filter's status, the wheel speed applied and standstill; ``--columns
#: all`` adds the planar trajectory, the raw measurement and the gate's details.
TRACK_TABLE = TableColumns("track", TRACK_COLUMNS, (
    "pitch_std_deg", "roll_std_deg", "height_std_m", "tx_std_m", "tz_std_m", "yaw_std_deg",
    "mount_pitch_deg", "mount_pitch_std_deg", "mount_roll_deg", "mount_roll_std_deg",
    "mount_height_m", "mount_height_std_m", "mount_yaw_deg",
    "speed_mps", "yaw_rate_dps", "filter_status", "wheel_speed_mps", "standstill",
    # the pair's own measurement: an interrupted smooth keeps the frames it had not smoothed
    # here, and nothing computed may be lost by default
    "meas_status", "meas_pitch_deg", "meas_roll_deg", "meas_tx_m", "meas_tz_m", "meas_yaw_deg",
))

WAITING = "waiting for first pairs"


def _num(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def track_row(state: FilterState, m: PairMeasurement | None, speed: float | None) -> dict:
    """The track-table row of one frame (see module doc)."""
    d = np.degrees
    row: dict = {"frame": state.frame, "t": state.t}
    if state.initialised:
        ps, ms, mts = state.pose_std, state.mount_std, state.motion_std
        row.update({
            "pitch_deg": d(state.pose[0]), "roll_deg": d(state.pose[1]),
            "height_m": state.pose[2], "tx_m": state.motion[0], "tz_m": state.motion[1],
            "yaw_deg": d(state.motion[2]), "status": "ok",
            "pitch_std_deg": d(ps[0]), "roll_std_deg": d(ps[1]), "height_std_m": ps[2],
            "tx_std_m": mts[0], "tz_std_m": mts[1], "yaw_std_deg": d(mts[2]),
            "mount_pitch_deg": d(state.mount[0]), "mount_pitch_std_deg": d(ms[0]),
            "mount_roll_deg": d(state.mount[1]), "mount_roll_std_deg": d(ms[1]),
            "mount_height_m": state.mount[2], "mount_height_std_m": ms[2],
            "mount_yaw_deg": d(state.mount_yaw),
            "speed_mps": state.speed, "yaw_rate_dps": d(state.yaw_rate),
            "x_m": state.position[0], "y_m": state.position[1], "heading_deg": d(state.heading),
        })
    else:
        row["status"] = WAITING
    row["filter_status"] = state.status
    if m is not None:
        row["meas_status"] = m.status
        if m.ok:
            row.update({
                "meas_pitch_deg": d(m.z[2]), "meas_roll_deg": d(m.z[3]), "meas_tx_m": m.z[4],
                "meas_tz_m": m.z[5], "meas_yaw_deg": d(m.z[6]),
            })
    row["wheel_speed_mps"] = None if speed is None else _num(speed)
    row["nis"] = _num(state.nis)
    row["gated"] = state.gated
    row["standstill"] = int(bool(state.standstill)) if state.initialised else None
    row["reset_reason"] = state.reset_reason
    return row


def track(
    measurements: Iterable[PairMeasurement],
    speed_series: SpeedSource | None = None,
    config: EkfConfig | None = None,
    ekf: ExtrinsicsEKF | None = None,
) -> Iterator[tuple[FilterState, PairMeasurement, float | None]]:
    """Filter a stream of measurements (one per frame), yielding (state, measurement, speed
    applied) per frame; speeds are taken from ``speed_series`` (camera clock) at frame times.
    ``ekf``: the filter to run (its ``mount_changes`` are then the caller's to read), else
    one made from ``config``."""
    ekf = ekf or ExtrinsicsEKF(config, speed_series=speed_series)
    for m in measurements:
        v = None
        if speed_series is not None:
            s = float(speed_at(speed_series, np.array([m.t]))[0])
            v = s if np.isfinite(s) else None
        yield ekf.step(m, m.t, v, m.frame), m, v


def write_track(
    steps: Iterable[tuple[FilterState, PairMeasurement, float | None]],
    out: str | Path,
    parquet: bool = False,
    columns: ColumnChoice = CONCISE,
) -> dict[str, int]:
    """Stream ``track`` output into a track table (``columns``: see
    ``vipm_track.table.choose_columns``); returns counts of filter statuses."""
    out = Path(out)
    counts: dict[str, int] = {}
    pq = out.with_suffix(".parquet") if parquet else None
    written = choose_columns(TRACK_TABLE, columns)
    with TableWriter(out, TRACK_COLUMNS, parquet_path=pq, columns=written) as writer:
        for state, m, v in steps:
            writer.write(track_row(state, m, v))
            counts[state.status] = counts.get(state.status, 0) + 1
    return counts
