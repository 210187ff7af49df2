"""The clock offset between the camera and a wheel-speed source, found from the data.

A pair's visual travel ``d_k = ‖(tx, tz)‖`` (metric at the assumed height h_a, CONVENTIONS.md,
Scale) and the wheel's distance over the same frame interval are proportional:

    d_k = c · (D(t_k − δ) − D(t_{k−1} − δ)) + e_k,      c = h_a / h_true,

with D the wheel distance (the speed integrated on its own clock) and δ the offset added to the
speed's times to reach the camera's (``--clock-offset``). Where the speed changes, a wrong δ
compares each pair with the wheel's travel at another moment, so the residual grows with the
offset error times the acceleration; at constant speed δ is unobservable (and said so).

:func:`estimate_clock_offset` scores every offset that keeps at least half of the drive's
pairs inside the speed samples on a coarse grid (blocks of pairs, the weighted uncentred
correlation of travel and wheel distance), refines the best few peaks by a parabola on the
residual profile over every pair (outliers dropped), and keeps the best only if no other
offset explains the pairs nearly as well (a paired test against the runner-up) and the
offset is determined to a useful precision.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vipm_track.errors import InputError
from vipm_track.measurement import PairMeasurement

from .row_correlation import correlation_inflation
from .wheel_speed import SpeedSeries, cumulative_distance

FloatArray = NDArray[np.float64]

#: fewest usable pairs for a fit
MIN_PAIRS = 20
#: the coarse search: a first pass over the whole range with blocks of the drive's duration
#: over ``FIRST_PASS_BLOCKS`` (within the bounds, seconds) and steps of a fifth of a block, then
#: a second pass of ``BLOCK_S`` blocks and ``COARSE_STEP_S`` steps around each of the first
#: pass's ``FIRST_PASS_PEAKS`` best peaks
FIRST_PASS_BLOCKS = 100
FIRST_PASS_BLOCK_BOUNDS_S = (0.5, 5.0)
FIRST_PASS_PEAKS = 8
COARSE_STEP_S = 0.05
BLOCK_S = 0.5
#: candidate peaks refined, and how far apart [s] two candidates must be
CANDIDATES = 4
CANDIDATE_SEPARATION_S = 1.0
#: the runner-up must explain the pairs both cover worse by this many standard errors of the
#: pairs' loss differences (paired test: at a wrong offset of a periodic or constant speed
#: the differences are noise and this is N(0, 1))
MIN_SEPARATION_Z = 5.0
#: an offset known worse than this [s, 1σ] is refused
MAX_STD_S = 0.1
#: relative floor on a pair's travel noise (wheel-speed noise, model error)
TRAVEL_NOISE_FLOOR = 0.002
#: the wheel/visual scale is solved per this many seconds of the drive [s]
SCALE_SEGMENT_S = 30.0
#: the wheel speed is averaged twice over this window [s] before it is compared
SPEED_SMOOTHING_S = 0.25
#: residual profile of the fine fit: half-width [s] of the first window, of the narrowest,
#: points per window and passes
PROFILE_HALF_WIDTH_S = 0.3
PROFILE_MIN_HALF_WIDTH_S = 0.05
PROFILE_POINTS = 61
PROFILE_PASSES = 3
#: the parabola's 1σ is this much too small on simulated drives (with 1.5 the RMS of error/σ
#: was 0.7–0.93 over 120 car and cart drives of 30–120 s; with 1.2 it is 0.89–1.29 over 240,
#: scripts/bench_clock_offset.py): what is left of the residual's roughness
STD_INFLATION = 1.2
#: pairs whose whitened residual exceeds this many robust σ are outliers
OUTLIER_SIGMAS = 5.0


@dataclass(frozen=True)
class ClockOffsetFit:
    """The offset [s] added to the speed's times to reach the camera clock, its 1σ [s], the
    wheel/visual scale ``c = h_assumed / h_true`` it comes with, the pairs used and rejected,
    and the best other offset [s] with how much worse it explains the pairs both cover
    (``separation_z``: standard errors of the paired loss differences; inf when no other
    offset could be tried)."""

    offset_s: float
    std_s: float
    scale: float
    pairs: int
    outliers: int
    runner_up_s: float | None
    separation_z: float

    def height_m(self, height_assumed_m: float) -> float:
        """The camera height [m] the wheel speed implies, given the assumed one."""
        return height_assumed_m / self.scale

    def line(self) -> str:
        """One line for a run's log."""
        runner = ("no other offset fits" if self.runner_up_s is None else
                  f"next best {self.runner_up_s:+.3f} s, {self.separation_z:.0f} σ worse")
        return (f"clock offset {self.offset_s:+.3f} s ± {self.std_s * 1e3:.1f} ms (speed time + "
                f"offset = camera time; {self.pairs} pairs, {self.outliers} outliers; {runner})")


