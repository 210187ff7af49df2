"""Offline test for steps of the mount in a whole drive's pair angles (the batch smoother's).

The online test (``filters.mount_change``) watches the EKF's innovations, which show a step
only until the filter's body state has taken it up: a 0.5° knock of a cart whose pairs are
good to hundredths of a degree went unseen (the batch's mount settled halfway, 0.25° from
both, its interval holding neither). Offline the whole drive is at hand, so the pairs' angle
of their current frame is tested for a change of its mean — the CUSUM test of a structural
change: for the series x₁…xₙ the statistic is

    T = max_k |Σ_{i≤k} (xᵢ − x̄)| / (σ_LR √n),

the largest excursion of the centred partial sums against the long-run standard deviation
σ_LR of the series about the best split's two means (``block_s`` block means, as
``mount_change`` measures it: the pairs' errors run on from frame to frame). Under a
constant mean T is the supremum of a Brownian bridge (P(T > 1.95) ≈ 0.1 %), but real roads
are not that: a car's body rolls for seconds in a turn, the road's camber changes, and
KITTI 07's rows reach T = 2.3–2.7 with no change of mount. ``threshold`` (5) is set above
that; on renders a 0.5° knock of the cart gives T = 12, 1° 32–33; a 1° or 2° knock added
halfway to KITTI 07's rows is not told from the road's wander, 3° is
(``scripts/bench_mount_steps.py``). Splits are searched again within each side (binary
segmentation), each side at least ``min_segment_s``; a series of fewer than 8 blocks is not
tested. A second step inflates the variance about the first split (a knock undone later:
neither found; two knocks: read as a drift), so each search also runs over seeded intervals
(halves, quarters, … overlapping by half, Kovács et al. 2020) of at least
``SEEDED_MIN_BLOCKS`` blocks, where one step stands alone; their statistic counts
``SEEDED_PENALTY`` times less for the many intervals searched. On drives of two minutes and
more both steps are found; on shorter ones not (a variance from differences of block means
found them there, but missed single knocks and drifts on the renders).

A mount that creeps (a loosening bracket) is no step: the same long-run variance, measured
over ever longer blocks, takes a steady drift for wander. So the pairs' angle is also tested
for a linear trend within the segments the steps leave, t = slope / its long-run standard
error, at ``trend_threshold`` (7): rendered carts drifting 0.6°/min over 30 s give t = 10–20,
KITTI 07's rows up to 4.5 (a turn's body roll), knocks 5–6 before their step is taken out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

FloatArray = NDArray[np.float64]


#: the shortest seeded interval, in blocks: shorter ones cannot tell a road's wander over
#: tens of seconds from a step
SEEDED_MIN_BLOCKS = 32
#: a seeded sub-interval's statistic is divided by this: the search over many intervals
#: (a 5-min drive under wander of τ 30 s gave T = 5.8 in one of ten)
SEEDED_PENALTY = 1.5


@dataclass(frozen=True)
class StepTestConfig:
    """The offline step test's design (module doc); ``enabled`` False turns it off."""

    enabled: bool = True
    threshold: float = 5.0
    min_segment_s: float = 1.0
    block_s: float = 1.0
    max_steps: int = 8
    trend_threshold: float = 7.0
    #: a drifting axis's mount walks by the drift over this time per that time [s]
    trend_walk_s: float = 10.0


@dataclass(frozen=True)
class MountStep:
    """A step of one angle's mean: the first frame's time after it [s], the statistic T,
    and the step (later mean less earlier, the series' unit)."""

    onset_s: float
    statistic: float
    step: float


#: blocks of ``StepTestConfig.block_s`` a series needs for its long-run variance
MIN_BLOCKS = 8


def untested_drive_note(t: FloatArray, cfg: StepTestConfig | None = None,
                        tests: str = "the batch's step and drift tests") -> str:
    """A warning for a drive whose frames at times ``t`` [s] fill too few blocks for the step
    and drift tests (:data:`MIN_BLOCKS` of ``block_s`` with 3 frames or more: the long-run
    variance they rest on): a knock or a creeping mount there is not looked for, and the
    mount intervals assume none. ``tests`` names what is not run. Empty where they run."""
    cfg = cfg or StepTestConfig()
    t = np.asarray(t, dtype=float)
    t = t[np.isfinite(t)]
    if not cfg.enabled or t.size == 0:
        return ""
    filled = int(np.count_nonzero(np.bincount(_blocks(t, cfg.block_s)) >= 3))
    if filled >= MIN_BLOCKS:
        return ""
    return (f"the drive's frames fill {filled} of the {MIN_BLOCKS} blocks of {cfg.block_s:g} s "
            f"{tests} need: a knock or a creeping mount within it is not looked for, and the "
            "mount intervals assume none (docs/filters.md)")


