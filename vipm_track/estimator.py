"""Two-frame pose and motion estimator (Hirano et al., section III): the paper's method.

For a pair of frames (k-1, k) it estimates the pose of both against the ground
(pitch, roll; the height is the assumed one) and the planar motion between them:

1. *Initial estimation on the image plane* (III-B): POC displacement of square patches at
   a grid of interest points, obvious outliers dropped by POC peak and displacement
   magnitude, LM over the seven parameters on random subsets, best by truncated residual,
   re-fitted on its inliers. Without a guess, a coarse pass on a downsampled pair first
   predicts each patch's displacement so that fast motion stays inside the patch windows.
2. *Refinement via virtual IPM* (III-C), ``config.refinements`` times: both frames warped
   onto bird's-eye planes of the current estimates, POC on IPM patches whose moving window
   is offset by the displacement the estimate predicts, outliers rejected against that
   prediction, LM on the reprojection residual on the IPM planes (eqs. 3-5).

Frames follow CONVENTIONS.md; parameters are ordered as ``measurement.PARAMETER_NAMES``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from . import ipm, poc
from .bundle import (
    DisplacementModel,
    FitResult,
    SteadyPoseModel,
    at_least,
    covariance_from_jacobian,
    heave_covariance,
    pack,
    robust_fit,
    unpack,
)
from .camera import CameraModel
from .errors import InputError
from .geometry import (
    GroundPose,
    IpmGrid,
    PlanarMotion,
    apply_homography,
    back_project,
    horizon_row,
    image_from_ipm_homography,
    ipm_from_image_homography,
    rotation_parallax,
)
from .measurement import PairMeasurement
from .roi import RoiSpec, interest_points, roi_mask, shrink_to_image
from .static_content import (
    PATCH_MAX_SHARE,
    noise_sigma,
    on_static,
    static_pixels,
    static_share,
)

FloatArray = NDArray[np.float64]

STATUS_OK = "ok"
STATUS_NO_TEXTURE = "no texture"
STATUS_NO_MOTION = "no motion"
STATUS_FEW_INLIERS = "too few inliers"
STATUS_NOT_CONVERGED = "did not converge"
STATUS_DEGENERATE = "degenerate"
STATUS_NO_NOMINAL = "no nominal pose"


#: nominal pitch below which a camera with the horizon in view gets the forward-looking
#: (level-camera) defaults of ``EstimatorConfig`` [deg]
LEVEL_MAX_PITCH_DEG = 10.0

#: forward reach of a level camera's automatic region of interest, camera heights: beyond
#: it the road's image is over 10x more compressed along than across the road, and leaving
#: it out made the estimates better (rendered level cars at 3°: pitch error 0.086 → 0.037°
#: RMS, distance 0.33 → 0.10 % median; KITTI 07: median distance error 3.28 → 2.62 %,
#: three seeds; 8 h was better on renders, worse in KITTI's tail; docs/kitti.md)
LEVEL_ROI_RANGE_H = 10.0
#: a steep camera's cold start (either start) is kept only where at least this share of its
#: last stage's measured patches are inliers: far from the true pose, with the frames half a
#: view apart, it can converge to a wrong minimum that a quarter of the patches agree with
#: (rendered cart at 0.6 m per frame: 22-29 % inliers and 90 % short); right ones have
#: 74-100 %, 78-82 % with an obstacle over a fifth of the view
COLD_MIN_INLIER_SHARE = 0.4
#: share of the measured patches that a cold start off the nominal pitch must have as inliers
#: in its last stage: more starts, more wrong minima to land in (the cart at 0.6 m per frame
#: from 65°: 43 % of the patches and 89 % short; KITTI 07 in a sharp turn from 2° below its
#: nominal: 29 % and 46 % long), while the starts that find the truth there have 100 %. Right
#: pairs of real scenes can have less (KITTI's 28-59 %): those stay failed, as without it
RETRY_MIN_INLIER_SHARE = 0.6
#: pitch steps from the nominal pose [deg] of the cold starts tried, in turn, where the
#: nominal one fails (too few inliers, no convergence): the further the vehicle moves per
#: frame, the closer to the true pitch a cold start must begin (a level car at 2.5 m per frame
#: converges from its true pitch but not from 1.5° off; a camera 45.8° down at 0.55 camera
#: heights per frame from 50° and 52°, not from 40° or 60°), and the road's slope alone puts a
#: car 2° off its nominal
COLD_PITCH_STEPS_DEG: dict[str, tuple[float, ...]] = {
    "level": (2.0, -2.0),
    "steep": (5.0, -5.0),
}

#: The refinement's patch weighting, as EstimatorConfig fields: "noise" (the steep-camera
#: default: modelled patch noise, re-centred windows, self-tightening inlier threshold) or
#: "uniform" (the paper's: every patch alike).
REFINEMENT_WEIGHTING: dict[str, dict[str, bool | float]] = {
    "noise": {"weight_patches": True, "recentre_windows": True, "inlier_median_factor": 6.0},
    "uniform": {"weight_patches": False, "recentre_windows": False, "inlier_median_factor": 0.0},
}


@dataclass(frozen=True)
class EstimatorConfig:
    """Settings of :class:`TwoFrameEstimator` (defaults follow the paper where it says).

    Fields left None take per-camera defaults: "forward-looking" below means a *level*
    camera (horizon in view and nominal pitch below ``LEVEL_MAX_PITCH_DEG``, 10°), "steep"
    every other one (the cold start alone goes by the horizon: ``cold_start_ipm``).

    Attributes
    ----------
    grid : interest points (nx, ny) over the region of interest.
    roi : region of interest (``roi.RoiSpec``); None picks the ground below the horizon
        within ``roi_max_range_h`` and ``roi_max_lateral_h`` camera heights.
    roi_max_range_h : forward reach of the automatic region, camera heights; None (default):
        ``LEVEL_ROI_RANGE_H`` (10) for forward-looking cameras, 15 for others (which rarely
        see that far). At a distance of Z the ground's image is Z/h times more compressed
        along the road than across it, so the far road's patches carry little and warp
        worst onto the bird's-eye plane.
    horizon_margin_deg : rays kept at least this far below the horizon (auto ROI, IPM).
    patch_image, patch_ipm : patch sizes on the image and virtual IPM planes, pixels.
    min_patch_image, min_patch_ipm : patches shrunk below these are dropped, pixels.
    n_subsets, subset_fraction : random subsets of the initial LM (paper: 50, 0.6).
    refine_subsets : random subsets in each refinement (0: one LM plus inlier trimming).
    refinements : virtual-IPM refinements after the initial estimate; None (default): 1 for
        steep cameras (the paper's), 2 for forward-looking ones (each refinement removes
        part of the pitch/travel coupling left by the distorted image patches).
    initial_pitch_deg, initial_roll_deg : cold-start pose (paper: 60°, 0°); give the nominal
        calibration for cameras far from it (forward-looking ones).
    coarse_scale, coarse_patch : downsampling and patch size (downsampled pixels) of the
        cold-start coarse pass (``coarse_scale = 1`` disables it).
    coarse_inlier_px : inlier threshold of the coarse pass, full-resolution pixels.
    coarse_peak_ratio : coarse patches whose POC peak is below this fraction of the 90th
        percentile peak are not used.
    min_peak : POC peaks below this mark a patch unusable.
    max_displacement_factor : image-plane displacements longer than this times the median
        (plus the patch size / 8) are obvious outliers.
    inlier_px_image, inlier_px_ipm : inlier residual thresholds, image / IPM pixels.
    refine_outlier_px : IPM displacements further than this from the prediction of the
        previous estimate are outliers, IPM pixels.
    min_inliers : fewer inliers than this fail the pair.
    min_motion_px : a median image displacement below this is "no motion", pixels.
    cold_start_ipm : a cold start also tries the median translation on the nominal pose's
        virtual IPM: forward cameras first (then the coarse image-plane pass), steep ones
        where the coarse image-plane pass fails (off: the image-plane pass alone).
    cold_pitch_steps_deg : where both cold starts fail (too few inliers, no convergence),
        they are tried again from the nominal pose with its pitch moved by each of these in
        turn [deg]; the first that succeeds is the result. Default per camera
        (``COLD_PITCH_STEPS_DEG``: ±2° level, ±5° others); ``()`` disables it.
    readout_s : rolling shutter: time from the exposure of the image's first row to its
        last [s] (0: global shutter); the residual model then moves each patch by the motion
        over its rows' exposure times (``bundle`` module doc), given each pair's frame
        interval (:meth:`TwoFrameEstimator.estimate`).
    max_deviation_deg : estimates whose pitch or roll differ from the initial (nominal) pose
        by more than this are rejected ("did not converge").
    max_roll_deg : plausible roll of a vehicle camera: estimates whose roll differs from the
        nominal roll (``initial_roll_deg``: level unless the user says otherwise) by more
        than this are rejected ("did not converge"); a roll fitted beyond it is vehicles or
        walls taken for the ground, not the mount.
    jackknife_covariance : each fit's covariance is at least its block jackknife's
        (``bundle.block_jackknife_covariance``): the formal one takes the patches' errors as
        independent, which real frames are not.
    heave_rate_mps : standard deviation of the body's vertical speed on its suspension
        [m/s] (a car on an ordinary road: a few cm/s); without ``vertical_motion`` the
        covariance includes what a heave of this speed over the pair's interval moves the
        fit by (``bundle.heave_covariance``; 0: off).
    nominal_undetermined : why the nominal pose could not be found on the drive (empty: it
        was given or found); every pair then has status "no nominal pose" — without a
        nominal pose the cold start has nothing to rest on, and its estimates would be the
        patches' second minima, not the camera's.
    ipm_resolution_scale : IPM metres per pixel as a multiple of the interest points'
        median ground sampling distance.
    ipm_max_side : largest IPM image side, pixels.
    vertical_motion : also estimate the camera's vertical motion within the pair (an eighth
        parameter; the paper neglects it, which costs ~0.25° of pitch per millimetre on a
        bouncing 0.7 m cart camera). Frame k's pose then has height ``height + dh``. None
        (default): on for steep cameras (the whole image below the horizon at the nominal
        pose), off for forward-looking ones, where it is poorly separable from pitch.
    pose_prior_deg : standard deviation of a prior on both frames' pitch and roll around the
        initial (nominal) pose inside every fit, degrees; it resolves the pitch/translation
        ambiguity of a near-level camera (a steeper pitch with a shorter travel explains
        the flow of the near road almost as well). 0 turns it off; None (default): 2° for
        forward-looking cameras, off for steep ones.
    track_prior_deg : in tracking mode, frame k-1's pitch and roll are also held to the
        previous pair's estimate of the same frame with this standard deviation, degrees
        (fused with the nominal prior; 0: off). Only with the pose prior on.
    stage_median : report the element-wise median of the accepted stages' estimates (the
        image stage and each refinement) instead of the last one, when two or more
        refinements are configured; the covariance stays the last stage's. None (default): on
        for forward-looking cameras, off for steep ones.
    weight_patches : weight each IPM patch's residual by its modelled noise (patches where
        the virtual IPM magnifies the image, in the far field, or shrunk ones are noisier;
        ``ipm.patch_noise_whitening``); the paper weighs all alike.
    recentre_windows : match IPM patches a second time with the current frame's window
        re-centred on the first measured shift (the windows' partial overlap pulls POC
        towards the window offset, carrying ~2 % of the previous stage's error over).
    inlier_median_factor : a refinement's inlier threshold tightens to this multiple of its
        inliers' median residual where that is below ``inlier_px_ipm`` (0: fixed threshold);
        weighted residuals of precise near-field patches are a few hundredths of a pixel,
        so a patch half on an obstacle is gross there but within the fixed 1.5 px.
        None (default) for these three: on (6 for the factor) for steep cameras, off for
        forward-looking ones (measured on KITTI 07: median distance error 2.8 % → 3.6 %,
        frames ok 96 % → 93 %; the far field of a level camera is not modelled by the
        noise model's single magnification term).
    moved_ipm : refinements warp frame k onto frame k-1's IPM plane moved by the current
        motion estimate, so that the patches match with no offset and no rotation (in a
        turn the rotation within a patch biases POC); off: each frame on its own plane with
        the patch windows offset by the predicted displacement (the paper's). None
        (default): on for steep cameras (cart turning 1.5°/frame: pitch/roll error 0.04° /
        0.12° → 0.005° / 0.006°), off for forward-looking ones (KITTI 07: frames ok 96 → 99 %
        with the turn at frames 138-143, but on the frames ok either way mean distance error
        3.8 → 4.2 % and p95 10 → 13 %, three seeds).
    seed : seed of the subset sampler (runs are deterministic).
    keep_images : keep the last refinement's IPM images in the result.
    """

    grid: tuple[int, int] = (11, 9)
    roi: RoiSpec = None
    roi_max_range_h: float | None = None
    roi_max_lateral_h: float = 2.5
    horizon_margin_deg: float = 2.0
    patch_image: int = 128
    patch_ipm: int = 256
    min_patch_image: int = 32
    min_patch_ipm: int = 64
    n_subsets: int = 50
    subset_fraction: float = 0.6
    refine_subsets: int = 0
    refinements: int | None = None
    initial_pitch_deg: float = 60.0
    initial_roll_deg: float = 0.0
    coarse_scale: int = 4
    coarse_patch: int = 64
    coarse_inlier_px: float = 10.0
    coarse_peak_ratio: float = 0.6
    min_peak: float = 0.05
    max_displacement_factor: float = 4.0
    inlier_px_image: float = 3.0
    inlier_px_ipm: float = 1.5
    refine_outlier_px: float = 8.0
    min_inliers: int = 12
    min_motion_px: float = 0.5
    max_deviation_deg: float = 25.0
    max_roll_deg: float = 10.0
    nominal_undetermined: str = ""
    jackknife_covariance: bool = True
    heave_rate_mps: float = 0.05
    cold_start_ipm: bool = True
    cold_pitch_steps_deg: tuple[float, ...] | None = None
    readout_s: float = 0.0
    ipm_resolution_scale: float = 1.0
    ipm_max_side: int = 3000
    vertical_motion: bool | None = None
    pose_prior_deg: float | None = None
    track_prior_deg: float = 0.5
    stage_median: bool | None = None
    weight_patches: bool | None = None
    recentre_windows: bool | None = None
    inlier_median_factor: float | None = None
    moved_ipm: bool | None = None
    seed: int = 0
    keep_images: bool = False

    def __post_init__(self) -> None:
        checks = {
            "grid": len(self.grid) == 2 and min(self.grid) >= 2,
            "patch_image": self.patch_image >= 16,
            "patch_ipm": self.patch_ipm >= 16,
            "min_patch_image": 8 <= self.min_patch_image <= self.patch_image,
            "min_patch_ipm": 8 <= self.min_patch_ipm <= self.patch_ipm,
            "n_subsets": self.n_subsets >= 0,
            "subset_fraction": 0.0 < self.subset_fraction <= 1.0,
            "refine_subsets": self.refine_subsets >= 0,
            "refinements": self.refinements is None or self.refinements >= 0,
            "coarse_scale": self.coarse_scale >= 1,
            "min_inliers": self.min_inliers >= 4,
            "inlier_px_image": self.inlier_px_image > 0,
            "inlier_px_ipm": self.inlier_px_ipm > 0,
            "refine_outlier_px": self.refine_outlier_px > 0,
            "ipm_resolution_scale": self.ipm_resolution_scale > 0,
            "roi_max_range_h": self.roi_max_range_h is None or self.roi_max_range_h > 0,
            "roi_max_lateral_h": self.roi_max_lateral_h > 0,
            "max_deviation_deg": self.max_deviation_deg > 0,
            "max_roll_deg": 0 < self.max_roll_deg <= 90,
            "cold_pitch_steps_deg": self.cold_pitch_steps_deg is None or all(
                np.isfinite(step) and abs(step) < self.max_deviation_deg
                for step in self.cold_pitch_steps_deg),
            "pose_prior_deg": self.pose_prior_deg is None or self.pose_prior_deg >= 0,
            "track_prior_deg": self.track_prior_deg >= 0,
            "inlier_median_factor": (self.inlier_median_factor is None
                                     or self.inlier_median_factor >= 0),
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise InputError(
                "estimator config: invalid " + ", ".join(f"{b}={getattr(self, b)!r}" for b in bad)
            )

    @property
    def initial_pose(self) -> tuple[float, float]:
        """Cold-start (pitch, roll), radians."""
        return float(np.radians(self.initial_pitch_deg)), float(np.radians(self.initial_roll_deg))


@dataclass(frozen=True)
class PairGuess:
    """A prior for a pair (tracking mode): LM start and patch-window offsets."""

    pose_prev: GroundPose
    pose_curr: GroundPose
    motion: PlanarMotion

    @classmethod
    def from_previous(cls, result: PairResult) -> PairGuess | None:
        """Constant-pose, constant-velocity guess for the next pair from an ``ok`` result
        (None otherwise, which means a cold start)."""
        if result is None or result.status != STATUS_OK:
            return None
        return cls(result.pose_curr, result.pose_curr, result.motion)


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


class _StageFailure(Exception):
    def __init__(self, status: str, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


class TwoFrameEstimator:
    """Pose of two frames against the ground and the planar motion between them.

    Parameters
    ----------
    camera : intrinsics; distorted frames are undistorted to ``camera.k`` first.
    height : assumed camera height [m] (scale of the translation, CONVENTIONS.md).
    config : settings; :class:`EstimatorConfig` defaults when None.
    """

    def __init__(self, camera: CameraModel, height: float, config: EstimatorConfig | None = None):
        if not height > 0:
            raise InputError(f"camera height must be > 0 m, got {height}")
        self.camera = camera
        self.height = float(height)
        self.config = config or EstimatorConfig()
        self.k = camera.k
        pitch0, roll0 = self.config.initial_pose
        self.nominal = GroundPose(pitch0, roll0, self.height)
        margin = np.radians(self.config.horizon_margin_deg)
        self._horizon_margin_px = float(np.tan(margin) * camera.fy)
        # Steep: the whole image sees the ground at the nominal pose (no horizon in view).
        self.steep = bool(horizon_row(camera.k, self.nominal, camera.cx) < 0)
        # Level: a forward-looking camera near the horizontal, whose pitch trades against the
        # travel (the second minimum of issue 5) and whose far-field IPM patches stretch by
        # 10-50x; the per-camera defaults below were tuned for it on KITTI 07 (pitch ~1°).
        # A camera pitched further down gets the steep defaults even with the horizon in view
        # (rendered 10-20° cameras: pitch error 0.14-0.33° -> 0.01°)
        self.level = not self.steep and self.nominal.pitch < np.radians(LEVEL_MAX_PITCH_DEG)
        # per-camera defaults of the fields left None (see EstimatorConfig)
        by_camera = {
            "roi_max_range_h": LEVEL_ROI_RANGE_H if self.level else 15.0,
            "vertical_motion": not self.level,
            "refinements": 2 if self.level else 1,
            "stage_median": self.level,
            "pose_prior_deg": 2.0 if self.level else 0.0,
            "moved_ipm": not self.level,
            "cold_pitch_steps_deg": COLD_PITCH_STEPS_DEG["level" if self.level else "steep"],
            **REFINEMENT_WEIGHTING["uniform" if self.level else "noise"],
        }
        self.config = dataclasses.replace(self.config, **{
            name: value for name, value in by_camera.items() if getattr(self.config, name) is None
        })
        mask = roi_mask(
            camera, self.config.roi, self.nominal,
            self.config.roi_max_range_h * self.height,
            self.config.roi_max_lateral_h * self.height, margin,
        )
        self.roi = mask
        # share of content fixed to the camera around each pixel, of the pair in hand
        self._static = np.zeros(mask.shape, np.float32)
        self.centres, self.sizes = interest_points(
            camera, mask, self.config.grid, self.config.patch_image,
            self.config.min_patch_image, self.nominal, self._horizon_margin_px,
        )
        if len(self.centres) < self.config.min_inliers:
            raise InputError(
                f"region of interest holds {len(self.centres)} usable interest points, fewer "
                f"than min_inliers={self.config.min_inliers}; enlarge the ROI or the grid"
            )
        self._maps = camera.undistortion_maps() if camera.has_distortion else None
        self._cache: tuple[int, NDArray] | None = None
        self._noise: tuple[NDArray, float] | None = None  # the last prepared image's noise
        self._readout_frames = 0.0  # rolling shutter of the pair in hand (estimate())
        self._heave_std_m = 0.0  # vertical motion the pair in hand may hide (estimate())
        self._previous_motion: FloatArray | None = None
        self._prior_mean, self._prior_sigma = self._pose_prior(None)

    # --- public -----------------------------------------------------------------------------

    def estimate(
        self, prev_img: NDArray, curr_img: NDArray, guess: PairGuess | None = None,
        frame_interval_s: float | None = None,
    ) -> PairResult:
        """Estimate both poses and the motion from frame k-1 (``prev_img``) to k.

        Images are grey or BGR arrays of the camera's size. ``guess`` (tracking mode) seeds
        the optimisation and offsets the patch windows by the displacements it predicts.
        ``frame_interval_s`` [s], the time between the frames, is needed with a rolling
        shutter (``EstimatorConfig.readout_s``) and unused otherwise; there the ``guess``'s
        motion (the previous pair's, scaled to this interval) also gives the vehicle's
        acceleration.
        Cold, both starts are tried (with ``cold_start_ipm``), the second where the first
        fails: a forward camera first from the nominal pose's virtual IPM, then from the
        coarse image-plane pass (a camera ~10° down on a fast car: the near field's IPM is
        too stretched to match from the nominal pose); a steep camera the other way round
        (moving a third of its distance to the ground per frame, the image scales by a third
        between the frames, which the image-plane patches cannot match but the bird's-eye
        plane turns into a translation).
        """
        if self.config.nominal_undetermined:
            return PairResult(status=STATUS_NO_NOMINAL, reason=self.config.nominal_undetermined)
        t_start = time.perf_counter()
        self._readout_frames = self._shutter_readout_frames(frame_interval_s)
        self._heave_std_m = self.config.heave_rate_mps * (
            frame_interval_s if frame_interval_s and frame_interval_s > 0 else 0.1)
        # the interval before's motion (tracking), for the rolling shutter's acceleration
        self._previous_motion = None if guess is None else np.array(
            [guess.motion.tx, guess.motion.tz, guess.motion.yaw])
        prev = self._prepare(prev_img, "previous frame")
        curr = self._prepare(curr_img, "current frame")
        # content fixed to the camera, once per pair (both cold starts leave it out)
        noise = (self._noise_sigma(prev), self._noise_sigma(curr))
        self._static = static_share(static_pixels(prev, curr, noise), self.config.patch_image // 2)
        prepared_s = time.perf_counter() - t_start
        result = self._estimate_starts(prev, curr, guess, 0.0)
        if guess is None and result.status in (STATUS_FEW_INLIERS, STATUS_NOT_CONVERGED):
            for step in self.config.cold_pitch_steps_deg:
                retry = self._estimate_starts(prev, curr, None, np.radians(step))
                self._reject_wrong_minimum(retry, retry=True)
                _add_timings(retry, result)
                if retry.status == STATUS_OK:
                    retry.reason = (f"cold start from the nominal pitch failed ({result.reason});"
                                    f" from {step:+g}° off it, {retry.reason or 'ok'}")
                    result = retry
                    break
                result.timings = retry.timings
            else:
                steps = ", ".join(f"{step:+g}°" for step in self.config.cold_pitch_steps_deg)
                if steps:
                    result.reason = f"{result.reason}; from the nominal pitch {steps} neither"
        result.timings["total"] += prepared_s
        return result

    def _estimate_starts(
        self, prev: NDArray[np.float32], curr: NDArray[np.float32], guess: PairGuess | None,
        pitch_step: float,
    ) -> PairResult:
        """:meth:`_estimate` from the ``guess``, or cold from both starts in turn, from the
        nominal pose with its pitch moved by ``pitch_step`` (radians)."""
        if guess is not None or not self.config.cold_start_ipm:
            starts = [False]
        else:
            starts = [False, True] if self.steep else [True, False]
        result = self._estimate(prev, curr, guess, starts[0], pitch_step)
        if guess is None:
            self._reject_wrong_minimum(result)
        if len(starts) > 1 and result.status not in (STATUS_OK, STATUS_NO_MOTION):
            second = self._estimate(prev, curr, None, starts[1], pitch_step)
            self._reject_wrong_minimum(second)
            names = {True: "from the nominal-pose IPM", False: "on the image plane"}
            _add_timings(second, result)
            if second.status == STATUS_OK:
                second.reason = (f"cold start {names[starts[0]]} failed ({result.reason}); "
                                 f"cold start {names[starts[1]]}")
                result = second
            else:
                result.timings = second.timings
                result.reason = (f"cold start {names[starts[0]]}: {result.reason}; "
                                 f"{names[starts[1]]}: {second.reason}")
        return result

    def _estimate(
        self, prev: NDArray[np.float32], curr: NDArray[np.float32], guess: PairGuess | None,
        ipm_start: bool, pitch_step: float = 0.0,
    ) -> PairResult:
        """:meth:`estimate` on the prepared images (``_prepare``) with the cold start chosen
        by ``ipm_start``, from the nominal pose with its pitch moved by ``pitch_step``
        (radians)."""
        t_start = time.perf_counter()
        timings = {"poc": 0.0, "warp": 0.0, "lm": 0.0}
        result = PairResult(status=STATUS_OK, timings=timings, height=self.height)
        rng = np.random.default_rng(self.config.seed)
        self._prior_mean, self._prior_sigma = self._pose_prior(guess)
        try:
            refinements = self.config.refinements
            loose = False
            start, source = None, "guess"
            if guess is not None:
                start = self._guess_vector(guess)
            elif ipm_start:
                start, source = (self._cold_start_ipm(prev, curr, pitch_step, result),
                                 "nominal-pose IPM")
            try:
                x = self._initial(prev, curr, start, rng, result, pitch_step)
            except _StageFailure as failure:
                if start is None or failure.status == STATUS_NO_MOTION:
                    raise
                # The start is better than a failed image-plane stage (fast forward motion
                # distorts image patches most); the virtual IPM removes that distortion,
                # given a wider outlier gate and one more pass.
                x = start
                result.reason = f"image stage skipped ({failure.reason}); refined from the {source}"
                refinements, loose = max(refinements, 1) + 1, True
            try:
                x = self._refine_all(prev, curr, x, refinements, loose, rng, result)
            except _StageFailure as failure:
                if start is None or loose:
                    raise
                # An image stage that passed its own checks but misleads the refinement
                # (a wrong minimum on the distorted image patches): refine from the start.
                result.reason = (f"refinement from the image stage failed ({failure.reason}); "
                                 f"refined from the {source}")
                x = self._refine_all(prev, curr, start, max(refinements, 1) + 1, True, rng,
                                     result)
            # only with several refinements configured: with one, a median of two stages would
            # average the refined estimate with the rougher image-stage one (when a later
            # refinement fails, the accepted stages' median still helps)
            if (self.config.stage_median and not self.config.vertical_motion
                    and self.config.refinements >= 2 and len(result.stage_estimates) >= 2):
                stack = np.array([pack(*s) for s in result.stage_estimates])
                result.pose_prev, result.pose_curr, result.motion = unpack(
                    np.median(stack, axis=0), self.height)
                # the median is uncertain by what the stages disagree on: on real frames
                # the image stage and the IPM refinements miss different parts of the model
                # (measured in docs/traffic.md); on exact renders they agree
                # (the stages' scatter about the median, as a covariance: they disagree on
                # both frames' pose alike far more than on the change between them)
                spread = stack[:, :4] - np.median(stack, axis=0)[:4]
                result.covariance[:4, :4] += spread.T @ spread / (len(stack) - 1)
        except _StageFailure as failure:
            _mark_failed(result, failure.status, failure.reason)
        timings["total"] = time.perf_counter() - t_start
        return result

    def _reject_wrong_minimum(self, result: PairResult, retry: bool = False) -> None:
        """Fail a steep camera's cold-start ``result`` whose last stage has fewer than
        ``COLD_MIN_INLIER_SHARE`` of its measured patches (visible in both frames, POC peak
        at least ``min_peak``) as inliers: a wrong minimum. ``retry`` (a start off the
        nominal pitch, ``cold_pitch_steps_deg``): any camera, and ``RETRY_MIN_INLIER_SHARE``."""
        if not (self.steep or retry) or result.status != STATUS_OK or not result.stages:
            return
        need = RETRY_MIN_INLIER_SHARE if retry else COLD_MIN_INLIER_SHARE
        stage = result.stages[-1]
        measured = (stage.sizes > 0) & (stage.peaks >= self.config.min_peak)
        share = float(np.sum(stage.inliers & measured) / max(int(measured.sum()), 1))
        if share < need:
            _mark_failed(result, STATUS_FEW_INLIERS,
                         f"cold start converged with {share:.0%} of the measured patches "
                         f"inliers (need {need:.0%}): a wrong minimum")

    # --- stages -----------------------------------------------------------------------------

    def _initial(
        self,
        prev: NDArray,
        curr: NDArray,
        start: FloatArray | None,
        rng: np.random.Generator,
        result: PairResult,
        pitch_step: float = 0.0,
    ) -> FloatArray:
        cfg = self.config
        if start is not None:
            x0 = start
            offsets = self._predicted_displacements(x0)
        else:
            x0 = self._cold_vector(pitch_step)
            offsets = np.zeros_like(self.centres)
            if cfg.coarse_scale > 1:
                x0, offsets = self._coarse(prev, curr, x0, rng, result)

        offsets = np.round(offsets)
        sizes = shrink_to_image(self.centres + offsets, self.sizes, self.camera.width,
                                self.camera.height, cfg.min_patch_image)
        t0 = time.perf_counter()
        disp, peaks = _match_grouped(prev, curr, self.centres, sizes, offsets)
        result.timings["poc"] += time.perf_counter() - t0

        usable = (sizes > 0) & (peaks >= cfg.min_peak) & ~on_static(self._static, self.centres)
        n_textured = int(usable.sum())
        if n_textured < cfg.min_inliers:
            raise _StageFailure(
                STATUS_NO_TEXTURE,
                f"only {n_textured} of {len(peaks)} patches correlate (POC peak ≥ "
                f"{cfg.min_peak}); the ground shows too little texture",
            )
        mag = np.where(usable, np.linalg.norm(np.nan_to_num(disp), axis=1), np.inf)
        median_mag = float(np.median(mag[usable]))
        if median_mag < cfg.min_motion_px:
            raise _StageFailure(
                STATUS_NO_MOTION,
                f"median displacement {median_mag:.2f} px < {cfg.min_motion_px} px: without "
                "motion the pose against the ground is unobservable",
            )
        usable &= mag <= cfg.max_displacement_factor * median_mag + cfg.patch_image / 8
        self._check_parallax(disp, usable)
        model = DisplacementModel(self.k, self.height, self.centres, self.centres + disp,
                                  **self._model_args(cfg.inlier_px_image))
        fit = self._fit(model, x0, usable, cfg.n_subsets, cfg.inlier_px_image, rng, result)
        result.stages.append(PatchField("image", self.centres, disp, peaks, fit.inliers, sizes))
        self._accept(fit, result, "initial estimate")
        return fit.x

    def _refine_all(
        self, prev: NDArray, curr: NDArray, x: FloatArray, n: int, loose: bool,
        rng: np.random.Generator, result: PairResult,
    ) -> FloatArray:
        """``n`` refinements from ``x``, the first with the wide gate when ``loose``. A
        refinement after the first that fails keeps the previous one's estimate (noted in
        ``result.reason``) instead of failing the pair."""
        for i in range(n):
            try:
                x = self._refine(prev, curr, x, rng, result, loose=loose and i == 0)
            except _StageFailure as failure:
                if i == 0:
                    raise
                note = f"refinement {i + 1} of {n} not used ({failure.reason})"
                result.reason = f"{result.reason}; {note}" if result.reason else note
                break
        return x

    def _cold_vector(self, pitch_step: float) -> FloatArray:
        """Parameter vector of a cold start: both frames at the nominal pose with its pitch
        moved by ``pitch_step`` (radians), no motion."""
        pitch0, roll0 = self.nominal.pitch + pitch_step, self.nominal.roll
        x0 = np.array([pitch0, roll0, pitch0, roll0, 0.0, 0.0, 0.0])
        return np.append(x0, 0.0) if self.config.vertical_motion else x0

    def _cold_start_ipm(self, prev: NDArray, curr: NDArray, pitch_step: float,
                        result: PairResult) -> FloatArray:
        """Cold start of a forward camera: both frames on the nominal pose's ground plane,
        where the motion is nearly one translation (tx, tz) at the nominal pose (yaw 0).

        On the downsampled planes (``coarse_scale``) one POC over the whole visible ground
        finds the translation however far the vehicle moved (a fast car moves further per
        frame than a patch is long); the patches, their windows offset by it, then give
        its median (robust to a turn and to what is not ground)."""
        cfg = self.config
        x0 = self._cold_vector(pitch_step)
        pose = GroundPose(x0[2], x0[3], self.height)
        t0 = time.perf_counter()
        grid = ipm.choose_grid(self.k, pose, PlanarMotion(0.0, 0.0, 0.0), self.centres,
                               cfg.patch_ipm, cfg.ipm_resolution_scale, cfg.ipm_max_side)
        s = max(cfg.coarse_scale, 1)
        size = (max(grid.width // s, 1), max(grid.height // s, 1))
        small_p = cv2.resize(ipm.warp(prev, self.k, pose, grid), size,
                             interpolation=cv2.INTER_AREA)
        small_c = cv2.resize(ipm.warp(curr, self.k, pose, grid), size,
                             interpolation=cv2.INTER_AREA)
        result.timings["warp"] += time.perf_counter() - t0
        q = grid.pixel_from_ground(back_project(self.k, pose, self.centres))
        # content fixed to the camera (hood, overlay) correlates at zero shift: left out
        q = q[np.all(np.isfinite(q), axis=1) & ~on_static(self._static, self.centres)]
        patch = int(min(cfg.coarse_patch, (min(size) - 2) // 16 * 16))
        if len(q) == 0 or patch < 16:
            return x0
        t0 = time.perf_counter()
        polygon = ipm.visible_polygon(self.k, pose, grid,
                                      (self.camera.width, self.camera.height),
                                      self._horizon_margin_px)
        inside = _polygon_mask(size, (polygon - (s - 1) / 2) / s)
        # and out of the global shift, which it pulls to zero
        fixed = cv2.resize(ipm.warp(self._static, self.k, pose, grid), size,
                           interpolation=cv2.INTER_AREA) > PATCH_MAX_SHARE
        shift = _global_shift(small_p, small_c, inside & ~fixed, cfg.min_peak)
        half = patch / 2
        centres = np.round(np.clip((q - (s - 1) / 2) / s, [half, half],
                                   [size[0] - 1 - half, size[1] - 1 - half]))
        # Windows at zero offset (slow motion) or at the global shift (fast): the global one
        # only where its windows correlate clearly better (twice the upper-quartile peak),
        # since in sharp turns neither is a translation and the zero offset fails safer.
        disp, peaks = poc.match_patches(small_p, small_c, centres, patch)
        if np.any(np.round(shift)):
            moved = poc.match_patches(small_p, small_c, centres, patch, np.round(shift))
            if _upper_quartile(moved[1]) > 2.0 * _upper_quartile(peaks):
                disp, peaks = moved
        result.timings["poc"] += time.perf_counter() - t0
        good = peaks >= max(cfg.min_peak, cfg.coarse_peak_ratio * float(np.max(peaks)))
        if not good.any():
            return x0
        du, dv = np.median(disp[good], axis=0) * s * grid.metres_per_pixel
        # Ground content moves by -t in the new frame: IPM u grows with X, v shrinks with Z.
        x0[4], x0[5] = -du, dv
        return x0

    def _check_parallax(self, disp: NDArray, usable: NDArray[np.bool_]) -> None:
        """Fail the pair as "no motion" where a pure rotation explains the matched field
        (``disp`` (N, 2) of the ``usable`` patches) to within ``min_motion_px`` (median): a
        standing vehicle's camera still pitches and rolls (engine, passengers, wind), which
        moves the image by pixels, but without translation the pose against the ground is
        unobservable and the fit diverges."""
        use = usable & np.isfinite(disp).all(axis=1)
        if use.sum() < 3:
            return
        centres = self.centres[use]
        residual, angle = rotation_parallax(self.k, centres, centres + disp[use])
        parallax = float(np.median(residual))
        if parallax < self.config.min_motion_px:
            raise _StageFailure(
                STATUS_NO_MOTION,
                f"a rotation of {np.degrees(angle):.2f}° explains the image motion to "
                f"{parallax:.2f} px < {self.config.min_motion_px} px (median): without "
                "translation the pose against the ground is unobservable",
            )

    def _coarse(
        self, prev: NDArray, curr: NDArray, x0: FloatArray, rng: np.random.Generator,
        result: PairResult,
    ) -> tuple[FloatArray, FloatArray]:
        """Cold start: displacements on a downsampled pair, a quick fit, and the patch
        offsets it predicts at full resolution (zero offsets where it cannot tell)."""
        cfg = self.config
        s = cfg.coarse_scale
        t0 = time.perf_counter()
        size = (curr.shape[1] // s, curr.shape[0] // s)
        small_p = cv2.resize(prev, size, interpolation=cv2.INTER_AREA)
        small_c = cv2.resize(curr, size, interpolation=cv2.INTER_AREA)
        patch = int(min(cfg.coarse_patch, (min(size) - 2) // 16 * 16))
        half = patch / 2
        coarse_centres = np.round(
            np.clip((self.centres - (s - 1) / 2) / s, [half, half],
                    [size[0] - 1 - half, size[1] - 1 - half])
        )
        disp, peaks = poc.match_patches(small_p, small_c, coarse_centres, patch)
        result.timings["poc"] += time.perf_counter() - t0
        pix = coarse_centres * s + (s - 1) / 2
        # Content fixed in the image (the vehicle's body, lens dirt, reflections) correlates
        # perfectly at zero shift while the ground moves: not ground, whatever its peak.
        mag = np.linalg.norm(np.nan_to_num(disp), axis=1) * s
        valid = peaks >= cfg.min_peak
        if not valid.any():
            return x0, np.zeros_like(self.centres)
        static = mag < max(cfg.min_motion_px, 0.1 * float(np.median(mag[valid])))
        # Patches whose content left the window still give a (lower) peak; trust the ones
        # that correlate nearly as well as the best moving ones.
        moving = valid & ~static
        if not moving.any():
            return x0, np.zeros_like(self.centres)
        floor = cfg.coarse_peak_ratio * float(np.percentile(peaks[moving], 90))
        usable = moving & (peaks >= max(cfg.min_peak, floor))
        if usable.sum() < cfg.min_inliers:
            return x0, np.zeros_like(self.centres)
        model = SteadyPoseModel(self.k, self.height, pix, pix + disp * s,
                                **self._model_args(cfg.coarse_inlier_px))
        fit = self._fit(model, SteadyPoseModel.reduce(x0), usable, cfg.n_subsets,
                        cfg.coarse_inlier_px, rng, result)
        if fit.inliers.sum() < cfg.min_inliers or not fit.converged:
            return x0, np.zeros_like(self.centres)
        x = model.full(fit.x)
        if len(x0) > len(x):
            x = np.append(x, x0[len(x):])
        return x, self._predicted_displacements(x)

    def _refine(
        self, prev: NDArray, curr: NDArray, x: FloatArray, rng: np.random.Generator,
        result: PairResult, loose: bool = False,
    ) -> FloatArray:
        """One virtual-IPM refinement from the estimate ``x``; ``loose`` widens the outlier
        gate (×3) and fits random subsets, for a start that is only a guess."""
        cfg = self.config
        pose_p, pose_c, motion = unpack(x, self.height)
        t0 = time.perf_counter()
        grid = ipm.choose_grid(self.k, pose_p, motion, self.centres, cfg.patch_ipm,
                               cfg.ipm_resolution_scale, cfg.ipm_max_side)
        ipm_p = ipm.warp(prev, self.k, pose_p, grid)
        # Patch centres: interest points on the previous virtual IPM plane, on whole pixels.
        q_p = np.round(grid.pixel_from_ground(back_project(self.k, pose_p, self.centres)))
        valid = np.all(np.isfinite(q_p), axis=1)
        q_p = np.where(valid[:, None], q_p, 0.0)
        pixels_prev = apply_homography(image_from_ipm_homography(self.k, pose_p, grid), q_p)
        plane_from_image = ipm_from_image_homography(self.k, pose_c, grid)
        pred = DisplacementModel(self.k, self.height, pixels_prev, q_p, plane_from_image,
                                 **self._shutter()).predict(x) - q_p
        pred = np.where(np.isfinite(pred), pred, 0.0)
        size_img = (self.camera.width, self.camera.height)
        poly_p = ipm.visible_polygon(self.k, pose_p, grid, size_img, self._horizon_margin_px)
        poly_c = ipm.visible_polygon(self.k, pose_c, grid, size_img, self._horizon_margin_px)
        if cfg.moved_ipm:
            # Frame k's plane moved onto frame k-1's by the estimate: the patches match
            # with no offset and no rotation between them (POC assumes a translation; a
            # turn's rotation within a patch biased its shift by the texture's layout).
            moved = ipm.moved_pixels_matrix(grid, motion)
            ipm_c = ipm.warp(curr, self.k, pose_c, grid, motion)
            poly_c = apply_homography(np.linalg.inv(moved), poly_c)
            # zero but for the rolling shutter's part of the motion
            offsets = np.round(apply_homography(np.linalg.inv(moved), q_p + pred) - q_p)
        else:
            ipm_c = ipm.warp(curr, self.k, pose_c, grid)
            offsets = np.round(pred)
        sizes = ipm.patch_sizes(grid, poly_p, poly_c, q_p, offsets, cfg.patch_ipm,
                                cfg.min_patch_ipm)
        sizes[~valid] = 0
        result.timings["warp"] += time.perf_counter() - t0

        t0 = time.perf_counter()
        # recentre: the Hann windows of a patch pair overlap less the further the content
        # moved from the window offset, which pulls the POC estimate towards that offset
        # (about 2 % of the gap, i.e. of the previous estimate's error)
        disp, peaks = _match_grouped(ipm_p, ipm_c, q_p, sizes, offsets,
                                     recentre=cfg.recentre_windows)
        if cfg.moved_ipm:
            disp = apply_homography(moved, q_p + disp) - q_p
        result.timings["poc"] += time.perf_counter() - t0

        usable = (sizes > 0) & (peaks >= cfg.min_peak) & ~on_static(self._static, pixels_prev)
        dev = np.linalg.norm(disp - pred, axis=1)
        usable &= dev <= cfg.refine_outlier_px * (3.0 if loose else 1.0)
        whitening = (ipm.patch_noise_whitening(plane_from_image, q_p + disp, sizes, cfg.patch_ipm)
                     if cfg.weight_patches else None)
        model = DisplacementModel(
            self.k, self.height, pixels_prev, q_p + disp, plane_from_image=plane_from_image,
            point_whitening=whitening, **self._model_args(cfg.inlier_px_ipm),
        )
        if usable.sum() < cfg.min_inliers:
            raise _StageFailure(
                STATUS_FEW_INLIERS,
                f"refinement {len(result.stages)}: {int(usable.sum())} IPM patches agree with "
                f"the previous estimate (need {cfg.min_inliers})",
            )
        n_subsets = max(cfg.refine_subsets, 20) if loose else cfg.refine_subsets
        inlier_px = cfg.inlier_px_ipm * (2.0 if loose else 1.0)
        fit = self._fit(model, x, usable, n_subsets, inlier_px, rng, result,
                        cfg.inlier_median_factor)
        result.stages.append(PatchField("ipm", q_p, disp, peaks, fit.inliers, sizes, grid))
        if cfg.keep_images:
            result.ipm_images = (ipm_p, ipm_c)
        self._accept(fit, result, f"refinement {len(result.stages) - 1}")
        return fit.x

    # --- helpers ----------------------------------------------------------------------------

    def _pose_prior(self, guess: PairGuess | None) -> tuple[FloatArray | None, FloatArray]:
        """Mean and standard deviation (4,) of the prior on (pitch_prev, roll_prev, pitch,
        roll), radians: the nominal pose with ``pose_prior_deg``, frame k-1's fused with the
        guess's pose of it at ``track_prior_deg`` (None mean: no prior)."""
        cfg = self.config
        sigma = np.radians(cfg.pose_prior_deg or 0.0)
        if sigma <= 0:
            return None, np.zeros(4)
        p, r = self.nominal.pitch, self.nominal.roll
        mean, std = np.array([p, r, p, r]), np.full(4, sigma)
        s_t = np.radians(cfg.track_prior_deg)
        if guess is not None and s_t > 0:
            w_n, w_t = 1.0 / sigma**2, 1.0 / s_t**2
            tracked = np.array([guess.pose_prev.pitch, guess.pose_prev.roll])
            mean[:2] = (w_n * mean[:2] + w_t * tracked) / (w_n + w_t)
            std[:2] = 1.0 / np.sqrt(w_n + w_t)
        return mean, std

    def _untracked_prior(self, model: DisplacementModel) -> DisplacementModel | None:
        """``model`` with its pose prior at the nominal pose's weight alone, where the prior
        also holds the previous pair's estimate (tracking); None otherwise."""
        if self._prior_mean is None or model.n_prior == 0:
            return None
        nominal = np.radians(self.config.pose_prior_deg or 0.0)
        if np.allclose(self._prior_sigma, nominal):
            return None
        return replace(model, prior_scale=np.asarray(model.prior_scale)
                       * self._prior_sigma / nominal)

    def _shutter_readout_frames(self, frame_interval_s: float | None) -> float:
        """The rolling shutter's readout in frame intervals of a pair ``frame_interval_s``
        seconds apart (``bundle.DisplacementModel``); 0 for a global shutter."""
        readout = self.config.readout_s
        if not readout:
            return 0.0
        if frame_interval_s is None or not (np.isfinite(frame_interval_s)
                                            and frame_interval_s > 0):
            raise ValueError(f"a rolling-shutter readout of {readout} s needs the pair's frame "
                             f"interval, got {frame_interval_s}")
        return readout / frame_interval_s

    def _model_args(self, inlier_px: float) -> dict:
        """Arguments of a residual model for the pair in hand: the pose prior
        (:meth:`_prior`) and the rolling shutter's row timing."""
        return {**self._prior(inlier_px), **self._shutter()}

    def _shutter(self) -> dict:
        """Rolling-shutter arguments of a residual model for the pair in hand."""
        return {"readout_frames": self._readout_frames, "image_rows": self.camera.height,
                "previous_motion": self._previous_motion}

    def _prior(self, inlier_px: float) -> dict:
        """Pose-prior arguments of a residual model whose inlier threshold is ``inlier_px``
        plane pixels (taken as 3 σ of a point's noise); see :meth:`_pose_prior`."""
        if self._prior_mean is None:
            return {}
        return {"prior_mean": self._prior_mean, "prior_scale": inlier_px / 3.0 / self._prior_sigma}

    def _fit(
        self, model: DisplacementModel, x0: FloatArray, usable: NDArray[np.bool_],
        n_subsets: int, inlier_px: float, rng: np.random.Generator, result: PairResult,
        median_factor: float = 0.0,
    ) -> FitResult:
        t0 = time.perf_counter()
        if usable.sum() < max(4, self.config.min_inliers):
            raise _StageFailure(
                STATUS_FEW_INLIERS,
                f"{int(usable.sum())} usable patches (need {self.config.min_inliers})",
            )
        fit = robust_fit(model, x0, usable, n_subsets, self.config.subset_fraction, inlier_px,
                         rng, median_factor, self.config.jackknife_covariance)
        if not np.all(np.isfinite(fit.covariance)):
            return fit
        inliers = np.flatnonzero(fit.inliers)
        untracked = self._untracked_prior(model)
        if untracked is not None and inliers.size >= len(fit.x):
            # the previous pair's estimate of frame k-1 shares this pair's errors (the same
            # image, the same road): it steadies the fit, but counted as independent evidence
            # in the covariance it makes every tracked pair look surer than it is
            fit = replace(fit, covariance=at_least(fit.covariance, covariance_from_jacobian(
                untracked.jacobian(fit.x, inliers), untracked.residuals(fit.x, inliers))))
        if not self.config.vertical_motion:
            fit = replace(fit, covariance=fit.covariance + heave_covariance(
                model, fit.x, inliers, self._heave_std_m))
        result.timings["lm"] += time.perf_counter() - t0
        return fit

    def _accept(self, fit: FitResult, result: PairResult, stage: str) -> None:
        """Check a stage's fit and make it the result's current estimate."""
        cfg = self.config
        n_in = int(fit.inliers.sum())
        if n_in < cfg.min_inliers:
            raise _StageFailure(
                STATUS_FEW_INLIERS, f"{stage}: {n_in} inliers (need {cfg.min_inliers})"
            )
        pose_p, pose_c, motion = unpack(fit.x, self.height)
        dev = np.radians(cfg.max_deviation_deg)
        roll_dev = min(dev, np.radians(cfg.max_roll_deg))
        plausible = (
            np.all(np.isfinite(fit.x))
            and all(-np.pi / 4 < p.pitch < 3 * np.pi / 4 for p in (pose_p, pose_c))
            and all(abs(p.roll) < np.pi / 4 for p in (pose_p, pose_c))
            and all(abs(p.pitch - self.nominal.pitch) < dev
                    and abs(p.roll - self.nominal.roll) < roll_dev for p in (pose_p, pose_c))
            and abs(motion.yaw) < np.pi / 4
        )
        if not (fit.converged and plausible):
            raise _StageFailure(
                STATUS_NOT_CONVERGED,
                f"{stage}: LM "
                f"{'did not converge' if not fit.converged else 'left the plausible range'}"
                f" (pitch {np.degrees(pose_c.pitch):.1f}°, roll {np.degrees(pose_c.roll):.1f}°)",
            )
        cov = fit.covariance
        if not np.all(np.isfinite(cov)) or np.any(np.linalg.eigvalsh(cov) <= 0):
            raise _StageFailure(
                STATUS_DEGENERATE, f"{stage}: the parameters are not all observable "
                "(singular normal equations)"
            )
        result.pose_prev, result.pose_curr, result.motion = pose_p, pose_c, motion
        result.covariance = cov[:7, :7]
        result.height_change = float(fit.x[7]) if len(fit.x) > 7 else 0.0
        result.n_inliers = n_in
        result.residual_px = fit.rms
        result.stage_estimates.append(StageEstimate(pose_p, pose_c, motion))

    def _guess_vector(self, guess: PairGuess) -> FloatArray:
        """Parameter vector of a guess at the assumed height (no vertical motion)."""
        x0 = pack(
            GroundPose(guess.pose_prev.pitch, guess.pose_prev.roll, self.height),
            GroundPose(guess.pose_curr.pitch, guess.pose_curr.roll, self.height),
            guess.motion,
        )
        return np.append(x0, 0.0) if self.config.vertical_motion else x0

    def _predicted_displacements(self, x: FloatArray) -> FloatArray:
        """Image displacements (N, 2) the parameters predict at the interest points (0 where
        undefined)."""
        model = DisplacementModel(self.k, self.height, self.centres, self.centres,
                                  **self._shutter())
        d = model.predict(x) - self.centres
        return np.where(np.isfinite(d), d, 0.0)

    def _noise_sigma(self, prepared: NDArray[np.float32]) -> float:
        """``noise_sigma`` of a prepared image; the last one is cached (in a sequence a frame
        is the current one of a pair and the previous one of the next)."""
        if self._noise is None or self._noise[0] is not prepared:
            self._noise = (prepared, noise_sigma(prepared))
        return self._noise[1]

    def _prepare(self, image: NDArray, name: str) -> NDArray[np.float32]:
        """Grey float32 undistorted image; the last one is cached (tracking reuses it)."""
        if self._cache is not None and self._cache[0] is image:
            return self._cache[1]
        arr = np.asarray(image)
        if arr.ndim == 3 and arr.shape[2] in (3, 4):
            code = cv2.COLOR_BGR2GRAY if arr.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
            arr = cv2.cvtColor(arr, code)
        if arr.ndim != 2:
            raise InputError(f"{name}: expected a grey or BGR image, got shape {arr.shape}")
        if arr.shape != (self.camera.height, self.camera.width):
            raise InputError(
                f"{name}: image is {arr.shape[1]}×{arr.shape[0]} px but the camera model is "
                f"{self.camera.width}×{self.camera.height} px"
            )
        out = arr.astype(np.float32)
        if self._maps is not None:
            out = cv2.remap(out, self._maps[0], self._maps[1], cv2.INTER_LINEAR)
        self._cache = (image, out)
        return out


def _add_timings(result: PairResult, earlier: PairResult) -> None:
    """Add an ``earlier`` attempt's stage timings to ``result``'s (the pair's cost is both)."""
    for key, seconds in earlier.timings.items():
        result.timings[key] = result.timings.get(key, 0.0) + seconds


def _mark_failed(result: PairResult, status: str, reason: str) -> None:
    """Make ``result`` a failed pair: ``status`` and ``reason``, no estimate."""
    result.status, result.reason = status, reason
    result.pose_prev = result.pose_curr = result.motion = None
    result.covariance = np.full((7, 7), np.nan)


def _match_grouped(
    ref: NDArray, moving: NDArray, centres: FloatArray, sizes: NDArray[np.int64],
    offsets: FloatArray, recentre: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """POC displacements (N, 2) and peaks (N,) of patches batched by size (one call per
    size); NaN displacement and zero peak where ``sizes`` is 0."""
    disp = np.full((len(centres), 2), np.nan)
    peaks = np.zeros(len(centres))
    for s in np.unique(sizes):
        if s <= 0:
            continue
        sel = np.flatnonzero(sizes == s)
        d, p = poc.match_patches(ref, moving, centres[sel], int(s), offsets=np.round(offsets[sel]),
                                 recentre=recentre)
        disp[sel] = d
        peaks[sel] = p
    return disp, peaks


def _polygon_mask(size: tuple[int, int], polygon: FloatArray) -> NDArray[np.bool_]:
    """Pixels (height, width) of an image of ``size`` (width, height) inside the convex
    ``polygon`` (pixels)."""
    mask = np.zeros((size[1], size[0]), np.uint8)
    if len(polygon) >= 3:
        cv2.fillConvexPoly(mask, np.round(polygon).astype(np.int32), 1)
    return mask.astype(bool)


def _global_shift(prev: NDArray, curr: NDArray, inside: NDArray[np.bool_], min_peak: float,
                  levels: int = 2) -> FloatArray:
    """Translation (dx, dy), pixels, of the content from ``prev`` to ``curr`` by one POC
    over both whole images, outside ``inside`` (the visible moving ground) filled with
    the mean grey so that the border of the view, fixed in both, does not pull the peak to
    zero. Tried at ``levels`` scales (1, 1/2, …): a pose off the nominal one stretches the
    far ground unevenly, which a coarser plane tolerates better; the highest peak wins.
    Zero where no peak reaches ``min_peak``."""
    h, w = prev.shape[:2]
    if inside.sum() < 256:
        return np.zeros(2)
    planes = []
    for image in (prev, curr):
        plane = np.array(image, np.float32)
        plane[~inside] = float(plane[inside].mean())
        planes.append(plane)
    best, best_peak = np.zeros(2), min_peak
    for level in range(levels):
        f = 2 ** level
        size = (w // f // 2 * 2, h // f // 2 * 2)
        if min(size) < 16:
            break
        pair = [cv2.resize(plane, size, interpolation=cv2.INTER_AREA) for plane in planes]
        shift, peak = poc.phase_correlate(pair[0], pair[1])
        if peak >= best_peak:
            best, best_peak = np.asarray(shift, float) * np.array([w, h]) / size, peak
    return best


def _upper_quartile(peaks: FloatArray) -> float:
    """75th percentile of the POC peaks of the patches that were measured (peak > 0): how
    well the better windows correlate; 0 where none was."""
    measured = peaks[peaks > 0]
    return float(np.percentile(measured, 75)) if measured.size else 0.0