@dataclass(frozen=True)
class _Pairs:
    """Usable pairs: interval start/end [s, camera clock], travel [m], travel std [m]."""

    a: FloatArray
    b: FloatArray
    d: FloatArray
    sigma: FloatArray


def estimate_clock_offset(
    measurements: Sequence[PairMeasurement],
    speed: SpeedSeries,
    min_overlap: float = 0.5,
) -> ClockOffsetFit:
    """The clock offset of ``speed`` against the camera clock of ``measurements`` (module doc).

    ``speed`` is on its own clock (no offset applied); ``min_overlap`` is the smallest share
    of the usable pairs an offset must leave inside the speed samples to be tried. Raises
    :class:`InputError` when too few pairs are usable, when the clocks cannot overlap, when the
    speed changes too little to fix the offset, or when two offsets fit alike."""
    pairs = _usable_pairs(measurements)
    source = speed.source or "wheel speed"
    if pairs.d.size < MIN_PAIRS:
        raise InputError(f"{source}: clock offset: {pairs.d.size} usable pairs with travel, "
                         f"need {MIN_PAIRS}")
    if len(speed) < 2:
        raise InputError(f"{source}: clock offset: fewer than two speed samples")
    t_speed, cum = _smoothed_distance(speed)
    lo, hi = _search_range(pairs, t_speed, min_overlap, source)
    starts = _candidates(pairs, t_speed, cum, lo, hi, min_overlap)
    if not starts:
        raise InputError(f"{source}: clock offset: no offset leaves {min_overlap:.0%} of the "
                         "pairs inside the speed samples")
    fits = [f for f in (_refine(pairs, t_speed, cum, s, min_overlap) for s in starts)
            if f is not None]
    if not fits:
        raise InputError(f"{source}: clock offset: at every candidate offset fewer than "
                         f"{MIN_PAIRS} of the {pairs.d.size} usable pairs (or under "
                         f"{min_overlap:.0%}) stay inside the speed samples "
                         f"({t_speed[-1] - t_speed[0]:.1f} s once averaged; the pairs span "
                         f"{pairs.b[-1] - pairs.a[0]:.1f} s); give --clock-offset SECONDS")
    best, runner, z = _select(fits)
    fit = ClockOffsetFit(offset_s=best.offset, std_s=best.std, scale=best.scale,
                         pairs=best.used, outliers=best.outliers,
                         runner_up_s=None if runner is None else runner.offset,
                         separation_z=z)
    if not best.std <= MAX_STD_S:
        raise InputError(f"{source}: clock offset: the speed changes too little while the camera "
                         f"runs to fix the offset ({fit.offset_s:+.3f} s ± {best.std:.2f} s); "
                         "give --clock-offset SECONDS")
    if z < MIN_SEPARATION_Z:
        raise InputError(f"{source}: clock offset: {best.offset:+.3f} s and "
                         f"{fit.runner_up_s:+.3f} s explain the travel almost alike ({z:.1f} σ "
                         "apart); give --clock-offset SECONDS")
    return fit


# --- data ------------------------------------------------------------------------------------


def _usable_pairs(measurements: Sequence[PairMeasurement]) -> _Pairs:
    """Pairs with status ok, a previous frame just before them and a travel above 1 mm."""
    a, b, d, sigma = [], [], [], []
    previous: PairMeasurement | None = None
    for m in measurements:
        if (previous is not None and m.ok and m.frame == previous.frame + 1
                and m.t > previous.t):
            tx, tz = float(m.z[4]), float(m.z[5])
            travel = float(np.hypot(tx, tz))
            if travel > 1e-3:
                g = np.array([tx, tz]) / travel
                var = float(g @ m.covariance[4:6, 4:6] @ g)
                var = max(var, 0.0) + (TRAVEL_NOISE_FLOOR * travel) ** 2
                a.append(previous.t)
                b.append(m.t)
                d.append(travel)
                sigma.append(np.sqrt(var))
        previous = m
    return _Pairs(*(np.asarray(x, dtype=np.float64) for x in (a, b, d, sigma)))


