"""The chain of consecutive pairs (``vipm_track.pair_chain``): tracking seeds, the cold retry
and the speed bound, on the stored rows of real runs and on made-up speeds."""

from __future__ import annotations

import copy
import math
import time
from pathlib import Path

import numpy as np
import pytest

from vipm_track.cli import main
from vipm_track.displacement_model import pack, unpack
from vipm_track.estimator_config import EstimatorConfig
from vipm_track.measurement import read_measurements
from vipm_track.pair_chain import (
    CLEARLY_MORE_PATCHES,
    MOTION_HORIZON_S,
    RECHECK_AFTER_PAIRS,
    PairChain,
    PairVelocity,
    from_the_nominal_too,
    motion_conflict,
    pair_velocity,
    predict_guess,
    wandered,
)
from vipm_track.pair_result import STATUS_IMPLAUSIBLE_MOTION, PairGuess, PairResult

DATA = Path(__file__).parent / "data"


class _Replay:
    """Stands in for the estimator: returns stored results in turn (whatever the guess)."""

    def __init__(self, results: list[PairResult], config: EstimatorConfig) -> None:
        self.results = iter(results)
        self.config = config
        self.guesses: list = []

    def estimate(self, prev, curr, guess=None, frame_interval_s=None):
        self.guesses.append(guess)
        return next(self.results)


def _result(z, cov=None, height=1.5, status="ok") -> PairResult:
    if status != "ok":
        return PairResult(status=status)
    prev, curr, motion = unpack(np.asarray(z, float), height)
    return PairResult(status, pose_prev=prev, pose_curr=curr, motion=motion,
                      covariance=np.eye(7) * 1e-8 if cov is None else cov, height=height)


def _stored(path: Path) -> tuple[list[PairResult], np.ndarray]:
    """The pair results of a stored estimate table (frame 0 is the first frame) and the times."""
    ms = read_measurements(path)
    results = [_result(m.z, m.covariance, m.height_assumed, "ok" if m.ok else m.status)
               for m in ms[1:]]
    return results, np.array([m.t for m in ms])


def _chain(results, config=None, **options) -> tuple[PairChain, _Replay]:
    config = config or EstimatorConfig()
    estimator = _Replay(results, config)
    # a replay answers each pair once: no second start from the nominal
    return PairChain(estimator, retry_cold=False, wander_deg=math.inf,
                     max_acceleration_mps2=config.max_acceleration_mps2, **options), estimator


def _chain_statuses(results, t, config=None) -> list[str]:
    chain, _ = _chain(results, config)
    return [chain.estimate(None, None, t[i + 1], t[i + 1] - t[i])[0].status
            for i in range(len(results))]


class _Camera:
    """Stands in for a level camera's estimator: its nominal pose and settings; a start held
    to the nominal pose gets (a copy of) ``second``, every other start ``tracked``."""

    def __init__(self, tracked: PairResult, second: PairResult,
                 config: EstimatorConfig | None = None) -> None:
        self.nominal = _result([0.02, 0.0, 0.02, 0.0, 0, 1, 0]).pose_curr
        self.config = config or EstimatorConfig(pose_prior_deg=2.0)
        self.tracked, self.second = tracked, second
        self.guesses: list = []
        self.prepared: list = []  # what each start was given, made by ``prepare_images``

    def prepare_images(self, prev, curr):
        return object()

    def estimate(self, prev, curr, guess=None, frame_interval_s=None, prepared=None):
        self.guesses.append(guess)
        self.prepared.append(prepared)
        held = guess is not None and guess.pose_prev == self.nominal
        return copy.deepcopy(self.second if held else self.tracked)

    @property
    def second_starts(self) -> int:
        return sum(g is not None and g.pose_prev == self.nominal for g in self.guesses)


def _with_patches(z, patches: int, seconds: float, status: str = "ok") -> PairResult:
    result = _result(z, np.eye(7) * 1e-6, status=status)
    result.stages = [type("Stage", (), {"inliers": np.ones(patches, bool)})()]
    result.timings = {"total": seconds}
    return result


