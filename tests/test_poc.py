"""Batched phase-only correlation: known sub-pixel shifts of real texture photographs."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from vipm_track.poc import (
    PatchSpectra,
    correlate_spectra,
    crop_patches,
    match_patches,
    patch_spectra,
    phase_correlate,
)
from vipm_track.poc_kernels import crop_centre_and_window

TEXTURES = Path(__file__).resolve().parents[1] / "data" / "textures"
NOISE = 2.0  # grey levels


def _texture(name: str) -> np.ndarray:
    path = TEXTURES / f"{name}.png"
    if not path.exists():
        pytest.skip(f"texture photo not found at {path}")
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).astype(np.float64)


def _fourier_shift(image: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    """``image`` moved by (dx, dy) pixels: out(x) = image(x − shift), exact for band-limited
    content. The image is mirrored first so that its periodic extension has no jumps."""
    h, w = image.shape
    big = np.pad(image, ((h // 2, h // 2), (w // 2, w // 2)), mode="symmetric")
    fy = np.fft.fftfreq(big.shape[0])[:, None]
    fx = np.fft.rfftfreq(big.shape[1])[None, :]
    phase = np.exp(-2j * np.pi * (fx * shift[0] + fy * shift[1]))
    moved = np.fft.irfft2(np.fft.rfft2(big) * phase, s=big.shape)
    return moved[h // 2: h // 2 + h, w // 2: w // 2 + w]


def _shifted_pairs(name: str, n: int, size: int | tuple[int, int], max_shift: float,
                   seed: int, noise: float = NOISE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n (ref, moving) patch pairs of a texture with known shifts and noise σ = ``noise``."""
    rng = np.random.default_rng(seed)
    tex = _texture(name)
    ph, pw = (size, size) if isinstance(size, int) else size
    refs, movs, shifts = [], [], []
    for _ in range(n):
        d = rng.uniform(-max_shift, max_shift, 2)
        y0 = rng.integers(40, tex.shape[0] - ph - 40)
        x0 = rng.integers(40, tex.shape[1] - pw - 40)
        region = tex[y0 - 40: y0 + ph + 40, x0 - 40: x0 + pw + 40]
        moved = _fourier_shift(region, (d[0], d[1]))
        refs.append(region[40:-40, 40:-40] + rng.normal(0, noise, (ph, pw)))
        movs.append(moved[40:-40, 40:-40] + rng.normal(0, noise, (ph, pw)))
        shifts.append(d)
    return np.array(refs), np.array(movs), np.array(shifts)


def _rmse(est: np.ndarray, true: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((est - true) ** 2, axis=1))))


@pytest.mark.parametrize("name", ["gravel", "grass", "brick"])
def test_subpixel_shifts_of_real_texture(name: str) -> None:
    ref, mov, true = _shifted_pairs(name, 16, 128, 2.5, seed=1)
    shift, peak = phase_correlate(ref, mov)
    assert shift.shape == (16, 2) and peak.shape == (16,)
    assert _rmse(shift, true) < 0.03
    assert np.abs(shift - true).max() < 0.1
    assert (peak > 0.5).all()


def test_sign_convention_integer_crop() -> None:
    tex = _texture("gravel")
    ref = tex[200:328, 200:328]
    mov = tex[197:325, 205:333]  # mov(i, j) = tex(197 + i, 205 + j) = ref(i - 3, j + 5)
    shift, peak = phase_correlate(ref, mov)
    np.testing.assert_allclose(shift, [-5.0, 3.0], atol=0.02)
    assert peak > 0.9


def test_batch_equals_single_pairs_and_single_shapes() -> None:
    ref, mov, _ = _shifted_pairs("grass", 5, 128, 3.0, seed=2)
    shift, peak = phase_correlate(ref, mov)
    for k in range(5):
        s, p = phase_correlate(ref[k], mov[k])
        assert s.shape == (2,) and isinstance(p, float)
        np.testing.assert_allclose(s, shift[k], atol=1e-4)
        assert p == pytest.approx(peak[k], abs=1e-4)


def test_reused_spectra_give_the_same_result() -> None:
    ref, mov, true = _shifted_pairs("gravel", 6, 128, 2.0, seed=3)
    spectra = patch_spectra(ref)
    assert isinstance(spectra, PatchSpectra) and len(spectra) == 6
    a, pa = phase_correlate(None, mov, ref_spectra=spectra)
    b, pb = correlate_spectra(spectra, patch_spectra(mov))
    np.testing.assert_allclose(pb, pa, atol=1e-6)
    c, pc = phase_correlate(ref, mov)
    np.testing.assert_allclose(a, c, atol=1e-6)
    np.testing.assert_allclose(b, c, atol=1e-6)
    np.testing.assert_allclose(pa, pc, atol=1e-6)
    sub, _ = correlate_spectra(spectra[2:4], patch_spectra(mov[2:4]))
    np.testing.assert_allclose(sub, c[2:4], atol=1e-6)
    assert _rmse(c, true) < 0.03