def _smoothed_distance(speed: SpeedSeries) -> tuple[FloatArray, FloatArray]:
    """Sample times [s, speed clock] and the wheel distance [m] of the speed averaged twice
    over ``SPEED_SMOOTHING_S`` (a triangle twice as wide; symmetric, so no time shift); the
    first and last window are dropped.

    Moving the offset swaps which samples each frame interval integrates; from the raw
    samples the residual would then be rough on the scale of their spacing, and that
    roughness (sample noise: 0.5 % of 13 m/s against an acceleration's 0.05 m/s per frame)
    would read as information about the offset. The average keeps the slow changes of the
    speed, which are what the offset moves."""
    t, v = speed.t, np.abs(speed.speed_mps)
    half = 0.5 * SPEED_SMOOTHING_S
    for _ in range(2):
        cum = cumulative_distance(t, v)
        mid = t[(t - half >= t[0]) & (t + half <= t[-1])]
        if mid.size < 2:
            raise InputError(f"{speed.source or 'wheel speed'}: clock offset: the speed "
                             f"samples span less than {2 * SPEED_SMOOTHING_S:.1f} s")
        v = (np.interp(mid + half, t, cum) - np.interp(mid - half, t, cum)) / SPEED_SMOOTHING_S
        t = mid
    return t, cumulative_distance(t, v)


def _wheel_travel(t_speed: FloatArray, cum: FloatArray, a: FloatArray, b: FloatArray,
                  offset: float | FloatArray) -> FloatArray:
    """Wheel distance [m] between camera times ``a`` and ``b`` (NaN outside the samples)."""
    ta, tb = a - offset, b - offset
    out = np.interp(tb, t_speed, cum) - np.interp(ta, t_speed, cum)
    return np.where((ta >= t_speed[0]) & (tb <= t_speed[-1]), out, np.nan)


def _search_range(pairs: _Pairs, t_speed: FloatArray, min_overlap: float,
                  source: str) -> tuple[float, float]:
    """Offsets [s] that can leave ``min_overlap`` of the pairs inside the speed samples."""
    q = np.clip(min_overlap, 0.0, 1.0)
    # offset δ keeps pair k inside iff t0 + δ <= a_k and b_k <= t1 + δ
    a_hi = np.quantile(pairs.a, 1.0 - q)   # δ up to this keeps ≥ q of the starts after t0 + δ
    b_lo = np.quantile(pairs.b, q)         # δ from this keeps ≥ q of the ends before t1 + δ
    lo, hi = b_lo - t_speed[-1], a_hi - t_speed[0]
    if hi < lo:
        raise InputError(f"{source}: clock offset: the speed samples "
                         f"span {t_speed[-1] - t_speed[0]:.1f} s, too short to cover "
                         f"{min_overlap:.0%} of the camera's {pairs.b[-1] - pairs.a[0]:.1f} s")
    # no bound beyond the overlap: a CAN log stamped in Unix time (1.7e9 s) beside a camera
    # counting from 0 is the commonest pairing of all
    return lo, hi


def _candidates(pairs: _Pairs, t_speed: FloatArray, cum: FloatArray, lo: float, hi: float,
                min_overlap: float) -> list[float]:
    """Offsets [s] in [lo, hi] whose block travel correlates best with the wheel's, best
    first: up to ``CANDIDATES``, ``CANDIDATE_SEPARATION_S`` apart."""
    duration = float(pairs.b[-1] - pairs.a[0])
    block = float(np.clip(duration / FIRST_PASS_BLOCKS, *FIRST_PASS_BLOCK_BOUNDS_S))
    grid = np.arange(lo, hi + 0.1 * block, 0.2 * block)
    score = _coarse_scores(_blocks(pairs, block), t_speed, cum, grid, min_overlap)
    fine_blocks = _blocks(pairs, BLOCK_S)
    reach = max(2.0, 2.0 * block)
    found: list[tuple[float, float]] = []
    for start in _peaks(grid, score, FIRST_PASS_PEAKS, 2.0 * block):
        fine = np.arange(max(lo, start - reach), min(hi, start + reach) + 0.5 * COARSE_STEP_S,
                         COARSE_STEP_S)
        fine_score = _coarse_scores(fine_blocks, t_speed, cum, fine, min_overlap)
        found += [(float(fine_score[np.argmin(np.abs(fine - p))]), p)
                  for p in _peaks(fine, fine_score, CANDIDATES, CANDIDATE_SEPARATION_S)]
    chosen: list[float] = []
    for _, offset in sorted(found, reverse=True):
        if all(abs(offset - c) >= CANDIDATE_SEPARATION_S for c in chosen):
            chosen.append(offset)
    return chosen[:CANDIDATES]


