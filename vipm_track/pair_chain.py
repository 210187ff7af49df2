"""Consecutive pairs of one camera, each estimated in the light of the pairs before it.

:class:`PairChain` is what the sequence runner (``pipeline.run_sequence``) and the live
monitor share: it seeds a pair from the last ``ok`` one (tracking: :func:`predict_guess`),
starts a tracked pair whose pose wandered far from the nominal once more from the nominal
(:func:`from_the_nominal_too`), reads a slow pair's pose over a longer baseline
(``long_baseline``), tries a tracked pair that fails once more cold, and holds
every ``ok`` pair to the vehicle's physics: its mean velocity on the ground may differ
from the reference pair's (the last ``ok`` pair that agreed with the one before it, within
:data:`MOTION_HORIZON_S`) by no more than the largest acceleration allows over the time
between them, plus three standard deviations of the change (the travel's, and the frame
times' jitter). A pair
beyond it gets status ``implausible motion``: a cold start, which knows nothing of the
pairs before it, can lock onto another minimum of the patch field (docs/usage.md). A pair
that agrees with the one rejected before it is taken, and becomes the reference: two pairs
in a row that agree outweigh the reference, so that a real change beyond the bound, or a
wrong reference, holds the pairs off for one pair only."""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .displacement_model import pack
from .estimator import PreparedPair, TwoFrameEstimator
from .long_baseline import RecentFrames, condition_on_pose
from .pair_result import FloatArray, PairGuess, add_timings, mark_failed
from .statuses import ESTIMATOR_ERROR, STATUS_IMPLAUSIBLE_MOTION

if TYPE_CHECKING:
    from .pair_result import PairResult

#: Bounds on the frame-interval ratio used to scale the previous motion into a prediction.
_DT_RATIO_RANGE = (0.25, 4.0)
#: an ``ok`` pair is held to the velocity of the last ``ok`` one only this close in time [s]:
#: beyond it the bound (10 m/s at 1 g) no longer tells a locked cold start from a real one
MOTION_HORIZON_S = 1.0
#: standard deviations of the velocity's change added to the physical bound
_SIGMAS = 3.0
#: the least error of a frame interval taken from two timestamps [s] (millisecond stamps);
#: more where the intervals scatter (a live camera stamped on arrival)
MIN_INTERVAL_STD_S = 1.4e-3
#: frame intervals whose scatter measures the timestamps' jitter
_INTERVALS_KEPT = 30
#: a tracked pose further than this from the nominal pose [deg] is also started from the
#: nominal: tracking can carry the pose into a wrong basin (vehicles alongside taken for the
#: ground), from which the gate around its guess keeps it
WANDER_DEG = 2.0
#: the nominal start replaces the tracked one where it keeps this many times the patches:
#: a clear margin, as the nominal's hold pulls its pose towards the nominal, which is the
#: truth only where the body is still
CLEARLY_MORE_PATCHES = 1.1
#: where a second start kept the tracked pose, the next wandered pairs up to this many take
#: its spread without one of their own: a camera knocked (or given a ``--pitch``) further
#: than ``WANDER_DEG`` from its nominal would otherwise pay a second fit on every pair
RECHECK_AFTER_PAIRS = 4
#: indices of tx and tz in ``PairResult.covariance`` (``measurement`` order)
_TRAVEL = slice(4, 6)


def predict_guess(previous: PairResult, dt_prev: float, dt: float) -> PairGuess:
    """Seed for the next pair, ``dt`` [s] long, from an ok result ``dt_prev`` [s] long
    (``PairGuess.from_previous``, the interval ratio clipped to [0.25, 4])."""
    ratio = dt / dt_prev if dt_prev > 0 and dt > 0 else 1.0
    return PairGuess.from_previous(previous, float(np.clip(ratio, *_DT_RATIO_RANGE)))


def estimate_pair(
    estimator: TwoFrameEstimator, prev: NDArray, curr: NDArray, guess: PairGuess | None,
    frame_interval_s: float | None = None, prepared: PreparedPair | None = None,
) -> PairResult:
    """One pair ``frame_interval_s`` seconds apart (``prepared``: its
    :meth:`TwoFrameEstimator.prepare_pair`, where made ahead); an exception inside the
    estimator becomes a failed result, not a dead run."""
    try:
        if prepared is not None:
            return estimator.estimate(prev, curr, guess, frame_interval_s, prepared=prepared)
        return estimator.estimate(prev, curr, guess, frame_interval_s)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return _FailedResult(f"{ESTIMATOR_ERROR}: {type(exc).__name__}: {exc}"[:200])