@pytest.mark.parametrize("shape", [(128, 128), (64, 80), (45, 33)])
def test_band_spectra_equal_the_2d_dft(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(9)
    patches = rng.normal(100, 20, (3, *shape)).astype(np.float32)
    spectra = patch_spectra(patches, band=0.5, window=False)
    ky, kx = int(0.5 * shape[0] / 2), int(0.5 * shape[1] / 2)
    ref = np.fft.rfft2(patches - patches.mean(axis=(1, 2), keepdims=True))
    rows = np.r_[0:ky, shape[0] - ky + 1: shape[0]]
    expected = ref[:, rows, :kx]
    assert spectra.spectra.shape == expected.shape
    np.testing.assert_allclose(spectra.spectra, expected, atol=1e-3 * np.abs(expected).max())


@pytest.mark.parametrize("size", [256, (96, 128), (64, 80)])
def test_other_patch_sizes(size: int | tuple[int, int]) -> None:
    ref, mov, true = _shifted_pairs("gravel", 6, size, 2.0, seed=4)
    shift, peak = phase_correlate(ref, mov)
    assert _rmse(shift, true) < 0.05
    assert (peak > 0.5).all()


def test_peak_separates_matching_from_unrelated_patches() -> None:
    ref, mov, _ = _shifted_pairs("gravel", 8, 128, 2.0, seed=5)
    other, _, _ = _shifted_pairs("brick", 8, 128, 2.0, seed=6)
    _, matching = phase_correlate(ref, mov)
    _, unrelated = phase_correlate(ref, other)
    assert matching.min() > 0.8
    assert unrelated.max() < 0.15


def test_bad_patches_get_zero_peak_and_do_not_spoil_the_batch() -> None:
    ref, mov, true = _shifted_pairs("grass", 4, 128, 2.0, seed=7)
    mov[1, 10, 20] = np.nan
    ref[2] = 77.0  # constant patch
    mov[3, :, :] = np.inf
    shift, peak = phase_correlate(ref, mov)
    assert peak[0] > 0.8 and np.abs(shift[0] - true[0]).max() < 0.1
    assert (peak[1:] == 0).all()
    assert np.isnan(shift[1:]).all()
    texture = patch_spectra(ref).texture
    assert texture[2] == 0 and texture[0] > 5


def test_shape_mismatch_and_bad_arguments_raise() -> None:
    a = np.zeros((3, 64, 64))
    with pytest.raises(ValueError, match="differ in shape"):
        phase_correlate(a, np.zeros((3, 64, 32)))
    with pytest.raises(ValueError, match="differ in shape"):
        phase_correlate(a, np.zeros((2, 64, 64)))
    with pytest.raises(ValueError, match=r"\(N, H, W\)"):
        phase_correlate(np.zeros(64), np.zeros(64))
    with pytest.raises(ValueError, match="band"):
        phase_correlate(a, a, band=0.0)
    with pytest.raises(ValueError, match="equal batches"):
        correlate_spectra(patch_spectra(a), patch_spectra(a, band=0.8))
    with pytest.raises(ValueError, match="2-D grey image"):
        crop_patches(np.zeros((10, 10, 3)), [[5, 5]], 4)
    with pytest.raises(ValueError, match="centres"):
        crop_patches(np.zeros((10, 10)), [[5, 5, 5]], 4)
    with pytest.raises(ValueError, match="offsets"):
        match_patches(np.zeros((64, 64)), np.zeros((64, 64)), [[32, 32]], 16, [[1, 2, 3]])
    with pytest.raises(ValueError, match="weighting"):
        phase_correlate(a, a, weighting=-0.5)


def test_empty_batches_give_empty_results() -> None:
    shift, peak = phase_correlate(np.zeros((0, 16, 16)), np.zeros((0, 16, 16)))
    assert shift.shape == (0, 2) and peak.shape == (0,)
    shift, peak = match_patches(np.zeros((64, 64)), np.zeros((64, 64)), np.zeros((0, 2)), 16)
    assert shift.shape == (0, 2) and peak.shape == (0,)


def test_crop_patches_matches_slices_and_flags_patches_leaving_the_image() -> None:
    image = np.arange(60 * 80, dtype=np.uint16).reshape(60, 80)
    centres = np.array([[40.0, 30.0], [10.4, 9.6], [5.0, 30.0], [40.0, 57.0], [np.nan, 30.0]])
    patches, inside = crop_patches(image, centres, (16, 20), return_mask=True)
    assert patches.dtype == np.float32 and patches.shape == (5, 16, 20)
    np.testing.assert_array_equal(inside, [True, True, False, False, False])
    np.testing.assert_array_equal(patches[0], image[22:38, 30:50])
    np.testing.assert_array_equal(patches[1], image[2:18, 0:20])
    assert np.isnan(patches[2:]).all()
    square = crop_patches(image, centres[:1], 9)
    np.testing.assert_array_equal(square[0], image[26:35, 36:45])


def test_patches_that_cannot_be_correlated_are_prepared_as_zeros() -> None:
    # the batch is allocated without zeroing it: a patch leaving the image or holding a NaN
    # must still come out as zeros, not as whatever the memory held before — here the
    # kernel's own freed output of the call before, whose usable patches sat where this
    # call's unusable ones are
    image = np.add.outer(np.arange(64.0), 3.0 * np.arange(64.0)).astype(np.float32)
    image[40, 40] = np.nan
    ok, out, nan = [0, 0], [60, 0], [32, 32]
    win = np.ones((16, 16), np.float32)
    for k in range(6):
        corners = np.array([ok, out, nan, ok] if k % 2 else [out, ok, ok, nan], np.int64)
        usable_expected = np.array([c == ok for c in corners.tolist()])
        patches, usable = crop_centre_and_window(image, corners, win)
        np.testing.assert_array_equal(usable, usable_expected)
        assert not patches[~usable].any()
        expected = image[:16, :16] - image[:16, :16].mean()
        np.testing.assert_allclose(patches[usable], [expected] * 2, atol=1e-4)


def test_match_patches_recovers_a_large_shift_with_offsets() -> None:
    tex = _texture("gravel")
    true = np.array([40.3, -25.7])
    moved = _fourier_shift(tex, (true[0], true[1]))
    rng = np.random.default_rng(8)
    img_ref = tex + rng.normal(0, NOISE, tex.shape)
    img_mov = moved + rng.normal(0, NOISE, tex.shape)
    centres = np.array([[200.0, 260.0], [260.0, 300.0], [300.0, 220.0], [100.0, 70.0]])
    shift, peak = match_patches(img_ref, img_mov, centres, 128, offsets=[38.6, -24.2])
    # The last patch's moving window (centre + offset) leaves the image's top edge.
    assert peak[3] == 0 and np.isnan(shift[3]).all()
    assert (peak[:3] > 0.7).all()
    np.testing.assert_allclose(shift[:3], np.tile(true, (3, 1)), atol=0.06)
    offsets = np.array([[33.0, -20.0], [33.0, -20.0], [np.nan, np.nan]])
    again, peak = match_patches(img_ref, img_mov, centres[:3], 128, offsets, recentre=True)
    np.testing.assert_allclose(again[:2], np.tile(true, (2, 1)), atol=0.06)
    assert peak[2] == 0 and np.isnan(again[2]).all()


def test_centres_beyond_the_int64_range_leave_the_image() -> None:
    """A centre or offset so far out that its pixel overflows int64 (a diverged prediction)
    gives a patch outside the image (peak 0), not a crop read past the image's memory."""
    rng = np.random.default_rng(3)
    image = rng.uniform(0, 255, (120, 160))
    centres = np.array([[80.0, 60.0], [80.0, 60.0], [80.0, 60.0], [1e19, 60.0]])
    offsets = np.array([[0.0, 0.0], [1e19, 0.0], [0.0, -3e19], [0.0, 0.0]])
    shift, peak = match_patches(image, image, centres, 32, offsets)
    assert peak[0] > 0.99
    np.testing.assert_array_equal(peak[1:], 0.0)
    assert np.isnan(shift[1:]).all()
    patches, inside = crop_patches(image, centres + offsets, 32, return_mask=True)
    np.testing.assert_array_equal(inside, [True, False, False, False])
    assert np.isnan(patches[1:]).all()


@pytest.mark.parametrize("weighting", [0.0, 0.5, 1.0])
def test_large_grey_levels_do_not_overflow_the_cross_power(weighting: float) -> None:
    """Patches of grey levels ~1e9 (float images in large units): their cross-power
    magnitudes pass float32's range only when squared; the shifts are those at unit scale."""
    rng = np.random.default_rng(6)
    tex = cv2.GaussianBlur(rng.normal(0, 1, (64, 64)), (0, 0), 1.5)
    ref, mov = tex[8:40, 8:40], tex[9:41, 6:38]
    unit = phase_correlate(ref, mov, weighting=weighting)
    scaled = phase_correlate(ref * 1e10, mov * 1e10, weighting=weighting)
    assert unit[1] > 0.9
    np.testing.assert_allclose(scaled[0], unit[0], atol=1e-3)
    assert abs(scaled[1] - unit[1]) < 1e-3


def _box_blurred(patches: np.ndarray, rows: int) -> np.ndarray:
    """``patches`` smeared along the columns by a box ``rows`` pixels long (centred: a
    pitch rate during the exposure), mirrored at the edges."""
    kernel = np.ones((rows, 1)) / rows
    return np.array([cv2.filter2D(p, -1, kernel, borderType=cv2.BORDER_REFLECT)
                     for p in patches])


@pytest.mark.parametrize("name", ["gravel", "grass", "brick"])
def test_blur_invariant_poc_is_not_pulled_off_by_a_blur_only_one_patch_has(name: str) -> None:
    ref, mov, true = _shifted_pairs(name, 16, 128, 2.5, seed=4)
    blurred = _box_blurred(mov, 9)
    plain, _ = correlate_spectra(patch_spectra(ref), patch_spectra(blurred))
    invariant, peak = correlate_spectra(patch_spectra(ref), patch_spectra(blurred),
                                        blur_invariant=True)
    # the box's negative lobe turns the phase of the band's upper vertical frequencies by π:
    # the plain peak splits and moves along the smear by pixels
    assert _rmse(plain, true) > 0.5
    assert _rmse(invariant, true) < 0.15 and _rmse(invariant, true) < _rmse(plain, true) / 5
    assert (peak > 0.3).all()


def test_blur_invariant_poc_equals_the_plain_one_on_sharp_patches() -> None:
    ref, mov, true = _shifted_pairs("gravel", 16, 128, 2.5, seed=5)
    plain, plain_peak = correlate_spectra(patch_spectra(ref), patch_spectra(mov))
    invariant, peak = correlate_spectra(patch_spectra(ref), patch_spectra(mov),
                                        blur_invariant=True)
    np.testing.assert_allclose(invariant, plain, atol=0.01)
    assert _rmse(invariant, true) < 0.03
    assert (peak > 0.5).all() and (peak <= plain_peak + 1e-6).all()


@pytest.mark.parametrize("true", [(36.3, -3.2), (-2.6, -37.1), (-35.5, 4.4), (33.2, 33.9)])
def test_blur_invariant_poc_takes_the_right_one_of_the_two_halved_shifts(
        true: tuple[float, float]) -> None:
    """Twice the shift is known modulo the patch: a shift beyond a quarter of it doubles to
    the same peak as one half a patch away, and the plain POC function tells them apart
    (beyond a quarter on both axes the windows share so little that the invariant peak is
    near the noise: the estimator's refinements place their windows on the predicted shift)."""
    tex = _texture("gravel")
    moved = _fourier_shift(tex, true)
    centres = np.array([[200.0, 260.0], [260.0, 300.0], [300.0, 220.0]])
    shift, peak = match_patches(tex, moved, centres, 128, blur_invariant=True)
    assert (peak > 0.08).all()
    np.testing.assert_allclose(shift, np.tile(true, (3, 1)), atol=0.25)


@pytest.mark.parametrize("name", ["gravel", "grass"])
def test_blur_invariant_sub_pixel_fit_trusts_the_strong_frequencies_too(name: str) -> None:
    """The squared phasors keep the sub-pixel fit's spectral weights: on small noisy patches
    (σ 12 grey levels, 64²) they cut the invariant shift's error as they cut the plain one's."""
    ref, mov, true = _shifted_pairs(name, 32, 64, 2.0, seed=7, noise=12.0)
    rmse = {w: _rmse(correlate_spectra(patch_spectra(ref), patch_spectra(mov), weighting=w,
                                       blur_invariant=True)[0], true) for w in (0.0, 0.5)}
    assert rmse[0.5] < 0.85 * rmse[0.0], rmse


@pytest.mark.parametrize("true", [(36.3, -3.2), (-2.6, -37.1)])
def test_blur_invariant_poc_takes_the_halved_shift_where_the_plain_peak_is_negative(
        true: tuple[float, float]) -> None:
    """A blur whose transfer function is negative where the texture's energy lies turns the
    plain POC function's peak at the true shift negative; the alias is chosen by its
    magnitude, not its sign. Here the extreme case: the moved image's contrast inverted (a
    point spread function of −δ, transfer −1 at every frequency)."""
    tex = _texture("gravel")
    moved = 255.0 - _fourier_shift(tex, true)
    centres = np.array([[200.0, 260.0], [260.0, 300.0], [300.0, 220.0]])
    shift, peak = match_patches(tex, moved, centres, 128, blur_invariant=True)
    assert (peak > 0.08).all()
    np.testing.assert_allclose(shift, np.tile(true, (3, 1)), atol=0.25)
