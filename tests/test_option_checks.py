"""Bad option values of ``simulate``, ``demo`` and ``can-speed`` stop the command before any
work with one line naming the option and the value (exit 2, no traceback), and the values
the simulator supports are still taken. The work itself (rendering, decoding a CAN log) is
replaced by a stand-in that fails the test where it is reached, so the checks are shown to
come first and the tests take a second."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from conftest import write_drive_inputs

import vipm_track.commands.simulate as simulate_command
import vipm_track.demo
import vipm_track.filters.speed_decoder
from vipm_track.cli import main
from vipm_track.commands.option_types import number, whole_number
from vipm_track.filters.drive_sim import DriveConfig, simulate_drive
from vipm_track.filters.wheel_speed import DecodeSummary, SpeedSeries, read_speed_csv


def _exit_code(argv: list[str]) -> int:
    """``main(argv)``'s exit status, whether argparse exits (a bad option type) or main
    returns."""
    try:
        return main(argv)
    except SystemExit as stop:
        return stop.code


def _no_work(*args, **kwargs):
    raise AssertionError("the command started its work before checking its options")


# --- the type functions ------------------------------------------------------------------------

def test_types_say_the_range_and_the_value():
    assert whole_number(0)("7") == 7
    assert whole_number(2, 5)("5") == 5
    assert number(0, 1, below=True)("0") == 0.0
    assert number(0, above=True)("1e-9") == 1e-9
    cases = [
        (whole_number(0), "-1", "expected a whole number >= 0, got '-1'"),
        (whole_number(0), "1.5", "expected a whole number >= 0, got '1.5'"),
        (whole_number(2, 5), "6", "expected a whole number in [2, 5], got '6'"),
        (number(0), "nan", "expected a finite number >= 0, got 'nan'"),
        (number(0), "inf", "expected a finite number >= 0, got 'inf'"),
        (number(0, above=True), "0", "expected a finite number > 0, got '0'"),
        (number(0, 1, below=True), "1", "expected a number in [0, 1), got '1'"),
        (number(0, 1), "nan", "expected a number in [0, 1], got 'nan'"),
        (number(0, what="number of seconds"), "x",
         "expected a finite number of seconds >= 0, got 'x'"),
    ]
    for parse, text, message in cases:
        with pytest.raises(argparse.ArgumentTypeError) as error:
            parse(text)
        assert str(error.value) == message


# --- simulate ----------------------------------------------------------------------------------

@pytest.fixture
def no_rendering(monkeypatch):
    monkeypatch.setattr(simulate_command, "simulate_sequence", _no_work)


@pytest.mark.parametrize(("option", "value", "expected"), [
    ("--seed", "-1", "a whole number >= 0"),
    ("--fps", "nan", "a frame rate in [0.1, 1000]"),
    ("--fps", "0", "a frame rate in [0.1, 1000]"),
    ("--speed", "nan", "a number in [0, 100]"),
    ("--speed", "-1", "a number in [0, 100]"),
    ("--speed", "1e6", "a number in [0, 100]"),  # speed.csv refuses it as a corrupt row
    ("--amplitude", "inf", "a finite number >= 0"),
    ("--amplitude", "-1", "a finite number >= 0"),
    ("--noise", "-1", "a finite number >= 0"),
    ("--exposure-drift", "5", "a number in [0, 1)"),
    ("--exposure-drift", "1", "a number in [0, 1)"),
    ("--vignetting", "1.5", "a number in [0, 1]"),
    ("--highlights", "-2", "a whole number >= 0"),
    ("--motion-blur", "5", "a number in [0, 1]"),
    ("--motion-blur", "nan", "a number in [0, 1]"),
    ("--readout-time", "nan", "a finite number of seconds >= 0"),
    ("--readout-time", "-0.01", "a finite number of seconds >= 0"),
])
def test_simulate_refuses_a_bad_value(tmp_path, capsys, no_rendering, option, value, expected):
    out = tmp_path / "sim"
    rc = _exit_code(["simulate", "--preset", "cart", "--frames", "5", option, value,
                     "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert f"vipm-track simulate: error: argument {option}: expected {expected}, got " \
           f"'{value}'" in err
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize(("profile", "amplitude", "frames", "said"), [
    ("height", "12", 40, "at or below the ground"),   # h · (1 + 1.2 sin) dips below zero
    ("gradual", "30", 100, "beyond ±90°"),             # 45° ± 60° of pitch
])
def test_simulate_refuses_an_amplitude_no_camera_can_follow(
        tmp_path, capsys, no_rendering, profile, amplitude, frames, said):
    out = tmp_path / "sim"
    rc = _exit_code(["simulate", "--frames", str(frames), "--profile", profile,
                     "--amplitude", amplitude, "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and f"--amplitude {amplitude} with --profile {profile}" in err and said in err
    assert not out.exists()


def test_simulate_readout_longer_than_the_frame_interval(tmp_path, capsys, no_rendering):
    rc = _exit_code(["simulate", "--frames", "3", "--fps", "20", "--readout-time", "0.06",
                     "--out", str(tmp_path / "sim")])
    assert rc == 2
    assert "--readout-time must be in [0, 1/fps] = [0, 0.05] s, got 0.06" in \
        capsys.readouterr().err


def test_estimate_refuses_a_readout_longer_than_the_frame_interval(tmp_path, capsys):
    """Every pair of a 10 fps drive read out over 0.5 s "did not converge", exit 1."""
    from conftest import render_small_drive

    drive = render_small_drive(tmp_path / "d", frames=3)
    rc = _exit_code(["estimate", "--images", str(drive / "images"), "--height", "0.7",
                     "--pitch", "45", "--readout-time", "0.5", "--out", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "--readout-time 0.5 s is longer than the frame interval" in err, err
    assert "(0.1 s between its first two frames)" in err and not (tmp_path / "e.csv").exists()


def test_simulate_takes_the_ends_of_every_range(tmp_path, monkeypatch):
    """Zero speed, full vignetting, a whole-interval exposure and readout, no highlights: the
    simulator renders them (two frames, rendered for real)."""
    taken = {}
    real = simulate_command.simulate_sequence

    def spy(*args, **kwargs):
        taken.update(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(simulate_command, "simulate_sequence", spy)
    out = tmp_path / "sim"
    assert main(["simulate", "--frames", "2", "--speed", "0", "--amplitude", "0", "--noise", "0",
                 "--exposure-drift", "0.99", "--vignetting", "1", "--highlights", "0",
                 "--motion-blur", "1", "--readout-time", "0.1", "--seed", "0",
                 "--out", str(out)]) == 0
    effects = taken["effects"]
    assert taken["speed"] == 0.0 and effects.vignetting == 1.0 and effects.motion_blur == 1.0
    assert effects.rolling_shutter == pytest.approx(1.0) and effects.exposure_drift == 0.99
    gt = np.genfromtxt(out / "gt.csv", delimiter=",", names=True)
    assert np.all(np.isfinite(gt["speed_mps"])) and np.all(gt["speed_mps"] == 0)
    assert len(list((out / "images").glob("*.png"))) == 2


# --- demo --------------------------------------------------------------------------------------

@pytest.fixture
def no_drive(monkeypatch):
    monkeypatch.setattr(vipm_track.demo, "render_drive", _no_work)


def test_demo_refuses_a_negative_seed(tmp_path, capsys, no_drive):
    out = tmp_path / "demo"
    rc = _exit_code(["demo", "--frames", "5", "--seed", "-1", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert "vipm-track demo: error: argument --seed: expected a whole number >= 0, got '-1'" \
        in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize(("option", "value", "message"), [
    ("--rerun-jpeg-quality", "0", "--rerun-jpeg-quality must be in 1..100, got 0"),
    ("--rerun-image-every", "-1", "--rerun-image-every must be >= 0, got -1"),
])
def test_demo_checks_its_rerun_options_before_the_drive(tmp_path, capsys, no_drive, option,
                                                         value, message):
    out = tmp_path / "demo"
    assert main(["demo", "--frames", "5", option, value, "--quiet", "--out", str(out)]) == 2
    assert f"vipm-track demo: error: {message}" in capsys.readouterr().err
    assert not out.exists()


# --- can-speed ---------------------------------------------------------------------------------

@pytest.fixture
def no_decoding(monkeypatch):
    monkeypatch.setattr(vipm_track.filters.speed_decoder, "decode_can_log", _no_work)


def _can_speed(tmp_path, *options: str) -> list[str]:
    # the log and the DBC are never opened: the options are refused first
    return ["can-speed", str(tmp_path / "drive.log"), "--dbc", str(tmp_path / "car.dbc"),
            *options, "--out", str(tmp_path / "speed.csv")]


@pytest.mark.parametrize(("option", "value"), [
    ("--max-gap", "-1"), ("--max-gap", "0"), ("--max-gap", "nan"), ("--max-gap", "inf"),
])
def test_can_speed_refuses_a_bad_max_gap(tmp_path, capsys, no_decoding, option, value):
    rc = _exit_code(_can_speed(tmp_path, option, value))
    err = capsys.readouterr().err
    assert rc == 2
    assert f"vipm-track can-speed: error: argument {option}: expected a finite number of " \
           f"seconds > 0, got '{value}'" in err


def test_can_speed_refuses_a_bus_duration_of_zero(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(vipm_track.filters.speed_decoder, "decode_bus", _no_work)
    rc = _exit_code(["can-speed", "--bus", "virtual:none", "--duration", "0", "--dbc",
                     str(tmp_path / "car.dbc"), "--out", str(tmp_path / "speed.csv")])
    assert rc == 2
    assert "argument --duration: expected a finite number of seconds > 0, got '0'" in \
        capsys.readouterr().err


def test_can_speed_option_conflicts_before_the_log(tmp_path, capsys, no_decoding):
    assert main(_can_speed(tmp_path, "--clock-offset", "auto")) == 2
    assert "--clock-offset auto needs --estimates EST.csv" in capsys.readouterr().err
    assert main(_can_speed(tmp_path, "--estimates", str(tmp_path / "est.csv"))) == 2
    assert "--estimates is read only with --clock-offset auto" in capsys.readouterr().err
    assert main(_can_speed(tmp_path, "--clock-offset", "auto", "--estimates",
                           str(tmp_path / "missing.csv"))) == 2
    assert "missing.csv" in capsys.readouterr().err


@pytest.mark.parametrize(("text", "message"), [
    (None, "--frame-times {path}: file not found"),
    ("0.0\n0.05\n0.1 # ok\nten\n", "{path}: line 4: not a timestamp in seconds: 'ten'"),
    ("0.0\n0.05\n0.05\n", "{path}: line 3: timestamp 0.05 does not increase"),
    ("# no times\n\n", "--frame-times {path}: no timestamps in it"),
], ids=["missing", "not-a-number", "not-increasing", "empty"])
def test_can_speed_reads_the_frame_times_before_the_log(tmp_path, capsys, no_decoding, text,
                                                        message):
    path = tmp_path / "times.txt"
    if text is not None:
        path.write_text(text)
    assert main(_can_speed(tmp_path, "--frame-times", str(path))) == 2
    err = capsys.readouterr().err
    assert f"vipm-track can-speed: error: {message.format(path=path)}" in err


def test_can_speed_auto_offset_from_estimates_read_first(tmp_path, capsys, monkeypatch):
    """The estimates, now read before the (stand-in) log, still fix the offset: a simulated
    drive whose wheel-speed clock is 0.6 s behind the camera's."""
    run = simulate_drive(DriveConfig(duration_s=30.0, speed_clock_offset_s=0.6), seed=1)
    est, _, _ = write_drive_inputs(run, tmp_path)
    series = SpeedSeries(run.speed.t, run.speed.speed_mps, source="drive.log")
    monkeypatch.setattr(vipm_track.filters.speed_decoder, "decode_can_log",
                        lambda *args, **kwargs: (series, DecodeSummary(source="drive.log")))
    assert main(_can_speed(tmp_path, "--clock-offset", "auto", "--estimates", str(est))) == 0
    written = read_speed_csv(tmp_path / "speed.csv")
    shift = np.median(written.t - series.t)
    assert abs(shift - 0.6) < 0.05, capsys.readouterr().err


