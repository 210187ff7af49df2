"""The batch smoother's offline tests for a mount that stepped or creeps
(``filters.mount_steps``), on the estimator's rows of rendered drives and of KITTI 07."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from vipm_track.filters.model import NoiseParams
from vipm_track.filters.mount_steps import StepTestConfig, mount_steps, mount_trend
from vipm_track.filters.smoother_config import SmootherConfig
from vipm_track.filters.smoothing import smooth
from vipm_track.measurement import read_measurements
from vipm_track.table import read_table

DATA = Path(__file__).parent / "data"


def _mount_pitch(frames) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame smoothed mount pitch and its σ [deg]."""
    return (np.array([math.degrees(f.mount[0]) for f in frames]),
            np.array([math.degrees(f.mount_std[0]) for f in frames]))


def _half_knock(undone_at: int | None = None):
    """The rendered cart's 1° knock (``knock_cart_est.csv``, its truth) made a 0.5° one: the
    pitch of every frame after the knock moved back by 0.5° in the rows and the truth (the
    estimator's own errors kept); from frame ``undone_at`` on, moved back by 1°: knocked back
    to the nominal."""
    gt = read_table(DATA / "knock_cart_gt.csv")
    after = {int(f) for f, m in zip(gt["frame"], gt["mount_pitch_deg"], strict=True)
             if m > 45.5}

    def back(frame: int) -> float:  # degrees
        return 0.0 if frame not in after else (
            1.0 if undone_at is not None and frame >= undone_at else 0.5)

    ms = [replace(m, z=m.z - np.radians([back(m.frame - 1), 0, back(m.frame), 0, 0, 0, 0]))
          for m in read_measurements(DATA / "knock_cart_est.csv")]
    truth = {int(f): m - back(int(f))
             for f, m in zip(gt["frame"], gt["mount_pitch_deg"], strict=True)}
    return ms, np.array([truth[m.frame] for m in ms]), min(after)


@pytest.mark.parametrize("enabled", [True, False])
def test_a_half_degree_knock_is_followed_by_the_batch(enabled):
    # The EKF's innovation test misses it (its body takes the step up before the test sees
    # it): the batch's mount settled halfway, 0.25° from both, every frame's interval
    # holding neither. The offline test finds it and the mount steps with the camera.
    ms, truth, knock = _half_knock()
    cfg = SmootherConfig(height_m=0.7, noise=NoiseParams.for_preset("cart"),
                         mount_steps=StepTestConfig(enabled=enabled))
    pitch, std = _mount_pitch(smooth(ms, None, cfg))
    covered = float(np.mean(np.abs(pitch - truth) <= 1.96 * std))
    if enabled:
        t = np.array([m.t for m in ms])
        t_knock = ms[[m.frame for m in ms].index(knock)].t
        assert covered > 0.95, covered
        assert np.max(np.abs(pitch - truth)[np.abs(t - t_knock) > 0.5]) < 0.05
    else:  # what the test is for
        assert covered < 0.2, covered


@pytest.mark.xfail(strict=True, reason="known limit: on a drive shorter than two 32-s seeded "
                   "intervals a second step inflates the long-run variance about the first "
                   "split, and a knock undone within it is not found (docs/filters.md)")
def test_a_knock_undone_later_is_followed_both_ways():
    # The knock back at 14 s of an 18-s drive inflates the long-run variance about the first
    # split: neither step is found (0 % coverage).
    ms, truth, knock = _half_knock(undone_at=140)
    t = np.array([m.t for m in ms if m.ok])
    steps = mount_steps(t, np.array([math.degrees(m.z[2]) for m in ms if m.ok]))
    onsets = [ms[[m.frame for m in ms].index(f)].t for f in (knock, 140)]
    assert [round(s.step, 1) for s in steps] == [0.5, -0.5], steps
    assert all(abs(s.onset_s - o) <= 0.1 for s, o in zip(steps, onsets, strict=True)), steps
    cfg = SmootherConfig(height_m=0.7, noise=NoiseParams.for_preset("cart"))
    pitch, std = _mount_pitch(smooth(ms, None, cfg))
    assert np.mean(np.abs(pitch - truth) <= 1.96 * std) > 0.95


@pytest.mark.parametrize("undone", [True, False])
def test_two_steps_in_a_long_drive_are_both_found(undone):
    # Two minutes of AR(1) pair errors (ρ = 0.9, 30 Hz) with a knock at 40 s and, at 80 s,
    # the knock undone or a second knock: the second step inflated the variance about the
    # first split and neither was found (or a "drift" instead); seeded intervals of 32 s and
    # more each hold one step alone
    rng = np.random.default_rng(5)
    t = np.arange(3600) / 30.0
    e = np.zeros(3600)
    for k in range(1, 3600):
        e[k] = 0.9 * e[k - 1] + rng.normal()
    size = 8.0 * e.std()
    x = e + size * (t >= 40.0) + (-size if undone else size) * (t >= 80.0)
    steps = mount_steps(t, x)
    assert [round(s.onset_s) for s in steps] == [40, 80], steps
    assert [np.sign(s.step) for s in steps] == [1.0, -1.0 if undone else 1.0]
    assert mount_trend(t, x, steps) is None


