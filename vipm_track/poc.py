"""Batched phase-only correlation (POC) with sub-pixel accuracy.

The translation between two patches is the location of the peak of their phase-only
correlation function (Kuglin & Hines 1975; Takita et al. 2003). This module computes it
for a whole batch of patch pairs at once:

1. each patch has its (window-weighted) mean removed and is multiplied by a Hann window;
   the whole batch is transformed at once in float32 (one ``cv2.dft`` call for the rows of
   all patches, one ``scipy.fft`` call for the columns), and only the band kept by step 2
   is computed and stored (:class:`PatchSpectra`: made once per set of patches, reusable,
   e.g. when a frame's patches are the moving ones of one pair and the reference ones of
   the next);
2. the normalised cross-power spectrum ``R = F_mov · conj(F_ref) / |F_mov · conj(F_ref)|``
   is band-limited (Takita et al. 2003, BLPOC): frequencies above ``band`` × Nyquist on
   either axis, where noise and aliasing dominate, are dropped, and so is DC;
3. one inverse FFT of the band, on the smallest grid that holds it exactly, samples the
   band-limited POC surface; its highest sample, refined by a parabola, is the coarse shift;
4. the sub-pixel shift maximises the continuous band-limited POC function
   ``r(d) = Σ_u w(u) Re(R(u) · exp(2πi u·d))`` by a few batched Newton steps from the coarse
   peak (two, the default, suffice from the parabola start). With ``w = 1`` this is the peak that
   Takita's peak-model fit approximates; the default weights ``w = |F_mov F_ref|^0.5``
   (partial whitening) trust the strong, less noisy frequencies more and halve the error
   on weakly textured patches;
5. optionally (``blur_invariant``), blur-invariant phase correlation (Ojansivu & Heikkilä
   2007): a centrally symmetric blur (a box along the image motion during the exposure)
   multiplies a spectrum by a real transfer function whose negative lobes turn those
   frequencies' phases by π. Where the two patches are blurred differently (a body that
   pitches faster in one frame than in the other), those frequencies pull the plain peak
   off the shift (steps 3–4). Squaring each phasor of R doubles its phase and removes the π:
   the same steps on R² find twice the shift, modulo the patch; of the two shifts per
   axis that double to it, the one where the plain POC function is largest in magnitude
   is taken.

Sign convention (as ``CONVENTIONS.md``'s image coordinates: x right, y down, pixels):
``shift = (dx, dy)`` is the displacement of the content from ``ref`` to ``moving``,
``moving(x) ≈ ref(x − shift)``. ``peak`` is the height of the POC peak at the sub-pixel
shift, normalised so that identical content gives 1; unrelated patches give about
``1/sqrt(number of band frequencies)``, i.e. a few hundredths. Patches that cannot be
correlated (a NaN, a constant patch, a patch that leaves the image) get ``peak = 0`` and a
NaN shift; nothing in a batch fails because one patch is bad.

Any patch shape (H, W) with H, W ≥ 8 works, square or not; FFT speed is best for sizes with
small prime factors (powers of two such as 128 and 256).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray

from . import poc_kernels

FloatArray = NDArray[np.float64]

#: Default fraction of the Nyquist frequency kept by the band limit (per axis).
DEFAULT_BAND = 0.5
#: Default number of Newton iterations of the sub-pixel refinement.
DEFAULT_ITERATIONS = 2
#: Default exponent of the spectral weights of the sub-pixel fit (see correlate_spectra).
DEFAULT_WEIGHTING = 0.5
#: Patches whose band-passed RMS (grey levels) is below this have no texture to correlate.
MIN_TEXTURE = 1e-3
#: Smallest patch side, pixels.
MIN_SIZE = 8


def _default_workers() -> int:
    # One thread: the heavy transform is cv2's (its own pool); scipy's remaining transforms
    # are small, and its threads stall on a busy machine more than they gain.
    return 1


@dataclass(frozen=True)
class PatchSpectra:
    """Band-limited, windowed spectra of a batch of patches, ready to be correlated.

    Attributes
    ----------
    spectra : ndarray, complex64, shape (N, 2·Ky − 1, Kx)
        2-D DFT of each mean-removed, windowed patch on the band only, in ``rfft2`` order:
        rows are the vertical frequencies 0 … Ky − 1, −(Ky − 1) … −1, columns the horizontal
        frequencies 0 … Kx − 1 (the negative ones are the complex conjugates), in cycles per
        patch; Ky = floor(band·H/2), Kx = floor(band·W/2).
    valid : ndarray, bool, shape (N,)
        False for patches that cannot be correlated (a NaN or inf, no texture in the band).
    texture : ndarray, shape (N,)
        RMS of the band-passed, windowed patch in grey levels (0 for invalid patches): how
        much there is to correlate.
    shape : tuple of int
        Patch shape (H, W), pixels.
    band : float
        Fraction of the Nyquist frequency kept on each axis.
    """

    spectra: NDArray[np.complex64]
    valid: NDArray[np.bool_]
    texture: FloatArray
    shape: tuple[int, int]
    band: float

    def __len__(self) -> int:
        return int(self.spectra.shape[0])

    def __getitem__(self, index: slice | ArrayLike) -> PatchSpectra:
        """Return the spectra of a subset of the patches (slice, indices or boolean mask)."""
        return PatchSpectra(self.spectra[index], self.valid[index], self.texture[index],
                            self.shape, self.band)


def patch_spectra(patches: ArrayLike, *, band: float = DEFAULT_BAND, window: bool = True,
                  workers: int | None = None) -> PatchSpectra:
    """Return the band-limited, windowed spectra of a batch of patches (reusable).

    Parameters
    ----------
    patches : array_like, shape (N, H, W) or (H, W)
        Grey patches (any real dtype, grey levels), H, W ≥ 8. A patch with a NaN or inf
        anywhere is marked invalid (not an error: one bad patch must not sink a batch).
    band : float
        Fraction (0, 1] of the Nyquist frequency kept on each axis (band-limited POC).
    window : bool
        Multiply by a 2-D Hann window (against the edge discontinuities of the FFT's
        periodic extension). Switch off only for periodic content.
    workers : int, optional
        Threads of ``scipy.fft`` for the column transforms; default 1 (the row transforms
        run in OpenCV's own thread pool).

    Returns
    -------
    PatchSpectra
    """
    arr = _as_batch(patches, "patches")
    _, h, w = arr.shape
    win = _window(h, w, window)
    # the batch as one tall image, each patch one crop of it
    corners = np.column_stack([np.zeros(len(arr), np.int64), h * np.arange(len(arr))])
    centred, finite = poc_kernels.crop_centre_and_window(arr.reshape(-1, w), corners, win)
    return _spectra(centred, finite, win, band, workers)


def correlate_spectra(ref: PatchSpectra, moving: PatchSpectra, *,
                      iterations: int = DEFAULT_ITERATIONS, weighting: float = DEFAULT_WEIGHTING,
                      blur_invariant: bool = False, workers: int | None = None,
                      ) -> tuple[FloatArray, FloatArray]:
    """Return the sub-pixel shifts and POC peak heights between two batches of spectra.

    Parameters
    ----------
    ref, moving : PatchSpectra
        Spectra of N reference and N moving patches of the same shape and band.
    iterations : int
        Newton iterations of the sub-pixel refinement (0: the coarse peak only).
    weighting : float
        Exponent α of the spectral weights ``|F_mov · F_ref|^α`` of the sub-pixel fit:
        0 is pure POC (every frequency counts the same); larger values trust the strong
        frequencies, whose phase is less noisy, more (beyond 1 the window's leakage at the
        lowest frequencies starts to dominate and biases the shift).
    blur_invariant : bool
        Correlate the phases modulo π (module doc, step 5): the shift of content blurred
        differently in the two patches, by any centrally symmetric blur, is not biased; the
        peak is then that of the blur-invariant POC function.
    workers : int, optional
        Threads of ``scipy.fft``.

    Returns
    -------
    shift : ndarray, shape (N, 2)
        (dx, dy) in pixels, ``moving(x) ≈ ref(x − shift)``; NaN where ``peak`` is 0.
    peak : ndarray, shape (N,)
        Band-limited POC peak height at ``shift``: 1 for identical content, about
        ``1/sqrt(number of band frequencies)`` for unrelated content, 0 for unusable pairs.
    """
    if not weighting >= 0:
        raise ValueError(f"weighting must be >= 0, got {weighting}")
    if ref.shape != moving.shape or len(ref) != len(moving) or ref.band != moving.band:
        raise ValueError(
            f"phase correlation needs equal batches of equal patch shapes and bands: ref has "
            f"{len(ref)} patches of {ref.shape} (band {ref.band}), moving has {len(moving)} "
            f"of {moving.shape} (band {moving.band})")
    h, w = ref.shape
    layout = _band_layout(h, w, ref.band)
    n = len(ref)
    shift = np.full((n, 2), np.nan)
    peak = np.zeros(n)
    ok = np.flatnonzero(ref.valid & moving.valid)
    if ok.size == 0:
        return shift, peak
    # Coarse: the band-limited POC surface sampled on the smallest grid that holds the band
    # (one inverse FFT for the batch); its highest sample is within a grid step of the peak.
    # Fine: Newton ascent on the (weighted) continuous POC function from there.
    r, rw, small = poc_kernels.cross_power(
        _interleaved(ref), _interleaved(moving), ok, layout.hermitian,
        layout.small_rows, layout.grid, float(weighting))
    if blur_invariant:
        plain = r
        r, rw, small = poc_kernels.squared_phasors(r, rw, layout.hermitian, layout.small_rows,
                                                   layout.grid)
    surface = scipy.fft.irfft2(small, s=layout.grid, workers=workers or _default_workers())
    d, value = poc_kernels.subpixel_peaks(surface, r, rw, layout.uy, layout.ux, (h, w),
                                          int(iterations))
    if blur_invariant:
        d = poc_kernels.halved_shifts(d, plain, layout.uy, layout.ux, (h, w))
    value /= layout.n_frequencies
    usable = (value > 0) & (np.abs(d) < [w / 2, h / 2]).all(axis=1)
    shift[ok[usable]] = d[usable]
    peak[ok[usable]] = value[usable]
    return shift, peak


def phase_correlate(ref: ArrayLike | None, moving: ArrayLike, *, band: float = DEFAULT_BAND,
                    iterations: int = DEFAULT_ITERATIONS, weighting: float = DEFAULT_WEIGHTING,
                    window: bool = True, ref_spectra: PatchSpectra | None = None,
                    workers: int | None = None) -> tuple[FloatArray, FloatArray | float]:
    """Return the sub-pixel shift and POC peak of each pair of patches.

    Parameters
    ----------
    ref, moving : array_like, shape (N, H, W) or (H, W)
        Reference and moving grey patches (grey levels). ``ref`` may be None when
        ``ref_spectra`` is given.
    band : float
        Fraction (0, 1] of the Nyquist frequency kept on each axis (band-limited POC).
    iterations : int
        Newton iterations of the sub-pixel refinement.
    weighting : float
        Exponent of the spectral weights of the sub-pixel fit (see :func:`correlate_spectra`).
    window : bool
        Hann-window the patches (default).
    ref_spectra : PatchSpectra, optional
        Precomputed spectra of ``ref`` (from :func:`patch_spectra`), reused instead.
    workers : int, optional
        Threads of ``scipy.fft``.

    Returns
    -------
    shift : ndarray, shape (N, 2), or (2,) for a single (H, W) pair
        (dx, dy) in pixels, the displacement of the content from ``ref`` to ``moving``:
        ``moving(x) ≈ ref(x − shift)``. NaN where ``peak`` is 0.
    peak : ndarray, shape (N,), or a float for a single pair
        POC peak height: 1 for identical content, a few hundredths for unrelated content,
        0 for unusable pairs (a NaN, a constant patch).

    Raises
    ------
    ValueError
        If the shapes of ``ref`` and ``moving`` differ, or are not (N, H, W) / (H, W).
    """
    single = np.ndim(moving) == 2
    if ref_spectra is None:
        if ref is None:
            raise ValueError("phase_correlate needs ref patches or ref_spectra")
        if np.shape(ref) != np.shape(moving):
            raise ValueError(f"ref and moving patches differ in shape: {np.shape(ref)} vs "
                             f"{np.shape(moving)}")
        ref_spectra = patch_spectra(ref, band=band, window=window, workers=workers)
    mov = patch_spectra(moving, band=ref_spectra.band, window=window, workers=workers)
    shift, peak = correlate_spectra(ref_spectra, mov, iterations=iterations,
                                    weighting=weighting, workers=workers)
    if single:
        return shift[0], float(peak[0])
    return shift, peak


def crop_patches(image: ArrayLike, centres: ArrayLike, size: int | tuple[int, int], *,
                 return_mask: bool = False,
                 ) -> NDArray[np.float32] | tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Return patches of ``image`` centred on ``centres``, as float32.

    Parameters
    ----------
    image : array_like, shape (H, W)
        Grey image.
    centres : array_like, shape (N, 2)
        Patch centres (x, y) in pixels, rounded to the nearest pixel (halves up); a NaN
        centre gives a NaN patch (like one that leaves the image). The patch
        of size (h, w) centred on pixel (cx, cy) spans columns ``cx - w//2 … cx - w//2 + w - 1``
        (the centre pixel is the patch's pixel (w//2, h//2)), likewise rows.
    size : int or (h, w)
        Patch size in pixels (an int for square patches; (rows, columns) otherwise).
    return_mask : bool
        Also return the mask of patches that lie entirely inside the image.

    Returns
    -------
    patches : ndarray, float32, shape (N, h, w)
        Patches that would leave the image are all NaN (never clamped), so that
        :func:`phase_correlate` gives them zero peak.
    inside : ndarray, bool, shape (N,)
        Only with ``return_mask``.
    """
    img = _grey_image(image)
    ph, pw = _patch_size(size)
    corner = _corners(_as_points(centres, "centres"), ph, pw)
    height, width = img.shape
    inside = ((corner[:, 0] >= 0) & (corner[:, 1] >= 0)
              & (corner[:, 0] + pw <= width) & (corner[:, 1] + ph <= height))
    # slice copies into an uninitialised batch: half the memory traffic of a NaN-filled
    # batch overwritten by a fancy-indexed gather
    patches = np.empty((len(corner), ph, pw), np.float32)
    for i in np.flatnonzero(inside):
        x, y = corner[i]
        patches[i] = img[y: y + ph, x: x + pw]
    patches[~inside] = np.nan
    return (patches, inside) if return_mask else patches


def match_patches(img_ref: ArrayLike, img_moving: ArrayLike, centres_ref: ArrayLike,
                  size: int | tuple[int, int], offsets: ArrayLike | None = None, *,
                  band: float = DEFAULT_BAND, iterations: int = DEFAULT_ITERATIONS,
                  weighting: float = DEFAULT_WEIGHTING, recentre: bool = False,
                  blur_invariant: bool = False, workers: int | None = None,
                  ) -> tuple[FloatArray, FloatArray]:
    """Return the displacement of each patch from ``img_ref`` to ``img_moving``.

    Reference patches are cropped at ``centres_ref``, moving patches at
    ``centres_ref + round(offsets)`` (a predicted displacement, so that large motions stay
    inside the patch); the result is the integer offset plus the measured residual shift.

    Parameters
    ----------
    img_ref, img_moving : array_like, shape (H, W)
        Grey images (previous and current frame, or their IPM images).
    centres_ref : array_like, shape (N, 2)
        Patch centres (x, y) in ``img_ref``, pixels.
    size : int or (h, w)
        Patch size, pixels.
    offsets : array_like, shape (N, 2) or (2,), optional
        Predicted displacements (dx, dy), pixels; default zero. NaN rows (no prediction)
        give those patches peak 0.
    recentre : bool
        Crop the moving patches a second time at the rounded measured displacement and
        measure again: the residual shift is then below half a pixel, where the window
        biases it least. Costs a second correlation.
    band, iterations, weighting, workers
        As :func:`phase_correlate`.
    blur_invariant : bool
        As :func:`correlate_spectra`.

    Returns
    -------
    shift : ndarray, shape (N, 2)
        Displacement (dx, dy) in pixels of each patch's content:
        ``img_moving(x + shift) ≈ img_ref(x)`` around ``centres_ref``.
        NaN where ``peak`` is 0 (a patch leaves an image, or cannot be correlated).
    peak : ndarray, shape (N,)
        POC peak height (confidence), 0 for unusable patches.
    """
    centres = _as_points(centres_ref, "centres_ref")  # NaN rows: peak 0
    if offsets is None:
        offset = np.zeros_like(centres)
    else:
        offset = np.asarray(offsets, np.float64)
        if offset.shape not in ((2,), centres.shape):
            raise ValueError(f"offsets must have shape (2,) or {centres.shape}, got "
                             f"{offset.shape}")
        offset = np.broadcast_to(offset, centres.shape)
    offset = np.floor(offset + 0.5)  # a NaN offset makes a NaN centre: that patch gets peak 0
    ref_spec = _cropped_spectra(img_ref, centres, size, band, workers)
    mov_spec = _cropped_spectra(img_moving, centres + offset, size, band, workers)
    residual, peak = correlate_spectra(ref_spec, mov_spec, iterations=iterations,
                                       weighting=weighting, blur_invariant=blur_invariant,
                                       workers=workers)
    shift = offset + residual
    if recentre:
        # only patches whose rounded displacement moved are cropped anew: the others' second
        # crop would be the first one
        moved = np.flatnonzero((peak > 0) & np.any(np.floor(shift + 0.5) != offset, axis=1))
        if moved.size:
            at = np.floor(shift[moved] + 0.5)
            again = _cropped_spectra(img_moving, centres[moved] + at, size, band, workers)
            residual, peak[moved] = correlate_spectra(ref_spec[moved], again,
                                                      iterations=iterations,
                                                      weighting=weighting,
                                                      blur_invariant=blur_invariant,
                                                      workers=workers)
            shift[moved] = at + residual
    return shift, peak


# --------------------------------------------------------------------------- helpers


def _corners(points: FloatArray, ph: int, pw: int) -> NDArray[np.int64]:
    """Top-left pixels (x, y) of (ph, pw) patches centred on ``points`` (rounded, halves
    up); a NaN centre, or one too far out for int64 pixels (a diverged prediction), gets a
    corner left of every image."""
    known = (np.abs(points) < 2.0**40).all(axis=1)  # False for NaN
    corner = np.full(points.shape, -(1 << 40), np.int64)
    corner[known] = np.floor(points[known] + 0.5).astype(np.int64) - [pw // 2, ph // 2]
    return corner


def _cropped_spectra(image: ArrayLike, centres: FloatArray, size: int | tuple[int, int],
                     band: float, workers: int | None) -> PatchSpectra:
    """:func:`patch_spectra` of ``crop_patches(image, centres, size)``, without the copies."""
    img = _grey_image(image)
    ph, pw = _patch_size(size)
    _check_patch_shape(ph, pw, "patches")
    win = _window(ph, pw, True)
    centred, finite = poc_kernels.crop_centre_and_window(
        np.ascontiguousarray(img, np.float32), _corners(centres, ph, pw), win)
    return _spectra(centred, finite, win, band, workers)


#: Largest spectral magnitude the cross-power kernel takes: it squares |F_mov · F_ref| in
#: float32 (and its vectorised 1/sqrt turns an overflowed square into NaN)
_MAX_MAGNITUDE = 2.0**28


def _interleaved(spectra: PatchSpectra) -> NDArray[np.float32]:
    """Complex spectra as float32 (…, 2·K) re, im pairs, as the kernels read them. Patches
    whose magnitudes may pass :data:`_MAX_MAGNITUDE` (grey levels beyond ~1e7) are scaled
    by a power of two, which is exact: their correlation is unchanged."""
    out = np.ascontiguousarray(spectra.spectra).view(np.float32)
    # |F| ≤ sqrt(band power) = texture · sqrt(h·w·Σ window²) ≤ texture · h·w
    big = np.flatnonzero(spectra.texture * float(np.prod(spectra.shape)) > _MAX_MAGNITUDE)
    if big.size:
        out = out.copy()
        largest = np.abs(out[big]).max(axis=(1, 2)).astype(np.float64)
        halvings = np.ceil(np.log2(np.maximum(largest, _MAX_MAGNITUDE) / _MAX_MAGNITUDE))
        out[big] = np.ldexp(out[big], -halvings.astype(np.int32)[:, None, None])
    return out


def _spectra(centred: NDArray[np.float32], finite: NDArray[np.bool_],
             win: NDArray[np.float32], band: float, workers: int | None) -> PatchSpectra:
    """The :class:`PatchSpectra` of mean-removed, windowed patches."""
    _, h, w = centred.shape
    layout = _band_layout(h, w, band)
    spectra, power = _band_spectra(centred, layout, workers or _default_workers())
    texture = np.sqrt(np.maximum(power, 0) / (h * w * float(np.square(win).sum())))
    valid = finite & (texture > MIN_TEXTURE)
    texture = np.where(valid, texture, 0.0)
    return PatchSpectra(spectra, valid, texture, (h, w), float(band))


def _as_batch(patches: ArrayLike, name: str) -> NDArray[np.float32]:
    arr = np.asarray(patches)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise ValueError(f"{name} must have shape (N, H, W) or (H, W), got {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
            or arr.dtype == np.bool_):
        raise ValueError(f"{name} must be real numbers, got dtype {arr.dtype}")
    _check_patch_shape(arr.shape[1], arr.shape[2], name)
    return np.ascontiguousarray(arr, np.float32)


def _check_patch_shape(h: int, w: int, name: str) -> None:
    if h < MIN_SIZE or w < MIN_SIZE:
        raise ValueError(f"{name} must be at least {MIN_SIZE}×{MIN_SIZE} pixels, got "
                         f"{h}×{w}")


def _grey_image(image: ArrayLike) -> NDArray:
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"crop_patches needs a 2-D grey image, got shape {img.shape}")
    return img


def _as_points(points: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(points, np.float64)
    if arr.shape == (2,):
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2) as (x, y) pixels, got {arr.shape}")
    return arr


def _patch_size(size: int | tuple[int, int]) -> tuple[int, int]:
    ph, pw = (size, size) if np.isscalar(size) else tuple(size)  # type: ignore[misc]
    if int(ph) != ph or int(pw) != pw or ph < 1 or pw < 1:
        raise ValueError(f"patch size must be positive integers, got {size}")
    return int(ph), int(pw)


def _window(h: int, w: int, hann: bool) -> NDArray[np.float32]:
    return _hann(h, w) if hann else _flat(h, w)


@lru_cache(maxsize=16)
def _flat(h: int, w: int) -> NDArray[np.float32]:
    win = np.ones((h, w), np.float32)
    win.flags.writeable = False
    return win


@lru_cache(maxsize=16)
def _hann(h: int, w: int) -> NDArray[np.float32]:
    # Periodic Hann: its FFT-periodic extension is smooth.
    wy = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(h) / h)
    wx = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(w) / w)
    win = np.outer(wy, wx).astype(np.float32)
    win.flags.writeable = False
    return win


