"""A wheel speed that does not fit the images is said before the filters run: the height it
implies (km/h, another drive, wheels standing still) and a clock it is offset on. The
filters' gates had rejected its pairs one by one (``partial``) and kept a confident height
without a word (`track`: 0.800 ± 0.040 m with a km/h speed; KITTI 07 with its speed 1 s
early: `smooth` 1.75 m against 1.68 m, the intervals apart)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vipm_track.cli import main
from vipm_track.commands.inputs import read_estimates
from vipm_track.filters.speed_check import speed_fit_notes, speed_scale
from vipm_track.filters.wheel_speed import SpeedSeries, read_speed_csv, write_speed_csv

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def car():
    """A rendered car swaying at 11.3–12.7 m/s (its speed changes: a clock offset shows)."""
    return (read_estimates(str(DATA / "car_sway_est.csv")),
            read_speed_csv(DATA / "car_sway_speed.csv").with_samples())


def _speed(speed: SpeedSeries, shift_s: float = 0.0, factor: float = 1.0) -> SpeedSeries:
    return SpeedSeries(speed.t + shift_s, speed.speed_mps * factor, source="speed.csv")


def test_the_right_speed_fits_without_a_note(car):
    measurements, speed = car
    scale, pairs = speed_scale(measurements, speed)
    assert abs(scale - 1.0) < 0.01 and pairs == 118
    assert speed_fit_notes(measurements, speed) == []


@pytest.mark.parametrize(("factor", "said"), [(3.6, "3.60×"), (0.0, "0.00×"), (0.7, "0.70×")])
def test_a_speed_of_another_scale_is_said(car, factor, said):
    measurements, speed = car
    notes = speed_fit_notes(measurements, _speed(speed, factor=factor))
    assert len(notes) == 1 and f"the wheels travel {said} what the images do" in notes[0]


def test_a_small_scale_error_is_the_heights_to_find(car):
    """1.2×: the wheel speed's job (the height assumed 20 % off), not a warning."""
    measurements, speed = car
    assert speed_fit_notes(measurements, _speed(speed, factor=1.2)) == []


@pytest.mark.parametrize("shift_s", [0.5, -0.3])
def test_a_speed_on_an_offset_clock_is_said(car, shift_s):
    measurements, speed = car
    notes = speed_fit_notes(measurements, _speed(speed, shift_s))
    assert len(notes) == 1 and "--clock-offset auto" in notes[0]
    said = float(notes[0].split("moved by ")[1].split(" s")[0])
    assert abs(said + shift_s) < 0.02
    assert speed_fit_notes(measurements, _speed(speed, 0.03)) == []  # a bus's latency


def test_travel_errors_that_drift_with_the_pose_are_no_clock_offset():
    """A rendered car pitching up 3.4° over 4 s at 30 fps, rolling shutter (``simulate
    --preset car --frames 120 --profile gradual --texture gravel --fps 30 --vignetting
    --exposure-drift --readout-time 0.03 --seed 9``, ``estimate --height 1.5 --readout-time
    0.03 --pitch 3``), its speed on the camera's clock: the travel's small errors drift with
    the pose (residuals' lag-1 correlation 0.84) and the fit said −75 ms ± 9 ms, and every
    filter told the user to give --clock-offset auto. Counted as correlated, nothing is said,
    while a real offset still is."""
    from vipm_track.filters.clock_offset import estimate_clock_offset

    measurements = read_estimates(str(DATA / "car_gradual_rs_est.csv"))
    speed = read_speed_csv(DATA / "car_gradual_rs_speed.csv").with_samples()
    fit = estimate_clock_offset(measurements, speed)
    assert abs(fit.offset_s) < 3 * fit.std_s, (fit.offset_s, fit.std_s)
    assert speed_fit_notes(measurements, speed) == []
    notes = speed_fit_notes(measurements, _speed(speed, 0.4))
    assert len(notes) == 1 and "--clock-offset auto" in notes[0]


def test_a_steady_speed_fixes_no_offset_and_says_none():
    """A cart at a near-constant 1.1–1.3 m/s: a 1 s offset moves nothing, and cannot be
    found; the scale is still judged."""
    measurements = read_estimates(str(DATA / "knock_cart_est.csv"))
    speed = read_speed_csv(DATA / "knock_cart_speed.csv").with_samples()
    assert speed_fit_notes(measurements, _speed(speed, 1.0)) == []
    assert "travel 3.64× what" in speed_fit_notes(measurements, _speed(speed, 1.0, 3.6))[0]


@pytest.mark.parametrize("command", ["track", "smooth", "monitor"])
def test_the_filters_say_it(car, tmp_path, capsys, command):
    _, speed = car
    kmh = tmp_path / "kmh.csv"
    write_speed_csv(_speed(speed, factor=3.6), kmh)
    extra = (["--nominal", str(tmp_path / "nominal.yaml")] if command == "monitor" else [])
    if command == "monitor":
        (tmp_path / "nominal.yaml").write_text(
            "pitch_deg: 3.0\nroll_deg: 0.0\nheight_m: 1.5\n")
    rc = main([command, "--estimates", str(DATA / "car_sway_est.csv"), "--speed-csv", str(kmh),
               "--out", str(tmp_path / "out.csv"), "--quiet", *extra])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "kmh.csv: over 118 moving pairs the wheels travel 3.60× what the images do" in err


def test_a_standing_wheel_speed_is_not_called_missing(car, tmp_path, capsys):
    """Wheels at 0 m/s under moving images: the monitor said "give wheel speed" although one
    was given; it now names the speed, and the scale check says 0.00× first."""
    _, speed = car
    zero = tmp_path / "zero.csv"
    write_speed_csv(_speed(speed, factor=0.0), zero)
    nominal = tmp_path / "nominal.yaml"
    nominal.write_text("pitch_deg: 3.0\nroll_deg: 0.0\nheight_m: 1.5\n")
    assert main(["monitor", "--estimates", str(DATA / "car_sway_est.csv"), "--speed-csv",
                 str(zero), "--nominal", str(nominal), "--out", str(tmp_path / "m.csv")]) == 0
    err = capsys.readouterr().err
    assert "the wheels travel 0.00× what the images do" in err
    assert "height not tested: no frame had a metric travel (118 of 120 frames held: " \
           "standstill)" in err


def test_untested_height_names_the_hold_that_kept_every_frame():
    """A level truck camera at 30 fps whose pairs were all held "slow for a forward camera":
    the monitor said its wheel speed (samples at 12 m/s all through) "says the vehicle stood
    or had no sample at every moving pair"."""
    from vipm_track.commands.monitor import _untested_height_why
    from vipm_track.filters.monitor_types import MonitorOutput

    def out(state: str, reason: str) -> MonitorOutput:
        return MonitorOutput(0, 0.0, state, reason, np.zeros(3), np.full(3, np.nan))

    slow = [out("HOLD", "slow for a forward camera; its pitch reads low")] * 119
    why = _untested_height_why([out("UNCALIBRATED", ""), *slow], speed_given=True)
    assert why == "119 of 120 frames held: slow for a forward camera"
    assert "stood" in _untested_height_why([out("CALIBRATED", "")] * 3, speed_given=True)
    assert "give wheel speed" in _untested_height_why(slow, speed_given=False)
