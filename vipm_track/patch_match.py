"""POC of many patches of several sizes between two planes, batched by size, on threads,
at full resolution or on the planes halved (a pyramid level)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from . import poc
from .workers import map_on_threads, threads

FloatArray = NDArray[np.float64]

#: A size's batch is split across threads only from this many patches on: below it the
#: per-call overhead (Python, small FFTs) outweighs the second core.
MIN_SPLIT_PATCHES = 16

def _batches(sizes: NDArray[np.int64]) -> list[tuple[int, NDArray[np.intp]]]:
    """(size, patch indices) of each batch: one per size, the large ones split in
    ``threads()`` parts; largest work first, so the threads finish together."""
    out = []
    for s in np.unique(sizes):
        if s <= 0:
            continue
        sel = np.flatnonzero(sizes == s)
        parts = threads() if len(sel) >= MIN_SPLIT_PATCHES else 1
        out += [(int(s), part) for part in np.array_split(sel, parts)]
    return sorted(out, key=lambda b: -b[0] ** 2 * len(b[1]))


def level_band(level: int) -> float:
    """POC band at pyramid ``level`` that keeps the frequencies of the scene that
    ``poc.DEFAULT_BAND`` keeps at full resolution, at most :data:`MAX_LEVEL_BAND`."""
    return min(poc.DEFAULT_BAND * 2.0**level, MAX_LEVEL_BAND)


#: Highest POC band on a halved plane: up to its Nyquist frequency. There the shifts lock
#: towards the halved pixel grid on broadband texture (a mean error of up to 0.04 px,
#: periodic in the shift; band 0.75: 0.009 px), yet on KITTI 07 band 0.75 measured the
#: travel worse (p95 over three seeds 15.9 against 13.1 %) (docs/speed.md).
MAX_LEVEL_BAND = 1.0


def match_grouped(
    ref: NDArray, moving: NDArray, centres: FloatArray, sizes: NDArray[np.int64],
    offsets: FloatArray, recentre: bool = False, level: int = 0, blur_invariant: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """POC displacements (N, 2) and peaks (N,) of patches batched by size (one call per
    size, or per part of a size on ``workers.threads()`` threads); NaN displacement and zero
    peak where ``sizes`` is 0; ``blur_invariant``: phases modulo π (``poc.correlate_spectra``).

    ``level`` > 0 correlates on both planes halved ``level`` times (``cv2.pyrDown``): the
    patches cover the same ground at ``sizes / 2**level`` pixels, on the band that holds
    the frequencies the full-resolution band holds (:func:`level_band`), at a quarter of the
    pixels per level. ``centres``, ``sizes``, ``offsets`` and the displacements returned
    are in the given planes' pixels either way; a patch is measured at its centre rounded
    to the halved grid, so centres on multiples of ``2**level`` are measured where they are
    (others up to ``2**(level-1)`` pixels away, which a rotating field turns into error)."""
    if level > 0:
        factor = 2**level
        for _ in range(level):
            ref, moving = cv2.pyrDown(ref), cv2.pyrDown(moving)
        # cv2.pyrDown's pixel i is the full plane's pixel 2i
        small = np.where(sizes >= factor * poc.MIN_SIZE, sizes // factor, 0)
        disp, peaks = _match_batches(ref, moving, centres / factor, small,
                                     np.asarray(offsets) / factor, recentre, level_band(level),
                                     blur_invariant)
        return disp * factor, peaks
    return _match_batches(ref, moving, centres, sizes, offsets, recentre, poc.DEFAULT_BAND,
                          blur_invariant)


def _match_batches(
    ref: NDArray, moving: NDArray, centres: FloatArray, sizes: NDArray[np.int64],
    offsets: FloatArray, recentre: bool, band: float, blur_invariant: bool,
) -> tuple[FloatArray, FloatArray]:
    """:func:`match_grouped` at the planes' own resolution, on ``band``."""
    disp = np.full((len(centres), 2), np.nan)
    peaks = np.zeros(len(centres))

    def run(batch: tuple[int, NDArray[np.intp]]) -> tuple[NDArray[np.intp], FloatArray,
                                                          FloatArray]:
        s, sel = batch
        d, p = poc.match_patches(ref, moving, centres[sel], s, offsets=np.round(offsets[sel]),
                                 recentre=recentre, band=band,
                                 blur_invariant=blur_invariant)
        return sel, d, p

    batches = _batches(sizes)
    if threads() > 1 and len(batches) > 1:
        results = map_on_threads(run, batches)
    else:
        results = [run(b) for b in batches]
    for sel, d, p in results:
        disp[sel] = d
        peaks[sel] = p
    return disp, peaks