def prepare_images(estimator: TwoFrameEstimator, prev: NDArray, curr: NDArray
                   ) -> PreparedPair | None:
    """:meth:`TwoFrameEstimator.prepare_images`, or None: where the estimator has no such
    method (a stand-in estimates from the images alone), where it reads no images (without
    a nominal pose every pair fails first) and where the images cannot be prepared (the
    estimator meets that again and reports it)."""
    prepare = getattr(estimator, "prepare_images", None)
    if prepare is None or getattr(getattr(estimator, "config", None), "nominal_undetermined",
                                  ""):
        return None
    try:
        return prepare(prev, curr)
    except Exception:  # the estimator's own path meets it again and reports it
        return None


def wandered(estimator: TwoFrameEstimator, result: PairResult,
             wander_deg: float = WANDER_DEG) -> bool:
    """Whether an ``ok`` pair's pose lies more than ``wander_deg`` from the estimator's nominal
    pose in pitch or roll, where the estimator has a pose prior to hold a second start with
    (:func:`from_the_nominal_too`; a steep camera's default has none, and without the hold a
    second start lands where tracking was)."""
    if result.pose_curr is None or not math.isfinite(wander_deg):
        return False
    nominal, config = estimator.nominal, estimator.config
    return (max(abs(result.pose_curr.pitch - nominal.pitch),
                abs(result.pose_curr.roll - nominal.roll)) > math.radians(wander_deg)
            and _holds_poses(config))


def _holds_poses(config: Any) -> bool:
    """Whether an estimator's ``config`` holds its poses to the nominal pose and a tracked
    pair's frame k-1 to its guess (a level camera's default; a steep camera's has no pose
    prior)."""
    return bool(config.pose_prior_deg and config.track_prior_deg)


def from_the_nominal_too(
    estimator: TwoFrameEstimator, prev: NDArray, curr: NDArray, guess: PairGuess,
    result: PairResult, frame_interval_s: float, prepared: PreparedPair | None = None,
) -> tuple[PairResult, FloatArray | None]:
    """``result``, a pair tracked from ``guess`` whose pose :func:`wandered`, checked against
    the same pair started again from the estimator's nominal pose; the pair's result and the
    spread added to its covariance (None where the second start failed).

    The second start holds frame k-1 to the nominal pose as tracking holds it to its guess
    (started from the nominal without the hold, the fit inherits the tracked travel, which
    pitch trades against, and lands back where tracking was). Where it keeps
    :data:`CLEARLY_MORE_PATCHES` times the tracked start's patches in its last stage, it is
    the pair's result. Either way the two starts' difference d is added to the result's
    covariance (d dᵀ): two minima that the pair's patches do not tell apart leave its pose
    uncertain by their distance (as the stages' scatter does within a start). The returned
    result's timings hold both starts'."""
    nominal = estimator.nominal
    held = dataclasses.replace(guess, pose_prev=nominal, pose_curr=nominal)
    other = estimate_pair(estimator, prev, curr, held, frame_interval_s, prepared)
    if other.status != "ok":
        add_timings(result, other)
        return result, None
    # patches kept in the last stage, the evidence each start has
    kept_other, kept_tracked = (int(r.stages[-1].inliers.sum()) if r.stages else 0
                                for r in (other, result))
    better = kept_other >= CLEARLY_MORE_PATCHES * kept_tracked
    chosen, dropped = (other, result) if better else (result, other)
    add_timings(chosen, dropped)
    d = (pack(chosen.pose_prev, chosen.pose_curr, chosen.motion)
         - pack(dropped.pose_prev, dropped.pose_curr, dropped.motion))
    spread = np.outer(d, d)
    chosen.covariance = chosen.covariance + spread
    return chosen, spread


def _reads_long_baselines(estimator: TwoFrameEstimator) -> bool:
    """Whether the estimator reads a slow pair's pose over a longer baseline
    (``long_baseline``): configured to, with a global shutter, holding its poses
    (:func:`_holds_poses`) and without a vertical motion in the fit (whose height the
    conditioning on pitch and roll alone would leave behind)."""
    config, rig = getattr(estimator, "config", None), getattr(estimator, "rig", None)
    return bool(config is not None and rig is not None and _holds_poses(config)
                and not rig.readout_s and not config.vertical_motion
                and config.long_baseline_heights > 0)


@dataclass
class _FailedResult:
    """Stand-in for a ``PairResult`` when the estimator raised (only ``status`` and ``ok``
    are read)."""

    status: str
    reason: str = ""
    timings: dict[str, float] = field(default_factory=dict)
    ok: bool = False

    def to_measurement(self, frame: int, t: float) -> Any:
        return None


