"""Forward cameras driving slowly: a level camera's pitch reads low and its travel long, pair
after pair, where the far field moves under a pixel per frame (docs/kitti.md, "Slow
driving"). Car renders at 20 and 30 fps, h 1.5 m, median over the pairs of two seeds:

| travel per frame / height | 0.10 | 0.17 | 0.20 | 0.24 | 0.27–0.31 |
| --- | --- | --- | --- | --- | --- |
| pitch error | −0.43 … −0.60° | −0.33 … −0.40° | −0.12 … −0.20° | −0.07 … +0.01° | ≤ 0.02° |

It is one way over a whole slow stretch, so averaging pairs does not remove it and their
standard deviations do not cover it: the monitor does not judge such pairs, and the drive
summary says how many of them it rests on. The estimator now reads such a pair's pose over a
longer baseline (``vipm_track.long_baseline``: on the same car renders within 0.02°), but not
on a shaking body, in a tight turn or where a table was made with ``--long-baseline 0``, and
KITTI's camera at 0.1 heights per frame still reads 0.5–0.8° low: the rule stands.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from vipm_track.estimator_config import LEVEL_MAX_PITCH_DEG
from vipm_track.measurement import PairMeasurement

#: a level camera's pair is judged from this travel per frame on [share of the height]
MIN_TRAVEL_FRAC_FORWARD = 0.25
#: the HOLD reason of such a pair in the monitor
SLOW_FORWARD = "slow for a forward camera"
#: share of a drive's usable pairs beyond which the summary calls the slow ones out
SLOW_SHARE_WARNING = 0.1


def is_level(pitch_deg: float) -> bool:
    """A forward-looking camera near the horizontal (the estimator's level defaults)."""
    return bool(level_pitches(np.asarray(pitch_deg)))


def level_pitches(pitch_deg: NDArray[np.float64]) -> NDArray[np.bool_]:
    """:func:`is_level` of each pitch [deg] (NaN is not level)."""
    with np.errstate(invalid="ignore"):
        return np.asarray(pitch_deg, dtype=float) < LEVEL_MAX_PITCH_DEG


def slow_pairs(z: NDArray[np.float64], height_assumed: NDArray[np.float64],
               min_travel_frac: float = MIN_TRAVEL_FRAC_FORWARD) -> NDArray[np.bool_]:
    """(n,) pairs ``z`` (n, 7) whose travel is below ``min_travel_frac`` of the height they
    assumed (the scale cancels: the travel is in units of that height); NaN travel is not
    slow."""
    travel = np.hypot(z[:, 4], z[:, 5])
    with np.errstate(invalid="ignore"):
        return travel < min_travel_frac * np.asarray(height_assumed, dtype=float)


def slow_drive_note(measurements: Sequence[PairMeasurement]) -> str:
    """A warning where a level camera's usable pairs are slow in more than
    ``SLOW_SHARE_WARNING`` of the drive ("" otherwise; :func:`slow_share_note`)."""
    ok = [m for m in measurements if m.ok]
    if not ok:
        return ""
    z = np.array([m.z for m in ok])
    height = np.array([m.height_assumed for m in ok])
    return slow_share_note(np.degrees(z[:, 2]), slow_pairs(z, height),
                           np.hypot(z[:, 4], z[:, 5]) / height)


def slow_share_note(pitch_deg: NDArray[np.float64], slow: NDArray[np.bool_],
                    travel_frac: NDArray[np.float64] | None = None) -> str:
    """The warning for usable pairs of measured pitches ``pitch_deg`` [deg] of which ``slow``
    are slow (``travel_frac``: each pair's travel per frame over the camera height, where
    known): where their median pitch is a level camera's and the slow share exceeds
    ``SLOW_SHARE_WARNING``; "" otherwise."""
    slow = np.asarray(slow, dtype=bool)
    if slow.size == 0 or not is_level(float(np.median(pitch_deg))):
        return ""
    share = float(np.mean(slow))
    if share <= SLOW_SHARE_WARNING:
        return ""
    median = "" if travel_frac is None else (
        f"; these pairs' median: {float(np.median(np.asarray(travel_frac)[slow])):.2f}")
    return (f"{int(slow.sum())} of the {slow.size} usable pairs ({share:.0%}) travel less than "
            f"{MIN_TRAVEL_FRAC_FORWARD:g} camera heights per frame: a forward camera's pitch "
            "is biased there, the more the slower (renders of open road, each pair alone: "
            "0.4–0.6° low at 0.1 heights per frame, about 0.9° at 0.05; over the longer "
            "baseline of --long-baseline, within 0.02° for a car, 0.5–0.8° low for KITTI's "
            "camera; among traffic up to 1° either way"
            f"{median}) and its travel with it (the height with wheel speed), one way for the "
            "whole stretch, which the mount intervals do not include; judge the mount from "
            "faster driving (docs/kitti.md, \"Slow driving\")")
