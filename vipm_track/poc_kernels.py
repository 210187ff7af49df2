"""The compiled inner loops of the phase-only correlation (``poc``): preparing patches for
their transforms, the band's cross-power spectrum, and the sub-pixel peak.

Each works patch by patch in one pass over its data, without the GIL, so the correlation
threads of ``patch_match`` run on both cores; the transforms themselves stay with OpenCV and
pocketfft. Complex spectra come and go as float32 views (re, im interleaved) so the loops
vectorise; sums may be reordered (``reduction_kernel``), so shifts agree with a plain loop to
about 1e-5 px.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .compiled import kernel, reduction_kernel

MAX_STEP_PX = 0.5  # largest Newton step, pixels (keeps the ascent on the peak it started on)

Float32Array = NDArray[np.float32]


@reduction_kernel
def crop_centre_and_window(image: NDArray, corners: NDArray[np.int64], win: Float32Array,
                           ) -> tuple[Float32Array, NDArray[np.bool_]]:
    """Patches of ``image`` whose top-left pixels (x, y) are ``corners`` (N, 2), with their
    window-weighted mean removed and multiplied by ``win`` (H, W): (N, H, W) float32, and
    whether each was usable (wholly inside the image, no NaN or inf); unusable ones are 0."""
    h, w = win.shape
    n = corners.shape[0]
    rows, cols = image.shape
    # not np.zeros: a batch of large patches is megabytes, and zeroing them first cost a
    # third of the kernel's time; only the unusable patches are zeroed
    out = np.empty((n, h, w), np.float32)
    usable = np.zeros(n, np.bool_)
    win_sum = 0.0
    for i in range(h):
        for j in range(w):
            win_sum += win[i, j]
    for k in range(n):
        x, y = corners[k, 0], corners[k, 1]
        if x < 0 or y < 0 or x > cols - w or y > rows - h:  # no overflow for any corner
            out[k] = 0.0
            continue
        total = 0.0
        for i in range(h):
            src, wrow = image[y + i, x: x + w], win[i]
            acc = np.float32(0.0)
            for j in range(w):
                acc += np.float32(src[j]) * wrow[j]
            total += acc
        mean = total / win_sum
        if not math.isfinite(mean):  # a NaN or inf anywhere shows in the mean
            out[k] = 0.0
            continue
        usable[k] = True
        mean32 = np.float32(mean)
        for i in range(h):
            src, wrow, dst = image[y + i, x: x + w], win[i], out[k, i]
            for j in range(w):
                dst[j] = (np.float32(src[j]) - mean32) * wrow[j]
    return out, usable


@reduction_kernel
def unpack_band_columns(ccs: Float32Array, kx: int) -> Float32Array:
    """The first ``kx`` complex columns of row DFTs packed as OpenCV's CCS rows
    (``Re0, Re1, Im1, Re2, Im2, …``), shape (rows, 2·kx) as re, im."""
    rows = ccs.shape[0]
    out = np.empty((rows, 2 * kx), np.float32)
    for r in range(rows):
        src, dst = ccs[r], out[r]
        dst[0] = src[0]
        dst[1] = 0.0
        for k in range(2, 2 * kx):
            dst[k] = src[k - 1]
    return out


@reduction_kernel
def band_rows_and_power(full: Float32Array, ky_max: int, hermitian: Float32Array,
                        ) -> tuple[Float32Array, NDArray[np.float64]]:
    """The band rows (vertical frequencies 0 … ky_max − 1, −(ky_max − 1) … −1) of column
    transforms ``full`` (N, H, 2·Kx as re, im), as (N, 2·ky_max − 1, 2·Kx), and each patch's
    band power weighted by ``hermitian``."""
    n, h, kx2 = full.shape
    kx = kx2 // 2
    rows = 2 * ky_max - 1
    src_all = full
    out = np.empty((n, rows, 2 * kx), np.float32)
    power = np.zeros(n)
    for k in range(n):
        total = 0.0
        for j in range(rows):
            src = src_all[k, j if j < ky_max else h - rows + j]
            dst, herm = out[k, j], hermitian[j]
            acc = np.float32(0.0)
            for i in range(kx):
                re, im = src[2 * i], src[2 * i + 1]
                dst[2 * i], dst[2 * i + 1] = re, im
                acc += (re * re + im * im) * herm[i]
            total += acc
        power[k] = total
    return out, power


@reduction_kernel
def cross_power(ref: Float32Array, moving: Float32Array, pairs: NDArray[np.intp],
                hermitian: Float32Array, small_rows: NDArray[np.intp], grid: tuple[int, int],
                weighting: float) -> tuple[Float32Array, Float32Array, NDArray[np.complex64]]:
    """For the patch pairs ``pairs`` of band spectra ``ref``, ``moving`` (N, Ky', 2·Kx as
    re, im): the normalised cross-power spectrum ``R`` (unit phasors times the Hermitian
    weights, 0 where there is no signal), the same weighted by ``|F_mov F_ref|^weighting``
    for the sub-pixel fit (both (M, Ky', 2·Kx) as re, im), and ``R`` on the half spectrum of
    the smallest grid (rows, cols) that samples the band."""
    m = pairs.shape[0]
    _, ky, kx2 = ref.shape
    kx = kx2 // 2
    r = np.empty((m, ky, kx2), np.float32)
    rw = np.empty((m, ky, kx2), np.float32)
    small = np.zeros((m, grid[0], grid[1] // 2 + 1), np.complex64)
    half, exponent = weighting == 0.5, 0.5 * weighting  # exponent of |F_mov|² |F_ref|²
    for k in range(m):
        p = pairs[k]
        for j in range(ky):
            a, b, herm = moving[p, j], ref[p, j], hermitian[j]
            rr, rwr = r[k, j], rw[k, j]
            for i in range(kx):
                ar, ai, br, bi = a[2 * i], a[2 * i + 1], b[2 * i], b[2 * i + 1]
                cr = ar * br + ai * bi
                ci = ai * br - ar * bi
                mag2 = cr * cr + ci * ci
                inv = np.float32(1.0) / np.sqrt(mag2) if mag2 > 0 else np.float32(0.0)
                scale = herm[i] * inv
                rr[2 * i], rr[2 * i + 1] = cr * scale, ci * scale
            # |F_mov F_ref|^α from the two magnitudes (the loops stay branch-free)
            if half:
                for i in range(kx):
                    q = (a[2 * i] * a[2 * i] + a[2 * i + 1] * a[2 * i + 1]) * (
                        b[2 * i] * b[2 * i] + b[2 * i + 1] * b[2 * i + 1])
                    weight = np.sqrt(np.sqrt(q))
                    rwr[2 * i], rwr[2 * i + 1] = rr[2 * i] * weight, rr[2 * i + 1] * weight
            elif weighting == 0.0:
                rwr[:] = rr
            else:
                for i in range(kx):
                    q = (a[2 * i] * a[2 * i] + a[2 * i + 1] * a[2 * i + 1]) * (
                        b[2 * i] * b[2 * i] + b[2 * i + 1] * b[2 * i + 1])
                    weight = np.float32(float(q) ** exponent)
                    rwr[2 * i], rwr[2 * i + 1] = rr[2 * i] * weight, rr[2 * i + 1] * weight
            dst = small[k, small_rows[j]]
            for i in range(kx):
                dst[i] = complex(rr[2 * i], rr[2 * i + 1])
    return r, rw, small


@reduction_kernel
def _moments(r: Float32Array, uy: NDArray[np.float64], ux: NDArray[np.float64],
             dx: float, dy: float) -> tuple[float, float, float, float, float, float]:
    """Value, gradient (x, y) and Hessian (xx, yy, xy) at (dx, dy) px of the POC function
    ``Σ Re(R(u) e^{2πi u·d})`` of one patch (``r``: (Ky', 2·Kx) as re, im, with the
    Hermitian weights). The phasor is separable: row sums first, then down the rows."""
    ky, kx2 = r.shape
    kx = kx2 // 2
    two_pi = 2.0 * math.pi
    exr, exi = np.empty(kx), np.empty(kx)
    for i in range(kx):
        exr[i], exi[i] = math.cos(two_pi * dx * ux[i]), math.sin(two_pi * dx * ux[i])
    m00r = m00i = m01i = m02r = m10i = m20r = m11r = 0.0
    for j in range(ky):
        row = r[j]
        t0r = t0i = t1r = t1i = t2r = t2i = 0.0
        for i in range(kx):
            a, b, u = row[2 * i], row[2 * i + 1], ux[i]
            vr = a * exr[i] - b * exi[i]
            vi = a * exi[i] + b * exr[i]
            t0r += vr
            t0i += vi
            t1r += vr * u
            t1i += vi * u
            t2r += vr * u * u
            t2i += vi * u * u
        eyr, eyi, v = math.cos(two_pi * dy * uy[j]), math.sin(two_pi * dy * uy[j]), uy[j]
        p0r, p0i = eyr * t0r - eyi * t0i, eyr * t0i + eyi * t0r
        p1r, p1i = eyr * t1r - eyi * t1i, eyr * t1i + eyi * t1r
        m00r += p0r
        m00i += p0i
        m01i += p1i
        m02r += eyr * t2r - eyi * t2i
        m10i += v * p0i
        m20r += v * v * p0r
        m11r += v * p1r
    c2 = two_pi * two_pi
    return m00r, -two_pi * m01i, -two_pi * m10i, -c2 * m02r, -c2 * m20r, -c2 * m11r


@kernel
def _vertex(minus: float, centre: float, plus: float) -> float:
    """Offset (within ±0.5) of the vertex of the parabola through three samples."""
    curve = minus - 2.0 * centre + plus
    if curve < 0:
        return min(0.5, max(-0.5, (minus - plus) / (2.0 * curve)))
    return 0.0


@kernel
def subpixel_peaks(surface: Float32Array, r: Float32Array, rw: Float32Array,
                   uy: NDArray[np.float64], ux: NDArray[np.float64], patch: tuple[int, int],
                   iterations: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Shifts (M, 2) as (dx, dy) px and unnormalised POC values (M,) at them.

    The coarse peak is the highest sample of each band-limited POC ``surface`` (M, gy, gx),
    moved by a parabola through its neighbours; then ``iterations`` Newton steps on the
    continuous function weighted as ``rw`` (a gradient step scaled by the largest
    curvature where the Hessian is not negative definite, so the ascent never climbs down;
    steps ≤ 0.5 px); the value is that of ``r`` at the result."""
    m, gy, gx = surface.shape
    h, w = patch
    d = np.empty((m, 2))
    value = np.empty(m)
    for k in range(m):
        s = surface[k]
        best, iy, ix = s[0, 0], 0, 0
        for y in range(gy):
            for x in range(gx):
                if s[y, x] > best:
                    best, iy, ix = s[y, x], y, x
        fy = _vertex(float(s[(iy - 1) % gy, ix]), float(best), float(s[(iy + 1) % gy, ix]))
        fx = _vertex(float(s[iy, (ix - 1) % gx]), float(best), float(s[iy, (ix + 1) % gx]))
        dx = ((ix - gx if ix >= gx // 2 else ix) + fx) * (w / gx)
        dy = ((iy - gy if iy >= gy // 2 else iy) + fy) * (h / gy)
        for _ in range(iterations):
            _, gxx, gyy, a, c, b = _moments(rw[k], uy, ux, dx, dy)
            det = a * c - b * b
            half_gap = math.sqrt(0.25 * (a - c) ** 2 + b * b)
            scale = max(abs(0.5 * (a + c)) + half_gap, 1e-12)
            if 0.5 * (a + c) + half_gap < -1e-3 * scale and det > 0:  # negative definite
                sx = -(c * gxx - b * gyy) / det
                sy = -(a * gyy - b * gxx) / det
            else:
                sx, sy = gxx / scale, gyy / scale
            shrink = min(1.0, MAX_STEP_PX / max(math.hypot(sx, sy), 1e-12))
            dx += sx * shrink
            dy += sy * shrink
        d[k, 0], d[k, 1] = dx, dy
        value[k] = _moments(r[k], uy, ux, dx, dy)[0]
    return d, value


@reduction_kernel
def squared_phasors(r: Float32Array, rw: Float32Array, hermitian: Float32Array,
                    small_rows: NDArray[np.intp], grid: tuple[int, int],
                    ) -> tuple[Float32Array, Float32Array, NDArray[np.complex64]]:
    """The blur-invariant counterparts of :func:`cross_power`'s outputs ``r`` and ``rw``:
    each unit phasor ``R`` squared (its phase doubled, so a frequency whose phase a centrally
    symmetric blur turned by π counts as one it left alone; Ojansivu & Heikkilä 2007),
    times the Hermitian weights and, for the fit, the same weights ``|F_mov F_ref|^α``;
    and ``R²`` on the small grid. Their POC function peaks at twice the shift."""
    m, ky, kx2 = r.shape
    kx = kx2 // 2
    r2 = np.empty_like(r)
    rw2 = np.empty_like(rw)
    small = np.zeros((m, grid[0], grid[1] // 2 + 1), np.complex64)
    for k in range(m):
        for j in range(ky):
            a, b, herm = r[k, j], rw[k, j], hermitian[j]
            o, ow = r2[k, j], rw2[k, j]
            dst = small[k, small_rows[j]]
            for i in range(kx):
                re, im, weight_h = a[2 * i], a[2 * i + 1], herm[i]
                mag = np.sqrt(re * re + im * im)
                if weight_h > 0 and mag > 0:
                    # r = h·R, so h·R² = r²/h; the fit's weight is |rw| / |r|
                    sr, si = (re * re - im * im) / weight_h, 2 * re * im / weight_h
                    weight = np.sqrt(b[2 * i] * b[2 * i] + b[2 * i + 1] * b[2 * i + 1]) / mag
                else:
                    sr, si, weight = np.float32(0.0), np.float32(0.0), np.float32(0.0)
                o[2 * i], o[2 * i + 1] = sr, si
                ow[2 * i], ow[2 * i + 1] = sr * weight, si * weight
                dst[i] = complex(sr, si)
    return r2, rw2, small


@kernel
def _wrapped(value: float, period: float) -> float:
    """``value`` moved by whole periods into [−period/2, period/2]."""
    return value - period * math.floor(value / period + 0.5)


@reduction_kernel
def halved_shifts(doubled: NDArray[np.float64], r: Float32Array, uy: NDArray[np.float64],
                  ux: NDArray[np.float64], patch: tuple[int, int]) -> NDArray[np.float64]:
    """Shifts (M, 2) as (dx, dy) px from the peaks ``doubled`` of the blur-invariant POC
    function, which sit at twice the shift modulo the patch: per axis, two shifts double to
    the same peak, half a patch apart; the one taken is where the plain POC function
    (``r``, as :func:`cross_power` gives it) is largest in magnitude (a blurred frequency
    turned by π lowers, or even turns negative, the true shift's value, but half a patch
    away the content does not correlate). The four candidates' values come from one pass:
    half a patch multiplies a frequency's term by (−1) to the power of its index."""
    m = doubled.shape[0]
    h, w = patch
    ky_n, kx2 = r.shape[1], r.shape[2]
    kx_n = kx2 // 2
    two_pi = 2.0 * math.pi
    out = np.empty((m, 2))
    for k in range(m):
        dx, dy = 0.5 * _wrapped(doubled[k, 0], w), 0.5 * _wrapped(doubled[k, 1], h)
        exr, exi = np.empty(kx_n), np.empty(kx_n)
        for i in range(kx_n):
            exr[i], exi[i] = math.cos(two_pi * dx * ux[i]), math.sin(two_pi * dx * ux[i])
        # sums[py, px]: Re(r e^{2πi u·d}) over the frequencies of index parities (py, px)
        s00 = s01 = s10 = s11 = 0.0
        for j in range(ky_n):
            row = r[k, j]
            even = odd = 0.0
            eyr, eyi = math.cos(two_pi * dy * uy[j]), math.sin(two_pi * dy * uy[j])
            for i in range(kx_n):
                a, b = row[2 * i], row[2 * i + 1]
                cr = a * exr[i] - b * exi[i]
                ci = a * exi[i] + b * exr[i]
                term = eyr * cr - eyi * ci
                if i % 2 == 0:
                    even += term
                else:
                    odd += term
            if abs(round(uy[j] * h)) % 2 == 0:
                s00 += even
                s01 += odd
            else:
                s10 += even
                s11 += odd
        values = (s00 + s01 + s10 + s11, s00 - s01 + s10 - s11,
                  s00 + s01 - s10 - s11, s00 - s01 - s10 + s11)
        best = 0
        for c in range(1, 4):
            if abs(values[c]) > abs(values[best]):
                best = c
        if best == 1 or best == 3:
            dx += -0.5 * w if dx >= 0 else 0.5 * w
        if best == 2 or best == 3:
            dy += -0.5 * h if dy >= 0 else 0.5 * h
        out[k, 0], out[k, 1] = dx, dy
    return out
