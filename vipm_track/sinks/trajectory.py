"""Planar trajectory of a per-frame table: the motions k-1 → k chained into world positions."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from ..geometry import PlanarMotion, compose_motion


def planar_path(columns: Mapping[str, NDArray], valid: NDArray | None = None) -> NDArray | None:
    """World positions (N, 2) = (x right, z forward) [m] in the ground frame G of the first
    frame, one per row of a ``table.read_table`` table; None when it has no motion columns.

    A table with ``world_x_m``/``world_z_m`` columns (ground truth of ``vipm-track
    simulate``) gives them directly. Otherwise ``tx_m, tz_m, yaw_deg`` are chained with
    ``geometry.compose_motion`` from (0, 0) at the first valid row; a row without them takes
    the pair's own measured motion where a track table has it (``meas_tx_m``, ``meas_tz_m``,
    ``meas_yaw_deg``: the EKF's first frames, before it starts, drew its path 12 % short),
    and holds the position where it has none (the path then misses that frame's travel);
    rows not ``valid`` are NaN.
    """
    n = len(columns["frame"])
    valid = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    if "world_x_m" in columns and "world_z_m" in columns:
        xz = np.stack([np.asarray(columns["world_x_m"], float),
                       np.asarray(columns["world_z_m"], float)], 1)
        xz[~valid] = np.nan
        return xz
    if not all(c in columns for c in ("tx_m", "tz_m", "yaw_deg")):
        return None
    tx, tz = np.asarray(columns["tx_m"], float), np.asarray(columns["tz_m"], float)
    yaw = np.radians(np.asarray(columns["yaw_deg"], float))
    if all(f"meas_{c}" in columns for c in ("tx_m", "tz_m", "yaw_deg")):
        none = ~(np.isfinite(tx) & np.isfinite(tz) & np.isfinite(yaw))
        tx = np.where(none, np.asarray(columns["meas_tx_m"], float), tx)
        tz = np.where(none, np.asarray(columns["meas_tz_m"], float), tz)
        yaw = np.where(none, np.radians(np.asarray(columns["meas_yaw_deg"], float)), yaw)
    xz = np.full((n, 2), np.nan)
    pose = PlanarMotion(0.0, 0.0, 0.0)
    # Sequential by nature (each step is rotated by the heading so far); one step per frame.
    for i in np.flatnonzero(valid):
        step = (float(tx[i]), float(tz[i]), float(yaw[i]))
        if all(math.isfinite(v) for v in step):
            pose = compose_motion(pose, PlanarMotion(*step))
        xz[i] = (pose.tx, pose.tz)
    return xz
