"""What the global shutter assumed without ``--readout-time`` stakes on a drive.

Most CMOS cameras expose their rows one after another. The two-frame fit given no readout
takes a global shutter, and a rolling shutter's row timing is then explained by another
pose and travel: the fit stays good and every row says ``ok`` (a cart at 1.2 m/s with a
50 ms readout: pitch 3.6° low, travel 12 % long, nothing in the residual to show it; see
``readout_search`` for when the residual does show it). What the drive stands to lose is
measured instead: a few pairs that move, solved with a global shutter and with a typical
readout (``TYPICAL_READOUT_S``), differ in pitch, roll and travel by what a camera of that
readout would put in every row. Where that is beyond ``MIN_ANGLE_DEG`` or ``MIN_TRAVEL``,
``estimate`` says so and asks for the readout (0 for a global shutter).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .estimator import TwoFrameEstimator
from .pair_chain import estimate_pair
from .pair_result import STATUS_OK
from .readout_search import spread_moving_pairs

if TYPE_CHECKING:
    from .estimator_config import EstimatorConfig
    from .rig import Rig
    from .sources import FrameSource

#: a typical rolling shutter's readout [s] (1080p CMOS sensors: about 15-33 ms), at most
#: half a frame interval
TYPICAL_READOUT_S = 0.02
#: what counts as at stake: a pitch or roll shift [deg] or a relative travel change
MIN_ANGLE_DEG = 0.2
MIN_TRAVEL = 0.02


@dataclass(frozen=True)
class ReadoutStake:
    """The median change of pitch, roll [deg] and travel (relative) over ``pairs`` pairs
    when solved with ``readout_s`` [s] instead of a global shutter."""

    readout_s: float
    pitch_deg: float
    roll_deg: float
    travel_rel: float
    pairs: int

    @property
    def matters(self) -> bool:
        return (max(abs(self.pitch_deg), abs(self.roll_deg)) >= MIN_ANGLE_DEG
                or abs(self.travel_rel) >= MIN_TRAVEL)

    def line(self) -> str:
        return (f"assuming a global shutter (no --readout-time): on {self.pairs} pairs of this "
                f"drive a rolling shutter's readout of {self.readout_s * 1e3:.0f} ms would move "
                f"pitch by {self.pitch_deg:+.2f}°, roll by {self.roll_deg:+.2f}° and the travel "
                f"by {self.travel_rel:+.1%} in every row; give --readout-time SECONDS from the "
                "sensor's datasheet (0 for a global shutter)")


def readout_stake(
    source: FrameSource, rig: Rig, config: EstimatorConfig, max_pairs: int = 3,
    scan_pairs: int = 6, max_frames: int = 300,
) -> ReadoutStake | None:
    """The stake (module doc) on the ``max_pairs`` furthest-travelling of ``scan_pairs``
    moving pairs spread over the first ``max_frames`` frames of ``source``, each started
    cold from ``rig``'s nominal pose; None where fewer than one pair is solved both ways."""
    spread = spread_moving_pairs(source, rig, scan_pairs, max_frames)
    if spread is None:
        return None
    pairs, interval = spread
    readout = min(TYPICAL_READOUT_S, 0.5 * interval)

    def solve(readout_s: float, chosen: list) -> list:
        estimator = TwoFrameEstimator(rig.with_readout(readout_s), config)
        return [estimate_pair(estimator, p.before, p.image, None, p.interval_s) for p in chosen]

    def usable(result) -> bool:
        return result.status == STATUS_OK and result.motion.distance > 0

    base = solve(0.0, pairs)
    order = sorted((j for j, r in enumerate(base) if usable(r)),
                   key=lambda j: -base[j].motion.distance)[:max_pairs]
    if not order:
        return None
    rolled = solve(readout, [pairs[j] for j in order])
    shifts = [(math.degrees(r.pose_curr.pitch - base[j].pose_curr.pitch),
               math.degrees(r.pose_curr.roll - base[j].pose_curr.roll),
               r.motion.distance / base[j].motion.distance - 1.0)
              for j, r in zip(order, rolled, strict=True) if usable(r)]
    if not shifts:
        return None
    pitch, roll, travel = np.median(np.asarray(shifts), axis=0)
    return ReadoutStake(readout, float(pitch), float(roll), float(travel), len(shifts))


__all__ = ["MIN_ANGLE_DEG", "MIN_TRAVEL", "TYPICAL_READOUT_S", "ReadoutStake", "readout_stake"]