def _blocks(pairs: _Pairs, length: float) -> _Pairs:
    """Runs of consecutive pairs cut into blocks of about ``length`` [s]: summed travel over
    the block's whole interval (the wheel distance telescopes over contiguous pairs)."""
    new_run = np.concatenate([[True], pairs.a[1:] != pairs.b[:-1]])
    run_id = np.cumsum(new_run)
    run_start = pairs.a[new_run][run_id - 1]
    block_key = run_id * 1e9 + np.floor((pairs.a - run_start) / length)
    starts = np.flatnonzero(np.concatenate([[True], block_key[1:] != block_key[:-1]]))
    ends = np.concatenate([starts[1:], [pairs.d.size]]) - 1
    d = np.add.reduceat(pairs.d, starts)
    var = np.add.reduceat(pairs.sigma ** 2, starts)
    return _Pairs(pairs.a[starts], pairs.b[ends], d, np.sqrt(var))


def _coarse_scores(blocks: _Pairs, t_speed: FloatArray, cum: FloatArray, grid: FloatArray,
                   min_overlap: float) -> FloatArray:
    """Weighted uncentred correlation of block travel and wheel distance at each offset
    (NaN where fewer than ``min_overlap`` of the blocks are covered)."""
    w = 1.0 / blocks.sigma ** 2
    out = np.full(grid.size, np.nan)
    chunk = max(1, 4_000_000 // max(blocks.d.size, 1))
    for i in range(0, grid.size, chunk):
        off = grid[i:i + chunk, None]
        wheel = _wheel_travel(t_speed, cum, blocks.a[None, :], blocks.b[None, :], off)
        ok = np.isfinite(wheel)
        wheel = np.where(ok, wheel, 0.0)
        d = np.where(ok, blocks.d[None, :], 0.0)
        sdw = (w * d * wheel).sum(axis=1)
        sww = (w * wheel * wheel).sum(axis=1)
        sdd = (w * d * d).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            score = sdw / np.sqrt(sww * sdd)
        covered = ok.mean(axis=1) >= min_overlap
        out[i:i + chunk] = np.where(covered & (sww > 0), score, np.nan)
    return out


def _peaks(grid: FloatArray, score: FloatArray, count: int, separation: float) -> list[float]:
    """Up to ``count`` offsets of the highest scores, each a local maximum at least
    ``separation`` [s] from the others."""
    finite = np.isfinite(score)
    if not finite.any():
        return []
    s = np.where(finite, score, -np.inf)
    left = np.concatenate([[-np.inf], s[:-1]])
    right = np.concatenate([s[1:], [-np.inf]])
    local = np.flatnonzero(finite & (s >= left) & (s >= right))
    chosen: list[float] = []
    for i in local[np.argsort(-s[local])]:
        if all(abs(grid[i] - c) >= separation for c in chosen):
            chosen.append(float(grid[i]))
        if len(chosen) == count:
            break
    return chosen


# --- fine fit ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Fine:
    offset: float
    std: float
    scale: float
    used: int
    outliers: int
    noise_scale: float
    residual: FloatArray  # whitened, every pair; NaN where not covered


def _profile(pairs: _Pairs, t_speed: FloatArray, cum: FloatArray, offsets: FloatArray,
             keep: NDArray[np.bool_]) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Weighted residual sum of squares [whitened units] at each of ``offsets``, over the kept
    pairs covered at every one of them, with the scale solved per ``SCALE_SEGMENT_S`` of the
    drive (the height, tyre radius and load drift; one scale for a whole drive would turn
    such a drift into an offset wherever it lines up with a speed change); the mean scale at
    each offset; the pairs used."""
    wheel = _wheel_travel(t_speed, cum, pairs.a[None, :], pairs.b[None, :], offsets[:, None])
    use = keep & np.isfinite(wheel).all(axis=0) & (np.nan_to_num(wheel) > 0).all(axis=0)
    w = 1.0 / pairs.sigma[use] ** 2
    d, wt = pairs.d[use], wheel[:, use]
    segment = _scale_segments(pairs)[use]
    starts = np.flatnonzero(np.concatenate([[True], segment[1:] != segment[:-1]]))
    sdd = np.add.reduceat(w * d * d, starts)
    sdw = np.add.reduceat(w * d * wt, starts, axis=1)
    sww = np.add.reduceat(w * wt * wt, starts, axis=1)
    cost = (sdd[None, :] - sdw ** 2 / sww).sum(axis=1)
    return cost, sdw.sum(axis=1) / sww.sum(axis=1), use


def _scale_segments(pairs: _Pairs) -> NDArray[np.int64]:
    """Each pair's ``SCALE_SEGMENT_S`` segment of the drive (0, 1, …; pairs are in time order)."""
    return np.floor((pairs.b - pairs.b[0]) / SCALE_SEGMENT_S).astype(np.int64)


def _local_scale(pairs: _Pairs, wheel: FloatArray, use: NDArray[np.bool_]) -> FloatArray:
    """Each pair's scale: the least-squares one of its ``SCALE_SEGMENT_S`` segment."""
    segment = _scale_segments(pairs)
    w = np.where(use, 1.0 / pairs.sigma ** 2, 0.0)
    wheel0 = np.nan_to_num(wheel)
    sdw = np.bincount(segment, w * pairs.d * wheel0)
    sww = np.bincount(segment, w * wheel0 * wheel0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (sdw / sww)[segment]


def _refine(pairs: _Pairs, t_speed: FloatArray, cum: FloatArray, start: float,
            min_overlap: float) -> _Fine | None:
    """The offset near ``start`` [s] minimising the pairs' residuals, from a parabola fitted
    to the residual profile over a window around it, its 1σ from the parabola's curvature.

    A parabola over a window rather than Gauss–Newton's local derivative: what is left of the
    residual's roughness (``_smoothed_distance``) averages out over the window."""
    keep = np.ones(pairs.d.size, dtype=bool)
    offset, half = start, PROFILE_HALF_WIDTH_S
    for _ in range(PROFILE_PASSES):
        offsets = offset + np.linspace(-half, half, PROFILE_POINTS)
        cost, _, use = _profile(pairs, t_speed, cum, offsets, keep)
        if use.sum() < max(MIN_PAIRS, min_overlap * pairs.d.size):
            return None
        j = int(np.argmin(cost))
        wheel = _wheel_travel(t_speed, cum, pairs.a, pairs.b, offsets[j])
        r = (pairs.d - _local_scale(pairs, wheel, use) * wheel) / pairs.sigma
        s = 1.4826 * float(np.median(np.abs(r[use]))) or 1.0
        outlier = use & (np.abs(r) > OUTLIER_SIGMAS * s)
        if outlier.any():
            keep &= ~outlier
            cost, _, use = _profile(pairs, t_speed, cum, offsets, keep)
            j = int(np.argmin(cost))
        a2, a1, _ = np.polyfit(offsets - offset, cost, 2)
        if a2 > 0:
            vertex = offset + float(np.clip(-a1 / (2.0 * a2), -half, half))
            std = STD_INFLATION * s / np.sqrt(a2)
        else:
            vertex, std = float(offsets[j]), np.inf
        # next pass: a window of a few σ around the vertex, where the parabola holds best
        offset = vertex
        half = float(np.clip(4.0 * std, PROFILE_MIN_HALF_WIDTH_S, PROFILE_HALF_WIDTH_S))
    _, scale_v, used_v = _profile(pairs, t_speed, cum, np.array([offset]), keep)
    wheel = _wheel_travel(t_speed, cum, pairs.a, pairs.b, offset)
    residual = (pairs.d - _local_scale(pairs, wheel, used_v) * wheel) / pairs.sigma
    # the parabola's σ counts every pair as news; a travel error that drifts with the pose
    # over seconds moves the fit further than it says
    std *= correlation_inflation(residual[used_v])
    return _Fine(offset=offset, std=float(std), scale=float(scale_v[0]),
                 used=int(used_v.sum()), outliers=int((~keep).sum()), noise_scale=s,
                 residual=np.where(np.isfinite(wheel) & (wheel > 0), residual, np.nan))


def _select(fits: list[_Fine]) -> tuple[_Fine, _Fine | None, float]:
    """The fit whose pairs are explained best, the runner-up more than half a candidate
    separation away, and how many standard errors of the paired loss differences apart.

    Each pair's loss is its squared whitened residual capped at ``OUTLIER_SIGMAS`` of the
    best noise level, so a fit cannot win by discarding pairs or by covering fewer."""
    cap = (OUTLIER_SIGMAS * min(f.noise_scale for f in fits)) ** 2
    losses = [np.minimum(f.residual ** 2, cap) for f in fits]
    order = np.argsort([float(np.nanmean(loss)) for loss in losses])
    best = fits[order[0]]
    runner, z_min = None, np.inf
    for i in order[1:]:
        if abs(fits[i].offset - best.offset) <= 0.5 * CANDIDATE_SEPARATION_S:
            continue
        diff = losses[i] - losses[order[0]]
        diff = diff[np.isfinite(diff)]
        if diff.size < MIN_PAIRS:
            continue
        spread = float(np.std(diff)) * np.sqrt(diff.size)
        z = float(diff.sum()) / spread if spread > 0 else np.inf
        if z < z_min:
            runner, z_min = fits[i], z
    return best, runner, z_min