@pytest.mark.parametrize(("options", "message"), [
    (["--speed-scale", "2"], "--speed-scale apply to a wheel speed: give --speed-csv or --can"),
    (["--clock-offset", "0.5"], "--clock-offset apply to a wheel speed"),
    (["--can-channel", "0"], "--can-channel decode a CAN log: give --can LOG"),
    (["--speed-csv", "{speed}", "--signals", "WHEEL_SPEEDS.X"],
     "--signals decode a CAN log (--can); --speed-csv"),
    (["--speed-csv", "{speed}", "--combine", "max"], "--combine decode a CAN log (--can)"),
])
def test_speed_options_without_what_they_apply_to_are_refused(tmp_path, capsys, options,
                                                              message):
    """A speed option with nothing to apply to was silently ignored (`track --speed-csv S
    --signals X` and `--speed-scale 2` without a speed exited 0)."""
    speed = tmp_path / "speed.csv"
    speed.write_text("t,speed_mps\n0,1\n1,1\n")
    est = tmp_path / "est.csv"
    est.write_text("frame,t\n0,0\n")
    argv = ["track", "--estimates", str(est), "--height", "1.5", "--out",
            str(tmp_path / "t.csv"), *[o.format(speed=speed) for o in options]]
    assert _exit_code(argv) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("command", ["track", "smooth", "monitor"])
