"""Mount changes inside a filter: a camera knocked out of its calibration steps its mount.

The filters model the mount as a random walk of a few thousandths of a degree per √s, right
for a calibration that creeps, but a knock of a degree would then take tens of seconds to be
followed, all the while with an interval that excludes where the camera now sits. So the
filter watches its own pose innovations: per axis (pitch, roll) a two-sided CUSUM on the
whitened innovation x = ν/√S of each pair's current-frame angle, for a mean shift of
``shift_sigma`` innovation standard deviations,

    g± = max(0, g± ± clip(x) − shift_sigma / 2),   alarm at g ≥ ``threshold``,

where a whitened innovation is clipped at ``clip`` so that a few outliers cannot alarm alone.
On an alarm the mean innovation since the statistic last was zero estimates the step, and the
filter adds its square to the mount's variance (re-opens it): the next pairs move the mount
to the camera's new pose at the pace their information allows.

The innovations of a filter whose model fits are white with unit variance, so the threshold
sets the false-alarm rate: with shift 1 and threshold 20 Siegmund's approximation gives an
average run length of ~3·10⁹ frames per one-sided test; a 3σ step (1° under 0.3° shaking)
alarms after ~8 frames, a 1σ step after ~40. On real roads they are not white: the measured
angles wander with camber and slope for seconds (KITTI 07: 1 s means scatter several times
more than white innovations would), which the test would take for steps. So each whitened
innovation is divided by the root of its measured long-run variance (at least 1): the mean
square of the means of the innovations over blocks of ``block_s`` seconds, times their count,
over the last ``blocks`` blocks — leaving out the newest ``holdout`` blocks, so that a step
has alarmed before it could raise its own yardstick. Until ``min_blocks`` such blocks are in,
the long-run variance is taken as ``unmeasured_variance``: a knock in the first seconds is
caught later, a road's wander not taken for one.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .mount_steps import pairs_steps, steps_text

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class MountChangeConfig:
    """The CUSUM's design (innovation standard deviations, log-likelihood units); ``enabled``
    False turns the test off (the mount then only random-walks)."""

    enabled: bool = True
    shift_sigma: float = 1.0
    threshold: float = 20.0
    clip: float = 4.0
    block_s: float = 1.0
    blocks: int = 30
    holdout: int = 2
    min_blocks: int = 4
    unmeasured_variance: float = 4.0


#: a step of the pairs counts as followed where the filter's test found a change on the same
#: axis with an onset this close to it [s]
FOLLOWED_WITHIN_S = 2.0


def unfollowed_steps_note(t: NDArray[np.float64], angles: NDArray[np.float64],
                          changes: list[tuple[float, int, float]]) -> str:
    """A warning where the usable pairs' pitch or roll (``t`` [s], ``angles`` (n, 2) [rad])
    steps (``mount_steps.pairs_steps``) and the EKF's mount-change test found no change
    there (``changes``: ``ExtrinsicsEKF.mount_changes``, (onset s, axis, step rad)): a knock
    before the test's yardstick is measured, taken up by the body state, left the mount 7.7σ
    from the camera's new one on a cart (45.53 ± 0.06° for 46°, no warning). Empty if none."""
    axes = {"pitch": 0, "roll": 1}
    missed = [(at, name, step) for at, name, step in pairs_steps(t, angles)
              if not any(axis == axes[name] and abs(onset - at) <= FOLLOWED_WITHIN_S
                         for onset, axis, _ in changes)]
    if not missed:
        return ""
    return (f"the pairs' {steps_text(missed)}, which the filter's mount-change test did "
            "not find (it is fully sensitive only after a drive's first seconds): the mount "
            "and its interval after it may hold neither mount; the batch smoother (`smooth`) "
            "splits the drive at the step")


def short_drive_note(seconds: float, cfg: MountChangeConfig | None = None) -> str:
    """A warning for a drive of ``seconds`` shorter than the test needs to be fully sensitive
    (``min_blocks + holdout`` blocks): a mount change there is caught late or not at all,
    and the filters' mount intervals assume there was none. Empty for longer drives."""
    cfg = cfg or MountChangeConfig()
    armed_s = (cfg.min_blocks + cfg.holdout) * cfg.block_s
    if not cfg.enabled or not seconds < armed_s:
        return ""
    spans = math.floor(seconds * 10) / 10  # (5.95 s is not "6.0 s, less than 6 s")
    return (f"the drive spans {spans:.1f} s, less than the {armed_s:g} s the mount-change "
            "test needs to be fully sensitive: a mount change within it is caught late or not "
            "at all, and the mount intervals assume none (docs/filters.md)")


def jump_variance(step: float) -> float:
    """Variance (rad²) a smoother lets its mount jump by where the test found a ``step``
    (rad): (2 × step)², wide enough that the pairs, not the prior, set the new mount."""
    return (2.0 * step) ** 2