def _blocks(t: FloatArray, length: float) -> NDArray[np.int64]:
    """The block of ``length`` seconds, from the first of ``t``, each time falls in."""
    return np.floor((t - t[0]) / length).astype(int)


def long_run_variance(residuals: FloatArray, t: FloatArray, block_s: float,
                      min_blocks: int = MIN_BLOCKS) -> float | None:
    """Long-run variance of ``residuals`` (at times ``t`` [s]) per sample: the mean of
    (block mean)² × block count over blocks of at least 3 samples, the largest over block
    lengths ``block_s``·2ʲ that give ``min_blocks`` such blocks (a road's wander over tens of
    seconds shows only in long blocks). None where even ``block_s`` gives fewer: the plain
    variance would take correlated errors for independent ones (a 3-s drive's slowly moving
    body read as a mount drift at t = 11-15), and 4-7 blocks are too few to measure it
    (6-14 % false finds on 4-6 s of correlated noise)."""
    best: float | None = None
    length = block_s
    while True:
        block = _blocks(t, length)
        counts = np.bincount(block)
        sums = np.bincount(block, weights=residuals)
        full = counts >= 3
        if np.count_nonzero(full) < min_blocks:
            return best
        variance = float(np.mean(sums[full] ** 2 / counts[full]))
        best = variance if best is None else max(best, variance)
        length *= 2.0


def _split(x: FloatArray, t: FloatArray, cfg: StepTestConfig) -> tuple[float, int] | None:
    """The most significant split of ``x`` (at times ``t``) with ``min_segment_s`` on each
    side: its statistic (module doc) and index (the last sample before it); None where no
    split leaves both sides that long or the long-run variance cannot be measured (or is
    zero: nothing varies)."""
    allowed = (t - t[0] >= cfg.min_segment_s) & (t[-1] - t >= cfg.min_segment_s)
    allowed[-1] = False
    if not allowed.any():
        return None
    partial = np.abs(np.cumsum(x - x.mean()))
    k = int(np.argmax(np.where(allowed, partial, -1.0)))
    residuals = np.concatenate([x[:k + 1] - x[:k + 1].mean(), x[k + 1:] - x[k + 1:].mean()])
    variance = long_run_variance(residuals, t, cfg.block_s)
    if variance is None or not variance > 0:
        return None
    return float(partial[k] / np.sqrt(variance * len(x))), k


def one_step_squares(x: FloatArray, cuts: NDArray[np.int64]) -> FloatArray:
    """Per cut k of ``cuts`` (0 < k < len(x)): the sum of squares of ``x`` about the means of
    ``x[:k]`` and ``x[k:]``, what one step at k leaves unexplained (least squares); the
    smallest set against a line's tells a knock from a creep."""
    total, square, n = np.cumsum(x), np.cumsum(x * x), len(x)
    left = square[cuts - 1] - total[cuts - 1] ** 2 / cuts
    right = (square[-1] - square[cuts - 1]) - (total[-1] - total[cuts - 1]) ** 2 / (n - cuts)
    return left + right


def step_onset(t: FloatArray, x: FloatArray, after_s: float) -> float:
    """Time [s] of the first sample after the least-squares single step of ``x`` (finite,
    at times ``t`` [s], in order) among the cuts at or after ``after_s``; NaN where there
    is no such cut (a sequential test's alarm says that a step came, the series where)."""
    cuts = np.flatnonzero(t >= after_s)
    cuts = cuts[(cuts > 0) & (cuts < len(x))]
    if not cuts.size:
        return math.nan
    return float(t[cuts[int(np.argmin(one_step_squares(x, cuts)))]])


def _best_split(x: FloatArray, t: FloatArray, cfg: StepTestConfig) -> MountStep | None:
    """The most significant split over ``x`` and its seeded intervals (halves, quarters, …
    overlapping by half, each at least ``SEEDED_MIN_BLOCKS`` blocks long): a second step in
    the series inflates the variance about the first split (a knock undone later: neither
    found), and an interval holding one step alone measures it cleanly (seeded binary
    segmentation, Kovács et al. 2020)."""
    best: tuple[float, int, int, int] | None = None  # statistic, start, end, split
    length = t[-1] - t[0]
    span = length
    while True:
        starts = [0.0] if span == length else np.arange(0.0, length - span + 1e-9, span / 2)
        for start in starts:
            a, b = np.searchsorted(t, t[0] + start), np.searchsorted(t, t[0] + start + span,
                                                                     side="right")
            found = _split(x[a:b], t[a:b], cfg) if b - a > 2 else None
            if found is None:
                continue
            # a search over many intervals finds wander more often than one over the whole:
            # a sub-interval's statistic counts SEEDED_PENALTY times less
            statistic = found[0] / (1.0 if span == length else SEEDED_PENALTY)
            if best is None or statistic > best[0]:
                best = (statistic, a, b, a + found[1])
        span /= 2.0
        if span < SEEDED_MIN_BLOCKS * cfg.block_s:
            break
    if best is None:
        return None
    statistic, a, b, k = best
    return MountStep(float(t[k + 1]), statistic, float(x[k + 1:b].mean() - x[a:k + 1].mean()))


