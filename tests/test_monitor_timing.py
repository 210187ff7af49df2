"""The monitor's state changes happen on the frame its configuration says: CALIBRATED after
``calibrate_after_s`` of frames, RECALIBRATE cleared ``clear_after_s`` after the last frame
with a warning. Noise-free inputs, so the frame of each change is known exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vipm_track.filters.monitor import DriftMonitor
from vipm_track.filters.monitor_types import MonitorConfig, MonitorInput
from vipm_track.filters.nominal import NominalCalibration

FPS = 10.0


def _run(offsets_deg: list[float], calibrate_s: float, clear_s: float):
    nominal = NominalCalibration(pitch_deg=2.0, roll_deg=0.0, height_m=1.5)
    config = MonitorConfig(fps=FPS, calibrate_after_s=calibrate_s, clear_after_s=clear_s)
    monitor = DriftMonitor(nominal, config)
    var = np.array([math.radians(0.1) ** 2, math.radians(0.1) ** 2, np.nan])
    out = []
    for k, off in enumerate(offsets_deg):
        pose = np.array([math.radians(2.0 + off), 0.0, np.nan])
        out.append(monitor.update(MonitorInput(frame=k, t=k / FPS, pose=pose, pose_var=var)))
    return out, config


@pytest.mark.parametrize(("calibrate_s", "clear_s"), [(1.0, 2.0), (0.5, 3.0)])
def test_state_changes_on_the_configured_frame(calibrate_s: float, clear_s: float) -> None:
    # at the nominal for 4 s, moved by 1° for 2 s, back at the nominal for 6 s
    offsets = [0.0] * 40 + [1.0] * 20 + [0.0] * 60
    out, config = _run(offsets, calibrate_s, clear_s)
    states = [o.state for o in out]
    calib_frames = round(calibrate_s * FPS)
    assert states[:calib_frames - 1] == ["UNCALIBRATED"] * (calib_frames - 1)
    assert states[calib_frames - 1:40] == ["CALIBRATED"] * (41 - calib_frames)
    flagged = states.index("RECALIBRATE")
    assert 40 <= flagged < 45  # a 1° step against a 0.1° tolerance: within half a second
    # the last frame with a warning (statistic at or above warn_enter × its threshold), then
    # exactly clear_after_s of quiet frames in RECALIBRATE, then CALIBRATED
    warned = [k for k, o in enumerate(out) if o.statistic.max() >= config.warn_enter]
    last_warn = max(warned)
    cleared = last_warn + round(clear_s * FPS)
    assert states[flagged:cleared] == ["RECALIBRATE"] * (cleared - flagged)
    assert states[cleared] == "CALIBRATED"
    assert set(states[cleared:]) == {"CALIBRATED"}