def test_estimator_options_with_an_estimates_table_are_refused(tmp_path, capsys, command):
    """``--max-roll 1`` meant to drop rows, given with ``--estimates``, did nothing, silently:
    the table's rows are taken as they are."""
    from pathlib import Path

    table = Path(__file__).parent / "data" / "car_sway_est.csv"
    nominal = tmp_path / "nominal.yaml"
    nominal.write_text("pitch_deg: 3.0\nroll_deg: 0.0\nheight_m: 1.5\n")
    extra = ["--nominal", str(nominal)] if command == "monitor" else []
    rc = _exit_code([command, "--estimates", str(table), "--max-roll", "1", "--pitch", "10",
                     "--out", str(tmp_path / "o.csv"), "--quiet", *extra])
    err = capsys.readouterr().err
    assert rc == 2 and "--pitch, --max-roll: estimator options, for --images/--video; with " \
        "--estimates the table's rows are taken as they are" in err, err
    assert not (tmp_path / "o.csv").exists()


def test_a_principal_point_far_from_the_centre_is_questioned(tmp_path, capsys):
    """Another camera's KITTI calib.txt (no image size to refuse it by) on a cart's frames:
    every row `ok`, 4–7° off at σ 0.007°, without a word."""
    from conftest import render_small_drive

    from vipm_track.camera import CameraModel, load_camera, write_ros_yaml

    drive = render_small_drive(tmp_path / "d", frames=2)
    camera = load_camera(drive / "camera.yaml")
    k = camera.k.copy()
    k[0, 2] = 0.85 * camera.width
    write_ros_yaml(CameraModel(k, camera.width, camera.height), tmp_path / "off.yaml")
    for name, said in (("off.yaml", True), ("d/camera.yaml", False)):
        _exit_code(["estimate", "--images", str(drive / "images"), "--camera",
                    str(tmp_path / name), "--height", "0.7", "--pitch", "45",
                    "--readout-time", "0", "--out", str(tmp_path / "e.csv"), "--quiet"])
        err = capsys.readouterr().err
        assert ("the principal point (340, 149.5) lies 35 % of the image from the centre of "
                "the 400×300 frames: is it their camera?" in err) == said, err