def test_the_tests_off_leave_the_mount_to_its_walk():
    ms = read_measurements(DATA / "drift_cart_est.csv")
    cfg = SmootherConfig(height_m=0.7 / 1.02, noise=NoiseParams.for_preset("cart"),
                         mount_steps=StepTestConfig(enabled=False))
    from vipm_track.filters.smoother import mount_creep, offline_steps
    assert not mount_creep(ms, cfg, offline_steps(ms, cfg)).any()


def test_a_creeping_mount_is_followed_by_the_batch():
    # A rendered cart whose mount creeps 0.6°/min in pitch and -0.36°/min in roll (26 s):
    # with the mount's walk alone the batch held it nearly still (coverage 39 % / 64 % on a
    # 30-s drive); the drift test lets the walk follow it.
    ms = read_measurements(DATA / "drift_cart_est.csv")
    t = np.array([m.t for m in ms])
    frames = smooth(ms, None, SmootherConfig(height_m=0.7 / 1.02,
                                             noise=NoiseParams.for_preset("cart")))
    for axis, rate, nominal in ((0, 0.01, 45.0), (1, -0.006, 0.0)):
        est = np.array([math.degrees(f.mount[axis]) for f in frames])
        std = np.array([math.degrees(f.mount_std[axis]) for f in frames])
        truth = nominal + rate * t
        assert np.mean(np.abs(est - truth) <= 1.96 * std) > 0.9, axis
        assert np.sqrt(np.mean((est - truth) ** 2)) < 0.04, axis


def test_real_frames_of_an_unchanged_mount_show_no_step_and_no_drift():
    # KITTI 07's rows: the body rolls for seconds in a turn (T = 2.3-2.7 with 1-s blocks), no
    # mount change
    ms = [m for m in read_measurements(DATA / "kitti07_estimates.csv") if m.ok]
    t = np.array([m.t for m in ms])
    for axis in (2, 3):
        x = np.array([m.z[axis] for m in ms])
        assert mount_steps(t, x) == []
        assert mount_trend(t, x, []) is None


def test_wander_slower_than_a_second_is_not_taken_for_steps():
    # Five minutes of AR(1) pair errors under a road's wander (Ornstein-Uhlenbeck, τ 30 s, as
    # large as the noise): one-second blocks alone see the wander as steps; the long-run
    # variance over the longer blocks does not
    rng = np.random.default_rng(3)
    t = np.arange(9000) / 30.0
    false = 0
    for _ in range(10):
        e, w = np.zeros(9000), np.zeros(9000)
        a = math.exp(-1.0 / (30.0 * 30.0))
        for k in range(1, 9000):
            e[k] = 0.9 * e[k - 1] + rng.normal()
            w[k] = a * w[k - 1] + rng.normal()
        x = e / e.std() + 0.7 * w / w.std()
        false += len(mount_steps(t, x)) + (mount_trend(t, x, []) is not None)
    assert false == 0


def test_edge_cases_give_no_step():
    t = np.arange(300) / 10.0
    assert mount_steps(t, np.ones(300)) == []  # nothing varies: T was 0/0 = inf
    assert mount_steps([], []) == [] and mount_trend([], [], []) is None
    x = np.random.default_rng(0).normal(size=300)
    x[10] = np.nan
    assert mount_steps(t, x) == []
    assert mount_steps(t[:60], x[:60]) == []  # 6 s: fewer than 8 one-second blocks


def test_correlated_noise_without_a_change_raises_no_step():
    # AR(1) pair errors (ρ = 0.9 frame to frame, the tracking chain's) over 30 s at 10 Hz
    rng = np.random.default_rng(7)
    t = np.arange(300) / 10.0
    false = 0
    for _ in range(40):
        e = np.zeros(300)
        for k in range(1, 300):
            e[k] = 0.9 * e[k - 1] + rng.normal()
        false += len(mount_steps(t, e)) + (mount_trend(t, e, []) is not None)
    assert false == 0
    # the same noise with a step of 10 of its own standard deviations at 12 s is found there,
    # up
    e[120:] += 10.0 * np.std(e)
    steps = mount_steps(t, e)
    assert len(steps) == 1 and abs(steps[0].onset_s - 12.0) < 1.0 and steps[0].step > 0
