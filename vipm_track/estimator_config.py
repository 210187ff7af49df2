"""Settings of the two-frame estimator: :class:`EstimatorConfig`, its per-camera defaults
(:func:`with_camera_defaults`, level vs steep cameras), the configuration that runs for a
rig (:func:`resolve`) and the constants they rest on."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .geometry import horizon_row
from .rig import Rig
from .roi import RoiSpec

#: nominal pitch below which a camera with the horizon in view gets the forward-looking
#: (level-camera) defaults of ``EstimatorConfig`` [deg]
LEVEL_MAX_PITCH_DEG = 10.0

#: forward reach of a level camera's automatic region of interest, camera heights: beyond
#: it the road's image is over 10x more compressed along than across the road, and leaving
#: it out made the estimates better on renders and real frames alike (docs/kitti.md)
LEVEL_ROI_RANGE_H = 10.0
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

    Fields left None take per-camera defaults (:func:`resolve`, from the rig's nominal pose):
    "forward-looking" below means a *level* camera (horizon in view and nominal pitch below
    ``LEVEL_MAX_PITCH_DEG``, 10°), "steep" every other one (the cold start alone goes by the
    horizon: ``cold_start_ipm``). The camera, its nominal pose, height and rolling-shutter
    readout are the rig's (``rig.Rig``), not settings.

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
    max_deviation_deg : estimates whose pitch or roll differ from the nominal pose (``Rig``)
        by more than this are rejected ("did not converge").
    max_roll_deg : plausible roll of a vehicle camera: estimates whose roll differs from the
        nominal roll (``Rig.roll_deg``: level unless the user says otherwise) by more
        than this are rejected ("did not converge"); a roll fitted beyond it is vehicles or
        walls taken for the ground, not the mount.
    jackknife_covariance : each fit's covariance is at least its block jackknife's
        (``bundle.block_jackknife_covariance``): the formal one takes the patches' errors as
        independent, which real frames are not.
    heave_rate_mps : standard deviation of the body's vertical speed on its suspension
        [m/s] (a car on an ordinary road: a few cm/s); without ``vertical_motion`` the
        covariance includes what a heave of this speed over the pair's interval moves the
        fit by (``bundle.heave_covariance``; 0: off).
    shutter_rate_covariance : under a rolling shutter, the covariance includes what frame k
        turning during its readout at a rate off the pair's moves the fit by
        (``bundle.shutter_rate_covariance``, at the running RMS of the rate's change from
        pair to pair: docs/shutter.md).
    nominal_undetermined : why the nominal pose could not be found on the drive (empty: it
        was given or found); every pair then has status "no nominal pose" — without a
        nominal pose the cold start has nothing to rest on, and its estimates would be the
        patches' second minima, not the camera's.
    ipm_resolution_scale : IPM metres per pixel as a multiple of the interest points'
        median ground sampling distance.
    ipm_max_side : largest IPM image side, pixels.
    ipm_poc_level : pyramid level of the refinements' patch correlation: both IPM planes
        halved this many times (``cv2.pyrDown``) and the patches with them
        (``patch_match.match_grouped``). POC's band keeps half the frequencies of a
        full-resolution patch, so level 1 sees the same ones at a quarter of the pixels:
        faster, at a cost in the pitch and the travel measured in docs/speed.md (forward
        cameras) and a steep camera's precision. 0 (default): full resolution.
    vertical_motion : also estimate the camera's vertical motion within the pair (an eighth
        parameter; the paper neglects it, which costs ~0.25° of pitch per millimetre on a
        bouncing 0.7 m cart camera). Frame k's pose then has height ``height + dh``. None
        (default): on for steep cameras (the whole image below the horizon at the nominal
        pose), off for forward-looking ones, where it is poorly separable from pitch.
    pose_prior_deg : standard deviation of a prior on both frames' pitch and roll around the
        rig's nominal pose inside every fit, degrees; it resolves the pitch/translation
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
        forward-looking ones (the far field of a level camera is not modelled by the
        noise model's single magnification term; docs/kitti.md).
    moved_ipm : refinements warp frame k onto frame k-1's IPM plane moved by the current
        motion estimate, so that the patches match with no offset and no rotation (in a
        turn the rotation within a patch biases POC); off: each frame on its own plane with
        the patch windows offset by the predicted displacement (the paper's). None
        (default): on for steep cameras (a turning cart's pose error falls tenfold), off for
        forward-looking ones (more pairs ok in sharp turns, but less accurate travel on
        the pairs ok either way; docs/kitti.md).
    blur_invariant_ipm : refinements correlate the IPM patches' phases modulo π
        (``poc.correlate_spectra``): a body that pitches faster during one frame's exposure
        than during the other's blurs the two differently, which biased a steep camera's
        pitch by degrees with a standard deviation that did not show it. None (default): on
        for steep cameras, off for forward-looking ones (whose far-field IPM patches, stretched
        many times, carry too little above the noise: fewer pairs ok and a worse travel on
        KITTI 07; docs/blur.md).
    max_acceleration_mps2 : the vehicle's largest acceleration [m/s²] (default 10, about
        what tyres on a dry road can give, braking or turning): in a sequence
        (``pair_chain.PairChain``) an ``ok`` pair whose mean velocity differs from the last
        ``ok`` pair's by more than it allows, plus three standard deviations, is marked
        "implausible motion" (inf: off).
    long_baseline_heights : in a tracked sequence, a pair of a level camera (pose prior on,
        global shutter) that travels less than this many camera heights also estimates frame
        k's pose against an earlier frame that far back, and takes that pose
        (``long_baseline``; 0: off). Default 0.3: about 0.5 m for a car.
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
    shutter_rate_covariance: bool = True
    cold_start_ipm: bool = True
    cold_pitch_steps_deg: tuple[float, ...] | None = None
    ipm_resolution_scale: float = 1.0
    ipm_max_side: int = 3000
    ipm_poc_level: int = 0
    vertical_motion: bool | None = None
    pose_prior_deg: float | None = None
    track_prior_deg: float = 0.5
    stage_median: bool | None = None
    weight_patches: bool | None = None
    recentre_windows: bool | None = None
    inlier_median_factor: float | None = None
    moved_ipm: bool | None = None
    blur_invariant_ipm: bool | None = None
    max_acceleration_mps2: float = 10.0
    long_baseline_heights: float = 0.3
    seed: int = 0
    keep_images: bool = False

    def __post_init__(self) -> None:
        wrong_type = [f"{f.name}={getattr(self, f.name)!r} (expected {f.type})"
                      for f in dataclasses.fields(self)
                      if not _of_type(getattr(self, f.name), str(f.type))]
        if wrong_type:
            raise InputError("estimator config: " + ", ".join(wrong_type))
        checks = {
            "grid": len(self.grid) == 2 and min(self.grid) >= 2,
            "patch_image": self.patch_image >= 16,
            "patch_ipm": self.patch_ipm >= 16,
            "min_patch_image": 8 <= self.min_patch_image <= self.patch_image,
            "min_patch_ipm": 8 <= self.min_patch_ipm <= self.patch_ipm,
            "n_subsets": self.n_subsets >= 0,
            "subset_fraction": 0.0 < self.subset_fraction <= 1.0,
            "refine_subsets": self.refine_subsets >= 0,
            "refinements": self.refinements is None or 0 <= self.refinements <= MAX_REFINEMENTS,
            "coarse_scale": self.coarse_scale >= 1,
            "min_inliers": self.min_inliers >= 4,
            "inlier_px_image": self.inlier_px_image > 0,
            "inlier_px_ipm": self.inlier_px_ipm > 0,
            "refine_outlier_px": self.refine_outlier_px > 0,
            "ipm_resolution_scale": self.ipm_resolution_scale > 0,
            "ipm_poc_level": type(self.ipm_poc_level) is int and self.ipm_poc_level in (0, 1),
            "roi_max_range_h": self.roi_max_range_h is None or self.roi_max_range_h > 0,
            "roi_max_lateral_h": self.roi_max_lateral_h > 0,
            "max_deviation_deg": self.max_deviation_deg > 0,
            "max_roll_deg": 0 < self.max_roll_deg <= 90,
            "max_acceleration_mps2": self.max_acceleration_mps2 > 0,
            "long_baseline_heights": 0 <= self.long_baseline_heights < 10,
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


#: the most virtual-IPM refinements a pair may be given (each is a full stage)
MAX_REFINEMENTS = 10

_NUMBER = (int, float, np.integer, np.floating)


def _of_type(value: object, annotation: str) -> bool:
    """Whether ``value`` is of a config field's type (its annotation, as written): a bool
    where one is meant (``vertical_motion='no'`` ran as true), an integer where a count is
    (a 1.5 refinement failed after the first pair), a number where a size is."""
    options = [a.strip() for a in annotation.split("|")]
    kinds = {"bool": (bool, np.bool_), "int": (int, np.integer), "float": _NUMBER}
    if value is None:  # (a type this check does not know may hold None: RoiSpec does)
        return "None" in options or not all(o in kinds or o.startswith("tuple[")
                                            for o in options)
    for option in options:
        if option in kinds:
            if isinstance(value, kinds[option]) and (
                    option == "bool" or not isinstance(value, (bool, np.bool_))):
                return True
        elif option.startswith("tuple[int"):
            if isinstance(value, tuple) and all(
                    isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in value):
                return True
        elif option.startswith("tuple[float"):
            if isinstance(value, tuple) and all(
                    isinstance(v, _NUMBER) and not isinstance(v, bool) for v in value):
                return True
        elif option != "None":  # a type this check does not know: the field's own check
            return True
    return False


def with_camera_defaults(config: EstimatorConfig, level: bool) -> EstimatorConfig:
    """``config`` with the fields left None set to the defaults of a level camera (``level``:
    forward-looking, horizon in view, nominal pitch below ``LEVEL_MAX_PITCH_DEG``) or a steep
    one (every other); see :class:`EstimatorConfig`."""
    by_camera = {
        "roi_max_range_h": LEVEL_ROI_RANGE_H if level else 15.0,
        "vertical_motion": not level,
        "refinements": 2 if level else 1,
        "stage_median": level,
        "pose_prior_deg": 2.0 if level else 0.0,
        "moved_ipm": not level,
        "blur_invariant_ipm": not level,
        "cold_pitch_steps_deg": COLD_PITCH_STEPS_DEG["level" if level else "steep"],
        **REFINEMENT_WEIGHTING["uniform" if level else "noise"],
    }
    return dataclasses.replace(config, **{
        name: value for name, value in by_camera.items() if getattr(config, name) is None
    })


def camera_kind(rig: Rig) -> tuple[bool, bool]:
    """(steep, level) of the rig's camera at its nominal pose. Steep: the whole image sees
    the ground (no horizon in view). Level: a forward-looking camera near the horizontal
    (horizon in view, pitch below ``LEVEL_MAX_PITCH_DEG``), whose pitch trades against the
    travel and whose far-field IPM patches stretch 10-50×. A camera pitched further down
    gets the steep defaults even with the horizon in view (docs/kitti.md)."""
    pose = rig.nominal_pose
    steep = bool(horizon_row(rig.camera.k, pose, rig.camera.cx) < 0)
    return steep, bool(not steep and pose.pitch < np.radians(LEVEL_MAX_PITCH_DEG))


def resolve(config: EstimatorConfig, rig: Rig) -> EstimatorConfig:
    """The configuration that runs for ``rig``: ``config`` with every field it leaves None
    set to the level or steep camera's default at the rig's nominal pose
    (:func:`camera_kind`, :func:`with_camera_defaults`). ``TwoFrameEstimator`` runs exactly
    this."""
    if not isinstance(config, EstimatorConfig) or not isinstance(rig, Rig):
        raise InputError(f"resolve needs an EstimatorConfig and a Rig, got "
                         f"{type(config).__name__} and {type(rig).__name__}")
    return with_camera_defaults(config, camera_kind(rig)[1])
