"""Whether a wheel speed fits the images it is to give the scale: its distance against the
pairs' travel (the height it implies, CONVENTIONS.md, Scale) and its clock against theirs.

A speed in other units, of another drive or standing still while the images move puts the
camera metres off its height; one offset in time by a second moves the height a filter
reports by 5–30 % where the vehicle speeds up or slows down. The filters' own gates reject
such pairs one by one (``partial``) and keep a confident height; these notes say so before
they run.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from vipm_track.errors import InputError
from vipm_track.measurement import PairMeasurement

from .clock_offset import estimate_clock_offset
from .pair_height import HEIGHT_SCALE_WARNING, MIN_TRAVEL_FRAC, wheel_distance
from .wheel_speed import SpeedSeries

#: a fitted clock offset is called out from this size [s] on (and beyond
#: :data:`OFFSET_SIGMAS` of its own error): below it, a CAN bus's usual latency
MIN_OFFSET_S = 0.05
OFFSET_SIGMAS = 3.0
#: the scale is judged on at least this many pairs that move in the images and have a speed
MIN_SCALE_PAIRS = 5


def speed_scale(measurements: Sequence[PairMeasurement], speed: SpeedSeries,
                ) -> tuple[float, int]:
    """The median over usable consecutive pairs that move in the images (travel of at least
    ``MIN_TRAVEL_FRAC`` heights) and lie within the speed's samples [camera clock] of the
    wheel distance over the pair's travel at its assumed height (1: the speed fits the
    assumed height; 0: the wheels stand still), and the number of such pairs."""
    usable = [(prev, m) for prev, m in itertools.pairwise(measurements)
              if m.ok and m.frame == prev.frame + 1]
    if not usable or len(speed) < 2:
        return float("nan"), 0
    t0 = np.array([p.t for p, _ in usable])
    t1 = np.array([m.t for _, m in usable])
    travel = np.array([np.hypot(m.z[4], m.z[5]) for _, m in usable])  # m at the assumed height
    h0 = np.array([m.height_assumed for _, m in usable])
    ends = wheel_distance(speed.t, speed.speed_mps, np.concatenate([t0, t1]))
    distance = np.abs(ends[len(t0):] - ends[:len(t0)])
    keep = np.isfinite(distance) & (travel >= MIN_TRAVEL_FRAC * h0)
    if not keep.any():
        return float("nan"), 0
    return float(np.median(distance[keep] / travel[keep])), int(keep.sum())


def speed_fit_notes(measurements: Sequence[PairMeasurement], speed: SpeedSeries,
                    check_clock: bool = True) -> list[str]:
    """Warnings (one line each; none where the speed fits): the height the speed puts the
    camera at beyond ``HEIGHT_SCALE_WARNING`` times the assumed one (or below its inverse),
    and, with ``check_clock`` (off for a speed already shifted by that fit), a clock offset
    the travel fits better than the speed's own times
    (``clock_offset.estimate_clock_offset``, where the drive's speed changes enough to fix
    one)."""
    notes = []
    source = speed.source or "wheel speed"
    scale, pairs = speed_scale(measurements, speed)
    assumed = float(np.median([m.height_assumed for m in measurements if m.ok] or [np.nan]))
    if pairs >= MIN_SCALE_PAIRS and not (
            1.0 / HEIGHT_SCALE_WARNING <= scale <= HEIGHT_SCALE_WARNING):
        notes.append(
            f"{source}: over {pairs} moving pairs the wheels travel {scale:.2f}× what the images "
            f"do at the assumed {assumed:g} m, which puts the camera {scale * assumed:.3f} m "
            "above the ground: the speed likely belongs to another drive, has another unit "
            "(km/h: 3.6×) or scale (--speed-scale), or stands still while the images move")
    if not check_clock:
        return notes
    try:
        fit = estimate_clock_offset(measurements, speed)
    except InputError:  # a steady speed, too few pairs: nothing to fix an offset by
        return notes
    if abs(fit.offset_s) > max(MIN_OFFSET_S, OFFSET_SIGMAS * fit.std_s):
        notes.append(
            f"{source}: the pairs' travel fits the speed best with its times moved by "
            f"{fit.offset_s:+.3f} s ± {fit.std_s * 1e3:.0f} ms (the speed's clock is offset "
            "from the camera's): give --clock-offset auto, or the offset, else the heights "
            "follow the speed's changes a moment late or early")
    return notes


__all__ = ["MIN_OFFSET_S", "speed_fit_notes", "speed_scale"]
