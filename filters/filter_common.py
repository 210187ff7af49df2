"""What every filter shares: ``FilterConfig`` (the settings of the EKF and of the smoothers
alike) and ``FrameEstimate`` (one frame's mount, pose, motion and covariance in the model's
layout, radians and metres)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from .model import NoiseParams
from .mount_change import MountChangeConfig
from .mount_steps import StepTestConfig

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class FilterConfig:
    """Settings every filter shares: the model's noise, the nominal height (prior mean,
    metres), the adaptive body shaking, the mount-step test, the start and the wheel speed's
    timeout."""

    height_m: float = 1.5
    noise: NoiseParams = field(default_factory=NoiseParams)
    #: adaptive body shaking: each frame's body std is the larger of the model's
    #: ``body_std_deg`` and a robust scale (1.4826 · MAD) of the measured body (pair pitch/roll
    #: minus the mount) over this many seconds, less their measurement noise; 0 keeps the
    #: model's std
    body_window_s: float = 6.0
    body_window_min_pairs: int = 10
    #: the body's heave (std of a frame's height about the mount's) while no wheel speed has
    #: measured it, as a share of ``height_m`` (``filters.heave``; the monitor's default)
    heave_std_unknown_frac: float = 0.02
    #: a step of the mount (a knocked camera) found in the pose innovations re-opens the
    #: mount (``filters.mount_change``)
    mount_change: MountChangeConfig = field(default_factory=MountChangeConfig)
    #: the offline test for steps of the mount in the pairs' angles (``filters.mount_steps``):
    #: the batch's on the whole drive, the EKF's and fixed lag's as it goes on
    #: (``filters.step_watch``), for the knocks the online test missed
    mount_steps: StepTestConfig = field(default_factory=StepTestConfig)
    #: good pairs whose medians start (and restart) the filter
    init_pairs: int = 5
    #: a pair moves the height only with a wheel speed within this many seconds of it
    #: (without a metric speed, scale is unobservable)
    speed_timeout_s: float = 1.0


#: the statuses of a frame estimate whose filter did not apply the frame's pair (none, a
#: late one, or the filter not started): its pair's residuals against it mean nothing
NOT_APPLIED = ("predicted", "waiting")


def _std(cov: FloatArray) -> FloatArray:
    return np.sqrt(np.clip(np.diag(cov), 0.0, None))


@dataclass(frozen=True)
class FrameEstimate:
    """One frame's filtered or smoothed estimate (radians, metres, seconds; frames of
    filters.model): the fields the EKF's :class:`FilterState` and the smoothers'
    ``SmoothedFrame`` share, so that tables, the monitor and the sinks take either."""

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
    standstill: bool = False  # the standstill pseudo-measurement / factor holds here

    @property
    def mount_std(self) -> FloatArray:
        """1-σ of ``mount``."""
        return _std(self.mount_cov)

    @property
    def pose_std(self) -> FloatArray:
        """1-σ of ``pose``."""
        return _std(self.pose_cov)

    @property
    def motion_std(self) -> FloatArray:
        """1-σ of ``motion``."""
        return _std(self.motion_cov)


def motion_residual(estimate: FrameEstimate, m: PairMeasurement
                    ) -> tuple[FloatArray, FloatArray] | None:
    """The pair's motion (tx, tz, yaw) less the estimate's, metres / rad, the pair's
    translation taken from its assumed height to the estimate's, and the pair's variances
    scaled alike; None where the filter did not apply the pair's motion (not ok, not applied,
    gated) or a height is unknown."""
    motion, height = estimate.motion, float(estimate.mount[2])
    if (not m.ok or estimate.status in NOT_APPLIED or "motion" in estimate.gated
            or motion is None or not height > 0 or not m.height_assumed > 0):
        return None
    scale = np.array([height / m.height_assumed] * 2 + [1.0])
    return m.z[4:7] * scale - motion, np.diag(m.covariance)[4:7] * scale**2
