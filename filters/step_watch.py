"""The batch's offline step test run while a drive goes on: knocks the online test missed.

The online mount-change test (``mount_change``) runs at full sensitivity only once it has
measured the road's wander (``min_blocks + holdout`` blocks: 6 s from the start and from each
change it calls); a knock before then is taken up by the window's body and mount and never
called (a car knocked 1° at 4 s: the fixed lag's mount 0.3–0.4° off to the drive's end, z
9–12, where the batch holds it within 0.1°). So a streaming filter also runs the batch's
test (``mount_steps``) on its usable pairs' angles, once per block, over the last
:data:`SPAN_S` seconds since the last change on each axis, and takes a step it finds that
the online test did not call (no change on the axis within ``FOLLOWED_WITHIN_S``) as a
change of the mount: late (the test needs ``MIN_BLOCKS`` blocks), but while the drive goes on.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from .mount_change import FOLLOWED_WITHIN_S
from .mount_steps import MIN_BLOCKS, StepTestConfig, mount_steps

FloatArray = NDArray[np.float64]

#: the longest stretch of pairs tested [s]: enough for the seeded intervals to stand a
#: second step alone, and a bounded cost per block on an hours-long drive
SPAN_S = 64.0
#: the test's threshold here, above the batch's (5: one test per drive): run every second
#: over a sliding stretch, a road's wander gets hundreds of chances, and 8 of 95 simulated
#: 300-s drives under 0.3° of it had steps of 0.5–0.8° called at 5.1–8.1 (most at the first
#: tests, on 8–9 blocks); a knock's statistic grows as its pairs come in (a car's 1° at
#: 4.8 s: 12–39 when first tested), so it is called a little later instead
THRESHOLD = 10.0


class StepWatch:
    """Feed it the usable pairs' (pitch, roll) with ``add``, the online test's changes with
    ``followed``; ``due`` returns the steps the online test missed, at most once per block."""

    def __init__(self, config: StepTestConfig | None = None) -> None:
        cfg = config or StepTestConfig()
        self.config = replace(cfg, threshold=max(cfg.threshold, THRESHOLD))
        self._t: list[float] = []
        self._angles: list[tuple[float, float]] = []
        self._since = np.full(2, -math.inf)  # per axis, the last change's onset [s]
        self._changes: list[tuple[float, int]] = []  # (onset s, axis) of the online test
        self._next_test = -math.inf

    def add(self, t: float, pitch: float, roll: float) -> None:
        """A usable pair's angles of its current frame (rad) at time ``t`` [s]; one not after
        the last (a filter's restart feeds its frame again) is left out."""
        if self._t and not t > self._t[-1]:
            return
        self._t.append(t)
        self._angles.append((pitch, roll))

    def followed(self, onset: float, axis: int) -> None:
        """The online test called a change on ``axis`` (0 pitch, 1 roll) from ``onset`` [s]:
        a step there is not missed, and the test looks only after it on that axis."""
        self._changes.append((onset, axis))
        self._since[axis] = max(self._since[axis], onset)

    def due(self, t: float, last: bool = False) -> list[tuple[int, float, float]]:
        """At time ``t`` [s], once per ``block_s`` (and at the ``last`` pair, whenever it
        comes): (axis, onset s, step rad) of each step the test finds in the pairs since the
        axis's last change that the online test did not call, oldest first; each is then
        taken as a change."""
        cfg = self.config
        if not cfg.enabled or (t < self._next_test and not last):
            return []
        self._next_test = t + cfg.block_s
        times = np.asarray(self._t)
        keep = times >= t - SPAN_S
        self._t = list(times[keep])
        self._angles = [a for a, k in zip(self._angles, keep, strict=True) if k]
        self._changes = [c for c in self._changes if c[0] >= t - SPAN_S - FOLLOWED_WITHIN_S]
        times, angles = times[keep], np.asarray(self._angles).reshape(-1, 2)
        out: list[tuple[int, float, float]] = []
        for axis in (0, 1):
            after = times >= self._since[axis]
            if not after.any() or times[-1] - times[after][0] < MIN_BLOCKS * cfg.block_s:
                continue
            for s in mount_steps(times[after], angles[after, axis], cfg):
                if not any(a == axis and abs(onset - s.onset_s) <= FOLLOWED_WITHIN_S
                           for onset, a in self._changes):
                    out.append((axis, s.onset_s, s.step))
        for axis, onset, _ in out:
            self.followed(onset, axis)
        return sorted(out, key=lambda s: s[1])
