"""The smoothers' settings and output: ``SmootherConfig`` (the batch's and the fixed-lag's
common settings) and ``SmoothedFrame`` (one frame's smoothed state: the EKF's
``FrameEstimate`` and why a frame has no pair)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from . import factors as F
from .filter_common import FilterConfig, FrameEstimate

FloatArray = NDArray[np.float64]

#: Gauss–Newton steps with the Huber loss before a loss that is not convex takes over: two
#: bring the dead-reckoned guess where that loss weighs the pairs (the traffic renders' frame
#: poses as after a converged Huber solve, three steps; one left them 0.003° worse)
CONVEX_START_STEPS = 2


@dataclass(frozen=True)
class SmootherConfig(FilterConfig):
    """Smoother settings (units in the names). Noise and priors are the EKF's
    (``filters.model.NoiseParams``); ``height_m`` is the nominal height (prior mean)."""

    #: sliding-window length; 0 smooths the whole drive in one batch
    lag_s: float = 0.0
    #: robust loss of the pair factors (``factors.LOSSES``); its threshold on the whitened
    #: norm of a block is √χ²(loss_probability, dof) (× ``factors.LOSS_K_SCALE``). Geman–McClure:
    #: its influence falls as 1/r³ (Cauchy's as 1/r), so a wrong pair ends with almost no
    #: pull, like the EKF's gate: with Cauchy, strong yaw outliers on the cart bent the
    #: trajectory (1.30× the EKF's RMS at 10 % outliers; GM: 0.92×, clean drives unchanged)
    loss: str = "geman-mcclure"
    loss_probability: float = 0.99
    #: the pair's motion given its angles (``model.motion_given_pose``): the estimator's tz is
    #: correlated ~−0.95 with its pitch, so a smoothed frame pose better than the pair's own
    #: corrects the pair's motion, as far as the robust loss trusts the pair's angles
    #: (``factors.GivenPose``). KITTI 07: distance error median 2.92 → 2.49 % (fixed-lag 2 s),
    #: 2.85 % (batch). Off by default: the batch's factor then acts on seven variables
    #: instead of four (batch 623 → 469 frames/s on a 120 s drive, below #7's 500) and the
    #: rendered car's trajectory was 12 % worse (docs/filters.md)
    motion_given_pose: bool = False
    #: ... unless undone within this many seconds (``persistent_changes``)
    mount_change_persist_s: float = 5.0
    #: robust loss of the wheel-speed factors
    speed_loss: str = "huber"
    #: side slip allowed per frame by the no-side-slip process model, metres
    cross_track_std_m: float = 0.001
    #: a pair block whose whitened norm exceeds √χ²(report_probability, dof) is reported
    #: as rejected in the frame status ('partial' / 'gated', as the EKF's gate)
    report_probability: float = 0.999
    max_iterations: int = 30
    #: Gauss–Newton stops when a step's predicted relative decrease of the error is below this
    #: (1e-5: the mount within ~1e-5 ° and the height within ~1 µm of the converged answer on
    #: the simulated drives, one step fewer than 1e-6)
    tolerance: float = 1e-5
    #: ... or below this many χ² units (half the step's squared Mahalanobis length), as the
    #: fixed-lag window's ``lag_tolerance_chi2``: the redescending loss's reweighting otherwise
    #: creeps on (rendered car: 26 steps, the last 15 moving the mount < 3e-4° and the height
    #: < 3 µm; with 0.1 it stops after 11)
    tolerance_chi2: float = 0.1
    marginals: bool = True
    #: fixed lag: iSAM2 updates of the window per frame (each relinearises every variable
    #: and solves again), more than one only while the last update still predicts a decrease
    #: of the cost above ``lag_tolerance_chi2`` (χ² units: half the step's squared
    #: Mahalanobis length). Two: the robust loss's reweighting keeps up with outlier pairs
    #: (one update per frame left their height 60 % worse); a third costs a third more time
    #: for no better mount or height (docs/gtsam.md)
    lag_tolerance_chi2: float = 0.1
    lag_max_iterations: int = 2

    def __post_init__(self) -> None:
        if self.height_m <= 0:
            raise ValueError(f"nominal height must be > 0, got {self.height_m}")
        if self.lag_s < 0:
            raise ValueError(f"lag must be >= 0 s, got {self.lag_s}")
        if self.loss not in F.LOSSES:
            raise ValueError(f"loss must be one of {F.LOSSES}, got {self.loss!r}")

    def convex_start(self) -> SmootherConfig | None:
        """These settings with the convex Huber loss for ``CONVEX_START_STEPS`` steps, where
        the pair loss is not convex (``factors.NON_CONVEX``): where to start that loss. From
        the dead-reckoned guess, whose frames each take the pose of their own pair, the
        pairs' precise pose changes miss by the disagreement of two pairs on a frame (a
        degree where the pose is loose) and the redescending loss rejects them for good:
        a rendered shaking drive in traffic came out 0.54° pitch error instead of 0.06°."""
        if self.loss not in F.NON_CONVEX:
            return None
        return replace(self, loss="huber", max_iterations=CONVEX_START_STEPS)

    def loss_k(self, dof: int) -> float:
        """Robust-loss threshold on the whitened norm of a ``dof``-dimensional block."""
        return chi_norm(self.loss_probability, dof)

    def pair_loss_k(self, dof: int) -> float:
        """Threshold of the pair factors' loss on the whitened norm of a ``dof``-dim block."""
        return F.LOSS_K_SCALE.get(self.loss, 1.0) * self.loss_k(dof)


@lru_cache(maxsize=64)
def chi_norm(probability: float, dof: int) -> float:
    """√(χ² quantile): the whitened norm a ``dof``-dim Gaussian stays below with ``probability``."""
    return float(math.sqrt(chi2.ppf(probability, dof)))


@dataclass(frozen=True)
class SmoothedFrame(FrameEstimate):
    """Smoothed estimate of one frame (``filters.filter_common.FrameEstimate``).

    ``status``: ``ok`` (pair used), ``partial`` / ``gated`` (one / both pair blocks
    rejected as outliers by the robust loss), ``predicted`` (no usable pair: ``reason`` gives
    the input status; the estimate comes from the neighbours), ``reset`` (fixed lag: the
    window was restarted at this frame, ``reason`` says why), ``skipped`` (not smoothed,
    e.g. a time not after the previous frame; numbers NaN)."""

    reason: str = ""

    @property
    def initialised(self) -> bool:
        return self.status != "skipped"

    @property
    def reset_reason(self) -> str:
        """The EKF's note column: here why a frame has no pair or was skipped."""
        return self.reason
