"""The EKF's settings and output: ``EkfConfig`` and ``FilterState`` (one frame's
``FrameEstimate`` with the wheel speed's gate and why the filter restarted)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .filter_common import FilterConfig, FrameEstimate

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class EkfConfig(FilterConfig):
    """EKF settings: the filters' common ones (``FilterConfig``), gating and divergence checks."""

    gate_probability: float = 0.999
    speed_gate_probability: float = 0.999
    max_consecutive_gated: int = 15
    #: motion-gated pairs in a row that restart speed, yaw rate, height and mount yaw (the
    #: motion model lost track: every later pair disagrees with it and would be gated too;
    #: KITTI 07 with 15: median travel error 4.3 %, p95 27 %; with 5: 3.4 % / 12 %). An
    #: outlier run that long is rare (10 % outliers: 1e-5 per frame)
    max_consecutive_motion_gated: int = 5
    #: wheel speeds gated in a row that restart the speed from the reading (and the height
    #: from its prior): braking or pulling away faster than the speed random walk expects
    #: leaves the state behind, and a gate against a lost state would reject the wheels for
    #: good (cart stopping within 1 s: every later reading gated, the height frozen 26 % off)
    max_consecutive_speed_gated: int = 3
    #: a wheel speed beyond the gate but within this factor of it is applied with its
    #: variance inflated by NIS / gate (the pose/motion blocks' soft gate): the wheels are
    #: rarely wrong, the speed random walk often is when braking
    speed_soft_gate_factor: float = 10.0
    max_mount_angle_std_deg: float = 10.0
    default_dt_s: float = 0.05  # frame interval assumed before the first frame time is known
    #: the start's speed / yaw-rate std is the robust spread (1.4826 · MAD) of the bootstrap
    #: pairs' values, at least these floors and at most the model's prior: with the wide prior
    #: the first pair, outlier or not, would be taken at face value and the gate would then
    #: reject the good pairs after it while the heading integrates the wrong yaw rate
    init_speed_std_min_mps: float = 0.2
    init_yaw_rate_std_min_dps: float = 1.0
    #: pose gate: a pose block beyond the χ² gate but within ``pose_soft_gate_factor`` times it
    #: is applied with its covariance inflated by NIS / gate (down-weighted, not dropped);
    #: beyond that it is rejected
    pose_soft_gate_factor: float = 4.0
    #: the same for the motion block (tx, tz, yaw): real estimates' covariances are optimistic
    #: and real driving changes speed and yaw rate faster than the model expects, so a hard
    #: gate drops good pairs in every manoeuvre (KITTI 07: 34 of 159; travel error median /
    #: p95 3.43 / 11.6 % → 3.15 / 9.5 % with 2); 2 keeps rejecting simulated outliers (cart
    #: trajectory with 10 % outliers unchanged; 4 let them bend it, 0.13 → 0.20 m RMS)
    motion_soft_gate_factor: float = 2.0


@dataclass(frozen=True)
class FilterState(FrameEstimate):
    """Filtered estimate after one frame (:class:`FrameEstimate`).

    ``status``: ``ok`` (pair applied), ``partial`` (pose or motion block gated), ``gated``
    (pair rejected by the gate), ``predicted``
    (no usable pair: the input status says why), ``waiting`` (not initialised yet),
    ``reset`` (re-initialised on this frame; ``reset_reason`` says why)."""

    speed_nis: float = float("nan")
    speed_gated: bool = False
    reset_reason: str = ""

    @property
    def initialised(self) -> bool:
        return self.status != "waiting"