WANDERED_Z = [0.08, -0.03, 0.08, -0.03, 0.0, 0.20, 0.001]  # 4.6° from a nominal of 1.1°
NOMINAL_Z = [0.02, 0.0, 0.021, 0.0, 0.0, 0.25, 0.0]


@pytest.mark.parametrize("patches", [34, 33, 32])  # of 30 kept by the tracked start
def test_a_wandered_pose_is_started_from_the_nominal_and_uncertain_by_the_two(patches):
    tracked = _with_patches(WANDERED_Z, 30, 0.05)
    camera = _Camera(tracked, _with_patches(NOMINAL_Z, patches, 0.04))
    assert wandered(camera, tracked)
    guess = PairGuess(tracked.pose_prev, tracked.pose_curr, tracked.motion)
    kept, spread = from_the_nominal_too(camera, None, None, guess, tracked, 0.1)
    # the second start holds frame k-1 to the nominal pose, with the tracked motion
    (start,) = camera.guesses
    assert start.pose_prev == camera.nominal and start.pose_curr == camera.nominal
    assert start.motion == tracked.motion
    clearly_more = patches >= CLEARLY_MORE_PATCHES * 30
    assert (kept is tracked) != clearly_more
    d = np.array(WANDERED_Z) - np.array(NOMINAL_Z)
    np.testing.assert_allclose(spread, np.outer(d, d), atol=1e-12)
    np.testing.assert_allclose(kept.covariance, np.eye(7) * 1e-6 + np.outer(d, d), atol=1e-12)
    assert kept.timings["total"] == pytest.approx(0.09)
    np.testing.assert_allclose(pack(kept.pose_prev, kept.pose_curr, kept.motion),
                               NOMINAL_Z if clearly_more else WANDERED_Z)


def test_a_pose_near_the_nominal_or_a_failed_second_start_leaves_the_pair_as_tracked():
    near = _with_patches([0.05, 0.0, 0.05, 0.0, 0.0, 0.2, 0.0], 30, 0.05)  # 1.7° off
    rolled = _with_patches([0.02, 0.06, 0.02, 0.06, 0.0, 0.2, 0.0], 30, 0.05)  # roll 3.4°
    camera = _Camera(near, _with_patches(None, 0, 0.04, status="did not converge"))
    assert not wandered(camera, near) and wandered(camera, rolled)
    assert not wandered(camera, rolled, math.inf)
    guess = PairGuess(rolled.pose_prev, rolled.pose_curr, rolled.motion)
    kept, spread = from_the_nominal_too(camera, None, None, guess, rolled, 0.1)
    assert kept is rolled and spread is None and len(camera.guesses) == 1
    np.testing.assert_array_equal(kept.covariance, np.eye(7) * 1e-6)
    assert kept.timings["total"] == pytest.approx(0.09)
    # without the pose prior (a steep camera's default) nothing holds a start to the nominal,
    # and a second start would land where tracking was
    assert not wandered(_Camera(near, near, EstimatorConfig(pose_prior_deg=0.0)), rolled)


def test_the_chain_starts_a_wandered_tracked_pair_from_the_nominal_and_carries_its_spread():
    camera = _Camera(_with_patches(WANDERED_Z, 30, 0.05), _with_patches(NOMINAL_Z, 40, 0.05))
    chain = PairChain(camera, retry_cold=False)
    first, _ = chain.estimate(None, None, 0.1, 0.1)
    assert camera.second_starts == 0 and first.ok  # a cold pair has no second start
    second, tracked = chain.estimate(None, None, 0.2, 0.1)
    assert tracked and camera.second_starts == 1
    # both starts of a pair read the images prepared once (a live camera's frames come
    # unprepared), each pair its own
    first_pair, *both_starts = camera.prepared
    assert both_starts[0] is both_starts[1] is not first_pair is not None
    np.testing.assert_allclose(pack(second.pose_prev, second.pose_curr, second.motion),
                               NOMINAL_Z)
    # where the second start keeps the tracked pose (a camera knocked further than the
    # wander from its nominal: the held start only pulled), the next wandered pairs carry
    # its spread without one; the pair after them is checked again
    camera.second = _with_patches(NOMINAL_Z, 30, 0.05)
    chain = PairChain(camera, retry_cold=False)
    camera.guesses.clear()
    rows = [chain.estimate(None, None, 0.1 * (k + 1), 0.1)[0]
            for k in range(RECHECK_AFTER_PAIRS + 3)]
    d = np.array(WANDERED_Z) - np.array(NOMINAL_Z)
    for row in rows[1:]:
        np.testing.assert_allclose(pack(row.pose_prev, row.pose_curr, row.motion), WANDERED_Z)
        np.testing.assert_allclose(row.covariance, np.eye(7) * 1e-6 + np.outer(d, d),
                                   atol=1e-12)
    assert camera.second_starts == 2  # pairs 2 and RECHECK_AFTER_PAIRS + 3
    assert camera.guesses[-1].pose_prev == camera.nominal


