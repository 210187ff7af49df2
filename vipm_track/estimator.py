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

The stages live beside it: ``image_stage`` (1), ``cold_start`` (its starts without a
guess), ``refinement`` (2), ``stage_context`` (what they share for a pair); the settings in
``estimator_config``, the result types in ``pair_result`` (both re-exported here).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .cold_start import cold_start_ipm, reject_wrong_minimum
from .displacement_model import pack, unpack
from .errors import InputError
from .estimator_config import EstimatorConfig, camera_kind, resolve
from .image_stage import image_stage
from .pair_result import (
    STATUS_DEGENERATE,
    STATUS_FEW_INLIERS,
    STATUS_NO_MOTION,
    STATUS_NO_NOMINAL,
    STATUS_NO_TEXTURE,
    STATUS_NOT_CONVERGED,
    STATUS_OK,
    PairGuess,
    PairResult,
    StageFailure,
    add_timings,
    mark_failed,
)
from .refinement import refine_all
from .rig import Rig
from .roi import interest_points, roi_mask
from .stage_context import StageContext, pose_prior
from .static_content import noise_sigma, static_pixels, static_share

#: the estimator's public names; the settings and result types are defined in
#: ``estimator_config`` and ``pair_result``
__all__ = [
    "STATUS_DEGENERATE",
    "STATUS_FEW_INLIERS",
    "STATUS_NOT_CONVERGED",
    "STATUS_NO_MOTION",
    "STATUS_NO_NOMINAL",
    "STATUS_NO_TEXTURE",
    "STATUS_OK",
    "EstimatorConfig",
    "PairGuess",
    "PairResult",
    "PreparedFrame",
    "PreparedPair",
    "TwoFrameEstimator",
]


@dataclass(frozen=True)
class PreparedFrame:
    """A frame as the stages read it: grey float32, undistorted to the camera matrix
    (``image``), and its sensor noise σ [grey levels] (``static_content.noise_sigma``)."""

    image: NDArray[np.float32]
    noise: float


@dataclass(frozen=True)
class PreparedPair:
    """What a pair needs before its stages run, made from the images alone (so it can be
    made ahead, while the pair before is estimated): both prepared frames and the share of
    content fixed to the camera around each pixel (``static_content.static_share``)."""

    prev: PreparedFrame
    curr: PreparedFrame
    static: NDArray[np.float32]


