"""What every stage of the two-frame estimator needs for one pair (:class:`StageContext`: the
camera's set-up and the pair's own state), and the fit and checks that end each stage."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from .bundle import (
    FitResult,
    at_least,
    covariance_from_jacobian,
    heave_covariance,
    robust_fit,
    shutter_rate_covariance,
)
from .camera import CameraModel
from .displacement_model import DisplacementModel, pack, unpack
from .estimator_config import EstimatorConfig
from .geometry import GroundPose
from .pair_result import (
    STATUS_DEGENERATE,
    STATUS_FEW_INLIERS,
    STATUS_NOT_CONVERGED,
    PairGuess,
    PairResult,
    StageEstimate,
    StageFailure,
)

FloatArray = NDArray[np.float64]

#: Weight of a pair's own rate change in the running mean square of
#: :meth:`StageContext.angular_accel_ms` (about the last 3 pairs count).
ANGULAR_ACCEL_WEIGHT = 0.3


def pose_change(x: FloatArray) -> FloatArray:
    """(pitch, roll) of frame k less frame k-1's in a parameter vector [rad]."""
    return np.asarray(x[2:4] - x[0:2], dtype=float)


def pose_prior(
    config: EstimatorConfig, nominal: GroundPose, guess: PairGuess | None,
) -> tuple[FloatArray | None, FloatArray]:
    """Mean and standard deviation (4,) of the prior on (pitch_prev, roll_prev, pitch,
    roll), radians: the ``nominal`` pose with ``pose_prior_deg``, frame k-1's fused with the
    guess's pose of it at ``track_prior_deg`` (None mean: no prior)."""
    sigma = np.radians(config.pose_prior_deg or 0.0)
    if sigma <= 0:
        return None, np.zeros(4)
    p, r = nominal.pitch, nominal.roll
    mean, std = np.array([p, r, p, r]), np.full(4, sigma)
    s_t = np.radians(config.track_prior_deg)
    if guess is not None and s_t > 0:
        w_n, w_t = 1.0 / sigma**2, 1.0 / s_t**2
        tracked = np.array([guess.pose_prev.pitch, guess.pose_prev.roll])
        mean[:2] = (w_n * mean[:2] + w_t * tracked) / (w_n + w_t)
        std[:2] = 1.0 / np.sqrt(w_n + w_t)
    return mean, std


