"""The residual model of a pair: where the patches of frame k-1 should land in frame k (on
the image or a virtual IPM plane) for both frames' poses against the ground and the planar
motion between them — the pair homography of ``geometry`` evaluated for a batch of
parameter vectors, with rolling shutter, per-patch noise whitening and a pose prior
(``DisplacementModel``); its parameter vector (``pack``/``unpack``); central differences
for its Jacobian. ``bundle`` fits it."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from .geometry import GroundPose, PlanarMotion
from .homography_lsq import (
    FD_STEP,
    homography_normal_equations,
    pair_homography_factors,
    pair_lm,
    project_points,
)
from .shutter import moved_pixels

FloatArray = NDArray[np.float64]

N_PARAMS = 7
#: Residual (plane pixels) given to a point that the candidate parameters put behind a
#: camera or above the horizon: large, finite, so LM steps away from such candidates.
INVALID_RESIDUAL = 1e3


def unpack(x: FloatArray, height: float) -> tuple[GroundPose, GroundPose, PlanarMotion]:
    """(pose_prev, pose_curr, motion) of a parameter 7- or 8-vector at the assumed height
    [m] (frame k at ``height + x[7]`` for an 8-vector)."""
    h_c = height + (float(x[7]) if len(x) > N_PARAMS else 0.0)
    return (
        GroundPose(float(x[0]), float(x[1]), height),
        GroundPose(float(x[2]), float(x[3]), h_c),
        PlanarMotion(float(x[4]), float(x[5]), float(x[6])),
    )


def pack(pose_prev: GroundPose, pose_curr: GroundPose, motion: PlanarMotion) -> FloatArray:
    """Parameter 7-vector (radians, metres) of two poses and the motion between them (the
    heights are not part of it)."""
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
    prior_mean : (4,) optional prior on (pitch_prev, roll_prev, pitch, roll), radians: the
        fit then also minimises ``prior_scale · (pose − prior_mean)``, four extra residuals
        in plane pixels appended after the points' (a Gaussian prior of standard deviation
        ``noise_px / prior_scale`` for a point noise of ``noise_px``).
    prior_scale : weight of the prior, plane pixels per radian, a scalar or one per pose
        angle (4,) (0: no prior).
    point_whitening : (N, 2, 2) optional per-point matrices W applied to each residual
        (``W · (predicted − measured)``): the inverse square root of the point's noise
        covariance relative to a typical point's, so that a weighted least-squares fit and
        its inlier thresholds stay in typical plane pixels (``ipm.patch_noise_whitening``).
    readout_frames, image_rows : rolling shutter: the time from the exposure of the first
        row to the last, in frame intervals (0: global shutter), and the image's rows.
    previous_motion : (3,) optional (tx, tz, yaw) over the frame interval before the pair,
        scaled to this pair's interval (the previous pair's estimate): with a rolling shutter
        the vehicle's acceleration then enters each point's travel (module doc); None:
        constant velocity.

    The prediction is the pair homography ``A · π(Θ_c) · T(Ψ) · π⁻¹(Θ_p)`` of geometry.py
    (exact for ground points), evaluated for a batch of parameter vectors at once so that
    the finite-difference Jacobian costs one vectorised call.
    """

    k: FloatArray
    height: float
    pixels_prev: FloatArray
    targets: FloatArray
    plane_from_image: FloatArray | None = None
    prior_mean: FloatArray | None = None
    prior_scale: float | FloatArray = 0.0
    point_whitening: FloatArray | None = None
    readout_frames: float = 0.0
    image_rows: int = 0
    previous_motion: FloatArray | None = None

    def _whiten(self, r: FloatArray, idx: NDArray[np.intp] | None = None) -> FloatArray:
        """Per-point residual vectors (..., n, 2) times their whitening matrices."""
        if self.point_whitening is None:
            return r
        w = self.point_whitening if idx is None else self.point_whitening[idx]
        return np.einsum("nij,...nj->...ni", w, r)

    @property
    def n_points(self) -> int:
        return int(self.pixels_prev.shape[0])

    @cached_property  # asked at every residual evaluation
    def n_prior(self) -> int:
        """Number of prior residuals appended to the points' (0 or 4)."""
        return 0 if self.prior_mean is None or np.all(np.asarray(self.prior_scale) <= 0) else 4

    def prior_batch(self, xs: FloatArray) -> FloatArray:
        """Prior residuals (B, n_prior) for parameter vectors (B, n), plane pixels."""
        xs = np.asarray(xs, dtype=float)
        if not self.n_prior:
            return np.zeros((len(xs), 0))
        return np.asarray(self.prior_scale) * (self.full(xs)[:, :4] - np.asarray(self.prior_mean))

    def prior_jacobian_batch(self, xs: FloatArray) -> FloatArray:
        """Jacobians (B, n_prior, n) of :meth:`prior_batch` (central differences)."""
        xs = np.asarray(xs, dtype=float)
        b, n = xs.shape
        if not self.n_prior:
            return np.zeros((b, 0, n))
        return central_difference(self.prior_batch(central_points(xs)), b).transpose(0, 2, 1)

    def full(self, xs: FloatArray) -> FloatArray:
        """The 7- (or 8-) parameter vectors (..., 7|8) of this model's parameters."""
        xs = np.asarray(xs, dtype=float)
        return xs[..., self.full_index(xs.shape[-1])]

    def full_index(self, n: int) -> NDArray[np.intp]:
        """For each of the full vector's parameters, which of this model's ``n`` it is."""
        return np.arange(n)

    def lm(self, x0: FloatArray, weights: FloatArray, max_iterations: int, tolerance: float,
           x_tolerance: float = 0.0) -> tuple[FloatArray, NDArray[np.bool_], int]:
        """Levenberg–Marquardt from ``x0`` (S, n) for each row of point weights (S, N),
        compiled (``homography_lsq.pair_lm``, tolerances as there): solutions, whether each
        converged, evaluations. Global shutter only (the rolling shutter's prediction is
        solved point by point)."""
        if self.readout_frames:
            raise ValueError("the compiled LM models a global shutter only")
        x0 = np.ascontiguousarray(x0, dtype=float)
        prior = self.n_prior > 0
        return pair_lm(
            x0, np.ascontiguousarray(weights, dtype=float), np.ascontiguousarray(self.k, float),
            float(self.height),
            np.eye(3) if self.plane_from_image is None else np.ascontiguousarray(
                self.plane_from_image, dtype=float),
            np.ascontiguousarray(self.pixels_prev, dtype=float),
            np.ascontiguousarray(self.targets, dtype=float),
            np.zeros((0, 2, 2)) if self.point_whitening is None else np.ascontiguousarray(
                self.point_whitening, dtype=float),
            self.full_index(x0.shape[1]),
            np.asarray(self.prior_mean, dtype=float) if prior else np.zeros(0),
            np.broadcast_to(np.asarray(self.prior_scale, dtype=float), (4,)).copy() if prior
            else np.zeros(0),
            INVALID_RESIDUAL, int(max_iterations), float(tolerance), float(x_tolerance))

    def predict_batch(self, xs: FloatArray, idx: NDArray[np.intp] | None = None) -> FloatArray:
        """Predicted positions (B, n, 2) for parameter vectors ``xs`` (B, 7); NaN where a
        point is above the horizon of Θ_p or behind the camera of Θ_c."""
        return self._predict(xs, idx)[0]

    def _predict(
        self, xs: FloatArray, idx: NDArray[np.intp] | None = None,
        start: FloatArray | None = None, active: NDArray[np.bool_] | None = None,
    ) -> tuple[FloatArray, FloatArray | None]:
        """:meth:`predict_batch`, and under a rolling shutter the row times (B, n) of frame k
        the points were solved at (None under a global shutter); ``start`` and ``active``
        as ``shutter.moved_pixels`` (rolling shutter only)."""
        pix = np.ascontiguousarray(self.pixels_prev if idx is None else self.pixels_prev[idx],
                                   dtype=float)
        if not self.readout_frames:
            return project_points(*self._homographies(xs), pix), None
        # rolling shutter: NaN off the ground of frame k-1 (at the row's time)
        img, times = self._rolling_shutter(self.full(xs), pix, start, active)
        a = np.eye(3) if self.plane_from_image is None else self.plane_from_image
        plane = img @ a.T
        with np.errstate(divide="ignore", invalid="ignore"):
            out = plane[..., :2] / plane[..., 2:3]
        out[~(img[..., 2] > 0)] = np.nan  # and in front of camera k
        return out, times

    def _rolling_shutter(
        self, xs: FloatArray, pixels_prev: FloatArray, start: FloatArray | None = None,
        active: NDArray[np.bool_] | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Homogeneous frame-k pixels (B, n, 3) of the ground seen at ``pixels_prev`` in frame
        k-1, each row exposed at its own time, and their row times (B, n) (module doc;
        ``shutter.moved_pixels``)."""
        params = np.zeros((len(xs), max(N_PARAMS + 1, xs.shape[1])))
        params[:, :xs.shape[1]] = xs
        motion = xs[:, 4:7]
        change = (np.zeros_like(motion) if self.previous_motion is None
                  else motion - np.asarray(self.previous_motion, dtype=float))
        shape = (len(xs), len(pixels_prev))
        return moved_pixels(np.asarray(self.k, dtype=float), params, float(self.height),
                            np.ascontiguousarray(pixels_prev, dtype=float),
                            np.ascontiguousarray(change), self.readout_frames / self.image_rows,
                            float(self.readout_frames),
                            np.full(shape, np.nan) if start is None
                            else np.ascontiguousarray(start, dtype=float),
                            np.ones(shape, bool) if active is None
                            else np.ascontiguousarray(active, dtype=bool))

    def _perturbed_predictions(
        self, xs: FloatArray, idx: NDArray[np.intp] | None = None,
        active: NDArray[np.bool_] | None = None,
    ) -> tuple[FloatArray | None, FloatArray]:
        """Predictions at ``xs`` (B, n) — under a rolling shutter only, else None — and at
        their :func:`central_points` (B·2n, m, 2). A rolling shutter's points are solved at
        ``xs`` first (``active`` ones only) and the perturbed solves start from those row
        times: a step of 1e-6 moves them by little, so few secant steps remain."""
        if not self.readout_frames:
            return None, self.predict_batch(central_points(xs), idx)
        base, times = self._predict(xs, idx, active=active)
        twice = 2 * np.shape(xs)[1]
        repeat = None if active is None else np.repeat(active, twice, axis=0)
        return base, self._predict(central_points(xs), idx, np.repeat(times, twice, axis=0),
                                   repeat)[0]

    def predict(self, x: FloatArray, idx: NDArray[np.intp] | None = None) -> FloatArray:
        """Predicted positions (n, 2) on the measurement plane; NaN where undefined."""
        return self.predict_batch(np.asarray(x, dtype=float)[None], idx)[0]

    def residuals(self, x: FloatArray, idx: NDArray[np.intp] | None = None) -> FloatArray:
        """Flattened residuals (2n + n_prior,) predicted − measured, plane pixels (LM's
        objective), the prior's last."""
        tgt = self.targets if idx is None else self.targets[idx]
        r = self._whiten(self.predict(x, idx) - tgt, idx).ravel()
        r = np.where(np.isfinite(r), r, INVALID_RESIDUAL)
        return np.concatenate([r, self.prior_batch(np.asarray(x, dtype=float)[None])[0]])

    def jacobian(self, x: FloatArray, idx: NDArray[np.intp] | None = None) -> FloatArray:
        """Jacobian (2n, 7) of :meth:`residuals` by central differences (one batched call)."""
        n = len(x)
        pert = self._perturbed_predictions(np.asarray(x, dtype=float)[None], idx)[1]
        d = central_difference(self._whiten(pert, idx), 1)[0]
        jac = d.reshape(n, -1).T  # d: (n_params, n_points, 2)
        jac = np.where(np.isfinite(jac), jac, 0.0)
        return np.concatenate([jac, self.prior_jacobian_batch(np.asarray(x, float)[None])[0]])

    def residuals_batch(self, xs: FloatArray) -> FloatArray:
        """Residuals (B, N, 2) over all points for parameter vectors (B, 7), invalid points
        given :data:`INVALID_RESIDUAL`."""
        return self._residuals_of(self.predict_batch(xs))

    def _residuals_of(self, predicted: FloatArray) -> FloatArray:
        """Whitened residuals (B, N, 2) of predictions (B, N, 2) over all points, invalid
        points given :data:`INVALID_RESIDUAL`."""
        r = self._whiten(predicted - self.targets[None])
        return np.where(np.isfinite(r), r, INVALID_RESIDUAL)

    def jacobian_batch(self, xs: FloatArray) -> FloatArray:
        """Jacobians (B, N, 2, 7) of the residuals for parameter vectors (B, 7)."""
        return self._jacobian_of(self._perturbed_predictions(xs)[1], len(xs))

    def _jacobian_of(self, perturbed: FloatArray, b: int) -> FloatArray:
        """Jacobians (B, N, 2, n) from the predictions at the central points of B vectors."""
        d = central_difference(self._whiten(perturbed), b)  # (B, n, N, 2)
        return np.where(np.isfinite(d), d, 0.0).transpose(0, 2, 3, 1)

    def normal_equations(
        self, xs: FloatArray, weights: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Levenberg–Marquardt's terms for parameter vectors ``xs`` (B, n) and point weights
        (B, N): cost ``Σ w·|r|²`` plus the prior's (B,), JᵀWJ (B, n, n) and JᵀWr (B, n).

        Under a global shutter the prediction is a homography: the compiled kernel forms
        the sums point by point from it and its central-difference derivative in each
        parameter; under a rolling shutter from the residuals and central-difference Jacobian
        of the weighted points (as :meth:`residuals_batch`, :meth:`jacobian_batch`)."""
        xs = np.asarray(xs, dtype=float)
        b, n = xs.shape
        if self.readout_frames:  # unweighted points (a subset's unused ones) left unsolved
            base, perturbed = self._perturbed_predictions(xs, active=weights > 0)
            r = self._residuals_of(base).reshape(b, -1, 1)
            jac = self._jacobian_of(perturbed, b).reshape(b, -1, n)
            w2 = np.repeat(weights, 2, axis=1)[:, :, None]
            jw_t = np.swapaxes(jac * w2, 1, 2)
            cost = np.sum(w2 * r**2, axis=(1, 2))
            a, g = jw_t @ jac, (jw_t @ r)[..., 0]
        else:
            h, ground_w, image_w = self._homographies(np.concatenate([xs, central_points(xs)]))
            dh = central_difference(h[b:], b)
            whitening = (np.zeros((0, 2, 2)) if self.point_whitening is None
                         else np.ascontiguousarray(self.point_whitening, dtype=float))
            cost, a, g = homography_normal_equations(
                np.ascontiguousarray(h[:b]), np.ascontiguousarray(dh), ground_w[:b],
                image_w[:b], np.ascontiguousarray(self.pixels_prev, dtype=float),
                np.ascontiguousarray(self.targets, dtype=float), whitening,
                np.ascontiguousarray(weights, dtype=float), INVALID_RESIDUAL)
        if self.n_prior:
            jp = self.prior_jacobian_batch(xs)  # (B, 4, n)
            p = self.prior_batch(xs)
            cost = cost + np.sum(p**2, axis=1)
            a = a + np.swapaxes(jp, 1, 2) @ jp
            g = g + (np.swapaxes(jp, 1, 2) @ p[..., None])[..., 0]
        return cost, a, g

    def _homographies(self, xs: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Global shutter: the plane-from-previous-image homographies (B, 3, 3) of parameter
        vectors ``xs`` (B, n) and the rows (B, 3) whose product with a homogeneous pixel is
        positive on the ground of frame k-1 and in front of camera k."""
        g_from_i, out_from_g = pair_homographies(self.k, self.height, self.full(xs))
        image_from_prev = out_from_g @ g_from_i
        a = np.eye(3) if self.plane_from_image is None else self.plane_from_image
        return (a @ image_from_prev, np.ascontiguousarray(g_from_i[:, 2]),
                np.ascontiguousarray(image_from_prev[:, 2]))

    def errors(self, x: FloatArray) -> FloatArray:
        """Per-point residual norms (N,), plane pixels (inf where undefined)."""
        e = np.linalg.norm(self._whiten(self.predict(x) - self.targets), axis=1)
        return np.where(np.isfinite(e), e, np.inf)

    def errors_batch(self, xs: FloatArray) -> FloatArray:
        """Per-point residual norms (B, N) for parameter vectors (B, 7) (inf where undefined)."""
        e = np.linalg.norm(self._whiten(self.predict_batch(xs) - self.targets[None]), axis=2)
        return np.where(np.isfinite(e), e, np.inf)


def pair_homographies(
    k: FloatArray, height: float, xs: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Batched factors of geometry's pair homography for parameter vectors ``xs`` (B, 7).

    Returns ``ground_from_image(Θ_p)`` (B, 3, 3) and ``image_from_ground(Θ_c) · T(Ψ)``
    (B, 3, 3), equal to geometry's ``ground_from_image_homography``,
    ``image_from_ground_homography`` and ``motion_matrix`` (checked by the tests) but built
    for the whole batch at once in a compiled loop (``homography_lsq``).
    """
    return pair_homography_factors(np.ascontiguousarray(k, dtype=float), float(height),
                                   np.ascontiguousarray(xs, dtype=float))


@dataclass(frozen=True)
class SteadyPoseModel(DisplacementModel):
    """The model with one pose for both frames: parameters (pitch, roll, tx, tz, yaw).

    Fewer unknowns for the cold start's coarse pass, whose few trusted displacements only
    need to predict where the patches go."""

    def full_index(self, n: int) -> NDArray[np.intp]:
        return np.array([0, 1, 0, 1, 2, 3, 4])

    @staticmethod
    def reduce(x: FloatArray) -> FloatArray:
        """(pitch, roll, tx, tz, yaw) of a 7-vector (its current-frame pose)."""
        return np.concatenate([x[2:4], x[4:7]])




def central_points(xs: FloatArray) -> FloatArray:
    """Parameter vectors (B·2n, n) at which central differences evaluate a function of
    ``xs`` (B, n): for each vector, +:data:`FD_STEP` along each parameter, then −."""
    n = xs.shape[1]
    steps = np.eye(n) * FD_STEP
    pert = np.concatenate([xs[:, None] + steps[None], xs[:, None] - steps[None]], axis=1)
    return pert.reshape(-1, n)


def central_difference(values: FloatArray, b: int) -> FloatArray:
    """Derivatives (B, n, ...) from a function's ``values`` (B·2n, ...) at
    :func:`central_points` of B parameter vectors."""
    v = values.reshape(b, 2, -1, *values.shape[1:])
    return (v[:, 0] - v[:, 1]) / (2 * FD_STEP)
