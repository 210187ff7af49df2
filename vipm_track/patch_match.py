"""POC of many patches of several sizes between two planes, batched by size, on threads."""

from __future__ import annotations

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


def match_grouped(
    ref: NDArray, moving: NDArray, centres: FloatArray, sizes: NDArray[np.int64],
    offsets: FloatArray, recentre: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """POC displacements (N, 2) and peaks (N,) of patches batched by size (one call per
    size, or per part of a size on ``workers.threads()`` threads); NaN displacement and zero
    peak where ``sizes`` is 0."""
    disp = np.full((len(centres), 2), np.nan)
    peaks = np.zeros(len(centres))

    def run(batch: tuple[int, NDArray[np.intp]]) -> tuple[NDArray[np.intp], FloatArray,
                                                          FloatArray]:
        s, sel = batch
        d, p = poc.match_patches(ref, moving, centres[sel], s, offsets=np.round(offsets[sel]),
                                 recentre=recentre)
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
