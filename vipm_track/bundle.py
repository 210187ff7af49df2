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

from .displacement_model import N_PARAMS, DisplacementModel
from .geometry import PlanarMotion, compose_motion, invert_motion
from .workers import map_on_threads, threads

FloatArray = NDArray[np.float64]
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


#: the random subsets are split across threads only from this many on (a thread's start
#: costs about what a few subsets' LM does)
MIN_SPLIT_SUBSETS = 16

#: relative cost decrease and relative step at which a re-fit on the inliers stops (the
#: ``ftol`` and ``xtol`` MINPACK had)
REFIT_TOLERANCE = 1e-10


def fit_lm(
    model: DisplacementModel, x0: FloatArray, idx: NDArray[np.intp], max_nfev: int = 400
) -> tuple[FloatArray, bool, FloatArray, FloatArray, int]:
    """Levenberg-Marquardt on the points ``idx`` from ``x0``: compiled under a global
    shutter (:meth:`DisplacementModel.lm`), MINPACK's otherwise.

    Returns (x, success, jacobian (2n, 7), residuals (2n,), function evaluations)."""
    if 2 * np.size(idx) + model.n_prior < len(x0):  # as MINPACK's LM said
        raise ValueError(f"{2 * np.size(idx) + model.n_prior} residuals for {len(x0)} "
                         "parameters: LM needs at least as many residuals as parameters")
    if not model.readout_frames:
        weights = np.zeros((1, model.n_points))
        weights[0, idx] = 1.0
        xs, converged, n = model.lm(np.asarray(x0, dtype=float)[None], weights, max_nfev,
                                    REFIT_TOLERANCE, REFIT_TOLERANCE)
        x = xs[0]
        return x, bool(converged[0]), model.jacobian(x, idx), model.residuals(x, idx), n + 2
    # imported here: only a rolling shutter's fit needs it, and it costs a start-up 0.2 s
    from scipy.optimize import least_squares

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
    Marquardt's diagonal damping: compiled, subset by subset, under a global shutter
    (:meth:`DisplacementModel.lm`); under a rolling shutter all subsets step in lockstep so
    that a step costs one vectorised residual and Jacobian evaluation for the whole batch.

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
    if not model.readout_frames:
        # the subsets are independent: split across the pair's threads (the kernel releases
        # the GIL), the same solutions for any split
        if threads() == 1 or n_sets < MIN_SPLIT_SUBSETS:
            found, converged, _ = model.lm(x, weights, max_iterations, tolerance)
            return found, converged
        solved = map_on_threads(
            lambda part: model.lm(x[part], weights[part], max_iterations, tolerance),
            np.array_split(np.arange(n_sets), threads()))
        return (np.concatenate([found for found, _, _ in solved]),
                np.concatenate([converged for _, converged, _ in solved]))
    return _lm_lockstep(model, x, weights, max_iterations, tolerance)


def _lm_lockstep(
    model: DisplacementModel, x: FloatArray, weights: FloatArray, max_iterations: int,
    tolerance: float,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """:func:`lm_batch` with the subsets stepping in lockstep (rolling shutter: one
    vectorised evaluation of the model for the whole batch per step)."""
    n_sets, n_par = x.shape
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
    block left out in turn; ``(G − 1)/G · Σ (x_g − x̄)(x_g − x̄)ᵀ``. Each ``x_g`` is one
    Gauss–Newton step from ``x`` on the remaining points (the linearised jackknife: ``x`` is
    the optimum of all points, so the step is small and one Jacobian serves every block).
    Unlike ``covariance_from_jacobian`` it does not take the points' errors as independent:
    what the model misses on real frames (a road that is not one plane, patches on a kerb or
    a vehicle's lower edge) is shared by neighbouring patches, and leaving their block out
    moves the fit by what they held."""
    n = len(x)
    px = model.pixels_prev[idx]
    col = np.searchsorted(np.quantile(px[:, 0], np.linspace(0, 1, columns + 1)[1:-1]), px[:, 0])
    row = np.searchsorted(np.quantile(px[:, 1], np.linspace(0, 1, rows + 1)[1:-1]), px[:, 1])
    block = col * rows + row
    jac, res = model.jacobian(x, idx), model.residuals(x, idx)
    # two residual rows per point, then the prior's (never left out)
    row_block = np.concatenate([np.repeat(block, 2), np.full(model.n_prior, -1)])
    fits = []
    for g in np.unique(block):
        if np.count_nonzero(block != g) < max(8, n):
            continue
        keep = row_block != g
        fits.append(x - np.linalg.lstsq(jac[keep], res[keep], rcond=None)[0])
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
    b = omitted_bias(model.jacobian(np.append(x, 0.0), idx), n, n)
    return np.zeros((n, n)) if b is None else heave_std_m**2 * np.outer(b, b)


def omitted_bias(jac: FloatArray, n: int, omitted: int | list[int]) -> FloatArray | None:
    """How a fit of the first ``n`` columns of ``jac`` (residuals × parameters) moves per unit
    of the ``omitted`` parameter(s) it leaves out (column indices): ``B = −(JᵀJ)⁻¹ Jᵀ J_o``,
    (n,) for one index, (n, len(omitted)) for a list. None where JᵀJ is singular or B not
    finite."""
    fitted, left_out = jac[:, :n], jac[:, omitted]
    try:
        b = -np.linalg.solve(fitted.T @ fitted, fitted.T @ left_out)
    except np.linalg.LinAlgError:
        return None
    return b if np.all(np.isfinite(b)) else None


def shutter_rate_covariance(
    model: DisplacementModel, x: FloatArray, idx: NDArray[np.intp], rate_std: FloatArray,
) -> FloatArray:
    """The covariance a fit at ``x`` (7 or 8 parameters) on the points ``idx`` misses under a
    rolling shutter by taking frame k's pitch and roll to change at the pair's own rate
    during its readout, when the true rates differ from it by ``rate_std`` (2,) [rad per
    frame interval]: the omitted parameters' bias ``B = −(JᵀJ)⁻¹ Jᵀ J_ω``, covariance
    ``B diag(σ²) Bᵀ``. Frame k's rate during its readout lies beyond the pair (it is the
    next interval's): a body shaking at 1–3 Hz, filmed at 10 fps, turns at a rate the pair
    cannot know, and a steep camera's pose takes the rows' turning for a pose."""
    n = len(x)
    if (not model.readout_frames or n not in (N_PARAMS, N_PARAMS + 1) or idx.size < 2 * n
            or not np.any(np.asarray(rate_std) > 0)):
        return np.zeros((n, n))
    extended = np.zeros(N_PARAMS + 5)  # heave, then frame k-1's and frame k's rate offsets
    extended[:n] = x
    b = omitted_bias(model.jacobian(extended, idx), n, [N_PARAMS + 3, N_PARAMS + 4])
    if b is None:
        return np.zeros((n, n))
    return (b * np.asarray(rate_std, dtype=float) ** 2) @ b.T


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
        candidates = canonical_batch(candidates)
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


def canonical_batch(xs: FloatArray) -> FloatArray:
    """:func:`canonical` of each row of ``xs`` (S, 7); the rows with no pitch beyond 90°
    (nearly all) in one vectorised step."""
    w = wrap_angles(xs)
    out = wrap_angles(w)
    for s in np.flatnonzero(np.any(np.abs(w[:, [0, 2]]) > np.pi / 2, axis=1)):
        out[s] = canonical(xs[s])
    return out


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
