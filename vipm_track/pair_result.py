"""What the two-frame estimator returns for a pair (:class:`PairResult`, its status
strings, each stage's :class:`PatchField`) and takes as a prior (:class:`PairGuess`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from .displacement_model import pack
from .geometry import GroundPose, IpmGrid, PlanarMotion
from .measurement import PairMeasurement
from .statuses import (
    STATUS_DEGENERATE,
    STATUS_FEW_INLIERS,
    STATUS_IMPLAUSIBLE_MOTION,
    STATUS_NO_MOTION,
    STATUS_NO_NOMINAL,
    STATUS_NO_TEXTURE,
    STATUS_NOT_CONVERGED,
    STATUS_OK,
)

FloatArray = NDArray[np.float64]

__all__ = [
    "STATUS_DEGENERATE",
    "STATUS_FEW_INLIERS",
    "STATUS_IMPLAUSIBLE_MOTION",
    "STATUS_NOT_CONVERGED",
    "STATUS_NO_MOTION",
    "STATUS_NO_NOMINAL",
    "STATUS_NO_TEXTURE",
    "STATUS_OK",
    "PairGuess",
    "PairResult",
    "PatchField",
    "StageEstimate",
    "StageFailure",
    "add_timings",
    "angular_change",
    "mark_failed",
]


@dataclass(frozen=True)
class PairGuess:
    """A prior for a pair (tracking mode): LM start and patch-window offsets."""

    pose_prev: GroundPose
    pose_curr: GroundPose
    motion: PlanarMotion
    #: the interval before's (pitch, roll) change, radians per this pair's frame interval
    #: (None: unknown), and the running mean square of its change from pair to pair
    #: (``PairResult.angular_accel_ms``): a rolling shutter's angular acceleration
    angular_rate: tuple[float, float] | None = None
    angular_accel_ms: tuple[float, float] | None = None

    @classmethod
    def from_previous(cls, result: PairResult, ratio: float = 1.0) -> PairGuess | None:
        """Constant-pose, constant-velocity guess for the next pair from an ``ok`` result
        (None otherwise, which means a cold start): frame k's pose for both frames, the
        motion and the angular rate scaled by ``ratio`` (the next frame interval over the
        result's), the angular acceleration's mean square by ``ratio``⁴."""
        if result is None or result.status != STATUS_OK:
            return None
        m = result.motion
        return cls(result.pose_curr, result.pose_curr,
                   PlanarMotion(m.tx * ratio, m.tz * ratio, m.yaw * ratio),
                   angular_change(result, ratio),
                   None if result.angular_accel_ms is None
                   else tuple(ratio**4 * np.asarray(result.angular_accel_ms)))


def angular_change(result: PairResult, scale: float = 1.0) -> tuple[float, float]:
    """(pitch, roll) change over ``result``'s pair [rad], times ``scale``."""
    return (scale * (result.pose_curr.pitch - result.pose_prev.pitch),
            scale * (result.pose_curr.roll - result.pose_prev.roll))


@dataclass(frozen=True)
class PatchField:
    """Displacements of one stage's patches, for dashboards.

    ``centres`` (N, 2) are patch centres on the previous frame's plane (image or IPM
    pixels), ``displacements`` (N, 2) the POC displacement to the current frame (same
    pixels, NaN where not measured), ``peaks`` (N,) POC peaks, ``inliers`` (N,) flags,
    ``sizes`` (N,) patch sides in pixels (0: not measured); ``grid`` is the virtual IPM grid
    of an "ipm" stage (its pixels ↔ ground metres of the estimated frames).
    """

    plane: str
    centres: FloatArray
    displacements: FloatArray
    peaks: FloatArray
    inliers: NDArray[np.bool_]
    sizes: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    grid: IpmGrid | None = None


class StageEstimate(NamedTuple):
    """Estimate after one stage."""

    pose_prev: GroundPose
    pose_curr: GroundPose
    motion: PlanarMotion


@dataclass
class PairResult:
    """Outcome of :meth:`TwoFrameEstimator.estimate` for one pair.

    ``status`` is ``"ok"`` or a short stable reason ("no texture", "no motion",
    "too few inliers", "did not converge", "degenerate"); ``reason`` explains it. Poses and
    motion are None unless ``ok``. ``covariance`` is 7×7 in ``measurement`` order (radians,
    metres); ``residual_px`` is the final stage's inlier RMS residual in that stage's pixels.
    ``stages`` holds every stage's patch field (the image stage even when it failed and
    tracking fell back to the guess); ``stage_estimates`` the estimate of each accepted stage.
    ``height`` is the assumed height of frame k-1 [m]; ``height_change`` the estimated
    vertical motion within the pair [m] (0 unless ``config.vertical_motion``).
    ``angular_accel_ms`` is the running mean square of the (pitch, roll) rate's change from
    pair to pair [rad² per interval²] (tracking under a rolling shutter; None otherwise).
    """

    status: str
    reason: str = ""
    pose_prev: GroundPose | None = None
    pose_curr: GroundPose | None = None
    motion: PlanarMotion | None = None
    covariance: FloatArray = field(default_factory=lambda: np.full((7, 7), np.nan))
    stages: list[PatchField] = field(default_factory=list)
    stage_estimates: list[StageEstimate] = field(default_factory=list)
    ipm_images: tuple[NDArray, NDArray] | None = None
    timings: dict[str, float] = field(default_factory=dict)
    n_inliers: int = 0
    residual_px: float = float("nan")
    height: float = float("nan")
    height_change: float = 0.0
    angular_accel_ms: tuple[float, float] | None = None

    @property
    def ok(self) -> bool:
        return self.status == STATUS_OK

    @property
    def std(self) -> FloatArray:
        """Standard deviations (7,) of the parameters, radians / metres."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def to_measurement(self, frame: int, t: float) -> PairMeasurement:
        """This pair as the filters' measurement for frame ``frame`` at time ``t`` [s]."""
        if self.ok and self.pose_prev and self.pose_curr and self.motion:
            z = pack(self.pose_prev, self.pose_curr, self.motion)[:7]
            cov = self.covariance
        else:
            z = np.full(7, np.nan)
            cov = np.full((7, 7), np.nan)
        return PairMeasurement(
            frame=frame, t=t, z=z, covariance=cov, height_assumed=self.height,
            status=self.status, inliers=self.n_inliers,
        )


class StageFailure(Exception):
    """A stage's failure: the pair's ``status`` and the ``reason`` for it."""

    def __init__(self, status: str, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason



def add_timings(result: PairResult, earlier: PairResult) -> None:
    """Add an ``earlier`` attempt's stage timings to ``result``'s (the pair's cost is both)."""
    for key, seconds in earlier.timings.items():
        result.timings[key] = result.timings.get(key, 0.0) + seconds


def mark_failed(result: PairResult, status: str, reason: str) -> None:
    """Make ``result`` a failed pair: ``status`` and ``reason``, no estimate."""
    result.status, result.reason = status, reason
    result.pose_prev = result.pose_curr = result.motion = None
    result.covariance = np.full((7, 7), np.nan)