def test_a_size_less_camera_file_on_resized_frames_is_questioned(tmp_path, capsys):
    """KITTI's calib.txt states no image size: on its frames resized to 75 % every row was
    `ok` with the pitch 3.7° off, without a word (the principal point 16 % off centre across
    the width, under the 20 % that any camera file is questioned at)."""
    from conftest import render_small_drive

    from vipm_track.camera import load_camera, write_ros_yaml

    drive = render_small_drive(tmp_path / "d", frames=2)
    camera = load_camera(drive / "camera.yaml")
    k = camera.k.copy()
    for name, cx, said in (("off.txt", 0.66, True), ("centred.txt", 0.5, False)):
        (tmp_path / name).write_text(f"P0: {k[0, 0]} 0 {cx * camera.width} 0 0 {k[1, 1]} "
                                     f"{k[1, 2]} 0 0 0 1 0\n")
        _exit_code(["estimate", "--images", str(drive / "images"), "--camera",
                    str(tmp_path / name), "--height", "0.7", "--pitch", "45",
                    "--readout-time", "0", "--out", str(tmp_path / "e.csv"), "--quiet"])
        err = capsys.readouterr().err
        assert ("the file states no image size: were the frames resized or cropped since it "
                "was calibrated?" in err) == said, err
    k[0, 2] = 0.66 * camera.width  # a file that states its size is not held to this
    write_ros_yaml(type(camera)(k, camera.width, camera.height), tmp_path / "off.yaml")
    _exit_code(["estimate", "--images", str(drive / "images"), "--camera",
                str(tmp_path / "off.yaml"), "--height", "0.7", "--pitch", "45",
                "--readout-time", "0", "--out", str(tmp_path / "e.csv"), "--quiet"])
    assert "principal point" not in capsys.readouterr().err


def test_an_estimates_table_timed_in_milliseconds_is_refused(tmp_path, capsys):
    """Times in milliseconds (frames 100 "s" apart) were taken as seconds: `track` wrote the
    cart's speed as 0.001 m/s without a word (only times more than an hour apart were
    refused)."""
    from pathlib import Path

    from vipm_track.table import read_table, write_table

    table = read_table(Path(__file__).parent / "data" / "knock_cart_est.csv")
    table["t"] = table["t"] * 1000.0
    rows = [{c: table[c][i] for c in table} for i in range(len(table["frame"]))]
    write_table(tmp_path / "ms.csv", rows, [c for c in table if c not in ("frame", "t")])
    rc = _exit_code(["track", "--estimates", str(tmp_path / "ms.csv"), "--height", "0.7",
                     "--out", str(tmp_path / "t.csv"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "ms.csv: t: consecutive frames are 100 s apart (median), a frame rate " \
        "outside 0.1–1000 Hz: the times must be in seconds" in err, err