class _FailsWhenTracked:
    """A level camera whose tracked starts fail and whose cold starts succeed; preparing a
    pair takes 20 ms."""

    def __init__(self) -> None:
        self.nominal = _result([0.02, 0.0, 0.02, 0.0, 0, 1, 0]).pose_curr
        self.config = EstimatorConfig(pose_prior_deg=2.0)
        self.prepared: list = []
        self.pairs_prepared = 0

    def prepare_images(self, prev, curr):
        self.pairs_prepared += 1
        time.sleep(0.02)
        return object()

    def estimate(self, prev, curr, guess=None, frame_interval_s=None, prepared=None):
        self.prepared.append(prepared)
        if guess is None:
            return _with_patches(NOMINAL_Z, 30, 0.05)
        return _with_patches(None, 0, 0.04, status="did not converge")


def test_a_pair_is_prepared_once_for_its_cold_retry_and_the_time_counted():
    camera = _FailsWhenTracked()
    chain = PairChain(camera)
    chain.estimate(None, None, 0.1, 0.1)
    retried, tracked = chain.estimate(None, None, 0.2, 0.1)
    assert retried.ok and not tracked and camera.pairs_prepared == 2
    first_pair, tracked_start, cold_retry = camera.prepared
    assert tracked_start is cold_retry is not first_pair is not None
    # the pair's time holds its preparation, as where the estimator prepares it itself
    assert retried.timings["total"] >= 0.05 + 0.02


def test_fast_shaking_car_loses_exactly_its_wrong_ok_rows():
    # the stored rows of a run that printed two `ok` rows with a tenth of the travel (a
    # rendered car shaking at 2.5 m per frame, 10 fps, beyond the motion range: cold pairs
    # after failed ones), one with tz z = -36
    results, t = _stored(DATA / "fast_shaking_est.csv")
    truth = np.genfromtxt(DATA / "fast_shaking_gt.csv", delimiter=",", names=True)
    stored = [r.status for r in results]
    travel_error = [abs(math.hypot(r.motion.tx, r.motion.tz)
                        - math.hypot(truth["tx_m"][i + 1], truth["tz_m"][i + 1]))
                    / truth["tz_m"][i + 1] for i, r in enumerate(results) if r.ok]
    wrong = [i + 1 for i, r in enumerate(results)
             if r.ok and abs(math.hypot(r.motion.tx, r.motion.tz)
                             - truth["tz_m"][i + 1]) > 0.1 * truth["tz_m"][i + 1]]
    statuses = _chain_statuses(results, t)  # (marks the rejected results failed)
    rejected = [i + 1 for i, s in enumerate(statuses) if s == STATUS_IMPLAUSIBLE_MOTION]
    assert wrong == [37, 56] and rejected == wrong
    assert sorted(travel_error)[-3] < 0.02  # every other ok row within 2 %
    # every other row keeps its status
    assert [s for i, s in enumerate(statuses) if i + 1 not in rejected] == [
        s for i, s in enumerate(stored) if i + 1 not in rejected]
    # the bound off: the rows as stored
    off = _chain_statuses(*_stored(DATA / "fast_shaking_est.csv"),
                          EstimatorConfig(max_acceleration_mps2=math.inf))
    assert off == stored


