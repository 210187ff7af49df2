"""The bundle adjustment's normal equations: the compiled homography path against the sums
formed from the model's own residuals and Jacobian, and the batched LM on exact data."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from vipm_track import bundle, geometry
from vipm_track import displacement_model as dm
from vipm_track.sim import PRESETS


def _reference(model: dm.DisplacementModel, xs: np.ndarray, weights: np.ndarray):
    """Cost, JᵀWJ, JᵀWr from residuals_batch, central differences of predict_batch over all
    points (every rolling-shutter point solved from its own row) and the prior's (numpy)."""
    b, n = xs.shape
    r = model.residuals_batch(xs).reshape(b, -1)
    d = dm.central_difference(
        model._whiten(model.predict_batch(dm.central_points(xs))), b)  # (B, n, N, 2)
    jac = np.where(np.isfinite(d), d, 0.0).transpose(0, 2, 3, 1).reshape(b, -1, n)
    w2 = np.repeat(weights, 2, axis=1)
    cost = np.sum(w2 * r**2, axis=1)
    a = np.einsum("bmi,bm,bmj->bij", jac, w2, jac)
    g = np.einsum("bmi,bm,bm->bi", jac, w2, r)
    if model.n_prior:
        p, jp = model.prior_batch(xs), model.prior_jacobian_batch(xs)
        cost += np.sum(p**2, axis=1)
        a += np.einsum("bki,bkj->bij", jp, jp)
        g += np.einsum("bki,bk->bi", jp, p)
    return cost, a, g


def _cart_model(rng: np.random.Generator, **changes) -> tuple[dm.DisplacementModel, np.ndarray]:
    k = PRESETS["cart"].camera().k
    pp, pc = geometry.GroundPose(0.8, 0.02, 0.7), geometry.GroundPose(0.81, 0.01, 0.7)
    mo = geometry.PlanarMotion(0.01, 0.1, 0.02)
    pix = np.stack(np.meshgrid(np.linspace(50, 750, 6), np.linspace(20, 580, 5)), -1).reshape(-1, 2)
    target = geometry.predict_pixels(k, pp, pc, mo, pix) + rng.normal(0, 0.3, (len(pix), 2))
    model = dm.DisplacementModel(k, 0.7, pix, target)
    return dataclasses.replace(model, **changes), dm.pack(pp, pc, mo)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), whiten=st.booleans(), prior=st.booleans(),
       plane=st.booleans(), eighth=st.booleans(), rolling=st.booleans())
def test_normal_equations_equal_the_residual_jacobian_sums(seed, whiten, prior, plane, eighth,
                                                           rolling):
    """The compiled homography path (global shutter) and the rolling shutter's (weighted
    points only, perturbed solves started from the base's row times) against sums over all
    points solved from scratch."""
    rng = np.random.default_rng(seed)
    n = 30
    changes: dict[str, object] = {}
    if rolling:
        changes.update(readout_frames=0.4, image_rows=600,
                       previous_motion=np.array([0.0, 0.09, 0.015]))
    if whiten:
        changes["point_whitening"] = np.eye(2) + 0.3 * rng.normal(size=(n, 2, 2))
    if prior:
        changes["prior_mean"] = np.radians([46.0, 1.0, 46.0, 1.0])
        changes["prior_scale"] = 50.0
    if plane:
        changes["plane_from_image"] = np.diag([0.5, 0.7, 1.0]) + 1e-4 * rng.normal(size=(3, 3))
    model, x = _cart_model(rng, **changes)
    if eighth:
        x = np.append(x, 0.002)
    # a batch around the truth, one of them pitched up so far that the top rows leave the
    # ground (invalid points: the constant residual, no gradient)
    xs = x + rng.normal(0, [0.02, 0.01, 0.02, 0.01, 0.01, 0.02, 0.01] + [0.001] * eighth,
                        (5, len(x)))
    xs[0, 0] -= 0.6
    weights = (rng.random((5, n)) < 0.6).astype(float) * rng.uniform(0.5, 2.0, (5, n))
    cost, a, g = model.normal_equations(xs, weights)
    ref_cost, ref_a, ref_g = _reference(model, xs, weights)
    assert np.any(~np.isfinite(model.predict_batch(xs[:1])))  # the invalid points are there
    np.testing.assert_allclose(cost, ref_cost, rtol=1e-9)
    scale_a = np.abs(ref_a).max(axis=(1, 2), keepdims=True)
    np.testing.assert_allclose(a / scale_a, ref_a / scale_a, atol=1e-6)
    scale_g = np.abs(ref_g).max(axis=1, keepdims=True)
    np.testing.assert_allclose(g / scale_g, ref_g / scale_g, atol=1e-6)