@dataclass(frozen=True, eq=False)
class StageContext:
    """The camera's set-up and one pair's state, as every stage of the pair reads them.

    Attributes
    ----------
    camera : intrinsics; ``k`` (3, 3) its undistorted camera matrix.
    height : assumed camera height of frame k-1 [m].
    config : settings, per-camera defaults resolved (``estimator_config.with_camera_defaults``).
    nominal : the nominal (cold-start) pose.
    centres : interest points (N, 2), image pixels; ``sizes`` (N,) their patch sides, pixels.
    horizon_margin_px : rays kept this many pixels below the horizon.
    static : share (height, width) of content fixed to the camera around each pixel, of this
        pair (``static_content.static_share``).
    readout_frames : rolling-shutter readout in frame intervals of this pair (0: global).
    heave_std_m : vertical motion this pair may hide [m] (``bundle.heave_covariance``).
    previous_motion : (tx, tz, yaw) of the interval before (tracking), for the rolling
        shutter's acceleration; None cold.
    previous_angular_rate : (pitch, roll) change over the interval before (tracking), rad
        per this pair's interval, for the rolling shutter's angular acceleration; None cold.
    previous_angular_accel_ms : the running mean square of that rate's change up to the pair
        before (``PairResult.angular_accel_ms``); None where not yet known.
    prior_mean, prior_sigma : the pose prior (4,) of every fit, radians (:func:`pose_prior`).
    """

    camera: CameraModel
    k: FloatArray
    height: float
    config: EstimatorConfig
    nominal: GroundPose
    centres: FloatArray
    sizes: NDArray[np.int64]
    horizon_margin_px: float
    static: NDArray[np.float32]
    readout_frames: float = 0.0
    heave_std_m: float = 0.0
    previous_motion: FloatArray | None = None
    previous_angular_rate: FloatArray | None = None
    previous_angular_accel_ms: FloatArray | None = None
    prior_mean: FloatArray | None = None
    prior_sigma: FloatArray = field(default_factory=lambda: np.zeros(4))

    def model_args(self, inlier_px: float) -> dict:
        """Arguments of a residual model for the pair: the pose prior (:meth:`prior`) and the
        rolling shutter's row timing."""
        return {**self.prior(inlier_px), **self.shutter()}

    def shutter(self) -> dict:
        """Rolling-shutter arguments of a residual model for the pair."""
        return {"readout_frames": self.readout_frames, "image_rows": self.camera.height,
                "previous_motion": self.previous_motion}

    def prior(self, inlier_px: float) -> dict:
        """Pose-prior arguments of a residual model whose inlier threshold is ``inlier_px``
        plane pixels (taken as 3 σ of a point's noise); see :func:`pose_prior`."""
        if self.prior_mean is None:
            return {}
        return {"prior_mean": self.prior_mean, "prior_scale": inlier_px / 3.0 / self.prior_sigma}

    def untracked_prior(self, model: DisplacementModel) -> DisplacementModel | None:
        """``model`` with its pose prior at the nominal pose's weight alone, where the prior
        also holds the previous pair's estimate (tracking); None otherwise."""
        if self.prior_mean is None or model.n_prior == 0:
            return None
        nominal = np.radians(self.config.pose_prior_deg or 0.0)
        if np.allclose(self.prior_sigma, nominal):
            return None
        return replace(model, prior_scale=np.asarray(model.prior_scale)
                       * self.prior_sigma / nominal)

    def guess_vector(self, guess: PairGuess) -> FloatArray:
        """Parameter vector of a guess at the assumed height (no vertical motion)."""
        x0 = pack(
            GroundPose(guess.pose_prev.pitch, guess.pose_prev.roll, self.height),
            GroundPose(guess.pose_curr.pitch, guess.pose_curr.roll, self.height),
            guess.motion,
        )
        return np.append(x0, 0.0) if self.config.vertical_motion else x0

    def predicted_displacements(self, x: FloatArray) -> FloatArray:
        """Image displacements (N, 2) the parameters predict at the interest points (0 where
        undefined)."""
        model = DisplacementModel(self.k, self.height, self.centres, self.centres,
                                  **self.shutter())
        d = model.predict(x) - self.centres
        return np.where(np.isfinite(d), d, 0.0)

    def fit(
        self, model: DisplacementModel, x0: FloatArray, usable: NDArray[np.bool_],
        n_subsets: int, inlier_px: float, rng: np.random.Generator, result: PairResult,
        median_factor: float = 0.0,
    ) -> FitResult:
        """Robust fit of ``model`` from ``x0`` on the ``usable`` patches (``bundle.robust_fit``),
        its covariance widened for tracking and heave; its time added to ``result``."""
        t0 = time.perf_counter()
        if usable.sum() < max(4, self.config.min_inliers):
            raise StageFailure(
                STATUS_FEW_INLIERS,
                f"{int(usable.sum())} usable patches (need {self.config.min_inliers})",
            )
        fit = robust_fit(model, x0, usable, n_subsets, self.config.subset_fraction, inlier_px,
                         rng, median_factor, self.config.jackknife_covariance)
        if not np.all(np.isfinite(fit.covariance)):
            return fit
        inliers = np.flatnonzero(fit.inliers)
        untracked = self.untracked_prior(model)
        if untracked is not None and inliers.size >= len(fit.x):
            # the previous pair's estimate of frame k-1 shares this pair's errors (the same
            # image, the same road): it steadies the fit, but counted as independent evidence
            # in the covariance it makes every tracked pair look surer than it is
            fit = replace(fit, covariance=at_least(fit.covariance, covariance_from_jacobian(
                untracked.jacobian(fit.x, inliers), untracked.residuals(fit.x, inliers))))
        if not self.config.vertical_motion:
            fit = replace(fit, covariance=fit.covariance + heave_covariance(
                model, fit.x, inliers, self.heave_std_m))
        if self.readout_frames and self.config.shutter_rate_covariance:
            fit = replace(fit, covariance=fit.covariance + shutter_rate_covariance(
                model, fit.x, inliers, self.shutter_rate_std(fit.x)))
        result.timings["lm"] += time.perf_counter() - t0
        return fit

    def angular_accel_ms(self, x: FloatArray) -> FloatArray | None:
        """The running mean square of the (pitch, roll) rate's change from pair to pair, this
        pair's (``x``'s) included [rad² per interval²]; None cold."""
        if self.previous_angular_rate is None:
            return None
        change = pose_change(x) - self.previous_angular_rate
        if self.previous_angular_accel_ms is None:
            return change**2
        return ((1 - ANGULAR_ACCEL_WEIGHT) * self.previous_angular_accel_ms
                + ANGULAR_ACCEL_WEIGHT * change**2)

    def shutter_rate_std(self, x: FloatArray) -> FloatArray:
        """How far frame k's (pitch, roll) rate during its readout may differ from the pair's
        (``x``'s change), rad per frame interval: the RMS of the rate's change from pair to
        pair (tracking; a single change swings with the shaking's phase), or the pair's own
        rate (cold)."""
        ms = self.angular_accel_ms(x)
        return np.abs(pose_change(x)) if ms is None else np.sqrt(ms)

    def accept(self, fit: FitResult, result: PairResult, stage: str) -> None:
        """Check a stage's fit and make it the result's current estimate."""
        cfg = self.config
        n_in = int(fit.inliers.sum())
        if n_in < cfg.min_inliers:
            raise StageFailure(
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
            raise StageFailure(
                STATUS_NOT_CONVERGED,
                f"{stage}: LM "
                f"{'did not converge' if not fit.converged else 'left the plausible range'}"
                f" (pitch {np.degrees(pose_c.pitch):.1f}°, roll {np.degrees(pose_c.roll):.1f}°)",
            )
        cov = fit.covariance
        if not np.all(np.isfinite(cov)) or np.any(np.linalg.eigvalsh(cov) <= 0):
            raise StageFailure(
                STATUS_DEGENERATE, f"{stage}: the parameters are not all observable "
                "(singular normal equations)"
            )
        result.pose_prev, result.pose_curr, result.motion = pose_p, pose_c, motion
        result.covariance = cov[:7, :7]
        result.height_change = float(fit.x[7]) if len(fit.x) > 7 else 0.0
        accel_ms = self.angular_accel_ms(fit.x) if self.readout_frames else None
        result.angular_accel_ms = None if accel_ms is None else (float(accel_ms[0]),
                                                                 float(accel_ms[1]))
        result.n_inliers = n_in
        result.residual_px = fit.rms
        result.stage_estimates.append(StageEstimate(pose_p, pose_c, motion))
