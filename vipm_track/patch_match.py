"""POC of many patches of several sizes between two planes, batched by size."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from . import poc

FloatArray = NDArray[np.float64]


def match_grouped(
    ref: NDArray, moving: NDArray, centres: FloatArray, sizes: NDArray[np.int64],
    offsets: FloatArray, recentre: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """POC displacements (N, 2) and peaks (N,) of patches batched by size (one call per
    size); NaN displacement and zero peak where ``sizes`` is 0."""
    disp = np.full((len(centres), 2), np.nan)
    peaks = np.zeros(len(centres))
    for s in np.unique(sizes):
        if s <= 0:
            continue
        sel = np.flatnonzero(sizes == s)
        d, p = poc.match_patches(ref, moving, centres[sel], int(s), offsets=np.round(offsets[sel]),
                                 recentre=recentre)
        disp[sel] = d
        peaks[sel] = p
    return disp, peaks