@dataclass(frozen=True)
class _BandLayout:
    """The band block of a spectrum, in ``rfft2`` order: vertical frequencies
    |ky| < ky_max (FFT order: 0 … ky_max − 1, −(ky_max − 1) … −1), horizontal
    0 ≤ kx < kx_max (the negative ones are their conjugates). The Nyquist frequency, whose
    sign is ambiguous, never enters."""

    ky_max: int
    kx_max: int
    hermitian: NDArray[np.float32]  # (Ky', Kx): 2 for columns standing for ±kx, 1 for kx = 0
    n_frequencies: float  # frequencies of the full plane that the band holds (DC excluded)
    uy: FloatArray  # (Ky',) cycles per pixel
    ux: FloatArray  # (Kx,) cycles per pixel
    grid: tuple[int, int]  # (rows, cols) of the smallest even grid that samples the band
    small_rows: NDArray[np.intp]  # row of each band row in that grid


@lru_cache(maxsize=16)
def _band_layout(h: int, w: int, band: float) -> _BandLayout:
    if not 0.0 < band <= 1.0:
        raise ValueError(f"band must be in (0, 1], got {band}")
    ky_max = int(np.floor(band * h / 2 + 1e-9))
    kx_max = int(np.floor(band * w / 2 + 1e-9))
    if ky_max < 2 or kx_max < 2:
        raise ValueError(f"band {band} keeps no frequencies of {h}×{w} patches; raise it")
    ky = np.concatenate([np.arange(ky_max), np.arange(-ky_max + 1, 0)])
    kx = np.arange(kx_max)
    hermitian = np.ones((ky.size, 1)) * np.where(kx == 0, 1.0, 2.0)[None, :]
    hermitian[0, 0] = 0.0  # DC carries the (removed) mean, not the shift
    herm = hermitian.astype(np.float32)
    herm.flags.writeable = False
    grid = (2 * ky_max, 2 * kx_max)
    return _BandLayout(ky_max, kx_max, herm, float(hermitian.sum()), ky / h, kx / w, grid,
                       np.where(ky >= 0, ky, grid[0] + ky).astype(np.intp))


