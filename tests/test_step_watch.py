"""The step watch: the batch's step test run as a drive goes on (``filters.step_watch``)."""

from __future__ import annotations

import numpy as np

from vipm_track.filters.drive_sim import DriveConfig, simulate_drive
from vipm_track.filters.step_watch import StepWatch


def _fed(watch: StepWatch, seed: int, until: float, onset: float = 3.0) -> list:
    """Pairs at 10 Hz, pitch noise 0.1° with a 1° step at ``onset`` [s]; what ``due`` said."""
    rng = np.random.default_rng(seed)
    said = []
    for t in np.arange(0.0, until, 0.1):
        pitch = np.radians(0.1) * rng.standard_normal() + np.radians(1.0) * (t >= onset)
        watch.add(float(t), float(pitch), float(np.radians(0.1) * rng.standard_normal()))
        said += [(round(t, 1), *s) for s in watch.due(float(t))]
    return said


def test_a_missed_step_is_said_once_when_8_s_of_pairs_are_in():
    said = _fed(StepWatch(), 0, 20.0)
    assert len(said) == 1, said
    at, axis, onset, step = said[0]
    assert 7.9 <= at <= 9.0 and axis == 0  # the test needs 8 one-second blocks
    assert abs(onset - 3.0) < 0.15 and abs(np.degrees(step) - 1.0) < 0.1


def test_a_step_the_online_test_called_is_not_said_again():
    for called in (3.1, 2.2):  # within 2 s of the step (the test looks from then on)
        watch = StepWatch()
        watch.followed(called, 0)
        assert _fed(watch, 1, 20.0) == []
    watch = StepWatch()
    watch.followed(0.5, 0)  # a change before: the test looks after it, and finds the step
    assert [s[1:3] for s in _fed(watch, 1, 20.0)] == [(0, 3.0)]


def test_no_step_no_word():
    assert _fed(StepWatch(), 2, 60.0, onset=np.inf) == []


def test_a_pair_fed_again_is_left_out():
    watch = StepWatch()
    watch.add(1.0, 0.0, 0.0)
    watch.add(1.0, 0.5, 0.5)  # a filter's restart feeds its frame again
    watch.add(0.5, 0.5, 0.5)
    watch.add(1.1, 0.0, 0.0)
    assert watch._t == [1.0, 1.1]


def test_a_road_wander_is_not_taken_for_a_step():
    # a simulated cart under 0.3° of road wander (τ 2 s), its mount fixed: at the batch's
    # threshold (5) the watch, testing every second, called a roll step at the first tests
    run = simulate_drive(DriveConfig.preset("cart", duration_s=30.0, road_std_deg=0.3,
                                            mount_random_walk=False), 8)
    watch, said = StepWatch(), []
    for m in run.measurements:
        if m.ok:
            watch.add(m.t, float(m.z[2]), float(m.z[3]))
            said += watch.due(m.t)
    assert said == []


def test_the_last_pair_is_tested_whenever_it_comes():
    # a step at 7.6 s: the test at 8 s has too little after it; the drive's last pair, at
    # 8.8 s (between two blocks' tests), is tested anyway
    watch = StepWatch()
    assert _fed(watch, 0, 8.9, onset=7.6) == []
    assert watch.due(8.8) == []
    (axis, onset, step), = watch.due(8.8, last=True)
    assert axis == 0 and abs(onset - 7.6) < 0.15 and abs(np.degrees(step) - 1.0) < 0.1