@dataclass(frozen=True)
class PairVelocity:
    """A pair's mean velocity over its interval on the ground, in its first frame's ground
    frame G: ``velocity`` (x, z) [m/s] and its 2×2 ``covariance`` [m²/s²], the interval's
    middle ``t_mid`` and half its length ``half_dt`` [s]; ``confirmed`` when it agreed with
    the ``ok`` pair before it. (A vehicle's velocity keeps its direction in its own frame
    through a turn, so two pairs' velocities compare in their own frames.)"""

    velocity: FloatArray
    covariance: FloatArray
    t_mid: float
    half_dt: float
    confirmed: bool = False


def pair_velocity(result: PairResult, t: float, dt: float, dt_std: float = 0.0
                  ) -> PairVelocity | None:
    """The mean velocity of an ``ok`` pair ending at ``t`` [s], ``dt`` [s] long, with its
    covariance from the travel's and from the interval's error ``dt_std`` [s] (which scales
    the velocity along itself); None where the travel's covariance is not known."""
    cov = getattr(result, "covariance", None)
    if cov is None or not np.all(np.isfinite(np.asarray(cov)[_TRAVEL, _TRAVEL])):
        return None
    velocity = np.array([result.motion.tx, result.motion.tz]) / dt
    cov = np.asarray(cov)[_TRAVEL, _TRAVEL] / dt**2 + (dt_std / dt) ** 2 * np.outer(velocity,
                                                                                   velocity)
    return PairVelocity(velocity, cov, t - dt / 2, dt / 2)


def motion_conflict(now: PairVelocity, before: PairVelocity, max_accel: float) -> str | None:
    """Why ``now`` cannot follow ``before`` at accelerations up to ``max_accel`` [m/s²]
    (None where it can): the change of mean velocity between two intervals is at most
    ``max_accel`` times the time between their middles, plus half their lengths' difference
    (which also covers the chord's turn between unequal intervals in a curve), and three
    standard deviations of the change (along it; the two pairs' errors independent)."""
    elapsed = now.t_mid - before.t_mid + abs(now.half_dt - before.half_dt)
    change = now.velocity - before.velocity
    size = float(np.hypot(*change))
    if size <= max_accel * elapsed:
        return None
    along = change / size
    std = math.sqrt(max(float(along @ (now.covariance + before.covariance) @ along), 0.0))
    if size <= max_accel * elapsed + _SIGMAS * std:
        return None
    speeds = [float(np.hypot(*v.velocity)) for v in (now, before)]
    return (f"velocity changed by {size:.1f} ± {std:.1f} m/s (speed {speeds[0]:.2f} m/s, "
            f"{speeds[1]:.2f} m/s {now.t_mid - before.t_mid:.2f} s before): more than the "
            f"{max_accel:g} m/s² of --max-acceleration allow")


