"""IPM patch sizes (ipm.patch_sizes): the largest square that fits both frames' views."""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

from vipm_track import ipm


class _Grid:
    width, height = 1000, 900


def _inside(polygon: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (N, 2) inside or on a convex polygon (M, 2) of either orientation."""
    if len(polygon) < 3:
        return np.zeros(len(points), bool)
    edge = np.roll(polygon, -1, axis=0) - polygon
    rel = points[:, None, :] - polygon[None]
    cross = edge[None, :, 0] * rel[..., 1] - edge[None, :, 1] * rel[..., 0]
    return np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)


def _reference(polygons, centres, moved, candidates) -> np.ndarray:
    """Each square's four corners tested one size at a time, largest first."""
    box = np.array([[0, 0], [999, 0], [999, 899], [0, 899]], float)
    sizes = np.zeros(len(centres), np.int64)
    for s in candidates:
        corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * s / 2
        fits = np.ones(len(centres), bool)
        for c in corners:
            fits &= (_inside(polygons[0], centres + c) & _inside(box, centres + c)
                     & _inside(polygons[1], moved + c) & _inside(box, moved + c))
        sizes = np.where((sizes == 0) & fits, s, sizes)
    return sizes


def test_sizes_are_the_largest_squares_inside_both_views() -> None:
    rng = np.random.default_rng(4)
    candidates = list(range(256, 31, -ipm.SIZE_STEP))
    for trial in range(60):
        polygons = []
        for _ in range(2):
            pts = rng.uniform(0, 1000, (8, 2))
            hull = pts[ConvexHull(pts).vertices]
            polygons.append(hull[::-1] if rng.random() < 0.5 else hull)  # either orientation
        if trial % 10 == 0:
            polygons[1] = polygons[1][:2]  # a view with no area: nothing fits
        centres = rng.uniform(0, 1000, (40, 2))
        offsets = rng.normal(0, 30, (40, 2))
        centres[0] = np.nan  # an undefined centre gets no patch
        sizes = ipm.patch_sizes(_Grid(), polygons[0], polygons[1], centres, offsets, 256, 32)
        expected = _reference(polygons, centres, centres + offsets, candidates)
        np.testing.assert_array_equal(sizes, expected)
        assert sizes[0] == 0
        if trial % 10 == 0:
            assert not sizes.any()
    assert expected.any()
