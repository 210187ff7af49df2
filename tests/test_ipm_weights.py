"""Noise model of virtual-IPM patches: whitening matrices and the weighted, self-tightening fit."""

from __future__ import annotations

import numpy as np

from vipm_track import bundle, geometry, ipm
from vipm_track import displacement_model as dm
from vipm_track.sim import PRESETS


def _cart_grid() -> tuple[np.ndarray, geometry.GroundPose, geometry.IpmGrid, np.ndarray]:
    cam = PRESETS["cart"].camera()
    pose = geometry.GroundPose(np.radians(45.0), 0.0, 0.7)
    pix = np.stack(np.meshgrid(np.linspace(60, 740, 8), np.linspace(40, 560, 6)),
                   -1).reshape(-1, 2)
    grid = ipm.choose_grid(cam.k, pose, geometry.PlanarMotion(0.0, 0.1, 0.0), pix, 256)
    return cam.k, pose, grid, pix


def test_whitening_inverts_the_modelled_covariance():
    k, pose, grid, pix = _cart_grid()
    a = geometry.ipm_from_image_homography(k, pose, grid)
    q = geometry.apply_homography(a, pix)
    sizes = np.full(len(q), 256)
    sizes[3] = 128
    sizes[5] = 0
    w = ipm.patch_noise_whitening(a, q, sizes, 256)
    jac = geometry.homography_jacobian(a, pix)
    area = np.maximum(1.0, np.abs(np.linalg.det(jac))) ** ipm.NOISE_AREA_POWER
    cov = (np.eye(2) + jac @ np.swapaxes(jac, 1, 2) * area[:, None, None]) * (
        (256 / np.maximum(sizes, 1)) ** 2)[:, None, None]
    white = w @ cov @ np.swapaxes(w, 1, 2)
    used = sizes > 0
    # Σ is whitened up to one common scale (the median patch keeps unit weight).
    scale = white[used, 0, 0]
    np.testing.assert_allclose(white[used], scale[:, None, None] * np.eye(2), atol=1e-9)
    np.testing.assert_allclose(scale, scale[0], rtol=1e-9)
    np.testing.assert_allclose(w[5], np.eye(2))
    # Far-field (magnified) patches and the shrunk one weigh less than near ones.
    gain = np.linalg.norm(w, axis=(1, 2))
    far, near = np.argmin(pix[:, 1]), np.argmax(pix[:, 1])
    assert gain[far] < 0.5 * gain[near]
    assert gain[3] < gain[2]


def test_weighted_fit_trusts_precise_patches_and_drops_a_gross_one():
    k, pose, grid, pix = _cart_grid()
    pc = geometry.GroundPose(pose.pitch + 0.002, 0.001, 0.7)
    mo = geometry.PlanarMotion(0.002, 0.12, 0.003)
    x = dm.pack(pose, pc, mo)
    a = geometry.ipm_from_image_homography(k, pc, grid)
    truth = geometry.apply_homography(a, geometry.predict_pixels(k, pose, pc, mo, pix))
    sizes = np.full(len(pix), 256)
    w = ipm.patch_noise_whitening(a, truth, sizes, 256)
    rng = np.random.default_rng(3)
    # Noise drawn from the model's own covariance (w⁻¹ w⁻ᵀ), 0.01 typical IPM px.
    noise = np.einsum("nij,nj->ni", np.linalg.inv(w), rng.normal(0.0, 0.01, (len(pix), 2)))
    targets = truth + noise
    targets[7] += [0.0, 0.4]  # one patch half on an obstacle: gross for its precision
    plain = dm.DisplacementModel(k, 0.7, pix, targets, plane_from_image=a)
    weighted = dm.DisplacementModel(k, 0.7, pix, targets, plane_from_image=a,
                                        point_whitening=w)
    usable = np.ones(len(pix), bool)
    fit_plain = bundle.robust_fit(plain, x, usable, 0, 1.0, 1.5, np.random.default_rng(0))
    fit_w = bundle.robust_fit(weighted, x, usable, 0, 1.0, 1.5, np.random.default_rng(0),
                              median_factor=6.0)
    assert fit_plain.inliers[7] and not fit_w.inliers[7]
    assert fit_w.inliers.sum() >= len(pix) - 3
    err_plain = np.abs(fit_plain.x - x)[[0, 1, 2, 3]].max()
    err_w = np.abs(fit_w.x - x)[[0, 1, 2, 3]].max()
    assert err_w < 0.5 * err_plain, (np.degrees(err_w), np.degrees(err_plain))
