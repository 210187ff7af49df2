"""A slow forward camera's pose over a longer baseline than one frame interval.

A level camera's pair measures the change of pose between its frames far better than the
pose itself, and the less it travels the worse: over 0.2 m (KITTI's camera at 2 m/s, 10 fps)
the pitch trades against the travel, far-field patches that move less than a pixel are pulled
towards zero by the warps' interpolation (docs/kitti.md, "Slow driving"), and a car ahead that
moves with us can hold the fit (docs/traffic.md). Where a pair in tracking mode travels less than
``EstimatorConfig.long_baseline_heights`` camera heights (0.3), frame k's pose is estimated once
more against an earlier frame r that far back (at most :data:`MAX_FRAMES_BACK` frames and
:data:`MAX_SECONDS_BACK` s, through ``ok`` pairs only), seeded by the pairs between them and
with frame r held to its own estimate, as tracking holds frame k-1 (not in a turn tighter than
:data:`TIGHT_TURN_DEG_PER_M`, nor on a body shaking faster than :data:`SHAKING_DEG_PER_S`).
The short pair is then
conditioned on that pose (:func:`condition_on_pose`): frame k's pose and its covariance become
the long pair's, and frame k-1's pose and the motion move with it through the short pair's
correlations, which keep the precise change between the two frames. The next pair is tracked
from there.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from .displacement_model import pack, unpack
from .geometry import PlanarMotion, compose_motion
from .pair_result import FloatArray, PairGuess

if TYPE_CHECKING:
    from .pair_result import PairResult

#: how far back the earlier frame may lie, in frames and in seconds
MAX_FRAMES_BACK = 5
MAX_SECONDS_BACK = 1.0
#: where no frame within reach is far enough (a crawl), the farthest is taken if it
#: travels at least this many times the short pair's distance
LEAST_GAIN = 2.0
#: a tighter turn [deg of yaw per metre of travel, over the longer pair] is left to the short
#: pair: on renders of cars turning on a 6 m radius (10°/m) each pair alone read the pitch
#: 0.07-0.26° off (mean), the longer pair 0.14-0.40° (the roll a little better)
TIGHT_TURN_DEG_PER_M = 4.0
#: a body whose pitch and roll change faster than this [deg/s, RMS over the pairs the longer
#: pair spans] is left to the short pair: it heaves as well, and over the longer interval the
#: heave the fit does not model costs more than the baseline gains (a car shaking at 8°/s in
#: dense traffic at 3 m/s: ok rows beyond 1.5° 5 and 3 → 11 and 3 with the longer pair; a
#: body pitching 1.3°/s gained from it)
SHAKING_DEG_PER_S = 4.0
#: frame k's pose (pitch, roll) in the 7-vector of a pair
_POSE = slice(2, 4)


@dataclass(frozen=True)
class _Frame:
    """A frame the chain has seen: its image, its time [s] and the pair ending at it (None
    where it began the chain)."""

    image: NDArray
    t: float
    pair: PairResult | None


@dataclass(frozen=True)
class LongPair:
    """The earlier frame's image and the pair's guess and interval [s]."""

    image: NDArray
    guess: PairGuess
    interval_s: float


class RecentFrames:
    """The last frames of a chain of consecutive pairs and the pairs ending at them (a pair
    that is not ``ok`` breaks the chain there), to reach back from (module doc)."""

    def __init__(self) -> None:
        self._frames: deque[_Frame] = deque(maxlen=MAX_FRAMES_BACK + 1)

    def clear(self) -> None:
        self._frames.clear()

    def add(self, prev: NDArray, curr: NDArray, t: float, dt: float, pair: PairResult) -> None:
        """The pair of ``prev`` and ``curr`` (ending at ``t`` [s], ``dt`` [s] long) has been
        estimated as ``pair``. A ``prev`` that is not the last frame added starts anew (a frame
        was dropped or could not be used)."""
        if not self._frames or self._frames[-1].image is not prev:
            self._frames.clear()
            self._frames.append(_Frame(prev, t - dt, None))
        self._frames.append(_Frame(curr, t, pair))

    def reference(self, baseline_m: float) -> LongPair | None:
        """The longer pair for the newest frame (module doc): the earlier frame at least
        ``baseline_m`` [m] of travel back, else the farthest within reach; None where its
        pair travelled that far, or no earlier frame gains enough."""
        frames = list(self._frames)
        newest = frames[-1].pair
        if not _ok(newest) or not newest.motion.distance < baseline_m:
            return None
        motion, after = newest.motion, newest  # the pair that starts at frames[i]
        best: tuple[int, PlanarMotion, PairResult] | None = None
        for i in range(len(frames) - 2, -1, -1):
            if i < len(frames) - 2:  # frames[i] is further back than the short pair's start
                if not frames[-1].t - frames[i].t <= MAX_SECONDS_BACK:
                    break
                best = (i, motion, after)
                if motion.distance >= baseline_m:
                    break
            pair = frames[i].pair
            if not _ok(pair):
                break
            motion, after = compose_motion(pair.motion, motion), pair
        if best is None or not (best[1].distance >= baseline_m
                                or best[1].distance >= LEAST_GAIN * newest.motion.distance):
            return None
        i, motion, after = best
        if (abs(math.degrees(motion.yaw)) > TIGHT_TURN_DEG_PER_M * motion.distance
                or _angular_rate_dps(frames[i:]) > SHAKING_DEG_PER_S):
            return None
        guess = PairGuess(after.pose_prev, newest.pose_curr, motion)
        return LongPair(frames[i].image, guess, frames[-1].t - frames[i].t)


def _ok(pair: PairResult | None) -> bool:
    """An ``ok`` pair ending at a frame (None where the frame began the chain)."""
    return pair is not None and pair.ok


def _angular_rate_dps(frames: list[_Frame]) -> float:
    """RMS rate [deg/s] of the pitch and roll change of the pairs ending at ``frames[1:]``;
    inf where an interval is not positive (frame times that repeat or go back)."""
    rates = []
    for before, f in itertools.pairwise(frames):
        interval = f.t - before.t
        if not interval > 0:
            return math.inf
        rates.append(math.degrees(math.hypot(f.pair.pose_curr.pitch - f.pair.pose_prev.pitch,
                                             f.pair.pose_curr.roll - f.pair.pose_prev.roll))
                     / interval)
    return math.sqrt(sum(r * r for r in rates) / len(rates)) if rates else 0.0


def condition_on_pose(result: PairResult, longer: PairResult,
                      spread: FloatArray | None = None) -> bool:
    """Condition ``result`` on the pose of its frame k that ``longer`` measured (module doc);
    whether it could (both covariances known). ``spread``: a part of ``result``'s covariance
    that its own fit did not measure (a second start's d dᵀ: two minima the patches do not
    tell apart, ``pair_chain.from_the_nominal_too``): left out of the conditioning, whose
    gain it would turn along the other minimum's direction, and added back after it (the
    longer pair, seeded from this one, does not settle which minimum is the camera's).

    The longer pair is taken whatever the two pairs' stated σ: the heave term of a pair's
    covariance grows with its interval, so the longer pair states a wider σ (1.2° against
    1.0° on an open road at 0.1 camera heights per frame) while it is nearer the truth (0.5°
    against 1.7° off); its own covariance goes with it."""
    extra = np.zeros((7, 7)) if spread is None else np.asarray(spread, dtype=float)
    cov = np.asarray(result.covariance, dtype=float) - extra
    other = np.asarray(longer.covariance, dtype=float)[_POSE, _POSE]
    own = cov[_POSE, _POSE]
    if not (np.all(np.isfinite(cov)) and np.all(np.isfinite(other))):
        return False
    gain: FloatArray = np.linalg.solve(own, cov[_POSE, :]).T  # 7×2
    x = pack(result.pose_prev, result.pose_curr, result.motion)
    y = np.array([longer.pose_curr.pitch, longer.pose_curr.roll])
    x = x + gain @ (y - x[_POSE])
    keep = np.eye(7)
    keep[:, _POSE] -= gain
    new = keep @ cov @ keep.T + gain @ other @ gain.T + extra
    result.covariance = 0.5 * (new + new.T)
    pose_prev, pose_curr, motion = unpack(x, result.pose_prev.height)
    result.pose_prev, result.motion = pose_prev, motion
    result.pose_curr = replace(result.pose_curr, pitch=pose_curr.pitch, roll=pose_curr.roll)
    return True