def test_real_kitti_drive_keeps_every_ok_row():
    # KITTI 07's stored rows: a real car accelerating, braking and turning at 10 fps
    results, t = _stored(DATA / "kitti07_estimates.csv")
    stored = [r.status for r in results]
    assert stored.count("ok") > 100
    assert _chain_statuses(results, t) == stored


def _speeds(speeds_mps, dt=0.1, std_m=0.01) -> tuple[list[PairResult], np.ndarray]:
    cov = np.diag([1e-8] * 4 + [std_m**2] * 2 + [1e-8])
    results = [_result([0.05, 0, 0.05, 0, 0.0, v * dt, 0], cov) if v is not None
               else _result(None, status="too few inliers") for v in speeds_mps]
    return results, dt * np.arange(len(speeds_mps) + 1)


def test_braking_at_one_g_passes_beyond_it_fails():
    # 9 m/s² of braking: 0.9 m/s less per 0.1-s pair
    results, t = _speeds([20 - 0.9 * k for k in range(10)])
    assert set(_chain_statuses(results, t)) == {"ok"}
    # a drop of 2.5 m/s in 0.1 s (25 m/s²) with 0.1 m/s of noise per speed: beyond
    # 1 m/s + 3 × 0.14 m/s
    results, t = _speeds([20, 20, 20, 17.5, 19.5])
    assert _chain_statuses(results, t) == ["ok", "ok", "ok", STATUS_IMPLAUSIBLE_MOTION, "ok"]
    # with 1 m/s of noise per speed the same drop is within 3σ
    results, t = _speeds([20, 20, 20, 17.5, 17.5], std_m=0.1)
    assert set(_chain_statuses(results, t)) == {"ok"}
    # a larger bound lets it through
    results, t = _speeds([20, 20, 20, 17.5, 17.5])
    assert set(_chain_statuses(results, t, EstimatorConfig(max_acceleration_mps2=30))) == {"ok"}


def test_a_wrong_first_pair_cannot_hold_the_truth_off():
    # the first ok pair is locked at a tenth of the speed: it agreed with nothing before it,
    # so the truth after it is kept, confirmed by the next, and then holds a later lock off
    results, t = _speeds([2.5, 25, 25, 25, 2.5, 25])
    assert _chain_statuses(results, t) == [
        "ok", "ok", "ok", "ok", STATUS_IMPLAUSIBLE_MOTION, "ok"]
    # a pair that disagreed with the one before it cannot reject the next either
    results, t = _speeds([2.5, 25, 2.5, 2.5])
    assert _chain_statuses(results, t) == ["ok"] * 4


def test_the_bound_reaches_across_failures_but_not_beyond_the_horizon():
    # three failed pairs: 0.4 s between the middles, 4 m/s allowed
    results, t = _speeds([25, 25, None, None, None, 2.5])
    assert _chain_statuses(results, t)[-1] == STATUS_IMPLAUSIBLE_MOTION
    results, t = _speeds([25, 25, None, None, None, 21.5])
    assert _chain_statuses(results, t)[-1] == "ok"
    # up to 1 s between the middles, not beyond
    assert MOTION_HORIZON_S == 1.0
    results, t = _speeds([25, 25, *[None] * 8, 2.5])
    assert _chain_statuses(results, t)[-1] == STATUS_IMPLAUSIBLE_MOTION
    results, t = _speeds([25, 25, *[None] * 10, 2.5, 2.5])
    assert _chain_statuses(results, t)[-2:] == ["ok", "ok"]


def test_a_rejected_pair_is_no_seed_and_no_reference():
    results, t = _speeds([25, 25, 2.5, 25, 25])
    chain, estimator = _chain(results)
    out = [chain.estimate(None, None, t[i + 1], 0.1) for i in range(len(results))]
    assert [r.status for r, _ in out] == ["ok", "ok", STATUS_IMPLAUSIBLE_MOTION, "ok", "ok"]
    assert [tracked for _, tracked in out] == [False, True, True, False, True]
    assert estimator.guesses[3] is None  # the pair after the rejected one starts cold
    assert estimator.guesses[1].motion.tz == pytest.approx(2.5)
    # nor the reference: a pair like the one before the rejected one is held to that
    results, t = _speeds([25, 25, 2.5, 24.9, 2.5])
    assert _chain_statuses(results, t) == [
        "ok", "ok", STATUS_IMPLAUSIBLE_MOTION, "ok", STATUS_IMPLAUSIBLE_MOTION]


