"""Geometric bundle adjustment of a frame pair: residual models and their robust LM fit.

The seven parameters are ordered as :data:`vipm_track.measurement.PARAMETER_NAMES`:
``(pitch_prev, roll_prev, pitch, roll, tx, tz, yaw)`` in radians and metres, the height
being fixed to the assumed one within the pair (CONVENTIONS.md, Scale).

One residual model serves both planes of the paper (section III):

- image plane (eq. 1): a ground point seen at ``m_p`` in frame k-1 is predicted at
  ``m_c = π(T(Ψ) π⁻¹(m_p; Θ_p); Θ_c)`` and compared with ``m_p + d`` (``d`` from POC);
- virtual IPM plane (eqs. 3-5): the same prediction mapped onto the current frame's
  virtual IPM image by the *fixed* estimate Θ̂_c, compared with ``q_p + d̂`` in IPM pixels,
  where ``m_p = π(q_p; Θ̂_p)`` is the image pixel of the previous IPM patch centre.

So a model is the prediction followed by a fixed homography ``plane_from_image`` (the
identity on the image plane, ``ipm_from_image_homography(k, Θ̂_c, grid)`` on the IPM).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from .geometry import (
    GroundPose,
    PlanarMotion,
    apply_homography,
    back_project,
    project,
    transform_ground,
)

FloatArray = NDArray[np.float64]
N_PARAMS = 7
#: Residual (plane pixels) given to a point that the candidate parameters put behind a
#: camera or above the horizon: large, finite, so LM steps away from such candidates.
INVALID_RESIDUAL = 1e3


def unpack(x: FloatArray, height: float) -> tuple[GroundPose, GroundPose, PlanarMotion]:
    """(pose_prev, pose_curr, motion) of a parameter 7-vector at the given height [m]."""
    return (
        GroundPose(float(x[0]), float(x[1]), height),
        GroundPose(float(x[2]), float(x[3]), height),
        PlanarMotion(float(x[4]), float(x[5]), float(x[6])),
    )


def pack(pose_prev: GroundPose, pose_curr: GroundPose, motion: PlanarMotion) -> FloatArray:
    """Parameter 7-vector (radians, metres) of two poses and the motion between them."""
    return np.array(
        [pose_prev.pitch, pose_prev.roll, pose_curr.pitch, pose_curr.roll,
         motion.tx, motion.tz, motion.yaw],
        dtype=float,
    )


@dataclass(frozen=True)
class DisplacementModel:
    """Where ground seen at ``pixels_prev`` in frame k-1 lands on frame k's measurement plane.

    Attributes
    ----------
    k : (3, 3) intrinsic matrix, pixels.
    height : assumed camera height [m], shared by both frames.
    pixels_prev : (N, 2) image pixels of frame k-1 (patch centres).
    targets : (N, 2) measured positions on frame k's plane (``centre + displacement``), in
        that plane's pixels.
    plane_from_image : (3, 3) fixed map from frame-k image pixels to the measurement plane,
        or None for the image plane itself.
    """

    k: FloatArray
    height: float
    pixels_prev: FloatArray
    targets: FloatArray
    plane_from_image: FloatArray | None = None

    @property
    def n_points(self) -> int:
        return int(self.pixels_prev.shape[0])

    def predict(self, x: FloatArray, idx: NDArray[np.intp] | None = None) -> FloatArray:
        """Predicted positions (n, 2) on the measurement plane; NaN where undefined."""
        pix = self.pixels_prev if idx is None else self.pixels_prev[idx]
        pose_prev, pose_curr, motion = unpack(x, self.height)
        ground = back_project(self.k, pose_prev, pix)
        m_c = project(self.k, pose_curr, transform_ground(motion, ground))
        if self.plane_from_image is not None:
            m_c = apply_homography(self.plane_from_image, m_c)
        return m_c

    def residuals(self, x: FloatArray, idx: NDArray[np.intp] | None = None) -> FloatArray:
        """Flattened residuals (2n,) predicted − measured, plane pixels (LM's objective)."""
        tgt = self.targets if idx is None else self.targets[idx]
        r = (self.predict(x, idx) - tgt).ravel()
        return np.where(np.isfinite(r), r, INVALID_RESIDUAL)

    def errors(self, x: FloatArray) -> FloatArray:
        """Per-point residual norms (N,), plane pixels (inf where undefined)."""
        e = np.linalg.norm(self.predict(x) - self.targets, axis=1)
        return np.where(np.isfinite(e), e, np.inf)


@dataclass(frozen=True)
class FitResult:
    """A robust fit: parameters, inlier flags over all points, covariance, quality."""

    x: FloatArray
    inliers: NDArray[np.bool_]
    errors: FloatArray
    covariance: FloatArray
    rms: float
    converged: bool
    n_evaluations: int


def fit_lm(
    model: DisplacementModel, x0: FloatArray, idx: NDArray[np.intp], max_nfev: int = 400
) -> tuple[FloatArray, bool, FloatArray, FloatArray, int]:
    """Levenberg-Marquardt on the points ``idx`` from ``x0``.

    Returns (x, success, jacobian (2n, 7), residuals (2n,), function evaluations)."""
    res = least_squares(
        model.residuals,
        np.asarray(x0, dtype=float),
        args=(idx,),
        method="lm",
        x_scale="jac",
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=max_nfev,
    )
    return res.x, bool(res.status > 0), res.jac, res.fun, int(res.nfev)


def covariance_from_jacobian(jac: FloatArray, residuals: FloatArray) -> FloatArray:
    """(JᵀJ)⁻¹ σ² with σ² the dof-corrected residual variance; NaN if rank-deficient."""
    m, n = jac.shape
    dof = max(m - n, 1)
    sigma2 = float(residuals @ residuals) / dof
    jtj = jac.T @ jac
    try:
        if np.linalg.cond(jtj) > 1e14:
            raise np.linalg.LinAlgError("ill-conditioned")
        return np.linalg.inv(jtj) * sigma2
    except np.linalg.LinAlgError:
        return np.full((n, n), np.nan)


def robust_fit(
    model: DisplacementModel,
    x0: FloatArray,
    usable: NDArray[np.bool_],
    n_subsets: int,
    fraction: float,
    inlier_px: float,
    rng: np.random.Generator,
) -> FitResult:
    """Best of random-subset LM fits, scored on all usable points, re-fitted on its inliers.

    Parameters
    ----------
    model : the residual model over all N points.
    x0 : start of the optimisation (cold-start value or a guess), parameter order above.
    usable : (N,) points that survived the pre-rejection (peak, magnitude).
    n_subsets, fraction : number of random subsets and the fraction of usable points each
        holds (the paper: 50 and 0.6); ``n_subsets = 0`` fits all usable points once.
    inlier_px : a point is an inlier when its residual norm is below this, plane pixels;
        subsets are scored by the truncated squared residual ``Σ min(e², inlier_px²)``.
    rng : seeded generator choosing the subsets.
    """
    use_idx = np.flatnonzero(usable)
    nfev = 0
    x_all, ok_all, _, _, n = fit_lm(model, x0, use_idx)
    nfev += n
    candidates = [x_all]
    m = max(4, round(fraction * use_idx.size))
    if n_subsets > 0 and m < use_idx.size:
        for _ in range(n_subsets):
            idx = np.sort(rng.choice(use_idx, size=m, replace=False))
            x_s, _, _, _, n = fit_lm(model, x_all, idx, max_nfev=100)
            nfev += n
            candidates.append(x_s)
    c2 = inlier_px**2
    scores = []
    for x in candidates:
        e = model.errors(x)[use_idx]
        scores.append(float(np.sum(np.minimum(e**2, c2))))
    best = candidates[int(np.argmin(scores))]

    # Re-fit on the best candidate's inliers until the inlier set settles (twice at most).
    x = best
    converged = ok_all
    inl = usable & (model.errors(x) < inlier_px)
    jac = np.zeros((0, N_PARAMS))
    res = np.zeros(0)
    for _ in range(3):
        idx = np.flatnonzero(inl)
        if idx.size < 4:
            break
        x, converged, jac, res, n = fit_lm(model, x, idx)
        nfev += n
        new_inl = usable & (model.errors(x) < inlier_px)
        if np.array_equal(new_inl, inl):
            break
        inl = new_inl
    errors = model.errors(x)
    inl = usable & (errors < inlier_px)
    if jac.shape[0] >= 2 * N_PARAMS:
        cov = covariance_from_jacobian(jac, res)
        rms = float(np.sqrt(np.mean(res**2) * 2)) if res.size else float("nan")
    else:
        cov = np.full((N_PARAMS, N_PARAMS), np.nan)
        rms = float("nan")
    return FitResult(x, inl, errors, cov, rms, converged, nfev)