class TwoFrameEstimator:
    """Pose of two frames against the ground and the planar motion between them.

    Parameters
    ----------
    rig : the camera (distorted frames are undistorted to ``camera.k`` first), its assumed
        height [m] (the scale of the translation, CONVENTIONS.md), its nominal pose (where
        a cold start begins) and its rolling-shutter readout [s].
    config : settings; :class:`EstimatorConfig` defaults when None, run as
        ``resolve(config, rig)``.
    """

    def __init__(self, rig: Rig, config: EstimatorConfig | None = None):
        self.rig = rig
        camera = self.camera = rig.camera
        self.height = float(rig.height_m)
        self.k = camera.k
        self.nominal = rig.nominal_pose
        self.config = resolve(config or EstimatorConfig(), rig)
        margin = np.radians(self.config.horizon_margin_deg)
        self._horizon_margin_px = float(np.tan(margin) * camera.fy)
        self.steep, self.level = camera_kind(rig)
        mask = roi_mask(
            camera, self.config.roi, self.nominal,
            self.config.roi_max_range_h * self.height,
            self.config.roi_max_lateral_h * self.height, margin,
        )
        self.roi = mask
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
        # the last image prepared, as given and prepared (in a sequence a frame is the
        # current one of a pair and the previous one of the next)
        self._last: tuple[NDArray, PreparedFrame] | None = None

    # --- public -----------------------------------------------------------------------------

    def estimate(
        self, prev_img: NDArray, curr_img: NDArray, guess: PairGuess | None = None,
        frame_interval_s: float | None = None, prepared: PreparedPair | None = None,
    ) -> PairResult:
        """Estimate both poses and the motion from frame k-1 (``prev_img``) to k.

        Images are grey or BGR arrays of the camera's size. ``guess`` (tracking mode) seeds
        the optimisation and offsets the patch windows by the displacements it predicts.
        ``frame_interval_s`` [s], the time between the frames, is needed with a rolling
        shutter (``Rig.readout_s``) and unused otherwise; there the ``guess``'s
        motion (the previous pair's, scaled to this interval) also gives the vehicle's
        acceleration. ``prepared``: the pair's :meth:`prepare_pair` of these images, where
        the caller made it ahead (``pipeline.run_sequence`` does, on another thread).
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
        # a rolling shutter without the pair's interval fails before the images are read
        self._shutter_readout_frames(frame_interval_s)
        if prepared is None:
            prepared = self.prepare_images(prev_img, curr_img)
        prev, curr = prepared.prev.image, prepared.curr.image
        context = self.stage_context(prev, curr, guess, frame_interval_s, prepared.static)
        prepared_s = time.perf_counter() - t_start
        result = self._estimate_starts(context, prev, curr, guess, 0.0)
        if guess is None and result.status in (STATUS_FEW_INLIERS, STATUS_NOT_CONVERGED):
            for step in self.config.cold_pitch_steps_deg:
                retry = self._estimate_starts(context, prev, curr, None, np.radians(step))
                reject_wrong_minimum(retry, self.steep, self.config.min_peak, retry=True)
                add_timings(retry, result)
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

    def stage_context(
        self, prev: NDArray[np.float32], curr: NDArray[np.float32],
        guess: PairGuess | None = None, frame_interval_s: float | None = None,
        static: NDArray[np.float32] | None = None,
    ) -> StageContext:
        """What every stage needs for the prepared pair ``prev``, ``curr`` (:meth:`prepare`):
        the camera's set-up, the content fixed to the camera (``static``, the pair's
        :attr:`PreparedPair.static`, where made already), the rolling shutter's and the
        heave's share of a pair ``frame_interval_s`` apart and the pose prior (with the
        ``guess`` of tracking mode); for running one stage alone as :meth:`estimate` would."""
        # the interval before's motion (tracking), for the rolling shutter's acceleration
        previous_motion = None if guess is None else np.array(
            [guess.motion.tx, guess.motion.tz, guess.motion.yaw])
        # content fixed to the camera, once per pair (both cold starts leave it out)
        if static is None:
            static = self._static(prev, curr, (noise_sigma(prev), noise_sigma(curr)))
        prior_mean, prior_sigma = pose_prior(self.config, self.nominal, guess)
        return StageContext(
            camera=self.camera, k=self.k, height=self.height, config=self.config,
            nominal=self.nominal, centres=self.centres, sizes=self.sizes,
            horizon_margin_px=self._horizon_margin_px,
            static=static,
            readout_frames=self._shutter_readout_frames(frame_interval_s),
            heave_std_m=self.config.heave_rate_mps * (
                frame_interval_s if frame_interval_s and frame_interval_s > 0 else 0.1),
            previous_motion=previous_motion, prior_mean=prior_mean, prior_sigma=prior_sigma,
            previous_angular_rate=None if guess is None or guess.angular_rate is None
            else np.array(guess.angular_rate),
            previous_angular_accel_ms=None if guess is None or guess.angular_accel_ms is None
            else np.array(guess.angular_accel_ms),
        )

    def _estimate_starts(
        self, context: StageContext, prev: NDArray[np.float32], curr: NDArray[np.float32],
        guess: PairGuess | None, pitch_step: float,
    ) -> PairResult:
        """:meth:`_estimate` from the ``guess``, or cold from both starts in turn, from the
        nominal pose with its pitch moved by ``pitch_step`` (radians)."""
        if guess is not None or not self.config.cold_start_ipm:
            starts = [False]
        else:
            starts = [False, True] if self.steep else [True, False]
        result = self._estimate(context, prev, curr, guess, starts[0], pitch_step)
        if guess is None:
            reject_wrong_minimum(result, self.steep, self.config.min_peak)
        if len(starts) > 1 and result.status not in (STATUS_OK, STATUS_NO_MOTION):
            second = self._estimate(context, prev, curr, None, starts[1], pitch_step)
            reject_wrong_minimum(second, self.steep, self.config.min_peak)
            names = {True: "from the nominal-pose IPM", False: "on the image plane"}
            add_timings(second, result)
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
        self, context: StageContext, prev: NDArray[np.float32], curr: NDArray[np.float32],
        guess: PairGuess | None, ipm_start: bool, pitch_step: float = 0.0,
    ) -> PairResult:
        """:meth:`estimate` on the prepared images (:meth:`prepare`) with the cold start chosen
        by ``ipm_start``, from the nominal pose with its pitch moved by ``pitch_step``
        (radians)."""
        t_start = time.perf_counter()
        timings = {"poc": 0.0, "warp": 0.0, "lm": 0.0}
        result = PairResult(status=STATUS_OK, timings=timings, height=self.height)
        rng = np.random.default_rng(self.config.seed)
        try:
            refinements = self.config.refinements
            loose = False
            start, source = None, "guess"
            if guess is not None:
                start = context.guess_vector(guess)
            elif ipm_start:
                start, source = (cold_start_ipm(context, prev, curr, pitch_step, result),
                                 "nominal-pose IPM")
            try:
                x = image_stage(context, prev, curr, start, rng, result, pitch_step)
            except StageFailure as failure:
                if start is None or failure.status == STATUS_NO_MOTION:
                    raise
                # The start is better than a failed image-plane stage (fast forward motion
                # distorts image patches most); the virtual IPM removes that distortion,
                # given a wider outlier gate and one more pass.
                x = start
                result.reason = f"image stage skipped ({failure.reason}); refined from the {source}"
                refinements, loose = max(refinements, 1) + 1, True
            try:
                x = refine_all(context, prev, curr, x, refinements, loose, rng, result)
            except StageFailure as failure:
                if start is None or loose:
                    raise
                # An image stage that passed its own checks but misleads the refinement
                # (a wrong minimum on the distorted image patches): refine from the start.
                result.reason = (f"refinement from the image stage failed ({failure.reason}); "
                                 f"refined from the {source}")
                x = refine_all(context, prev, curr, start, max(refinements, 1) + 1, True, rng,
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
        except StageFailure as failure:
            mark_failed(result, failure.status, failure.reason)
        timings["total"] = time.perf_counter() - t_start
        return result

    # --- helpers ----------------------------------------------------------------------------

    def _shutter_readout_frames(self, frame_interval_s: float | None) -> float:
        """The rolling shutter's readout in frame intervals of a pair ``frame_interval_s``
        seconds apart (``bundle.DisplacementModel``); 0 for a global shutter."""
        readout = self.rig.readout_s
        if not readout:
            return 0.0
        if frame_interval_s is None or not (np.isfinite(frame_interval_s)
                                            and frame_interval_s > 0):
            raise ValueError(f"a rolling-shutter readout of {readout} s needs the pair's frame "
                             f"interval, got {frame_interval_s}")
        return readout / frame_interval_s

    def prepare_frame(self, image: NDArray, name: str) -> PreparedFrame:
        """The :class:`PreparedFrame` of a grey or BGR image of the camera's size (``name``
        says which in an error); touches no state, so another thread may run it."""
        prepared = self._prepared_image(image, name)
        return PreparedFrame(prepared, noise_sigma(prepared))

    def prepare_pair(self, prev: PreparedFrame, curr: PreparedFrame) -> PreparedPair:
        """The :class:`PreparedPair` of two prepared frames; touches no state."""
        return PreparedPair(prev, curr, self._static(prev.image, curr.image,
                                                     (prev.noise, curr.noise)))

    def prepare_images(self, prev_img: NDArray, curr_img: NDArray) -> PreparedPair:
        """:meth:`prepare_pair` of two grey or BGR images of the camera's size; the last
        frame prepared is reused where it is ``prev_img`` (tracking: the pair before's
        current frame)."""
        return self.prepare_pair(self._frame(prev_img, "previous frame"),
                                 self._frame(curr_img, "current frame"))

    def prepare(self, image: NDArray, name: str) -> NDArray[np.float32]:
        """Grey float32 undistorted image; the last one is cached (tracking reuses it)."""
        return self._frame(image, name).image

    def _frame(self, image: NDArray, name: str) -> PreparedFrame:
        """:meth:`prepare_frame`, the last one cached."""
        if self._last is None or self._last[0] is not image:
            self._last = (image, self.prepare_frame(image, name))
        return self._last[1]

    def _static(self, prev: NDArray[np.float32], curr: NDArray[np.float32],
                noise: tuple[float, float]) -> NDArray[np.float32]:
        """The share of content fixed to the camera around each pixel of a prepared pair
        whose frames' noise σ are ``noise``."""
        return static_share(static_pixels(prev, curr, noise), self.config.patch_image // 2)

    def _prepared_image(self, image: NDArray, name: str) -> NDArray[np.float32]:
        """Grey float32 undistorted copy of ``image`` (``InputError`` naming ``name``)."""
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
        return out