def pairs_steps(t: FloatArray, angles: FloatArray, cfg: StepTestConfig | None = None,
                ) -> list[tuple[float, str, float]]:
    """(onset [s], ``pitch`` or ``roll``, step [rad]) of each step :func:`mount_steps` finds
    in the usable pairs' pitch and roll (``t`` [s], ``angles`` (n, 2) [rad]), in time order."""
    return sorted((s.onset_s, name, s.step) for i, name in enumerate(("pitch", "roll"))
                  for s in mount_steps(t, angles[:, i], cfg))


def steps_text(steps: Sequence[tuple[float, str, float]]) -> str:
    """``pitch stepped +1.00° at 3.20 s, …``: :func:`pairs_steps`' steps for a warning."""
    return ", ".join(f"{name} stepped {math.degrees(step):+.2f}° at {at:.2f} s"
                     for at, name, step in steps)


def usable_angles(ms: Sequence[PairMeasurement]) -> tuple[FloatArray, FloatArray]:
    """Times [s] and (n, 2) angles of their current frame (pitch, roll; rad) of the usable
    pairs: the series the step and drift tests look at."""
    usable = [m for m in ms if m.ok]
    return (np.array([m.t for m in usable]),
            np.array([m.z[2:4] for m in usable]).reshape(-1, 2))


def _finite(t: FloatArray, x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``t``, ``x`` as float arrays, the samples where either is not finite left out."""
    t, x = np.asarray(t, dtype=float), np.asarray(x, dtype=float)
    keep = np.isfinite(t) & np.isfinite(x)
    return t[keep], x[keep]


def mount_steps(t: FloatArray, x: FloatArray, cfg: StepTestConfig | None = None
                ) -> list[MountStep]:
    """Steps of the mean of ``x`` (one angle of the pairs, at times ``t`` [s], increasing),
    in time order: binary segmentation with the CUSUM test of the module doc."""
    cfg = cfg or StepTestConfig()
    t, x = _finite(t, x)
    found: list[MountStep] = []
    if len(x) < 2:
        return found
    pending = [(0, len(x))]
    while pending and len(found) < cfg.max_steps:
        lo, hi = pending.pop()
        split = _best_split(x[lo:hi], t[lo:hi], cfg)
        if split is None or not split.statistic > cfg.threshold:
            continue
        found.append(split)
        k = lo + int(np.searchsorted(t[lo:hi], split.onset_s))
        pending += [(lo, k), (k, hi)]
    return sorted(found, key=lambda s: s.onset_s)


def mount_trend(t: FloatArray, x: FloatArray, steps: list[MountStep],
                cfg: StepTestConfig | None = None) -> float | None:
    """The slope [unit of ``x`` per s] of a linear trend of ``x`` (at times ``t`` [s]) within
    the segments ``steps`` leave, where its statistic (module doc) exceeds
    ``cfg.trend_threshold``; None where it does not."""
    cfg = cfg or StepTestConfig()
    trend = trend_statistic(t, x, steps, cfg)
    return trend[0] if trend is not None and trend[1] > cfg.trend_threshold else None


def trend_statistic(t: FloatArray, x: FloatArray, steps: list[MountStep],
                    cfg: StepTestConfig | None = None) -> tuple[float, float] | None:
    """The slope [unit of ``x`` per s] of a linear trend of ``x`` (at times ``t`` [s]) within
    the segments ``steps`` leave and its statistic (the slope over its long-run standard
    error); None where it cannot be measured."""
    cfg = cfg or StepTestConfig()
    t, x = _finite(t, x)
    if len(x) < 3:
        return None
    segment = np.searchsorted([s.onset_s for s in steps], t, side="right")
    tc, xc = t.copy(), x.copy()
    for i in np.unique(segment):
        inside = segment == i
        tc[inside] -= tc[inside].mean()
        xc[inside] -= xc[inside].mean()
    spread = float(np.sum(tc ** 2))
    if spread <= 0:
        return None
    slope = float(np.sum(tc * xc) / spread)
    variance = long_run_variance(xc - slope * tc, t, cfg.block_s)
    if variance is None or not variance > 0:
        return None
    return slope, abs(slope) / float(np.sqrt(variance / spread))
