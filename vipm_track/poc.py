"""Batched phase-only correlation (POC) with sub-pixel accuracy.

The translation between two patches is the location of the peak of their phase-only
correlation function (Kuglin & Hines 1975; Takita et al. 2003). This module computes it
for a whole batch of patch pairs at once:

1. each patch has its (window-weighted) mean removed and is multiplied by a Hann window,
   then the batch goes through one real FFT (``scipy.fft.rfft2``, float32, ``workers``);
   the spectra of a frame's patches can be kept (:class:`PatchSpectra`) and reused;
2. the normalised cross-power spectrum ``R = F_mov · conj(F_ref) / |F_mov · conj(F_ref)|``
   is band-limited (Takita's BLPOC): frequencies above ``band`` × Nyquist, where noise and
   aliasing dominate, are dropped, and so is DC;
3. one inverse FFT gives the band-limited POC surface; its integer peak is the coarse shift;
4. the sub-pixel shift maximises the continuous POC function
   ``r(d) = Σ_u Re(R(u) · exp(2πi u·d))`` (the surface the peak-model fit approximates)
   by a few batched Newton steps started at the integer peak. This is exact for the DFT
   peak rather than a model fit, and costs a few small matrix products per iteration.

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

import os
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Default fraction of the Nyquist frequency kept by the band limit (per axis).
DEFAULT_BAND = 0.5
#: Default number of Newton iterations of the sub-pixel refinement.
DEFAULT_ITERATIONS = 4
#: Default exponent of the spectral weights of the sub-pixel fit (see correlate_spectra).
DEFAULT_WEIGHTING = 0.5
#: Patches whose standard deviation is below this (grey levels) are "constant".
MIN_PATCH_STD = 1e-3
_MIN_SIZE = 8


def _default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


@dataclass(frozen=True)
class PatchSpectra:
    """Windowed spectra of a batch of patches, ready to be correlated.

    Attributes
    ----------
    spectra : ndarray, complex64, shape (N, H, W // 2 + 1)
        ``rfft2`` of the mean-removed, Hann-windowed patches.
    valid : ndarray, bool, shape (N,)
        False for patches that cannot be correlated (NaN, constant).
    shape : tuple of int
        Patch shape (H, W), pixels.
    """

    spectra: NDArray[np.complex64]
    valid: NDArray[np.bool_]
    shape: tuple[int, int]

    def __len__(self) -> int:
        return int(self.spectra.shape[0])

    def __getitem__(self, index: slice | ArrayLike) -> PatchSpectra:
        """Return the spectra of a subset of the patches (slice, indices or boolean mask)."""
        return PatchSpectra(self.spectra[index], self.valid[index], self.shape)


def patch_spectra(patches: ArrayLike, *, window: bool = True, workers: int | None = None,
                  ) -> PatchSpectra:
    """Return the windowed spectra of a batch of patches (computed once, reusable).

    Parameters
    ----------
    patches : array_like, shape (N, H, W) or (H, W)
        Grey patches (any real dtype, grey levels). NaN anywhere in a patch marks it invalid.
    window : bool
        Multiply by a 2-D Hann window (against the edge discontinuities of the FFT's
        periodic extension). Switch off only for periodic content.
    workers : int, optional
        Threads of ``scipy.fft``; default: the CPU count (at most 8).

    Returns
    -------
    PatchSpectra
    """
    arr = _as_batch(patches, "patches")
    n, h, w = arr.shape
    finite = np.isfinite(arr).all(axis=(1, 2))
    arr = np.where(finite[:, None, None], arr, np.float32(0.0))
    win = _hann(h, w) if window else np.ones((h, w), np.float32)
    # Remove the window-weighted mean so that the window itself leaves no DC peak and a
    # constant patch becomes exactly zero.
    mean = np.einsum("nij,ij->n", arr, win, dtype=np.float64) / float(win.sum())
    centred = arr - mean.astype(np.float32)[:, None, None]
    std = np.sqrt(np.einsum("nij,nij->n", centred, centred, dtype=np.float64) / (h * w))
    valid = finite & (std > MIN_PATCH_STD)
    spectra = scipy.fft.rfft2(centred * win, workers=workers or _default_workers())
    return PatchSpectra(spectra.astype(np.complex64, copy=False), valid, (h, w))


def correlate_spectra(ref: PatchSpectra, moving: PatchSpectra, *, band: float = DEFAULT_BAND,
                      iterations: int = DEFAULT_ITERATIONS, weighting: float = DEFAULT_WEIGHTING,
                      workers: int | None = None) -> tuple[FloatArray, FloatArray]:
    """Return the sub-pixel shifts and POC peak heights between two batches of spectra.

    Parameters
    ----------
    ref, moving : PatchSpectra
        Spectra of N reference and N moving patches of the same shape.
    band : float
        Fraction (0, 1] of the Nyquist frequency kept on each axis (band-limited POC).
    iterations : int
        Newton iterations of the sub-pixel refinement (0: the coarse peak only).
    weighting : float
        Exponent α of the spectral weights ``|F_mov · F_ref|^α`` of the sub-pixel fit:
        0 is pure POC (every frequency counts the same), larger values trust the strong
        frequencies more, whose phase noise is small.
    workers : int, optional
        Threads of ``scipy.fft``.

    Returns
    -------
    shift : ndarray, shape (N, 2)
        (dx, dy) in pixels, ``moving(x) ≈ ref(x − shift)``; NaN where ``peak`` is 0.
    peak : ndarray, shape (N,)
        Band-limited POC peak height at ``shift`` (1 for identical content), 0 for
        unusable pairs.
    """
    if ref.shape != moving.shape or len(ref) != len(moving):
        raise ValueError(
            f"phase correlation needs equal batches of equal patch shapes: ref has "
            f"{len(ref)} patches of {ref.shape}, moving has {len(moving)} of {moving.shape}")
    if not 0.0 < band <= 1.0:
        raise ValueError(f"band must be in (0, 1], got {band}")
    h, w = ref.shape
    n = len(ref)
    shift = np.full((n, 2), np.nan)
    peak = np.zeros(n)
    ok = np.flatnonzero(ref.valid & moving.valid)
    if ok.size == 0:
        return shift, peak
    bb = _band_layout(h, w, band)
    # Work on the band block only: band × band of the spectrum.
    cross = _take_band(moving.spectra, ok, bb) * np.conj(_take_band(ref.spectra, ok, bb))
    mag = np.abs(cross)
    nonzero = mag > 0
    r = np.where(nonzero, cross / np.where(nonzero, mag, 1), 0).astype(np.complex64)
    r *= bb.hermitian
    n_band = np.float32(bb.hermitian.sum())

    # Coarse: peak of the band-limited POC surface, exactly sampled on the small grid that
    # the band needs (one inverse FFT for the batch).
    small = np.zeros((ok.size, bb.grid[0], bb.grid[1] // 2 + 1), np.complex64)
    small[:, bb.small_rows, : bb.kx_max] = r
    surface = scipy.fft.irfft2(small, s=bb.grid, workers=workers or _default_workers())
    iy, ix = np.divmod(surface.reshape(ok.size, -1).argmax(axis=1), bb.grid[1])
    d = np.stack([_wrap(ix, bb.grid[1]) * (w / bb.grid[1]),
                  _wrap(iy, bb.grid[0]) * (h / bb.grid[0])], axis=1)

    # Fine: Newton ascent on the (weighted) continuous POC function from the coarse peak.
    rw = r if weighting == 0 else (r * mag**np.float32(weighting)).astype(np.complex64)
    for _ in range(iterations):
        _, grad, hess = _poc_moments(rw, bb.ux, bb.uy, d)
        step = np.linalg.solve(_negative_definite(hess), -grad[..., None])[..., 0]
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        d += step * np.minimum(1.0, 0.5 / np.maximum(norm, 1e-12))
    value = _poc_value(r, bb.ux, bb.uy, d) / n_band
    usable = nonzero.any(axis=(1, 2)) & (value > 0) & (np.abs(d) <= [w / 2, h / 2]).all(axis=1)
    shift[ok[usable]] = d[usable]
    peak[ok[usable]] = value[usable]
    return shift, peak


def phase_correlate(ref: ArrayLike, moving: ArrayLike, *, band: float = DEFAULT_BAND,
                    iterations: int = DEFAULT_ITERATIONS, weighting: float = DEFAULT_WEIGHTING,
                    window: bool = True, ref_spectra: PatchSpectra | None = None, workers: int | None = None,
                    ) -> tuple[FloatArray, FloatArray]:
    """Return the sub-pixel shift and POC peak of each pair of patches.

    Parameters
    ----------
    ref, moving : array_like, shape (N, H, W) or (H, W)
        Reference and moving grey patches. ``ref`` may be None when ``ref_spectra`` is given.
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
    shift : ndarray, shape (N, 2), or (2,) for a single pair
        (dx, dy) in pixels, the displacement of the content from ``ref`` to ``moving``:
        ``moving(x) ≈ ref(x − shift)``. NaN where ``peak`` is 0.
    peak : ndarray, shape (N,), or a float for a single pair
        POC peak height (1 for identical content, a few hundredths for unrelated content,
        0 for unusable pairs: NaN, constant patch).
    """
    single = np.ndim(moving) == 2
    mov = patch_spectra(moving, window=window, workers=workers)
    if ref_spectra is None:
        if ref is None:
            raise ValueError("phase_correlate needs ref patches or ref_spectra")
        if np.shape(ref) != np.shape(moving):
            raise ValueError(f"ref and moving patches differ in shape: {np.shape(ref)} vs "
                             f"{np.shape(moving)}")
        ref_spectra = patch_spectra(ref, window=window, workers=workers)
    shift, peak = correlate_spectra(ref_spectra, mov, band=band, iterations=iterations,
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
        Patch centres (x, y) in pixels, rounded to the nearest pixel (halves up). The patch
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
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"crop_patches needs a 2-D grey image, got shape {img.shape}")
    ph, pw = _patch_size(size)
    corner = _corners(centres, ph, pw)
    height, width = img.shape
    inside = ((corner[:, 0] >= 0) & (corner[:, 1] >= 0)
              & (corner[:, 0] + pw <= width) & (corner[:, 1] + ph <= height))
    patches = np.full((len(corner), ph, pw), np.nan, np.float32)
    if inside.any() and ph <= height and pw <= width:
        view = np.lib.stride_tricks.sliding_window_view(img, (ph, pw))
        patches[inside] = view[corner[inside, 1], corner[inside, 0]]
    return (patches, inside) if return_mask else patches


def match_patches(img_ref: ArrayLike, img_moving: ArrayLike, centres_ref: ArrayLike,
                  size: int | tuple[int, int], offsets: ArrayLike | None = None, *,
                  band: float = DEFAULT_BAND, iterations: int = DEFAULT_ITERATIONS,
                  weighting: float = DEFAULT_WEIGHTING, recentre: bool = False, workers: int | None = None,
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
        Predicted displacements (dx, dy), pixels; default zero.
    recentre : bool
        Crop the moving patches a second time at the rounded measured displacement and
        measure again: the residual shift is then below half a pixel, where the window
        biases it least. Costs a second correlation.
    band, iterations, weighting, workers
        As :func:`phase_correlate`.

    Returns
    -------
    shift : ndarray, shape (N, 2)
        Displacement (dx, dy) in pixels of each patch's content:
        ``img_moving(x + shift) ≈ img_ref(x)`` around ``centres_ref``.
        NaN where ``peak`` is 0 (a patch leaves an image, or cannot be correlated).
    peak : ndarray, shape (N,)
        POC peak height (confidence), 0 for unusable patches.
    """
    centres = _as_points(centres_ref, "centres_ref")
    if offsets is None:
        offset = np.zeros_like(centres)
    else:
        offset = np.broadcast_to(np.asarray(offsets, np.float64), centres.shape).copy()
        if not np.isfinite(offset).all():
            raise ValueError("offsets contain NaN or inf")
    offset = np.floor(offset + 0.5)
    ref_patches = crop_patches(img_ref, centres, size)
    ref_spec = patch_spectra(ref_patches, workers=workers)
    passes = 2 if recentre else 1
    for k in range(passes):
        mov_patches = crop_patches(img_moving, centres + offset, size)
        residual, peak = correlate_spectra(ref_spec, patch_spectra(mov_patches, workers=workers),
                                           band=band, iterations=iterations,
                                           weighting=weighting, workers=workers)
        shift = offset + residual
        if k + 1 < passes:
            good = peak > 0
            offset = np.where(good[:, None], np.floor(shift + 0.5), offset)
    return shift, peak


# --------------------------------------------------------------------------- helpers


def _as_batch(patches: ArrayLike, name: str) -> NDArray[np.float32]:
    arr = np.asarray(patches)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise ValueError(f"{name} must have shape (N, H, W) or (H, W), got {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
            or arr.dtype == np.bool_):
        raise ValueError(f"{name} must be real numbers, got dtype {arr.dtype}")
    if arr.shape[1] < _MIN_SIZE or arr.shape[2] < _MIN_SIZE:
        raise ValueError(f"{name} must be at least {_MIN_SIZE}×{_MIN_SIZE} pixels, got "
                         f"{arr.shape[1]}×{arr.shape[2]}")
    return np.asarray(arr, np.float32)


def _as_points(points: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(points, np.float64)
    if arr.ndim == 1 and arr.shape == (2,):
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2) as (x, y) pixels, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contain NaN or inf")
    return arr


def _patch_size(size: int | tuple[int, int]) -> tuple[int, int]:
    ph, pw = (size, size) if np.isscalar(size) else tuple(size)  # type: ignore[misc]
    if int(ph) != ph or int(pw) != pw or ph < 1 or pw < 1:
        raise ValueError(f"patch size must be positive integers, got {size}")
    return int(ph), int(pw)


def _corners(centres: ArrayLike, ph: int, pw: int) -> NDArray[np.int64]:
    c = _as_points(centres, "centres")
    pix = np.floor(c + 0.5).astype(np.int64)
    return pix - np.array([pw // 2, ph // 2])


def _wrap(index: NDArray[np.int64], n: int) -> NDArray[np.int64]:
    return np.where(index > n // 2, index - n, index)


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
    """Where the band-limited block of an rfft2 spectrum lies, and its small grid.

    Kept frequencies: rows ``|ky| < ky_max``, columns ``0 <= kx < kx_max`` (so the Nyquist
    row/column, whose sign is ambiguous, never enters).
    """

    ky_max: int
    kx_max: int
    hermitian: NDArray[np.float32]  # (Hb, Wb): 2 for columns standing for ±kx, 1 for kx = 0
    uy: FloatArray  # (Hb,) cycles per pixel
    ux: FloatArray  # (Wb,) cycles per pixel
    grid: tuple[int, int]  # the smallest even grid that holds the band exactly
    small_rows: NDArray[np.intp]  # row of each band row in that grid's rfft2 layout


@lru_cache(maxsize=16)
def _band_layout(h: int, w: int, band: float) -> _BandLayout:
    ky_max = int(np.floor(band * h / 2 + 1e-9))
    kx_max = int(np.floor(band * w / 2 + 1e-9))
    if ky_max < 2 or kx_max < 2:
        raise ValueError(f"band {band} keeps no frequencies of {h}×{w} patches; raise it")
    ky = np.concatenate([np.arange(ky_max), np.arange(-ky_max + 1, 0)])
    kx = np.arange(kx_max)
    hermitian = np.where(kx == 0, 1.0, 2.0)[None, :] * np.ones((ky.size, 1))
    hermitian[0, 0] = 0.0  # DC carries the (removed) mean, not the shift
    grid = (2 * ky_max, 2 * kx_max)
    herm = hermitian.astype(np.float32)
    herm.flags.writeable = False
    return _BandLayout(ky_max, kx_max, herm, ky / h, kx / w, grid,
                       np.where(ky >= 0, ky, grid[0] + ky).astype(np.intp))


def _take_band(spectra: NDArray[np.complex64], rows: NDArray[np.intp], bb: _BandLayout,
               ) -> NDArray[np.complex64]:
    """The band block (n, Hb, Wb) of the spectra of the patches ``rows``."""
    h = spectra.shape[1]
    return np.concatenate([spectra[rows, : bb.ky_max, : bb.kx_max],
                           spectra[rows, h - bb.ky_max + 1:, : bb.kx_max]], axis=1)


def _poc_value(rb: NDArray[np.complex64], ux: FloatArray, uy: FloatArray, d: FloatArray,
               ) -> FloatArray:
    """r(d) = Σ Re(R(u) e^{2πi u·d}) per pair (R already carries the Hermitian weights)."""
    ex = np.exp(2j * np.pi * d[:, 0:1] * ux[None, :]).astype(np.complex64)
    ey = np.exp(2j * np.pi * d[:, 1:2] * uy[None, :]).astype(np.complex64)
    return np.einsum("ny,ny->n", ey, (rb @ ex[:, :, None])[:, :, 0]).real.astype(np.float64)


def _poc_moments(rb: NDArray[np.complex64], ux: FloatArray, uy: FloatArray, d: FloatArray,
                 ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Value, gradient (2,) and Hessian (2, 2) of r(d) = Σ Re(R(u) e^{2πi u·d}) per pair.

    The phasor is separable, so all moments come from two batched matrix products.
    """
    ex = np.exp(2j * np.pi * d[:, 0:1] * ux[None, :])  # (N, Wb)
    ey = np.exp(2j * np.pi * d[:, 1:2] * uy[None, :])  # (N, Hb)
    px = np.stack([ex, ex * ux, ex * ux**2], axis=2).astype(np.complex64)  # (N, Wb, 3)
    py = np.stack([ey, ey * uy, ey * uy**2], axis=1).astype(np.complex64)  # (N, 3, Hb)
    m = (py @ (rb @ px)).astype(np.complex128)  # m[a, b] = Σ R e^{..} uy^a ux^b
    two_pi = 2 * np.pi
    value = m[:, 0, 0].real
    grad = -two_pi * np.stack([m[:, 0, 1].imag, m[:, 1, 0].imag], axis=1)
    hxx = -two_pi**2 * m[:, 0, 2].real
    hyy = -two_pi**2 * m[:, 2, 0].real
    hxy = -two_pi**2 * m[:, 1, 1].real
    hess = np.stack([np.stack([hxx, hxy], -1), np.stack([hxy, hyy], -1)], -2)
    return value, grad, hess


def _negative_definite(hess: FloatArray) -> FloatArray:
    """Hessians made safely negative definite (away from a peak, Newton would climb down)."""
    vals, vecs = np.linalg.eigh(hess)
    scale = np.abs(vals).max(axis=1, keepdims=True)
    vals = -np.maximum(np.abs(vals), 1e-3 * np.maximum(scale, 1e-12))
    return (vecs * vals[:, None, :]) @ np.swapaxes(vecs, 1, 2)
