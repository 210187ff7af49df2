"""The rolling shutter's readout time found from the frames (``--readout-time auto``).

A CMOS camera exposes its rows one after another: over the readout time the vehicle moves on,
so the near field (bottom rows) is seen later than the far field. The two-frame fit models this
given the readout (``Rig.readout_s``); with the wrong one, part of the row-timing
motion cannot be explained by any pose and motion, and the fit's residual rises with the
error. On rendered car and cart pairs the squared RMS residual grows with the square of the
readout error (car at 12 m/s, 33 ms readout: 0.060 px² at the truth, +0.04 / +0.16 / +0.37 px²
at 11 / 22 / 33 ms off), so it is a parabola in the readout whose vertex is the readout.

:func:`search_readout` cold-starts pairs in which the view moves, spread over the first frames,
with a global shutter, keeps those that travel furthest (the effect grows with the motion) and
solves them at each of a grid of readouts (fractions of the frame interval, 0 = global shutter
to 1 = a whole interval); it averages the squared residuals of the pairs solved at every readout
near the grid's best and takes the vertex of the parabola through them; the spread of the
pairs' own vertices gives its standard error. The answer counts only where the profile dips
clearly (``MIN_DEPTH_Z``, ``MIN_AGREEMENT``): on KITTI 07, whose camera has a global shutter
and whose ground spans few image rows, the residual only jitters with the readout, and a
readout fitted to that jitter moved the travel by up to -8 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from .estimator import TwoFrameEstimator
from .nominal_search import MovingPair, spread_pairs
from .pair_chain import estimate_pair
from .pair_result import STATUS_OK

if TYPE_CHECKING:
    from .estimator_config import EstimatorConfig
    from .rig import Rig
    from .sources import FrameSource

FloatArray = NDArray[np.float64]

#: readouts tried, as fractions of the frame interval (a readout longer than the interval
#: would overlap the next frame's)
CANDIDATE_FRACTIONS: tuple[float, ...] = tuple(np.round(np.linspace(0.0, 1.0, 11), 3))
#: grid points around the best one that the parabola is fitted through
PARABOLA_POINTS = 5
#: fewest pairs solved at every one of those points (only such pairs enter the fit)
MIN_PAIRS = 2
#: the readout counts as determined where the pooled cost's dip (its median over the readouts
#: less its lowest value) is at least this many times its noise (from the jitter of each
#: pair's profile between neighbouring readouts) ...
MIN_DEPTH_Z = 6.0
#: ... and at least this share of the pairs has its own lowest cost within one readout step
#: of the pooled one. Where the residual only jitters with the inlier sets (KITTI 07: its
#: first frames at 0.1 m per frame z 4.6 with 4 of 6 pairs agreeing, its fastest pairs z 2.2
#: with 3 of 6) the lowest point is anywhere; the rendered rolling and global shutters dip
#: deep and shared (z 12-185, every pair)
MIN_AGREEMENT = 0.8


@dataclass(frozen=True)
class ReadoutSearch:
    """The readout found [s] with its standard error [s] (NaN with fewer than 3 pairs), the
    frame interval it is measured against [s], the pairs (``frames``: first and last frame
    index) behind it, the pooled cost profile (candidate readouts [s] and the mean squared
    RMS residual of the pairs there [px²], NaN where a pair failed), the dip's depth in units
    of its noise and the share of pairs whose own lowest cost lies beside the pooled one:
    ``determined`` where both pass (``MIN_DEPTH_Z``, ``MIN_AGREEMENT``)."""

    readout_s: float
    std_s: float
    interval_s: float
    pairs: int
    frames: tuple[int, int]
    candidates_s: tuple[float, ...]
    cost_px2: tuple[float, ...]
    depth_z: float
    agreement: float

    @property
    def determined(self) -> bool:
        return self.depth_z >= MIN_DEPTH_Z and self.agreement >= MIN_AGREEMENT

    @property
    def global_shutter(self) -> bool:
        """True where a global shutter (readout 0) is within two standard errors."""
        return self.readout_s <= 2.0 * self.std_s if math.isfinite(self.std_s) else (
            self.readout_s == 0.0)

    def line(self) -> str:
        rms = np.sqrt(np.asarray(self.cost_px2))
        evidence = (f"{self.pairs} pairs of frames {self.frames[0]}-{self.frames[1]}: fit "
                    f"residual {rms[0]:.3f} px with a global shutter, "
                    f"{np.nanmin(rms):.3f}-{np.nanmax(rms):.3f} px over 0-"
                    f"{self.candidates_s[-1] * 1e3:.0f} ms")
        if not self.determined:
            return (f"--readout-time auto: not determined ({evidence}: a dip of "
                    f"{self.depth_z:.1f}× its noise, {self.agreement:.0%} of the pairs lowest "
                    "beside it); going on with a global shutter. Where the ground "
                    "spans few image rows or the frames move little, a readout moves pitch "
                    "and travel instead of the residual: give --readout-time SECONDS from the "
                    "sensor's datasheet for a rolling-shutter camera")
        std = f" ± {self.std_s * 1e3:.1f}" if math.isfinite(self.std_s) else ""
        kind = " (a global shutter within 2σ)" if self.global_shutter else ""
        return (f"--readout-time auto: {self.readout_s * 1e3:.1f}{std} ms"
                f" = {self.readout_s / self.interval_s:.2f} frame intervals{kind}, from "
                f"{evidence}")


def spread_moving_pairs(
    source: FrameSource, rig: Rig, scan_pairs: int, max_frames: int,
) -> tuple[list[MovingPair], float] | None:
    """Up to ``scan_pairs`` pairs of ``source`` in which the view moves, spread over its first
    ``max_frames`` frames, and their median frame interval [s]; None where there is none (or
    no positive interval)."""
    pairs = spread_pairs(source, rig.camera, scan_pairs, max_frames)
    if not pairs:
        return None
    interval = float(np.median([p.interval_s for p in pairs]))
    if not (math.isfinite(interval) and interval > 0):
        return None
    return pairs, interval


def search_readout(
    source: FrameSource,
    rig: Rig,
    config: EstimatorConfig,
    max_pairs: int = 6,
    max_frames: int = 300,
    fractions: tuple[float, ...] = CANDIDATE_FRACTIONS,
    scan_pairs: int = 12,
) -> ReadoutSearch | None:
    """The readout [s] that fits pairs of ``source`` in which the view moves best (module
    doc). ``scan_pairs`` such pairs, spread over the first ``max_frames`` frames, are started
    cold from ``rig``'s nominal pose at the first readout of ``fractions`` (× the pairs'
    median frame interval); the ``max_pairs`` of them that travel furthest (the rolling
    shutter's effect grows with the motion) then at every other one. None where fewer than
    ``MIN_PAIRS`` pairs are solved at the readouts around the best one."""
    spread = spread_moving_pairs(source, rig, scan_pairs, max_frames)
    if spread is None:
        return None
    pairs, interval = spread
    readouts = np.asarray(fractions, dtype=float) * interval

    def costs(readout: float, chosen: list) -> tuple[FloatArray, FloatArray]:
        """Squared RMS residual [px²] and travel [m] of each pair at ``readout``."""
        estimator = TwoFrameEstimator(rig.with_readout(readout), config)
        cost, travel = np.full(len(chosen), np.nan), np.full(len(chosen), np.nan)
        for j, pair in enumerate(chosen):
            result = estimate_pair(estimator, pair.before, pair.image, None, pair.interval_s)
            if result.status == STATUS_OK and math.isfinite(result.residual_px):
                cost[j], travel[j] = result.residual_px ** 2, result.motion.distance
        return cost, travel

    first, travel = costs(float(readouts[0]), pairs)
    order = np.argsort(np.where(np.isfinite(travel), -travel, np.inf), kind="stable")
    keep = np.sort(order[:max_pairs])
    pairs = [pairs[j] for j in keep]
    cost = np.full((len(readouts), len(pairs)), np.nan)
    cost[0] = first[keep]
    for i in range(1, len(readouts)):
        cost[i] = costs(float(readouts[i]), pairs)[0]
    vertex = _pooled_vertex(readouts, cost)
    if vertex is None:
        return None
    readout, std, used, pooled = vertex
    depth_z, agreement = _dip(cost)
    return ReadoutSearch(
        readout_s=float(np.clip(readout, 0.0, readouts[-1])),
        std_s=std,
        interval_s=interval,
        pairs=used,
        frames=(pairs[0].frames[0], pairs[-1].frames[1]),
        candidates_s=tuple(float(r) for r in readouts),
        cost_px2=tuple(float(c) for c in pooled),
        depth_z=depth_z,
        agreement=agreement,
    )


def _dip(cost: FloatArray) -> tuple[float, float]:
    """How clearly the costs (candidates × pairs, px², NaN = not solved) dip: the depth of
    the pooled (mean) cost below its median, in standard errors of a pooled value, and the
    share of pairs whose lowest cost is within one candidate of the pooled lowest, over the
    pairs solved at 3 candidates or more and the candidates where all of those are solved
    (0, 0 where fewer than 3 such candidates or 2 pairs). A cost's noise is the robust spread
    of each pair's second differences about their median (which a smooth curvature
    leaves): for independent noise of σ a second difference has √6 σ."""
    c = cost[:, np.isfinite(cost).sum(axis=0) >= 3]
    c = c[np.isfinite(c).all(axis=1)]
    if c.shape[0] < 3 or c.shape[1] < MIN_PAIRS:
        return 0.0, 0.0
    pooled = c.mean(axis=1)
    best = int(np.argmin(pooled))
    agreement = float(np.mean(np.abs(np.argmin(c, axis=0) - best) <= 1))
    depth = float(np.median(pooled) - pooled[best])
    if c.shape[0] < 4:
        return (math.inf if depth > 0 else 0.0), agreement
    second = c[2:] - 2.0 * c[1:-1] + c[:-2]
    sigma = 1.4826 * float(np.median(np.abs(second - np.median(second, axis=0)))) / math.sqrt(6)
    if sigma <= 0.0:
        return (math.inf if depth > 0 else 0.0), agreement
    return depth / (sigma / math.sqrt(c.shape[1])), agreement


def _pooled_vertex(
    readouts: FloatArray, cost: FloatArray,
) -> tuple[float, float, int, FloatArray] | None:
    """Vertex [s] of the parabola through the mean costs (candidates × pairs, px², NaN = not
    solved) of the pairs solved at the ``PARABOLA_POINTS`` candidates around the best
    median cost; its standard error from the pairs' own vertices (that of a median,
    1.2533 · 1.4826 · MAD / √n; NaN below 3 pairs); the pairs used; the pooled cost per
    candidate (mean over those pairs; NaN where one failed). None without ``MIN_PAIRS``
    such pairs."""
    solved = np.isfinite(cost)
    if not solved.any():
        return None
    median = np.full(len(readouts), np.inf)
    rows = solved.sum(axis=1) >= MIN_PAIRS
    if not rows.any():
        return None
    median[rows] = np.nanmedian(cost[rows], axis=1)
    best = int(np.argmin(median))
    n_points = min(PARABOLA_POINTS, len(readouts))
    lo = int(np.clip(best - n_points // 2, 0, len(readouts) - n_points))
    window = slice(lo, lo + n_points)
    complete = solved[window].all(axis=0)
    if complete.sum() < MIN_PAIRS:
        return None
    x = readouts[window]
    pooled = np.mean(cost[:, complete], axis=1)  # NaN where one of them failed
    vertex = _parabola_vertex(x, pooled[window])
    if vertex is None:  # flat or concave: the grid's best
        vertex = float(readouts[best])
    own = [v for j in np.flatnonzero(complete)
           if (v := _parabola_vertex(x, cost[window, j])) is not None]
    std = float("nan")
    if len(own) >= 3:
        mad = float(np.median(np.abs(np.asarray(own) - np.median(own))))
        std = 1.2533 * 1.4826 * mad / math.sqrt(len(own))
    return vertex, std, int(complete.sum()), pooled


def _parabola_vertex(x: FloatArray, y: FloatArray) -> float | None:
    """Abscissa of the least-squares parabola's minimum through (x, y); None where the
    parabola is not convex (no minimum). Unclipped: a vertex may lie outside ``x``."""
    a, b, _ = np.polyfit(x, y, 2)
    if not a > 0:
        return None
    return float(-b / (2.0 * a))
