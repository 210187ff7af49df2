"""Steps of the mount found in the monitor's whitening innovations (``last_step``): the
signature of a step, no step where there is none, the frame of one where there is."""

from __future__ import annotations

import numpy as np
import pytest

from vipm_track.filters.drive_sim import DriveConfig, MountChange, simulate_drive
from vipm_track.filters.monitor_core import MonitorCore
from vipm_track.filters.monitor_inputs import inputs_from_measurements
from vipm_track.filters.monitor_segments import last_step, step_signature
from vipm_track.filters.monitor_types import MonitorConfig
from vipm_track.filters.nominal import NominalCalibration

FPS = 10.0
NOMINAL = NominalCalibration(3.0, 0.0, 1.5, 0.1, 0.1, 0.005)


@pytest.mark.parametrize("a, gain", [(0.9, 0.4), (0.5, 0.9), (0.99, 0.05)])
def test_signature_starts_whole_and_settles_at_rho(a, gain):
    g, rho = step_signature(a, gain, 4000)
    assert rho == pytest.approx((1.0 - a) / (1.0 - a + a * gain))
    assert g[0] == 1.0 and abs(g[-1] - rho) < 1e-6 and np.all(np.diff(g) <= 1e-12)
    assert len(g) < 4000  # settled: the rest is rho


def test_signature_sums_equal_the_full_correlation():
    """The settled signature's sums (a short correlation and a suffix sum) against the
    whole sum written out."""
    from vipm_track.filters.monitor_segments import _signature_sums

    rng = np.random.default_rng(3)
    y = rng.normal(size=300)
    g, rho = step_signature(0.9, 0.4, 300)
    full = np.concatenate([g, np.full(300, rho)])[:300]
    want = np.array([np.dot(full[:300 - m], y[m:]) for m in range(300)])
    np.testing.assert_allclose(_signature_sums(y, g, rho), want, rtol=0, atol=1e-9)


def _whitening(change_t: float | None, seed: int) -> tuple[np.ndarray, ...]:
    changes = () if change_t is None else (MountChange(change_t, pitch_deg=0.5),)
    run = simulate_drive(DriveConfig.preset("car", fps=FPS, duration_s=40.0,
                                            mount_changes=changes, mount_random_walk=False,
                                            stop_probability=0.0), seed=seed)
    core = MonitorCore(NOMINAL, MonitorConfig(fps=FPS))
    rows = []
    for inp in inputs_from_measurements(run.measurements, run.speed):
        core.step(np.array([inp.t]), np.asarray(inp.pose)[None], np.asarray(inp.pose_var)[None],
                  np.array([inp.usable]))
        if inp.usable:
            rows.append((inp.t, *(v[0] for v in core.last_whitening)))
    t = np.array([r[0] for r in rows])
    nu, s, a, gain = (np.array([r[i] for r in rows]) for i in range(1, 5))
    return t, nu, s, np.median(a, axis=0), np.median(gain, axis=0)


def test_no_step_is_found_where_there_is_none():
    found = 0
    for seed in range(20):
        t, nu, s, a, gain = _whitening(None, seed)
        later = t >= 10.0  # past the start-up of the body's filter
        found += last_step(nu[later], s[later], a, gain, np.ones(3), NOMINAL.tolerances) > 0
    assert found <= 1


def test_a_half_degree_step_is_placed_at_its_frame():
    placed = 0
    for seed in range(20):
        t, nu, s, a, gain = _whitening(20.0, seed)
        later = t >= 10.0
        k = last_step(nu[later], s[later], a, gain, np.ones(3), NOMINAL.tolerances)
        placed += k > 0 and abs(t[later][k] - 20.0) <= 0.25
    assert placed >= 18
