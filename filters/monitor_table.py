"""The monitor's per-frame table: the columns ``vipm-track monitor`` writes beside the
conventions' pose and motion, and one row from a measurement, its EKF state and the
monitor's verdict (``docs/formats.md``)."""

from __future__ import annotations

import math
from typing import Any

from vipm_track.measurement import PairMeasurement
from vipm_track.table import TableColumns

from .track import WAITING

MONITOR_COLUMNS: tuple[str, ...] = (
    "monitor_state", "reason", "stat_pitch", "stat_roll", "stat_height",
    "dev_pitch_deg", "dev_roll_deg", "dev_height_m",
    "mount_pitch_deg", "mount_roll_deg", "mount_height_m",
    "new_pitch_deg", "new_roll_deg", "new_height_m",
    "new_pitch_lo_deg", "new_pitch_hi_deg", "new_roll_lo_deg", "new_roll_hi_deg",
    "new_height_lo_m", "new_height_hi_m",
)
#: The concise monitor table: state and reason, the filter's mount, the new extrinsics with
#: their 95 % interval; ``--columns all`` adds the CUSUM statistics and the deviations.
MONITOR_TABLE = TableColumns("monitor", MONITOR_COLUMNS, tuple(
    c for c in MONITOR_COLUMNS if not c.startswith(("stat_", "dev_"))))


def monitor_row(m: PairMeasurement, state: Any, out: Any) -> dict[str, Any]:
    """One output row (module doc) from a measurement, its filter state and monitor output."""
    deg = math.degrees
    row: dict[str, Any] = {"frame": m.frame, "t": m.t, "status": m.status}
    if state is None or getattr(state, "status", "waiting") == "waiting":
        # no filter estimate yet: the base columns are empty, so the row must not say ``ok``
        # (CONVENTIONS.md; the track table's status for the same frames)
        if m.status == "ok":
            row["status"] = WAITING
    else:
        row.update(pitch_deg=deg(state.pose[0]), roll_deg=deg(state.pose[1]),
                   height_m=float(state.mount[2]), tx_m=float(state.motion[0]),
                   tz_m=float(state.motion[1]), yaw_deg=deg(state.motion[2]),
                   mount_pitch_deg=deg(state.mount[0]), mount_roll_deg=deg(state.mount[1]),
                   mount_height_m=float(state.mount[2]))
    row.update(
        monitor_state=out.state, reason=out.reason,
        stat_pitch=float(out.statistic[0]), stat_roll=float(out.statistic[1]),
        stat_height=float(out.statistic[2]),
        dev_pitch_deg=deg(out.deviation[0]), dev_roll_deg=deg(out.deviation[1]),
        dev_height_m=float(out.deviation[2]),
    )
    if out.estimate is not None:
        e, iv = out.estimate, out.interval95
        row.update(
            new_pitch_deg=deg(e[0]), new_roll_deg=deg(e[1]), new_height_m=float(e[2]),
            new_pitch_lo_deg=deg(iv[0, 0]), new_pitch_hi_deg=deg(iv[0, 1]),
            new_roll_lo_deg=deg(iv[1, 0]), new_roll_hi_deg=deg(iv[1, 1]),
            new_height_lo_m=float(iv[2, 0]), new_height_hi_m=float(iv[2, 1]),
        )
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in row.items()}