def test_steady_pose_model_normal_equations_use_its_five_parameters():
    rng = np.random.default_rng(3)
    full, x = _cart_model(rng)
    model = dm.SteadyPoseModel(**{f.name: getattr(full, f.name)
                                      for f in dataclasses.fields(full)})
    xs = dm.SteadyPoseModel.reduce(x) + rng.normal(0, 0.01, (4, 5))
    weights = np.ones((4, full.n_points))
    cost, a, g = model.normal_equations(xs, weights)
    ref = _reference(model, xs, weights)
    assert a.shape == (4, 5, 5) and g.shape == (4, 5)
    np.testing.assert_allclose(cost, ref[0], rtol=1e-9)
    np.testing.assert_allclose(a, ref[1], rtol=1e-5, atol=1e-6 * np.abs(ref[1]).max())


@pytest.mark.parametrize("readout", [0.0, 0.4])
def test_batched_lm_recovers_the_pair_from_exact_displacements(readout):
    k = PRESETS["car"].camera().k
    pp, pc = geometry.GroundPose(0.05, 0.01, 1.5), geometry.GroundPose(0.052, 0.008, 1.5)
    mo = geometry.PlanarMotion(0.02, 0.8, 0.01)
    pix = np.stack(np.meshgrid(np.linspace(100, 1180, 8), np.linspace(420, 700, 5)),
                   -1).reshape(-1, 2)
    x = dm.pack(pp, pc, mo)
    model = dm.DisplacementModel(k, 1.5, pix, pix, readout_frames=readout, image_rows=720)
    model = dataclasses.replace(model, targets=model.predict(x))
    rng = np.random.default_rng(0)
    weights = np.ones((6, len(pix)))
    weights[1:] = rng.random((5, len(pix))) < 0.6
    start = x + np.array([0.01, -0.005, 0.01, -0.005, 0.02, 0.05, 0.003])
    found, converged = bundle.lm_batch(model, start, weights)
    assert converged.all()
    np.testing.assert_allclose(found, np.broadcast_to(x, found.shape), atol=1e-7)


def test_rolling_shutter_solves_from_a_start_and_only_the_active_points():
    """Started from the row times of nearby parameters, the secant solve lands on the same
    pixels as from frame k-1's rows (to 1e-9 px) and returns times with b = v·per_row;
    inactive points stay NaN."""
    rng = np.random.default_rng(5)
    model, x = _cart_model(rng, readout_frames=0.5, image_rows=600)
    xs = x + rng.normal(0, 0.01, (3, len(x)))
    times = model._predict(xs)[1]
    assert np.isfinite(times).all()
    rows = model._rolling_shutter(model.full(xs), model.pixels_prev)[0]
    np.testing.assert_allclose(rows[..., 1] / rows[..., 2] * 0.5 / 600, times, atol=1e-9)
    active = rng.random(times.shape) < 0.6
    near = xs + 1e-6
    warm = model._predict(near, start=times, active=active)[0]
    np.testing.assert_allclose(warm[active], model.predict_batch(near)[active], atol=1e-9)
    assert np.isnan(warm[~active]).all()


def test_a_point_mapped_to_the_planes_line_at_infinity_is_undefined_not_an_error():
    """A measurement plane whose w vanishes exactly at a predicted pixel (the compiled
    projection divides by it) gives that point no prediction, as the normal equations do,
    instead of a ZeroDivisionError out of the LM."""
    rng = np.random.default_rng(5)
    model, x = _cart_model(rng)
    image = model.predict(x)
    plane = np.eye(3)
    plane[2] = [1.0, 0.0, -image[0, 0]]  # w = u - u_0: zero at the first point only
    moved = dataclasses.replace(model, plane_from_image=plane)
    out = moved.predict(x)
    assert np.isnan(out[0]).all() and np.isfinite(out[1:]).all()
    assert np.isinf(moved.errors(x)[0])