def across_jump(covariance: FloatArray, jump_var: FloatArray) -> FloatArray:
    """A pair's covariance (7×7, the filters' ``pair_covariance``) when the mount stepped by
    variance ``jump_var`` (pitch, roll; rad²) between its two frames: it saw its previous
    frame on the old mount, which a factor with one mount for both frames can only take with
    the step's doubt on the previous angles. A copy."""
    cov = np.array(covariance, dtype=float)
    cov[[0, 1], [0, 1]] += jump_var
    return cov


class MountChangeDetector:
    """Two-sided CUSUM per axis (pitch, roll) on whitened innovations (module doc)."""

    def __init__(self, config: MountChangeConfig | None = None) -> None:
        self.config = config or MountChangeConfig()
        self.reset()

    def reset(self) -> None:
        """Forget all evidence (after an alarm, or when the filter restarts)."""
        self._g = np.zeros((2, 2))  # (axis, side)
        self._sum = np.zeros((2, 2))  # innovations since g was last zero, rad
        self._n = np.zeros((2, 2), dtype=np.int64)
        self._since = np.full((2, 2), np.nan)  # time of the first of those, s
        cfg = self.config
        # long-run variance of the whitened innovations, per axis: the open block (start
        # time, sum, count) and n × mean² of the closed ones
        self._block_t0 = np.full(2, np.nan)
        self._block_sum = np.zeros(2)
        self._block_n = np.zeros(2, dtype=np.int64)
        self._blocks: list[deque[float]] = [
            deque(maxlen=cfg.blocks + cfg.holdout) for _ in range(2)]
        #: per axis, the time (s) the change began for the last alarm (NaN: none)
        self.onset = np.full(2, np.nan)

    def update(self, t: float, innovation: FloatArray, variance: FloatArray) -> FloatArray:
        """Feed one pair's current-frame (pitch, roll) innovations (rad) and their variances
        (rad²) at time ``t`` (s); return per axis the estimated mount step (rad) where the
        test alarmed (``onset`` then says when it began), NaN elsewhere. An axis without a
        finite innovation is skipped."""
        cfg = self.config
        out = np.full(2, np.nan)
        if not cfg.enabled:
            return out
        nu = np.asarray(innovation, dtype=float)
        var = np.asarray(variance, dtype=float)
        for j in range(2):
            if not (np.isfinite(nu[j]) and var[j] > 0):
                continue
            white = float(np.clip(nu[j] / np.sqrt(var[j]), -cfg.clip, cfg.clip))
            x = white / np.sqrt(self._long_run_variance(j))
            if not t - self._block_t0[j] < cfg.block_s:  # also the first (NaN)
                if self._block_n[j]:
                    self._blocks[j].append(self._block_sum[j] ** 2 / self._block_n[j])
                self._block_t0[j], self._block_sum[j], self._block_n[j] = t, 0.0, 0
            self._block_sum[j] += white
            self._block_n[j] += 1
            for side, sign in enumerate((1.0, -1.0)):
                g = self._g[j, side] + sign * x - 0.5 * cfg.shift_sigma
                if g <= 0.0:
                    self._g[j, side], self._sum[j, side], self._n[j, side] = 0.0, 0.0, 0
                    continue
                if self._n[j, side] == 0:
                    self._since[j, side] = t
                self._g[j, side] = g
                self._sum[j, side] += nu[j]
                self._n[j, side] += 1
            side = int(np.argmax(self._g[j]))
            if self._g[j, side] >= cfg.threshold:
                out[j] = self._sum[j, side] / self._n[j, side]
                self.onset[j] = self._since[j, side]
                self._g[j], self._sum[j], self._n[j] = 0.0, 0.0, 0
        return out

    def pending_since(self, fraction: float) -> float:
        """The time (s) the evidence began of a change not yet called where a statistic has
        reached ``fraction`` of the threshold (the earliest, over axes and sides), else NaN:
        a smoother that reports frames before the call takes the new mount for the old."""
        armed = np.array([self._measured(j) for j in range(2)])[:, None]
        pending = armed & (self._g >= fraction * self.config.threshold)
        return float(np.min(self._since[pending])) if pending.any() else math.nan

    def _measured(self, axis: int) -> bool:
        """The axis's long-run variance is measured (``min_blocks`` blocks before the
        holdout): its test runs at full sensitivity."""
        cfg = self.config
        return len(self._blocks[axis]) - cfg.holdout >= cfg.min_blocks

    def _long_run_variance(self, axis: int) -> float:
        """Measured long-run variance of the axis's whitened innovations (module doc), ≥ 1;
        ``unmeasured_variance`` until ``min_blocks`` blocks older than the holdout are in."""
        cfg = self.config
        if not self._measured(axis):
            return cfg.unmeasured_variance
        return max(1.0, float(np.mean(list(self._blocks[axis])[: -cfg.holdout or None])))
