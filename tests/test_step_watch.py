"""The step watch: the batch's step test run as a drive goes on (``filters.step_watch``)."""

from __future__ import annotations

import numpy as np

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
    watch = StepWatch()
    watch.followed(3.1, 0)  # within 2 s of the step: the online test's
    assert _fed(watch, 1, 20.0) == []
    watch = StepWatch()
    watch.followed(0.5, 0)  # a change before: the test looks after it, and finds the step
    assert [s[1:3] for s in _fed(watch, 1, 20.0)] == [(0, 3.0)]


def test_no_step_no_word():
    assert _fed(StepWatch(), 2, 60.0, onset=np.inf) == []