class PairChain:
    """Estimates a camera's consecutive pairs (module doc).

    ``tracking``: seed a pair from the last ``ok`` one ending where it starts (or, with
    ``track_within_s``, ending at most that long before its end: frames may be dropped).
    ``retry_cold``: try a tracked pair that fails once more cold. ``max_acceleration_mps2``:
    the bound on the motion between pairs (inf: none). ``wander_deg``: a tracked pose further
    than this from the nominal is also started from the nominal (:func:`from_the_nominal_too`;
    inf: never); where that start kept the tracked pose, the next
    :data:`RECHECK_AFTER_PAIRS` wandered pairs take its spread instead. A level camera's
    pair (tracking) that travels less than ``config.long_baseline_heights`` reads frame k's pose
    over a longer baseline (``long_baseline``).
    """

    def __init__(self, estimator: TwoFrameEstimator, tracking: bool = True,
                 retry_cold: bool = True, track_within_s: float | None = None,
                 max_acceleration_mps2: float = math.inf,
                 wander_deg: float = WANDER_DEG) -> None:
        self.estimator = estimator
        self.wander_deg = wander_deg
        self.tracking = tracking
        self.retry_cold = retry_cold
        self.track_within_s = track_within_s
        self.max_accel = max_acceleration_mps2
        self._last_ok: tuple[PairResult, float, float] | None = None  # result, its dt, its t
        self._reference: PairVelocity | None = None
        self._rejected: PairVelocity | None = None
        self._intervals: deque[float] = deque(maxlen=_INTERVALS_KEPT)
        # the last second start's spread while it is carried, and for how many more pairs
        self._carried: tuple[FloatArray, int] | None = None
        self._recent = RecentFrames()
        self._spread: FloatArray | None = None  # the second start's d dᵀ in this pair's σ
        self._long_baseline = tracking and _reads_long_baselines(estimator)

    def break_tracking(self) -> None:
        """The next pair does not follow the last one (a frame could not be used): start it
        cold. The bound on the motion still holds across the gap."""
        self._last_ok = None
        self._recent.clear()

    def estimate(self, prev: NDArray, curr: NDArray, t: float, dt: float,
                 prepared: PreparedPair | None = None) -> tuple[PairResult, bool]:
        """The pair of ``prev`` and ``curr`` (a frame ending at ``t``, ``dt`` [s] after the one
        before) and whether the returned result was seeded by tracking."""
        guess = self._guess(t, dt)
        self._spread = None
        preparing_s = 0.0
        if prepared is None:
            # once for every start of this pair (a second start, a cold retry)
            started = time.perf_counter()
            prepared = prepare_images(self.estimator, prev, curr)
            if prepared is not None:
                preparing_s = time.perf_counter() - started
        result = estimate_pair(self.estimator, prev, curr, guess, dt, prepared)
        if guess is not None and result.status == "ok":
            result = self._second_start(prev, curr, guess, result, dt, prepared)
        else:
            self._carried = None
        if guess is not None and result.status != "ok" and self.retry_cold:
            result = estimate_pair(self.estimator, prev, curr, None, dt, prepared)
            guess, self._spread = None, None
        if self._long_baseline:
            self._recent.add(prev, curr, t, dt, result)
            if result.status == "ok":
                self._over_a_longer_baseline(curr, result)
        if preparing_s:  # as the estimator counts a pair it prepares itself
            result.timings["total"] = result.timings.get("total", 0.0) + preparing_s
        if math.isfinite(dt) and dt > 0:
            self._intervals.append(dt)
        if result.status == "ok":
            self._hold_to_physics(result, t, dt)
        self._last_ok = (result, dt, t) if result.status == "ok" else None
        return result, guess is not None

    def _second_start(self, prev: NDArray, curr: NDArray, guess: PairGuess,
                      result: PairResult, dt: float, prepared: PreparedPair | None,
                      ) -> PairResult:
        """A tracked ``ok`` pair after :func:`from_the_nominal_too` where its pose wandered,
        or with the spread carried from the last one (class doc)."""
        if not wandered(self.estimator, result, self.wander_deg):
            self._carried = None
            return result
        if self._carried is not None and self._carried[1] > 0:
            spread, left = self._carried
            self._carried = (spread, left - 1)
            result.covariance = result.covariance + spread
            self._spread = spread
            return result
        kept, spread = from_the_nominal_too(self.estimator, prev, curr, guess, result, dt,
                                            prepared)
        self._carried = (None if kept is not result or spread is None
                         else (spread, RECHECK_AFTER_PAIRS))
        self._spread = spread
        return kept

    def _over_a_longer_baseline(self, curr: NDArray, result: PairResult) -> None:
        """A slow pair's frame k estimated once more against an earlier frame, and the pair
        conditioned on that pose (``long_baseline``); both fits' time in its timings."""
        longer = self._recent.reference(
            self.estimator.config.long_baseline_heights * result.height)
        if longer is None:
            return
        other = estimate_pair(self.estimator, longer.image, curr, longer.guess,
                              longer.interval_s)
        add_timings(result, other)
        if other.status == "ok":
            condition_on_pose(result, other, self._spread)

    def _guess(self, t: float, dt: float) -> PairGuess | None:
        if not self.tracking or self._last_ok is None:
            return None
        previous, dt_prev, t_prev = self._last_ok
        within = self.track_within_s
        if within is not None and not t - t_prev <= within:
            return None
        return predict_guess(previous, dt_prev, dt)

    def interval_std(self) -> float:
        """The error of a frame interval [s]: the scatter of the recent intervals (a
        timestamp's jitter enters two intervals), at least :data:`MIN_INTERVAL_STD_S`."""
        spread = float(np.std(self._intervals)) if len(self._intervals) > 1 else 0.0
        return max(MIN_INTERVAL_STD_S, spread)

    def _hold_to_physics(self, result: PairResult, t: float, dt: float) -> None:
        """Mark ``result`` implausible where its velocity conflicts with the reference's
        within :data:`MOTION_HORIZON_S` and not with the pair rejected before it; otherwise
        it becomes the reference (confirmed where it agreed with the one before)."""
        if not math.isfinite(self.max_accel) or not dt > 0:
            return
        now = pair_velocity(result, t, dt, self.interval_std())
        if now is None:
            return
        before = self._reference
        if before is None or now.t_mid - before.t_mid > MOTION_HORIZON_S:
            self._reference, self._rejected = now, None
            return
        conflict = motion_conflict(now, before, self.max_accel)
        if conflict is not None and before.confirmed:
            rejected = self._rejected
            if (rejected is None or now.t_mid - rejected.t_mid > MOTION_HORIZON_S
                    or motion_conflict(now, rejected, self.max_accel) is not None):
                mark_failed(result, STATUS_IMPLAUSIBLE_MOTION, conflict)
                self._rejected = now
                return
            conflict = None  # two pairs in a row agree: they outweigh the reference
        self._reference = dataclasses.replace(now, confirmed=conflict is None)
        self._rejected = None