def _model_variant(rng, whiten: bool, prior: bool, plane: bool, eighth: bool, steady: bool):
    """A noisy cart model (30 points) with the options of the compiled LM, and its truth."""
    changes: dict[str, object] = {}
    if whiten:
        changes["point_whitening"] = np.eye(2) + 0.3 * rng.normal(size=(30, 2, 2))
    if prior:
        changes["prior_mean"] = np.radians([46.0, 1.0, 46.0, 1.0])
        changes["prior_scale"] = np.array([50.0, 20.0, 50.0, 20.0])
    if plane:
        changes["plane_from_image"] = np.diag([0.5, 0.7, 1.0]) + 1e-4 * rng.normal(size=(3, 3))
    model, x = _cart_model(rng, **changes)
    if steady:
        model = dm.SteadyPoseModel(**{f.name: getattr(model, f.name)
                                      for f in dataclasses.fields(model)})
        x = dm.SteadyPoseModel.reduce(x)
    elif eighth:
        x = np.append(x, 0.002)
    return model, x


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), whiten=st.booleans(), prior=st.booleans(),
       plane=st.booleans(), eighth=st.booleans(), steady=st.booleans())
def test_compiled_normal_equations_equal_the_models(seed, whiten, prior, plane, eighth, steady):
    """``homography_lsq.pair_normal_equations`` (one vector, inside the compiled LM) against
    ``DisplacementModel.normal_equations`` (a batch), every option of the global shutter."""
    from vipm_track.homography_lsq import pair_normal_equations

    rng = np.random.default_rng(seed)
    model, x = _model_variant(rng, whiten, prior, plane, eighth, steady)
    xs = x + rng.normal(0, 0.01, (3, len(x)))
    weights = (rng.random((3, 30)) < 0.6) * rng.uniform(0.5, 2.0, (3, 30))
    cost, a, g = model.normal_equations(xs, weights)
    prior_args = ((np.asarray(model.prior_mean, float), np.asarray(model.prior_scale, float))
                  if prior else (np.zeros(0), np.zeros(0)))
    for b in range(3):
        c1, a1, g1 = pair_normal_equations(
            xs[b], weights[b], model.k, model.height,
            np.eye(3) if model.plane_from_image is None else model.plane_from_image,
            model.pixels_prev, model.targets,
            np.zeros((0, 2, 2)) if model.point_whitening is None else model.point_whitening,
            model.full_index(len(x)), *prior_args, dm.INVALID_RESIDUAL)
        assert c1 == pytest.approx(cost[b], rel=1e-9)
        np.testing.assert_allclose(a1 / np.abs(a[b]).max(), a[b] / np.abs(a[b]).max(),
                                   atol=1e-7)
        np.testing.assert_allclose(g1 / np.abs(g[b]).max(), g[b] / np.abs(g[b]).max(),
                                   atol=1e-7)


@pytest.mark.parametrize(("prior", "steady"), [(False, False), (True, False), (True, True)])
def test_compiled_lm_takes_the_lockstep_steps(prior, steady):
    """The compiled LM (global shutter) and the lockstep one (kept for the rolling shutter)
    reach the same solutions and the same convergence for random subsets of noisy points."""
    rng = np.random.default_rng(3)
    model, x = _model_variant(rng, False, prior, False, False, steady)
    weights = np.ones((12, 30))
    weights[1:] = rng.random((11, 30)) < 0.6
    start = x + rng.normal(0, 0.02, len(x))
    found, converged = bundle.lm_batch(model, start, weights)
    lock, lock_converged = bundle._lm_lockstep(
        model, np.broadcast_to(start, found.shape).copy(), weights, 50, 1e-7)
    assert converged.sum() >= 10 and np.array_equal(converged, lock_converged)
    np.testing.assert_allclose(found, lock, atol=1e-8)
    # 0.3 px of noise on 18-30 points; the steady model's one pose misses the pair's two
    assert np.abs(found[converged] - x).max() < (0.1 if steady else 0.02)


@settings(max_examples=50, deadline=None)
@given(xs=hnp.arrays(np.float64, st.tuples(st.integers(1, 6), st.sampled_from([7, 8])),
                     elements=st.floats(-7.0, 7.0)))