def test_two_pairs_that_agree_outweigh_the_reference():
    # two wrong pairs at the start agree with each other: the truth after them is held off
    # for one pair only, then taken (it agrees with the one rejected)
    results, t = _speeds([2.5, 2.5, *[25] * 6])
    assert _chain_statuses(results, t) == ["ok", "ok", STATUS_IMPLAUSIBLE_MOTION, *["ok"] * 5]


def test_the_bound_holds_across_a_break_in_tracking():
    results, t = _speeds([25, 25, 2.5])
    chain, estimator = _chain(results)
    chain.estimate(None, None, t[1], 0.1)
    chain.estimate(None, None, t[2], 0.1)
    chain.break_tracking()
    result, tracked = chain.estimate(None, None, t[3], 0.1)
    assert result.status == STATUS_IMPLAUSIBLE_MOTION and not tracked
    assert estimator.guesses[2] is None


def test_millisecond_timestamps_and_jitter_do_not_reject_steady_driving():
    # 30 m/s at 30 fps, 1 m per frame: stamps rounded to the millisecond (33/33/34-ms
    # intervals) make the speeds 30 ± 0.9 m/s, and 2 ms of jitter at 15 m/s far more
    frames = 40
    true_t = np.arange(frames + 1) / 30.0
    for speed, stamps in ((30.0, np.round(true_t, 3)),
                          (15.0, true_t + np.random.default_rng(3).normal(0, 2e-3, frames + 1))):
        cov = np.diag([1e-8] * 4 + [1e-6] * 2 + [1e-8])
        results = [_result([0.05, 0, 0.05, 0, 0.0, speed / 30.0, 0], cov) for _ in range(frames)]
        assert set(_chain_statuses(results, stamps)) == {"ok"}, speed
    # the same jitter on a locked pair still rejects it
    results = [_result([0.05, 0, 0.05, 0, 0.0, 0.5, 0], cov) for _ in range(frames)]
    results[20] = _result([0.05, 0, 0.05, 0, 0.0, 0.05, 0], cov)
    statuses = _chain_statuses(results, stamps)
    assert statuses[20] == STATUS_IMPLAUSIBLE_MOTION and statuses.count("ok") == frames - 1


def test_a_live_chain_tracks_only_within_its_window():
    results, _ = _speeds([25, 25, 25])
    chain, estimator = _chain(results, track_within_s=1.0)
    chain.estimate(None, None, 0.1, 0.1)
    chain.estimate(None, None, 0.2, 0.1)
    chain.estimate(None, None, 1.5, 0.1)  # frames dropped: 1.3 s after the last pair
    assert estimator.guesses[1] is not None and estimator.guesses[2] is None


def test_the_guess_scales_the_motion_by_the_interval_ratio_clipped():
    result = _speeds([25])[0][0]
    assert predict_guess(result, 0.1, 0.2).motion.tz == pytest.approx(5.0)
    assert predict_guess(result, 0.1, 1.0).motion.tz == pytest.approx(10.0)  # clipped at 4×
    assert predict_guess(result, 0.1, 0.001).motion.tz == pytest.approx(0.625)  # at 0.25×


