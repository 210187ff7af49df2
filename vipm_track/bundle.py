"""Geometric bundle adjustment of a frame pair: residual models and their robust LM fit.

The seven parameters are ordered as :data:`vipm_track.measurement.PARAMETER_NAMES`:
``(pitch_prev, roll_prev, pitch, roll, tx, tz, yaw)`` in radians and metres, the height
being fixed to the assumed one within the pair (CONVENTIONS.md, Scale). Optionally an eighth
parameter ``dh`` [m], the camera's vertical motion within the pair (frame k at height
``h + dh``), for rigs that bounce (the paper assumes it negligible; each millimetre of it
otherwise shows up as about 0.25° of pitch on a 0.7 m, 45° camera).

One residual model serves both planes of the paper (section III):

- image plane (eq. 1): a ground point seen at ``m_p`` in frame k-1 is predicted at
  ``m_c = π(T(Ψ) π⁻¹(m_p; Θ_p); Θ_c)`` and compared with ``m_p + d`` (``d`` from POC);
- virtual IPM plane (eqs. 3-5): the same prediction mapped onto the current frame's
  virtual IPM image by the *fixed* estimate Θ̂_c, compared with ``q_p + d̂`` in IPM pixels,
  where ``m_p = π(q_p; Θ̂_p)`` is the image pixel of the previous IPM patch centre.

So a model is the prediction followed by a fixed homography ``plane_from_image`` (the
identity on the image plane, ``ipm_from_image_homography(k, Θ̂_c, grid)`` on the IPM).

Rolling shutter (``readout_frames`` > 0, the readout over the frame interval, of an image of
``image_rows`` rows): row v of a frame is exposed ``v · readout_frames / image_rows`` frame
intervals after its row 0 (the time the frame's pose refers to). Ground seen at time a (its
row) of frame k-1 is back-projected with the pose at k-1+a, travels to time b of frame k,
``(1 + b − a)·Ψ`` at constant velocity (Ψ the motion over the frame interval) plus
``(b² − a² + a + b)/2 · (Ψ − Ψ₋₁)`` at a constant acceleration (Ψ₋₁ the previous interval's
motion, ``previous_motion``, where known; the motion's three components scaled alike), and
is projected with the pose at k+b: the poses change at the pair's own rate (frame k's minus
frame k-1's per interval; a shaking rig turns by up to 15°/s). b depends on the prediction
itself: it is solved per point by the secant method (``shutter.moved_pixels``, compiled). A
central-difference Jacobian solves its points at the parameters first and starts the
perturbed solves from those row times; Levenberg–Marquardt's subsets solve only the points
they weight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from .geometry import GroundPose, PlanarMotion, compose_motion, invert_motion
from .homography_lsq import homography_normal_equations
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

    @property
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
        return np.asarray(xs, dtype=float)

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
        xs = self.full(xs)
        pix = self.pixels_prev if idx is None else self.pixels_prev[idx]
        a = np.eye(3) if self.plane_from_image is None else self.plane_from_image
        times = None
        if self.readout_frames:  # NaN off the ground of frame k-1 (at the row's time)
            img, times = self._rolling_shutter(xs, pix, start, active)
            good = img[..., 2] > 0  # in front of camera k
        else:
            m = np.concatenate([pix, np.ones((len(pix), 1))], axis=1)  # (n, 3)
            g_from_i, out_from_g = pair_homographies(self.k, self.height, xs)
            ground = np.einsum("bij,nj->bni", g_from_i, m)  # (B, n, 3); w > 0 on the ground
            img = np.einsum("bij,bnj->bni", out_from_g, ground)
            good = (ground[..., 2] > 0) & (img[..., 2] > 0)  # and in front of camera k
        plane = img @ a.T
        with np.errstate(divide="ignore", invalid="ignore"):
            out = plane[..., :2] / plane[..., 2:3]
        out[~good] = np.nan
        return out, times

    def _rolling_shutter(
        self, xs: FloatArray, pixels_prev: FloatArray, start: FloatArray | None = None,
        active: NDArray[np.bool_] | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Homogeneous frame-k pixels (B, n, 3) of the ground seen at ``pixels_prev`` in frame
        k-1, each row exposed at its own time, and their row times (B, n) (module doc;
        ``shutter.moved_pixels``)."""
        params = np.zeros((len(xs), N_PARAMS + 1))
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
    for the whole batch at once: R_GC = Rx(-pitch)·Rz(roll), lift (X, Z) → (X, h, Z).
    """
    xs = np.asarray(xs, dtype=float)
    kinv = np.linalg.inv(k)
    lift_inv = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0 / height, 0.0]])
    lift = np.zeros((len(xs), 3, 3))
    lift[:, 0, 0] = lift[:, 2, 1] = 1.0
    lift[:, 1, 2] = height + (xs[:, 7] if xs.shape[1] > N_PARAMS else 0.0)
    r_p = _rotations(xs[:, 0], xs[:, 1])
    r_c = _rotations(xs[:, 2], xs[:, 3])
    g_from_i = lift_inv @ r_p @ kinv
    cy, sy = np.cos(xs[:, 6]), np.sin(xs[:, 6])
    t = np.zeros((len(xs), 3, 3))
    t[:, 0, 0], t[:, 0, 1], t[:, 1, 0], t[:, 1, 1], t[:, 2, 2] = cy, -sy, sy, cy, 1.0
    t[:, 0, 2] = -(cy * xs[:, 4] - sy * xs[:, 5])
    t[:, 1, 2] = -(sy * xs[:, 4] + cy * xs[:, 5])
    out_from_g = k @ np.swapaxes(r_c, 1, 2) @ lift @ t
    return g_from_i, out_from_g


def _rotations(pitch: FloatArray, roll: FloatArray) -> FloatArray:
    """R_GC (B, 3, 3) = Rx(-pitch) · Rz(roll) for arrays of angles (geometry's convention)."""
    c, s = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    r = np.empty((len(pitch), 3, 3))
    r[:, 0] = np.stack([cr, -sr, np.zeros_like(cr)], axis=1)
    r[:, 1] = np.stack([c * sr, c * cr, s], axis=1)
    r[:, 2] = np.stack([-s * sr, -s * cr, c], axis=1)
    return r


@dataclass(frozen=True)
class SteadyPoseModel(DisplacementModel):
    """The model with one pose for both frames: parameters (pitch, roll, tx, tz, yaw).

    Fewer unknowns for the cold start's coarse pass, whose few trusted displacements only
    need to predict where the patches go."""

    def full(self, xs: FloatArray) -> FloatArray:
        xs = np.asarray(xs, dtype=float)
        return np.concatenate([xs[..., :2], xs[..., :2], xs[..., 2:5]], axis=-1)

    @staticmethod
    def reduce(x: FloatArray) -> FloatArray:
        """(pitch, roll, tx, tz, yaw) of a 7-vector (its current-frame pose)."""
        return np.concatenate([x[2:4], x[4:7]])


#: Central-difference step of the Jacobian, radians / metres.
_FD_STEP = 1e-6


def central_points(xs: FloatArray) -> FloatArray:
    """Parameter vectors (B·2n, n) at which central differences evaluate a function of
    ``xs`` (B, n): for each vector, +:data:`_FD_STEP` along each parameter, then −."""
    n = xs.shape[1]
    steps = np.eye(n) * _FD_STEP
    pert = np.concatenate([xs[:, None] + steps[None], xs[:, None] - steps[None]], axis=1)
    return pert.reshape(-1, n)


def central_difference(values: FloatArray, b: int) -> FloatArray:
    """Derivatives (B, n, ...) from a function's ``values`` (B·2n, ...) at
    :func:`central_points` of B parameter vectors."""
    v = values.reshape(b, 2, -1, *values.shape[1:])
    return (v[:, 0] - v[:, 1]) / (2 * _FD_STEP)


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
        jac=model.jacobian,
        args=(idx,),
        method="lm",
        x_scale="jac",
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=max_nfev,
    )
    return res.x, bool(res.status > 0), res.jac, res.fun, int(res.nfev)