def test_canonical_batch_is_canonical_row_by_row(xs):
    np.testing.assert_array_equal(bundle.canonical_batch(xs),
                                  np.array([bundle.canonical(x) for x in xs]))


@pytest.mark.parametrize("readout", [0.0, 0.4])
def test_a_refit_on_fewer_residuals_than_parameters_is_refused(readout):
    rng = np.random.default_rng(0)
    model, x = _cart_model(rng, readout_frames=readout, image_rows=600)
    with pytest.raises(ValueError, match="residuals"):
        bundle.fit_lm(model, x, np.arange(3))


@pytest.mark.parametrize("prior", [False, True])
@pytest.mark.parametrize("offsets", [(0.01, 0.0), (-0.008, 0.0), (0.0, 0.006)])
def test_shutter_rate_covariance_is_what_frame_ks_unmodelled_rate_moves_the_fit_by(offsets,
                                                                                  prior):
    """Displacements made with frame k turning during its readout at a rate off the pair's by
    ``offsets`` (pitch, roll; rad per frame interval), fitted with the pair's rate: the fit's
    pitch and roll move by the omitted parameter's bias, which the covariance's standard
    deviations (at σ = |offset|) state within 10 %; two angles' variances add."""
    rng = np.random.default_rng(6)
    model, x = _cart_model(rng, readout_frames=0.4, image_rows=600)
    if prior:  # a pose prior at the truth (tracking): its rows are in the fit and in J
        model = dataclasses.replace(model, prior_mean=x[:4].copy(), prior_scale=30.0)
    x = np.append(x, 0.0)  # with the vertical motion: a steep camera's fit
    turning = np.zeros(12)
    turning[:8], turning[10:12] = x, offsets
    model = dataclasses.replace(model, targets=model.predict(turning))
    idx = np.arange(model.n_points)
    fit, *_ = bundle.fit_lm(model, x, idx)
    moved = np.abs(fit - x)
    assert max(moved[2], moved[3]) > 1e-3  # 0.06°: the shutter's rate matters
    sigma = np.abs(offsets)
    cov = bundle.shutter_rate_covariance(model, x, idx, sigma)
    for angle in (2, 3):  # frame k's pitch, roll
        assert math.sqrt(cov[angle, angle]) == pytest.approx(moved[angle], rel=0.1, abs=1e-5)
    both = bundle.shutter_rate_covariance(model, x, idx, sigma + 0.004)
    np.testing.assert_allclose(both, bundle.shutter_rate_covariance(
        model, x, idx, (sigma[0] + 0.004, 0.0)) + bundle.shutter_rate_covariance(
        model, x, idx, (0.0, sigma[1] + 0.004)), rtol=1e-9, atol=1e-15)
    global_shutter = dataclasses.replace(model, readout_frames=0.0)
    assert not np.any(bundle.shutter_rate_covariance(global_shutter, x, idx, sigma))
    assert not np.any(bundle.shutter_rate_covariance(model, x, idx, np.zeros(2)))


def test_frame_rate_offsets_of_zero_leave_the_rolling_shutter_prediction_unchanged():
    rng = np.random.default_rng(7)
    model, x = _cart_model(rng, readout_frames=0.4, image_rows=600)
    extended = np.zeros(12)
    extended[:7] = x
    np.testing.assert_array_equal(model.predict(extended), model.predict(x))
    extended[8] = 0.01  # frame k-1's pitch rate: moves its ground points, not frame k's pose
    assert np.abs(model.predict(extended) - model.predict(x)).max() > 0.05
    # columns 8–9 are frame k-1's (its row 0 is seen at the pose itself), 10–11 frame k's
    top = dataclasses.replace(model, pixels_prev=np.column_stack(
        [np.linspace(50, 750, 6), np.zeros(6)]), targets=np.zeros((6, 2)))
    for column, moves in ((8, False), (9, False), (10, True), (11, True)):
        extended = np.zeros(12)
        extended[:7], extended[column] = x, 0.01
        moved = np.abs(top.predict(extended) - top.predict(x)).max()
        assert (moved > 1e-2) if moves else (moved < 1e-9), (column, moved)