def _band_spectra(centred: NDArray[np.float32], layout: _BandLayout, workers: int,
                  ) -> tuple[NDArray[np.complex64], FloatArray]:
    """The band block (N, Ky', Kx) of the 2-D DFT of each patch, computed for the batch,
    and each patch's power in the band.

    Only the band is needed. The real DFT along the rows goes through one ``cv2.dft`` call
    for all rows of all patches (``DFT_ROWS``; several times faster than pocketfft at these
    sizes), packed as OpenCV's CCS rows ``Re0, Re1, Im1, Re2, Im2, …``; the band's columns
    are unpacked and one complex ``scipy.fft.fft`` down the columns finishes the transform.
    """
    n, h, w = centred.shape
    if n == 0:  # (cv2.dft gives None for no rows)
        return np.zeros((0, 2 * layout.ky_max - 1, layout.kx_max), np.complex64), np.zeros(0)
    ccs = cv2.dft(centred.reshape(n * h, w), flags=cv2.DFT_ROWS)
    half = poc_kernels.unpack_band_columns(ccs, layout.kx_max).view(np.complex64)
    full = scipy.fft.fft(half.reshape(n, h, layout.kx_max), axis=1, workers=workers,
                         overwrite_x=True)
    band, power = poc_kernels.band_rows_and_power(full.view(np.float32), layout.ky_max,
                                                  layout.hermitian)
    return band.view(np.complex64), power