def lm_batch(
    model: DisplacementModel,
    x0: FloatArray,
    weights: FloatArray,
    max_iterations: int = 50,
    tolerance: float = 1e-7,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Levenberg-Marquardt run for many point subsets at once (the random subsets).

    Each subset s minimises ``Σ_n weights[s, n] · |r_n(x_s)|²`` from ``x0`` with
    Marquardt's diagonal damping; all subsets step in lockstep so that a step costs one
    vectorised residual and Jacobian evaluation for the whole batch.

    Parameters
    ----------
    model : residual model over all N points.
    x0 : (7,) common start, or (S, 7) one start per subset.
    weights : (S, N) point weights (0/1 for subsets).
    max_iterations, tolerance : stop after this many steps, or once a subset's relative
        cost decrease falls below ``tolerance``.

    Returns
    -------
    x : (S, 7) solutions, converged : (S,) whether each met the tolerance.
    """
    n_sets = weights.shape[0]
    n_par = np.shape(x0)[-1]
    x = np.broadcast_to(np.asarray(x0, dtype=float), (n_sets, n_par)).copy()
    # The normal equations at each subset's current x, refreshed when a step is accepted.
    c, a, g = model.normal_equations(x, weights)
    lam = np.full(n_sets, 1e-3)
    active = np.ones(n_sets, bool)
    converged = np.zeros(n_sets, bool)
    eye = np.eye(n_par)
    for _ in range(max_iterations):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        a_act = a[idx]
        diag = np.einsum("aii->ai", a_act)
        damp = (diag + 1e-9 * diag.max(axis=1, keepdims=True) + 1e-12)[:, :, None] * eye
        step = -np.linalg.solve(a_act + lam[idx, None, None] * damp, g[idx][..., None])[..., 0]
        x_new = x[idx] + step
        c_new, a_new, g_new = model.normal_equations(x_new, weights[idx])
        better = c_new < c[idx]
        rel = (c[idx] - c_new) / np.maximum(c[idx], 1e-300)
        moved = idx[better]
        x[moved], c[moved], a[moved], g[moved] = (x_new[better], c_new[better], a_new[better],
                                                  g_new[better])
        lam[idx] = np.where(better, np.maximum(lam[idx] / 3.0, 1e-9), lam[idx] * 4.0)
        done = (better & (rel < tolerance)) | (lam[idx] > 1e9) | (
            np.max(np.abs(step), axis=1) < 1e-12)
        converged[idx[done & (lam[idx] <= 1e9)]] = True
        active[idx[done]] = False
    return x, converged


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


def block_jackknife_covariance(
    model: DisplacementModel, x: FloatArray, idx: NDArray[np.intp], columns: int = 4,
    rows: int = 2,
) -> FloatArray:
    """Delete-a-block jackknife covariance of the fit at ``x`` on the points ``idx``: the
    points split into ``columns`` × ``rows`` blocks by their image position (quantiles), each
    block left out in turn and the fit redone from ``x``;
    ``(G − 1)/G · Σ (x_g − x̄)(x_g − x̄)ᵀ``. Unlike ``covariance_from_jacobian`` it does not
    take the points' errors as independent: what the model misses on real frames (a road
    that is not one plane, patches on a kerb or a vehicle's lower edge) is shared by
    neighbouring patches, and leaving their block out moves the fit by what they held."""
    n = len(x)
    px = model.pixels_prev[idx]
    col = np.searchsorted(np.quantile(px[:, 0], np.linspace(0, 1, columns + 1)[1:-1]), px[:, 0])
    row = np.searchsorted(np.quantile(px[:, 1], np.linspace(0, 1, rows + 1)[1:-1]), px[:, 1])
    block = col * rows + row
    fits = []
    for g in np.unique(block):
        keep = idx[block != g]
        if keep.size < max(8, n):
            continue
        fits.append(fit_lm(model, x, keep, max_nfev=30)[0])
    if len(fits) < 3:
        return np.full((n, n), np.nan)
    d = np.array(fits) - np.mean(fits, axis=0)
    return (len(fits) - 1) / len(fits) * d.T @ d


def heave_covariance(
    model: DisplacementModel, x: FloatArray, idx: NDArray[np.intp], heave_std_m: float,
) -> FloatArray:
    """The covariance a 7-parameter fit at ``x`` on the points ``idx`` misses by leaving out
    the camera's vertical motion within the pair (the 8th parameter), when that motion has
    a standard deviation of ``heave_std_m`` [m]: a heave ``dh`` the fit does not model moves
    its parameters by ``b · dh``, ``b = −(JᵀJ)⁻¹ Jᵀ j_h`` (the omitted parameter's bias), so
    their covariance gains ``σ_h² b bᵀ``. Over a short travel a level camera's flow takes a
    heave for a pitch change: a body bouncing at slow speed moves the pitch by far more than
    the formal covariance says."""
    n = len(x)
    if heave_std_m <= 0 or n != N_PARAMS or idx.size < 2 * n:
        return np.zeros((n, n))
    jac8 = model.jacobian(np.append(x, 0.0), idx)
    jac, j_heave = jac8[:, :n], jac8[:, n]
    try:
        b = -np.linalg.solve(jac.T @ jac, jac.T @ j_heave)
    except np.linalg.LinAlgError:
        return np.zeros((n, n))
    return heave_std_m**2 * np.outer(b, b) if np.all(np.isfinite(b)) else np.zeros((n, n))


def robust_fit(
    model: DisplacementModel,
    x0: FloatArray,
    usable: NDArray[np.bool_],
    n_subsets: int,
    fraction: float,
    inlier_px: float,
    rng: np.random.Generator,
    median_factor: float = 0.0,
    jackknife: bool = False,
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
    median_factor : when > 0, the threshold then tightens to this multiple of the inliers'
        median residual norm (where that is below ``inlier_px``; never to fewer than half
        the inliers), re-fitting until the set settles: a fixed threshold sized for the
        worst patches admits gross errors among precise ones.
    """
    use_idx = np.flatnonzero(usable)
    nfev = 0
    m = max(4, round(fraction * use_idx.size))
    # Subset 0 holds every usable point; the others are random subsets of them.
    weights = np.zeros((1 + (n_subsets if m < use_idx.size else 0), model.n_points))
    weights[0, use_idx] = 1.0
    for s in range(1, len(weights)):
        weights[s, rng.choice(use_idx, size=m, replace=False)] = 1.0
    candidates, _ = lm_batch(model, x0, weights)
    if candidates.shape[1] >= N_PARAMS:
        candidates = np.array([canonical(c) for c in candidates])
    c2 = inlier_px**2
    e = model.errors_batch(candidates)[:, use_idx]
    scores = np.sum(np.minimum(e**2, c2), axis=1) + np.sum(model.prior_batch(candidates)**2,
                                                           axis=1)
    scores[~plausible(model.full(candidates))] = np.inf
    best = candidates[int(np.argmin(scores))]
    ok_all = bool(np.isfinite(scores.min()))

    # Re-fit on the best candidate's inliers until the inlier set settles: three fits at most
    # with a fixed threshold (as before the tightening existed, so those fits are unchanged),
    # six while a median_factor may still tighten it.
    x = best
    converged = ok_all
    threshold = inlier_px
    inl = usable & (model.errors(x) < threshold)
    jac = np.zeros((0, len(x0)))
    res = np.zeros(0)
    for _ in range(6 if median_factor > 0 else 3):
        idx = np.flatnonzero(inl)
        if idx.size < 4:
            break
        x, converged, jac, res, n = fit_lm(model, x, idx)
        nfev += n
        errors = model.errors(x)
        if median_factor > 0:
            tight = median_factor * float(np.median(errors[inl]))
            if tight < threshold and np.sum(usable & (errors < tight)) >= inl.sum() / 2:
                threshold = tight
        new_inl = usable & (errors < threshold)
        if np.array_equal(new_inl, inl):
            break
        inl = new_inl
    errors = model.errors(x)
    inl = usable & (errors < threshold)
    if jac.shape[0] >= 2 * len(x0):
        cov = covariance_from_jacobian(jac, res)
        pts = res[:res.size - model.n_prior]
        rms = float(np.sqrt(np.mean(pts**2) * 2)) if pts.size else float("nan")
    else:
        cov = np.full((len(x0), len(x0)), np.nan)
        rms = float("nan")
    xc = canonical(x) if len(x) >= N_PARAMS else x
    if not np.allclose(xc, x if len(x) < N_PARAMS else wrap_angles(x)):
        # The same solution in the canonical chart: re-evaluate its covariance there.
        _, _, jac, res, _ = fit_lm(model, xc, np.flatnonzero(inl), max_nfev=20)
        cov = covariance_from_jacobian(jac, res) if jac.shape[0] >= 2 * len(x0) else cov
    if jackknife and np.all(np.isfinite(cov)):
        cov = at_least(cov, block_jackknife_covariance(model, xc, np.flatnonzero(inl)))
    return FitResult(xc, inl, errors, cov, rms, converged, nfev)


def at_least(cov: FloatArray, other: FloatArray) -> FloatArray:
    """``cov`` with each parameter's standard deviation raised to ``other``'s where that is
    larger (correlations kept)."""
    if not np.all(np.isfinite(other)):
        return cov
    scale = np.sqrt(np.maximum(1.0, np.diag(other) / np.diag(cov)))
    return cov * np.outer(scale, scale)


def wrap_angles(x: FloatArray) -> FloatArray:
    """Parameters (..., 7) with the angles wrapped to (-π, π]."""
    out = np.array(x, dtype=float)
    ang = [0, 1, 2, 3, 6]
    out[..., ang] = -((-out[..., ang] + np.pi) % (2 * np.pi) - np.pi)
    return out


def canonical(x: FloatArray) -> FloatArray:
    """Parameters (7,) with angles wrapped and each pitch in [-π/2, π/2].

    A pitch beyond 90° with the roll turned by 180° is the same camera with its ground
    frame G turned by 180° about the normal (G's z axis is the optical axis projected onto
    the ground); the motion is re-expressed between the turned frames."""
    w = wrap_angles(x)
    flips = []
    for i in (0, 2):
        flip = abs(w[i]) > np.pi / 2
        if flip:
            w[i] = np.sign(w[i]) * np.pi - w[i]
            w[i + 1] += np.pi
        flips.append(PlanarMotion(0.0, 0.0, np.pi if flip else 0.0))
    if flips[0].yaw or flips[1].yaw:
        m = compose_motion(invert_motion(flips[0]),
                           compose_motion(PlanarMotion(w[4], w[5], w[6]), flips[1]))
        w[4:7] = m.tx, m.tz, m.yaw
    return wrap_angles(w)


def plausible(x: FloatArray) -> NDArray[np.bool_]:
    """Whether parameters (..., 7) describe a camera above the ground looking at it:
    pitch in (-45°, 135°), |roll| < 45°, |yaw change| < 45° (angles wrapped first)."""
    w = wrap_angles(x)
    pitch = w[..., [0, 2]]
    roll = w[..., [1, 3]]
    return (
        np.all(np.isfinite(w), axis=-1)
        & np.all((pitch > -np.pi / 4) & (pitch < 3 * np.pi / 4), axis=-1)
        & np.all(np.abs(roll) < np.pi / 4, axis=-1)
        & (np.abs(w[..., 6]) < np.pi / 4)
    )