def test_pair_velocity_and_its_covariance():
    cov = np.zeros((7, 7))
    cov[4:6, 4:6] = [[0.04, 0.012], [0.012, 0.01]]  # tx σ 0.2, tz σ 0.1, correlation 0.6
    result = _result([0, 0, 0, 0, 0.6, 0.8, 0], cov)
    v = pair_velocity(result, t=1.0, dt=0.1)
    np.testing.assert_allclose(v.velocity, [6.0, 8.0])
    np.testing.assert_allclose(v.covariance, cov[4:6, 4:6] / 0.01)
    assert (v.t_mid, v.half_dt) == pytest.approx((0.95, 0.05))
    # an interval known to 2 ms scales the velocity by 2 % along itself
    timed = pair_velocity(result, t=1.0, dt=0.1, dt_std=0.002)
    np.testing.assert_allclose(timed.covariance - v.covariance,
                               0.02**2 * np.outer([6.0, 8.0], [6.0, 8.0]))
    # an unknown covariance: nothing to judge by
    assert pair_velocity(_result([0, 0, 0, 0, 0.6, 0.8, 0], np.full((7, 7), np.nan)),
                         1.0, 0.1) is None


def _velocity(x, z, t_mid, half_dt, var=0.0):
    return PairVelocity(np.array([x, z], float), np.eye(2) * var, t_mid, half_dt)


def test_motion_conflict_counts_unequal_intervals_and_the_direction():
    # a 0.2-s pair after a 0.1-s one: means over intervals whose middles are 0.15 s apart
    # and whose lengths differ by 0.1 s may differ by up to 2 m/s at 10 m/s²
    before = _velocity(0, 20, 0.05, 0.05)
    assert motion_conflict(_velocity(0, 18.01, 0.2, 0.1), before, 10.0) is None
    why = motion_conflict(_velocity(0, 17.9, 0.2, 0.1), before, 10.0)
    assert why is not None and "by 2.1 ± 0.0 m/s" in why and "--max-acceleration" in why
    # the same speed in another direction: a car cannot turn its travel 10° in 0.1 s at
    # 20 m/s (3.5 m/s of change), nor go sideways
    before = _velocity(0, 20, 0.05, 0.05)
    turned = 20 * np.array([np.sin(np.radians(10)), np.cos(np.radians(10))])
    assert motion_conflict(_velocity(*turned, 0.15, 0.05), before, 10.0) is not None
    assert motion_conflict(_velocity(*turned, 0.15, 0.05, var=1.0), before, 10.0) is None
    assert motion_conflict(_velocity(-20, 0, 0.15, 0.05), before, 10.0) is not None
    # the standard deviation counts along the change only: a large one across it does not
    # excuse it
    wide_across = PairVelocity(np.array([0.0, 17.0]), np.diag([100.0, 0.0]), 0.15, 0.05)
    assert motion_conflict(wide_across, before, 10.0) is not None
    # both pairs' standard deviations count: 3 m/s in 0.1 s is within 1 + 3 × 1 m/s, 4.1 not
    uncertain_before = _velocity(0, 20, 0.05, 0.05, var=1.0)
    assert motion_conflict(_velocity(0, 17, 0.15, 0.05), uncertain_before, 10.0) is None
    assert motion_conflict(_velocity(0, 15.9, 0.15, 0.05), uncertain_before, 10.0) is not None


def test_a_sideways_lock_is_rejected():
    # the same length of travel, turned 140° (a cold start locked on a wrong minimum)
    results, t = _speeds([25, 25, 25, 25])
    locked = _result([0.05, 0, 0.05, 0, 2.5 * np.sin(2.44), 2.5 * np.cos(2.44), 0],
                     np.diag([1e-8] * 4 + [1e-4] * 2 + [1e-8]))
    results[2] = locked
    assert _chain_statuses(results, t) == ["ok", "ok", STATUS_IMPLAUSIBLE_MOTION, "ok"]


@pytest.mark.parametrize("value", ["0", "-3", "nan"])
def test_max_acceleration_is_checked(tmp_path: Path, capsys, value):
    from vipm_track.camera import write_ros_yaml
    from vipm_track.sim import PRESETS

    camera = tmp_path / "camera.yaml"
    write_ros_yaml(PRESETS["car"].camera(), camera)
    code = main(["estimate", "--images", str(tmp_path), "--camera", str(camera), "--height",
                 "1", "--out", str(tmp_path / "o.csv"), "--max-acceleration", value])
    assert code == 2
    assert "--max-acceleration must be > 0" in capsys.readouterr().err
