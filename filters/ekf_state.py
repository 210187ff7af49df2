"""The EKF's settings and output: ``EkfConfig``, and ``FilterState`` (one frame's filtered
mount, pose, motion and covariance in the model's layout, radians and metres) with the
standard deviations every filter's frame shares (``FrameStds``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .model import NoiseParams
from .mount_change import MountChangeConfig

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class EkfConfig:
    """EKF settings: the model's noise, the nominal height (prior mean, metres), gating and
    divergence checks."""

    height_m: float = 1.5
    noise: NoiseParams = field(default_factory=NoiseParams)
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
    init_pairs: int = 5  # good pairs whose medians start (and restart) the filter
    #: the start's speed / yaw-rate std is the robust spread (1.4826 · MAD) of the bootstrap
    #: pairs' values, at least these floors and at most the model's prior: with the wide prior
    #: the first pair, outlier or not, would be taken at face value and the gate would then
    #: reject the good pairs after it while the heading integrates the wrong yaw rate
    init_speed_std_min_mps: float = 0.2
    init_yaw_rate_std_min_dps: float = 1.0
    speed_timeout_s: float = 1.0  # h is estimated only while wheel speeds are this recent
    #: adaptive body shaking: the body's stationary std per axis is the larger of the model's
    #: ``body_std_deg`` and a robust scale (1.4826 · MAD) of the measured body (pair pitch/roll
    #: minus the filtered mount) over this many seconds; 0 keeps the model's std
    body_window_s: float = 6.0
    body_window_min_pairs: int = 10
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
    #: a step of the mount (a knocked camera) found in the pose innovations re-opens the
    #: mount's variance (``filters.mount_change``)
    mount_change: MountChangeConfig = field(default_factory=MountChangeConfig)


class FrameStds:
    """1-σ of a per-frame estimate's ``mount_cov``, ``pose_cov`` and ``motion_cov`` (shared
    by the EKF's :class:`FilterState` and the smoother's ``SmoothedFrame``)."""

    mount_cov: FloatArray
    pose_cov: FloatArray
    motion_cov: FloatArray

    @property
    def mount_std(self) -> FloatArray:
        return _std(self.mount_cov)

    @property
    def pose_std(self) -> FloatArray:
        return _std(self.pose_cov)

    @property
    def motion_std(self) -> FloatArray:
        return _std(self.motion_cov)


def _std(cov: FloatArray) -> FloatArray:
    return np.sqrt(np.clip(np.diag(cov), 0.0, None))


@dataclass(frozen=True)
class FilterState(FrameStds):
    """Filtered estimate after one frame (radians, metres, seconds; frames of filters.model).

    ``status``: ``ok`` (pair applied), ``partial`` (pose or motion block gated), ``gated``
    (pair rejected by the gate), ``predicted``
    (no usable pair: the input status says why), ``waiting`` (not initialised yet),
    ``reset`` (re-initialised on this frame; ``reset_reason`` says why)."""

    frame: int
    t: float
    status: str
    mount: FloatArray  # (pitch_m, roll_m, h_m)
    mount_cov: FloatArray  # 3×3
    mount_yaw: float
    pose: FloatArray  # frame pose (pitch, roll, h) = mount + body
    pose_cov: FloatArray
    motion: FloatArray  # (tx, tz, yaw) frame k-1 → k, metric (true scale), G_{k-1}
    motion_cov: FloatArray
    speed: float
    yaw_rate: float
    position: FloatArray  # (x, y) world, metres
    heading: float
    state: FloatArray  # full 16-vector (``filters.model`` layout)
    covariance: FloatArray  # 16×16
    nis: float = float("nan")
    gated: str = ""  # rejected blocks: '', 'pose', 'motion' or 'pose+motion'
    speed_nis: float = float("nan")
    speed_gated: bool = False
    reset_reason: str = ""
    standstill: bool = False  # the standstill pseudo-measurement was applied on this frame

    @property
    def initialised(self) -> bool:
        return self.status != "waiting"
