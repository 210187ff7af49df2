"""Every input error reported where it is, every interrupted run keeps its work: one test per
row of issue 34's table (and issue 32's bad filter inputs), run through the CLI as a user
would."""

from __future__ import annotations

import json
import os
import re
import signal
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import ROOT, shared_data

from vipm_track.cli import main
from vipm_track.table import read_table

KITTI_ESTIMATES = ROOT / "tests" / "data" / "kitti07_estimates.csv"
CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")


@pytest.fixture(scope="module")
def est(tmp_path_factory) -> Path:
    """The first 120 frames of KITTI 07's estimates table (camera 1.65 m, pitch ~1°)."""
    path = tmp_path_factory.mktemp("est") / "est.csv"
    lines = KITTI_ESTIMATES.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:121]))
    return path


@pytest.fixture(scope="module")
def nominal(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("nominal") / "nominal.yaml"
    text = (ROOT / "data" / "nominal_car.yaml").read_text()
    path.write_text(text.replace("pitch_deg: 3.0", "pitch_deg: 1.0", 1)
                    .replace("height_m: 1.5", "height_m: 1.65", 1))
    return path


def _run(capsys, *argv: str) -> tuple[int, str]:
    rc = main([str(a) for a in argv])
    return rc, capsys.readouterr().err


def _rows(path: Path) -> list[str]:
    data = path.read_bytes()
    assert b"\r" not in data, f"{path}: not \\n line ends"
    assert data.endswith(b"\n"), f"{path}: ends in half a line"
    return data.decode().splitlines()[1:]


# -- output paths: checked before any work, exit 2 with the path and the OS reason -------------

def _unwritable(tmp_path: Path) -> Path:
    """A folder that cannot be created: its parent is a file (works as root, unlike chmod)."""
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder\n")
    return blocker / "sub"


@pytest.mark.parametrize("command", [
    "estimate", "track", "smooth", "monitor", "can-speed", "report", "simulate", "demo"])
def test_every_subcommand_checks_its_output_before_any_work(tmp_path, capsys, est, nominal,
                                                            command):
    bad = _unwritable(tmp_path)
    can = shared_data("comma2k19_can")
    argv = {
        "estimate": ["estimate", "--images", tmp_path / "none", "--camera", tmp_path / "none.yaml",
                     "--height", "1", "--out", bad / "est.csv"],
        "track": ["track", "--estimates", est, "--height", "1.65", "--out", bad / "t.csv"],
        "smooth": ["smooth", "--estimates", est, "--height", "1.65", "--out", bad / "s.csv"],
        "monitor": ["monitor", "--estimates", est, "--nominal", nominal, "--out", bad / "m.csv"],
        "can-speed": ["can-speed", can / "rav4_drive.log", "--dbc", can / "toyota_2017.dbc",
                      "--out", bad / "speed.csv"],
        "report": ["report", est, "--out", bad / "report"],
        "simulate": ["simulate", "--frames", "2", "--out", bad / "sim"],
        "demo": ["demo", "--frames", "2", "--out", bad / "demo"],
    }[command]
    rc, err = _run(capsys, *argv)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert str(bad) in lines[0] and "Not a directory" in lines[0]


def test_other_outputs_are_checked_too(tmp_path, capsys, est, nominal):
    bad = _unwritable(tmp_path)
    good = tmp_path / "m.csv"
    for extra in (["--events", bad / "e.jsonl"], ["--rerun", bad / "r.rrd"]):
        rc, err = _run(capsys, "monitor", "--estimates", est, "--nominal", nominal, "--out", good,
                       "--quiet", *extra)
        assert rc == 2 and str(bad) in err and len(err.strip().splitlines()) == 1
        assert not good.exists()  # nothing computed, nothing written
    rc, err = _run(capsys, "smooth", "--estimates", est, "--height", "1.65", "--out", good,
                   "--summary", bad / "s.json", "--quiet")
    assert rc == 2 and "--summary" in err and not good.exists()


def test_a_write_error_during_the_run_is_one_line_naming_the_file(capsys, est):
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full here")
    rc, err = _run(capsys, "track", "--estimates", est, "--height", "1.65", "--out", "/dev/full",
                   "--quiet")
    assert rc == 2 and err.strip() == "vipm-track track: error: /dev/full: No space left on device"


# -- interrupts: what is decided is written, exit 130 --------------------------------------------

def _interrupt_after(monkeypatch, cls, method: str, calls: int, sig: bool = False) -> None:
    real = getattr(cls, method)
    count = [0]

    def wrapped(self, *a, **k):
        count[0] += 1
        if count[0] > calls:
            if sig:  # a real SIGTERM to this process: the CLI's handler turns it into an interrupt
                os.kill(os.getpid(), signal.SIGTERM)
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(cls, method, wrapped)


def test_ctrl_c_during_fixed_lag_smoothing_writes_what_is_decided(tmp_path, capsys, est,
                                                                  monkeypatch):
    from vipm_track.filters.fixed_lag import FixedLagSmoother

    out = tmp_path / "s.csv"
    _interrupt_after(monkeypatch, FixedLagSmoother, "step", 60)
    rc, err = _run(capsys, "smooth", "--estimates", est, "--height", "1.65", "--lag", "1",
                   "--out", out, "--quiet")
    assert rc == 130 and "interrupted" in err
    table = read_table(out)
    assert list(table["frame"]) == list(range(120))  # every frame once
    status = list(table["status"])
    smoothed = [s != "interrupted: not smoothed" for s in status]
    assert 30 < sum(smoothed) < 60 and smoothed == sorted(smoothed, reverse=True)
    summary = json.loads(out.with_suffix(".summary.json").read_text())
    assert summary["status"].startswith("interrupted")


def test_sigterm_during_batch_smoothing_writes_the_measurements_with_a_status(
        tmp_path, capsys, est, monkeypatch):
    import vipm_track.filters.smoothing

    def stopped(*a, **k):
        os.kill(os.getpid(), signal.SIGTERM)
        raise AssertionError("SIGTERM did not interrupt")

    monkeypatch.setattr(vipm_track.filters.smoothing, "smooth_batch", stopped)  # the solve
    out = tmp_path / "s.csv"
    rc, _err = _run(capsys, "smooth", "--estimates", est, "--height", "1.65", "--out", out,
                   "--quiet", "--columns", "all")
    assert rc == 130
    table = read_table(out)
    assert len(table["frame"]) == 120 and set(table["status"]) == {"interrupted: not smoothed"}
    ok = np.isfinite(table["meas_pitch_deg"])
    assert ok.sum() > 100  # the measurements are kept
    assert "interrupted" in json.loads(out.with_suffix(".summary.json").read_text())["status"]


def test_ctrl_c_while_the_batch_computes_its_marginals_keeps_the_estimate(
        tmp_path, capsys, est, monkeypatch):
    """The solve had converged (its bar full) when Ctrl-C came: every frame was written
    "interrupted: not smoothed" and the summary lost its mount. The estimate is now kept,
    its std columns empty, and the run still ends interrupted (exit 130)."""
    import vipm_track.filters.smoother

    def stopped(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(vipm_track.filters.smoother, "block_marginals", stopped)
    out = tmp_path / "s.csv"
    rc, err = _run(capsys, "smooth", "--estimates", est, "--height", "1.65", "--out", out,
                   "--quiet")
    assert rc == 130 and "interrupted" in err
    table = read_table(out)
    assert len(table["frame"]) == 120 and "interrupted: not smoothed" not in set(table["status"])
    assert np.isfinite(table["pitch_deg"]).sum() > 100
    assert np.isnan(table["pitch_std_deg"]).all()
    summary = json.loads(out.with_suffix(".summary.json").read_text())
    assert summary["status"] == ("interrupted: all 120 frames smoothed; interrupted while "
                                 "computing the standard deviations: their columns are empty")
    assert abs(summary["pitch"]["mean"] - np.nanmedian(table["pitch_deg"])) < 0.5


def test_fixed_lag_rows_are_on_disk_as_they_leave_the_window(tmp_path, capsys, est, monkeypatch):
    from vipm_track.filters.fixed_lag import FixedLagSmoother

    out = tmp_path / "s.csv"
    seen: list[int] = []
    real = FixedLagSmoother.step

    def step(self, *a, **k):
        seen.append(len(out.read_text().splitlines()) - 1 if out.exists() else -1)
        return real(self, *a, **k)

    monkeypatch.setattr(FixedLagSmoother, "step", step)
    rc, _ = _run(capsys, "smooth", "--estimates", est, "--height", "1.65", "--lag", "1",
                 "--out", out, "--quiet")
    assert rc == 0
    assert seen[-1] > 100  # at the last frame, all but the window's ~10 frames are written


def test_a_table_cut_mid_row_is_read_up_to_the_cut(tmp_path, capsys, est):
    """An estimates table whose writer died mid-row (the last line cut, no line end) is read
    without its last row, which is named on stderr; the rows before are all used."""
    text = est.read_text()
    cut = tmp_path / "cut.csv"
    cut.write_text(text[: text.rstrip("\n").rfind(",") - 3])  # inside the last row
    rows = len(text.splitlines()) - 1
    table = read_table(cut)
    assert len(table["frame"]) == rows - 1
    err = capsys.readouterr().err
    assert f"{cut}: line {rows + 1}: the last row is cut short" in err
    out = tmp_path / "track.csv"
    assert main(["track", "--estimates", str(cut), "--out", str(out), "--quiet"]) == 0
    assert len(read_table(out)["frame"]) == rows - 1


def test_a_damaged_row_before_the_last_is_still_an_error(tmp_path, capsys, est):
    lines = est.read_text().splitlines(keepends=True)
    damaged = tmp_path / "damaged.csv"
    lines[5] = lines[5][: lines[5].rfind(",")] + "\n"  # one cell short, mid-file
    damaged.write_text("".join(lines))
    assert main(["track", "--estimates", str(damaged), "--out", str(tmp_path / "t.csv")]) == 2
    assert f"{damaged}: line 6: " in capsys.readouterr().err
    whole = tmp_path / "whole.csv"  # the last row short but ended: damaged, not cut
    lines = est.read_text().splitlines(keepends=True)
    lines[-1] = lines[-1][: lines[-1].rfind(",")] + "\n"
    whole.write_text("".join(lines))
    assert main(["track", "--estimates", str(whole), "--out", str(tmp_path / "u.csv")]) == 2
    assert "cells but the header has" in capsys.readouterr().err
    unended = tmp_path / "unended.csv"  # damaged mid-file, the last row without a line end
    lines = est.read_text().splitlines(keepends=True)
    lines[5] = lines[5][: lines[5].rfind(",")] + "\n"
    lines[-1] = lines[-1].rstrip("\n")
    unended.write_text("".join(lines))
    assert main(["track", "--estimates", str(unended), "--out", str(tmp_path / "v.csv")]) == 2
    assert f"{unended}: line 6: " in capsys.readouterr().err


@pytest.mark.parametrize("sig", [False, True])
def test_interrupted_monitor_keeps_complete_rows(tmp_path, capsys, est, nominal, monkeypatch, sig):
    from vipm_track.filters.monitor import DriftMonitor

    out, events = tmp_path / "m.csv", tmp_path / "e.jsonl"
    _interrupt_after(monkeypatch, DriftMonitor, "update", 50, sig=sig)
    rc, err = _run(capsys, "monitor", "--estimates", est, "--nominal", nominal, "--out", out,
                   "--events", events, "--quiet")
    assert rc == 130 and "interrupted" in err
    rows = _rows(out)
    assert len(rows) == 50
    assert read_table(out)["frame"].tolist() == list(range(50))
    for line in events.read_text().splitlines():
        json.loads(line)


def test_streamed_monitor_judges_as_the_whole_sequence_does(est, nominal):
    """The frame-by-frame monitor (``monitor_frames``, what the command streams) against
    the whole sequence filtered first (``run_filter``), its states read into the inputs."""
    from vipm_track.commands.inputs import read_estimates
    from vipm_track.filters.ekf import run_filter
    from vipm_track.filters.ekf_state import EkfConfig
    from vipm_track.filters.monitor import DriftMonitor
    from vipm_track.filters.monitor_inputs import (
        forward_camera_options,
        frame_rate,
        inputs_from_measurements,
        monitor_frames,
    )
    from vipm_track.filters.monitor_types import MonitorConfig
    from vipm_track.filters.nominal import load_nominal
    from vipm_track.filters.wheel_speed import SpeedSeries

    def monitor_measurements(ms, nom, sp, cfg, ekf):
        states = run_filter(ms, sp, ekf)
        mon = DriftMonitor(nom, cfg)
        inputs = inputs_from_measurements(ms, sp, states, **forward_camera_options(nom))
        return states, [mon.update(i) for i in inputs]

    ms = read_estimates(str(est))
    nom = load_nominal(nominal)
    ekf = EkfConfig(height_m=1.65)
    cfg = MonitorConfig.from_noise(ekf.noise, fps=frame_rate(ms))
    t = np.arange(0.0, 14.0, 0.02)
    speed = SpeedSeries(t, 8.0 + np.sin(t))
    for n, sp in ((120, None), (120, speed), (2, None), (1, None)):
        _states, whole = monitor_measurements(ms[:n], nom, sp, cfg, ekf)
        streamed = list(monitor_frames(ms[:n], nom, sp, cfg, ekf))
        assert [o.state for _, _, o in streamed] == [o.state for o in whole]
        assert [o.reason for _, _, o in streamed] == [o.reason for o in whole]
        np.testing.assert_array_equal([o.statistic for _, _, o in streamed],
                                      [o.statistic for o in whole])


# -- CAN logs ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def can_data():
    return shared_data("comma2k19_can")


@pytest.fixture(scope="module")
def asc_lines(can_data, tmp_path_factory) -> list[str]:
    """3000 lines of a Vector .asc written by python-can from the RAV4 log."""
    import can

    path = tmp_path_factory.mktemp("asc") / "drive.asc"
    with can.ASCWriter(str(path)) as writer:
        for i, msg in enumerate(can.LogReader(str(can_data / "rav4_drive.log"))):
            if i == 2995:
                break
            writer.on_message_received(msg)
    lines = path.read_text().splitlines()
    assert len(lines) >= 3000
    return lines[:3000]


def _decode(path: Path, can_data: Path):
    from vipm_track.filters.speed_decoder import decode_can_log

    return decode_can_log(path, can_data / "toyota_2017.dbc")


def test_asc_bad_hex_byte_is_skipped_and_reading_goes_on(tmp_path, can_data, asc_lines):
    clean = tmp_path / "clean.asc"
    clean.write_text("\n".join(asc_lines) + "\n")
    full, _ = _decode(clean, can_data)
    lines = list(asc_lines)
    k = next(i for i in range(999, 3000) if re.search(r"\s(AA|aa)\s+Rx", lines[i]))
    lines[k] = re.sub(r"(d 8 )(\S\S)", r"\g<1>G\2", lines[k])
    bad = tmp_path / "bad.asc"
    bad.write_text("\n".join(lines) + "\n")
    series, summary = _decode(bad, can_data)
    assert len(series) == len(full) - 1 and summary.bad_lines == 1
    assert f"{bad}:{k + 1}: " in str(summary) and not summary.read_errors


def test_asc_cut_and_garbage_lines_are_counted_and_named(tmp_path, can_data, asc_lines):
    rng = np.random.default_rng(0)
    lines = list(asc_lines)
    hit = sorted(rng.choice(np.arange(10, 3000), 81, replace=False))
    for i in hit[:60]:
        lines[i] = lines[i][: len(lines[i]) // 3]
    for i in hit[60:]:
        lines[i] = "".join(chr(c) for c in rng.integers(0x21, 0x7E, 30))
    bad = tmp_path / "bad.asc"
    bad.write_text("\n".join(lines) + "\n")
    _series, summary = _decode(bad, can_data)
    assert summary.bad_lines == 81 and summary.frames == 2995 - 81
    text = str(summary)
    assert "81 lines the log reader could not read" in text
    assert f"{bad}:{hit[0] + 1}: " in text  # the first few are named by line


def test_a_log_in_another_format_says_what_its_lines_are_not(tmp_path, can_data, asc_lines):
    """An .asc renamed .log: each bad line said 'ValueError: too many values to unpack'."""
    renamed = tmp_path / "drive.log"
    renamed.write_text("\n".join(asc_lines) + "\n")
    from vipm_track.errors import InputError

    with pytest.raises(InputError, match="no speed sample decoded") as info:
        _decode(renamed, can_data)
    assert "3000 lines the log reader could not read" in str(info.value)
    assert f"{renamed}:1: not a candump -l line '(time) iface id#data' (" in str(info.value)


@pytest.mark.parametrize("fmt", ["log", "asc", "trc", "csv", "blf"])
def test_every_python_can_format_reads_the_same_frames(tmp_path, can_data, fmt):
    import can

    msgs = list(can.LogReader(str(can_data / "rav4_drive.log")))[:4000]
    path = tmp_path / f"drive.{fmt}"
    with can.Logger(str(path)) as writer:
        for msg in msgs:
            writer.on_message_received(msg)
    series, summary = _decode(path, can_data)
    assert summary.frames == 4000 and summary.bad == 0 and len(series) > 100


def test_a_cut_blf_says_it_was_cut_and_keeps_what_it_read(tmp_path, capsys, can_data):
    """A BLF shorter than its header says (a copy or a recording cut short) reads the frames
    it holds and says that it was cut, instead of passing for a short drive."""
    cut = tmp_path / "cut.blf"
    cut.write_bytes((can_data / "rav4_drive.blf").read_bytes()[:300_000])
    out = tmp_path / "s.csv"
    rc, err = _run(capsys, "can-speed", cut, "--dbc", can_data / "toyota_2017.dbc", "--out",
                   out)
    assert rc == 0 and len(_rows(out)) > 500
    assert "holds 300000 bytes but its header says" in err and "cut short" in err
    rc, err = _run(capsys, "can-speed", can_data / "rav4_drive.blf", "--dbc",
                   can_data / "toyota_2017.dbc", "--out", out)
    assert rc == 0 and "cut short" not in err


def test_binary_dbc_is_not_echoed(tmp_path, capsys, can_data):
    dbc = tmp_path / "garbage.dbc"
    dbc.write_bytes(bytes(np.random.default_rng(1).integers(0, 256, 3000, dtype=np.uint8)))
    rc, err = _run(capsys, "can-speed", can_data / "rav4_drive.log", "--dbc", dbc, "--out",
                   tmp_path / "s.csv")
    assert rc == 2 and "binary content" in err
    assert not CONTROL.search(err.replace("\n", "")) and len(err) < 300


# -- exit codes ----------------------------------------------------------------------------------

def test_estimate_with_no_usable_frame_exits_1(tmp_path, capsys):
    from conftest import CAR_CAMERA_YAML

    images = tmp_path / "images"
    images.mkdir()
    for k in range(3):
        (images / f"{k:06d}.png").write_bytes(b"not an image")
    (tmp_path / "cam.yaml").write_text(CAR_CAMERA_YAML)
    rc, err = _run(capsys, "estimate", "--images", images, "--camera", tmp_path / "cam.yaml",
                   "--height", "1.5", "--fps", "10", "--out", tmp_path / "est.csv", "--quiet")
    assert rc == 1 and "no frame has an estimate" in err and "3× unreadable frame" in err


@pytest.mark.parametrize("command", ["track", "smooth", "monitor"])
def test_estimates_without_a_usable_row_exit_1_without_a_summary(tmp_path, capsys, est, nominal,
                                                               command):
    table = read_table(est)
    lines = est.read_text().splitlines()
    header = lines[0].split(",")
    s = header.index("status")
    bad = tmp_path / "failed.csv"
    bad.write_text("\n".join([lines[0]] + [
        ",".join(c if j < 2 or j == 4 else ("no motion" if j == s else "")
                 for j, c in enumerate(line.split(","))) for line in lines[1:]]) + "\n")
    assert len(read_table(bad)["frame"]) == len(table["frame"])
    out = tmp_path / "out.csv"
    extra = ["--nominal", nominal] if command == "monitor" else ["--height", "1.65"]
    rc, err = _run(capsys, command, "--estimates", bad, "--out", out, *extra)
    assert rc == 1 and "no frame has a usable pair" in err and "120× no motion" in err
    assert not out.exists() and not out.with_suffix(".summary.json").exists()


def test_monitor_height_contradicting_the_nominal_is_an_error(tmp_path, capsys, est, nominal):
    rc, err = _run(capsys, "monitor", "--estimates", est, "--nominal", nominal, "--height", "1.5",
                   "--out", tmp_path / "m.csv")
    assert rc == 2 and "--height 1.5 m" in err and "height_m 1.65 m" in err
    rc, _ = _run(capsys, "monitor", "--estimates", est, "--nominal", nominal, "--height", "1.65",
                 "--out", tmp_path / "m.csv", "--quiet")
    assert rc == 0


# -- tables -----------------------------------------------------------------------------------

def test_track_writes_a_duplicated_frame_once_and_says_which_row(tmp_path, capsys, est):
    lines = est.read_text().splitlines()
    dup = tmp_path / "dup.csv"
    dup.write_text("\n".join([*lines[:9], lines[8], *lines[9:]]) + "\n")  # frame 7 twice
    out = tmp_path / "t.csv"
    rc, err = _run(capsys, "track", "--estimates", dup, "--height", "1.65", "--out", out)
    assert rc == 0
    frames = read_table(out)["frame"].tolist()
    assert frames == list(range(120))
    assert "row 10 frame 7 (first row 9)" in err


def test_backward_times_and_missing_numbers_are_reported_with_rows(tmp_path, capsys, est):
    lines = est.read_text().splitlines()
    header = lines[0].split(",")
    cells = [line.split(",") for line in lines[1:]]
    cells[20][1] = cells[18][1]  # frame 20's time before frame 19's
    cells[30][header.index("pitch_deg")] = ""  # ok, but no pitch (rows: CSV lines)
    # ok, but no assumed height: its travel has no scale (the batch smoother's system was
    # indeterminate, a gtsam traceback)
    cells[35][header.index("height_m")] = ""
    assert cells[30][header.index("status")] == cells[35][header.index("status")] == "ok"
    path = tmp_path / "bad.csv"
    path.write_text("\n".join([lines[0], *(",".join(c) for c in cells)]) + "\n")
    out = tmp_path / "t.csv"
    rc, err = _run(capsys, "track", "--estimates", path, "--height", "1.65", "--out", out,
                   "--columns", "all")
    assert rc == 0
    assert "row 22 t " in err and "row 32 frame 30; row 37 frame 35" in err
    cells[40][1] = "nan"  # a time that is no number is named as such, not as 'nan after'
    path.write_text("\n".join([lines[0], *(",".join(c) for c in cells)]) + "\n")
    rc, err = _run(capsys, "track", "--estimates", path, "--height", "1.65",
                   "--out", tmp_path / "t2.csv")
    assert rc == 0 and "row 42 t not a number" in err and "nan after" not in err
    cells[40][1] = lines[41].split(",")[1]
    path.write_text("\n".join([lines[0], *(",".join(c) for c in cells)]) + "\n")
    table = read_table(out)
    assert 20 not in table["frame"].tolist() and len(table["frame"]) == 119
    for frame in (30, 35):
        k = table["frame"].tolist().index(frame)
        assert table["meas_status"][k] == "no estimate (numbers missing in the table)"
    # smooth's drive summary keeps the notes
    out = tmp_path / "s.csv"
    assert _run(capsys, "smooth", "--estimates", path, "--height", "1.65", "--out", out,
                "--quiet")[0] == 0
    notes = json.loads(out.with_suffix(".summary.json").read_text())["input_notes"]
    assert len(notes) == 2 and "row 22 t " in notes[0]
    assert "row 32 frame 30; row 37 frame 35" in notes[1]


def test_report_leaves_out_repeated_and_backward_rows_naming_them(tmp_path, capsys, est):
    """report reads a table as track does: a repeated frame counts once, a frame going
    backwards is left out, each named by its row; the time span stays positive."""
    lines = est.read_text().splitlines()
    bad = tmp_path / "bad.csv"
    # frame 7 twice, then frame 3 again after frame 50
    bad.write_text("\n".join([*lines[:9], lines[8], *lines[9:52], lines[4], *lines[52:]])
                   + "\n")
    rc, err = _run(capsys, "report", bad, "--out", tmp_path / "rep")
    assert rc == 0
    assert "row 10 frame 7 (first row 9)" in err and "row 54 frame 3" in err
    text = (tmp_path / "rep" / "report.md").read_text()
    assert "(120 rows, frames 0–119)" in text
    # every row but one out of order: no sequence of frames at all (a report of one row,
    # exit 0, before), bad input naming the rows
    backwards = tmp_path / "backwards.csv"
    backwards.write_text("\n".join([lines[0], *lines[1:][::-1]]) + "\n")
    rc, err = _run(capsys, "report", backwards, "--out", tmp_path / "rep2")
    assert rc == 2 and "119 of 120 rows repeat a frame or have a frame or time out of" in err
    assert "119 rows have a frame out of order with the rows around it" in err


def test_numbers_are_written_at_sensible_precision_with_one_line_ending(tmp_path, capsys):
    from vipm_track.table import TableWriter

    with TableWriter(tmp_path / "t.csv") as writer:
        writer.write({"frame": 3, "t": 3 * 0.1, "pitch_deg": sum([0.1] * 10),
                      "roll_deg": 1.0 / 3.0, "height_m": 1e-7 / 3})
    data = (tmp_path / "t.csv").read_bytes()
    assert data == (b"frame,t,pitch_deg,roll_deg,height_m,tx_m,tz_m,yaw_deg,status\n"
                    b"3,0.3,1.0,0.333333333333333,3.33333333333333e-08,,,,\n")


def test_fps_beside_times_txt_says_which_is_used(tmp_path, capsys):
    from vipm_track.sources import open_source

    images = tmp_path / "images"
    images.mkdir()
    for k in range(3):
        cv2.imwrite(str(images / f"{k:06d}.png"), np.zeros((8, 8), np.uint8))
    (tmp_path / "times.txt").write_text("0.0\n0.1\n0.2\n")
    source = open_source(images=images, fps=25.0)
    assert [f.t for f in source] == [0.0, 0.1, 0.2]
    err = capsys.readouterr().err
    assert "--fps 25 not used" in err and "times.txt" in err


def test_unknown_camera_yaml_key_is_named_with_the_valid_ones(tmp_path):
    from conftest import CAR_CAMERA_YAML

    from vipm_track.camera import CameraFileError, load_camera

    path = tmp_path / "cam.yaml"
    path.write_text(CAR_CAMERA_YAML + "distortion_coeficients: {data: [0.1, 0, 0, 0, 0]}\n")
    with pytest.raises(CameraFileError, match=r"'distortion_coeficients'.*valid keys are "
                       r"image_width, .*distortion_coefficients"):
        load_camera(path)
    path.write_text(CAR_CAMERA_YAML.replace("rows: 3, cols: 3", "rows: 3, colls: 3"))
    with pytest.raises(CameraFileError, match=r"'camera_matrix.colls'.*rows, cols, data"):
        load_camera(path)
    fs = cv2.FileStorage(str(tmp_path / "cv.yaml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.array([[900.0, 0, 640], [0, 900, 360], [0, 0, 1]]))
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("image_widht", 1280)
    fs.release()
    with pytest.raises(CameraFileError, match=r"'image_widht'.*valid keys are camera_matrix"):
        load_camera(tmp_path / "cv.yaml")


def test_wrong_image_size_names_both_sizes(tmp_path):
    from vipm_track.camera import CameraModel
    from vipm_track.errors import InputError
    from vipm_track.pipeline import run_sequence
    from vipm_track.rig import DEFAULT_PITCH_DEG, Rig
    from vipm_track.sources import open_source

    images = tmp_path / "images"
    images.mkdir()
    camera = CameraModel(np.array([[50.0, 0, 20], [0, 50, 15], [0, 0, 1]]), 40, 30)
    rig = Rig(camera, 1.0, DEFAULT_PITCH_DEG)
    cv2.imwrite(str(images / "000000.png"), np.zeros((30, 41), np.uint8))
    with pytest.raises(InputError, match=r"41×30 px but the camera model is 40×30 px"):
        list(run_sequence(open_source(images=images, fps=10), rig, estimator=object()))
    cv2.imwrite(str(images / "000000.png"), np.zeros((30, 40), np.uint8))
    cv2.imwrite(str(images / "000001.png"), np.zeros((24, 32), np.uint8))
    steps = list(run_sequence(open_source(images=images, fps=10), rig,
                              estimator=object()))
    assert steps[1].status == "wrong image size 32×24 (camera 40×30): 000001.png"


def test_simulate_into_an_earlier_run_leaves_no_stale_images(tmp_path, capsys):
    out = tmp_path / "sim"
    assert _run(capsys, "simulate", "--frames", "4", "--out", out)[0] == 0
    rc, err = _run(capsys, "simulate", "--frames", "2", "--out", out)
    assert rc == 0 and "removed 4 images of an earlier run" in err
    assert sorted(p.name for p in (out / "images").iterdir()) == ["000000.png", "000001.png"]
    assert len((out / "times.txt").read_text().splitlines()) == 2
    (out / "images" / "mine.jpg").write_bytes(b"x")
    rc, err = _run(capsys, "simulate", "--frames", "2", "--out", out)
    assert rc == 2 and "mine.jpg" in err and (out / "images" / "mine.jpg").exists()


def test_interrupted_can_speed_writes_the_samples_decoded_before_it(tmp_path, capsys, can_data,
                                                                    monkeypatch):
    import vipm_track.filters.can_logs

    real = vipm_track.filters.can_logs.LogRecords.__iter__

    def stopping(self):
        for k, msg in enumerate(real(self)):
            if k == 20000:
                raise KeyboardInterrupt
            yield msg

    monkeypatch.setattr(vipm_track.filters.can_logs.LogRecords, "__iter__", stopping)
    out = tmp_path / "speed.csv"
    rc, err = _run(capsys, "can-speed", can_data / "rav4_drive.log", "--dbc",
                   can_data / "toyota_2017.dbc", "--out", out)
    assert rc == 130 and "interrupted after 20000 frames" in err
    rows = _rows(out)
    assert 500 < len(rows) < 2000 and all(len(r.split(",")) == 2 for r in rows)


@pytest.mark.parametrize("command", ["track", "smooth"])
def test_a_cut_last_row_is_named_once(tmp_path, capsys, est, command):
    """Without --height the table is read for its height and then for its rows: the cut last
    row is still named once, not once per reading."""
    text = est.read_text()
    cut = tmp_path / "cut.csv"
    cut.write_text(text[: text.rstrip("\n").rfind(",") - 3])
    rc, err = _run(capsys, command, "--estimates", cut, "--out", tmp_path / "o.csv")
    assert rc == 0
    assert err.count("the last row is cut short") == 1


@pytest.mark.parametrize("command", ["track", "smooth"])
def test_a_table_of_only_a_header_says_it_has_no_rows(tmp_path, capsys, est, command):
    """A header without rows (a run that died before its first row) and no --height: the
    error says the table has no rows, not that it lacks the height_m it has."""
    empty = tmp_path / "header.csv"
    empty.write_text(est.read_text().splitlines(keepends=True)[0])
    rc, err = _run(capsys, command, "--estimates", empty, "--out", tmp_path / "o.csv")
    assert rc == 2
    assert f"{empty}: no rows" in err and "has no height_m" not in err


def test_ctrl_c_before_the_first_row_says_nothing_was_written(tmp_path, capsys, monkeypatch):
    """An interrupt in the nominal-pose search (no --pitch), before the table is opened, does
    not claim rows were kept — least of all an earlier run's table at the same path."""
    from conftest import CAR_CAMERA_YAML

    import vipm_track.nominal_search

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(vipm_track.nominal_search, "search_nominal_pose", interrupted)
    images = tmp_path / "images"
    images.mkdir()
    for k in range(3):
        cv2.imwrite(str(images / f"{k:06d}.png"), np.zeros((720, 1280), np.uint8))
    (tmp_path / "cam.yaml").write_text(CAR_CAMERA_YAML)
    out = tmp_path / "est.csv"
    out.write_text("frame,t\n")  # an earlier run's
    os.utime(out, (1e9, 1e9))
    rc, err = _run(capsys, "estimate", "--images", images, "--camera", tmp_path / "cam.yaml",
                   "--fps", "10", "--height", "1.5", "--out", out, "--quiet")
    assert rc == 130
    assert f"interrupted; it came before anything was written to {out}" in err
    assert "kept" not in err


# -- interrupts at awkward moments ------------------------------------------------------------

def test_ctrl_c_while_a_command_starts_is_an_interruption_not_a_traceback(capsys, monkeypatch):
    """A command's parser imports gtsam or cantools: a Ctrl-C in that second printed a
    KeyboardInterrupt traceback."""
    import vipm_track.cli

    def importing(only=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(vipm_track.cli, "build_parser", importing)
    rc, err = _run(capsys, "smooth", "--estimates", "x.csv", "--out", "y.csv")
    assert rc == 130 and err == "vipm-track smooth: interrupted while starting; nothing was done\n"


def _interrupted_stream(statuses: list[str], inside_kernel: bool):
    """An estimate stream whose pairs carry ``statuses``, then a Ctrl-C (as a compiled kernel
    returns it with ``inside_kernel``: a SystemError whose context is the interrupt)."""
    from vipm_track.measurement import PairMeasurement

    def stream(*args, **kwargs):
        for k, status in enumerate(statuses):
            yield PairMeasurement(k, 0.1 * k, np.full(8, np.nan), np.full((8, 8), np.nan), 1.5,
                                  status)
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            if inside_kernel:
                raise SystemError("CPUDispatcher(<function pair_lm>) returned a result with "
                                  "an exception set") from None
            raise

    return stream


@pytest.mark.parametrize("inside_kernel", [False, True])
def test_ctrl_c_before_a_usable_pair_is_an_interruption_not_nothing_usable(
        tmp_path, capsys, monkeypatch, inside_kernel):
    """`smooth --images` interrupted in its first frames said "nothing usable ... give
    --pitch" (exit 1); inside a compiled kernel the interrupt came as a SystemError
    traceback."""
    from conftest import CAR_CAMERA_YAML

    import vipm_track.commands.inputs

    monkeypatch.setattr(vipm_track.commands.inputs, "estimate_stream",
                        _interrupted_stream(["first frame", "no motion"], inside_kernel))
    images = tmp_path / "images"
    images.mkdir()
    for k in range(3):
        (images / f"{k:06d}.png").write_bytes(b"")
    (images / "camera.yaml").write_text(CAR_CAMERA_YAML)
    out = tmp_path / "s.csv"
    rc, err = _run(capsys, "smooth", "--images", images, "--height", "1.5", "--fps", "10",
                   "--pitch", "3", "--out", out, "--quiet")
    assert rc == 130 and "interrupted" in err and "nothing usable" not in err
    assert "Traceback" not in err


def test_quiet_still_names_the_rows_left_out(tmp_path, capsys, est):
    """--quiet silences progress and summaries; it hid the warnings about rows left out."""
    lines = est.read_text().splitlines()
    dup = tmp_path / "dup.csv"
    dup.write_text("\n".join([*lines[:9], lines[8], *lines[9:]]) + "\n")  # frame 7 twice
    for command in ("track", "smooth"):
        rc, err = _run(capsys, command, "--estimates", dup, "--height", "1.65", "--quiet",
                       "--out", tmp_path / f"{command}.csv")
        assert rc == 0 and "row 10 frame 7 (first row 9)" in err
        assert "frames (ok" not in err  # the summary line stays quiet


@pytest.mark.parametrize("command", ["track", "smooth", "monitor"])
def test_an_output_that_is_the_input_is_refused_before_any_work(tmp_path, capsys, est, nominal,
                                                                command):
    """`smooth --estimates x.csv --out x.csv` replaced the table it read by its output."""
    table = tmp_path / "same.csv"
    table.write_bytes(est.read_bytes())
    extra = ["--nominal", nominal] if command == "monitor" else ["--height", "1.65"]
    rc, err = _run(capsys, command, "--estimates", table, "--out", table, *extra)
    assert rc == 2 and f"--out {table}: is the input --estimates {table}" in err
    assert table.read_bytes() == est.read_bytes()


def test_an_output_over_a_frame_of_the_images_is_refused(tmp_path, capsys):
    from conftest import CAR_CAMERA_YAML

    images = tmp_path / "images"
    images.mkdir()
    frame = images / "000001.png"
    cv2.imwrite(str(frame), np.zeros((8, 8), np.uint8))
    before = frame.read_bytes()
    (images / "camera.yaml").write_text(CAR_CAMERA_YAML)
    rc, err = _run(capsys, "estimate", "--images", images, "--height", "1.5", "--fps", "10",
                   "--out", frame)
    assert rc == 2 and f"--out {frame}: is a file of the input --images {images}" in err
    assert frame.read_bytes() == before


def test_a_byte_order_mark_is_read_past(tmp_path, capsys, est):
    """Excel's "CSV UTF-8" starts the file with a BOM: the header read '\\ufeffframe' and the
    table was refused for a missing column 'frame' (times.txt and calib files alike)."""
    from vipm_track.sources import read_times
    from vipm_track.text_files import read_text

    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + est.read_bytes())
    rc, err = _run(capsys, "track", "--estimates", bom, "--height", "1.65", "--quiet",
                   "--out", tmp_path / "t.csv")
    assert rc == 0, err
    assert read_text(bom) == est.read_text()
    times = tmp_path / "times.txt"
    times.write_bytes(b"\xef\xbb\xbf0.0\n0.1\n")
    np.testing.assert_array_equal(read_times(times), [0.0, 0.1])


def _tiny_images(tmp_path: Path, size: tuple[int, int] = (8, 8)) -> Path:
    """Three black frames, a times.txt beside their folder and a car camera.yaml in it."""
    from conftest import CAR_CAMERA_YAML

    images = tmp_path / "images"
    images.mkdir()
    for k in range(3):
        cv2.imwrite(str(images / f"{k:06d}.png"), np.zeros(size, np.uint8))
    (images / "camera.yaml").write_text(CAR_CAMERA_YAML)
    (tmp_path / "times.txt").write_text("0.0\n0.1\n0.2\n")
    return images


def test_outputs_over_files_read_beside_the_images_are_refused(tmp_path, capsys):
    """An audit overwrote the times.txt and the camera.yaml that estimate had found beside the
    images (the next run then failed on them); only inputs named by an option were guarded."""
    images = _tiny_images(tmp_path)
    for target in (tmp_path / "times.txt", images / "camera.yaml"):
        before = target.read_bytes()
        rc, err = _run(capsys, "estimate", "--images", images, "--height", "1.5", "--pitch", "3",
                       "--readout-time", "0", "--out", target)
        assert rc == 2 and f"--out {target}: is " in err and "destroy the input" in err
        assert target.read_bytes() == before


def test_two_outputs_that_are_one_file_are_refused(tmp_path, capsys, est):
    """`--out x.csv --rerun x.csv` interleaved a table and a recording in one file; smooth's
    --summary replaced the estimates it read (or its own table) by JSON."""
    table = tmp_path / "est.csv"
    table.write_bytes(est.read_bytes())
    out = tmp_path / "sm.csv"
    rc, err = _run(capsys, "smooth", "--estimates", table, "--height", "1.65", "--out", out,
                   "--summary", table)
    assert rc == 2 and f"--summary {table}: is the input --estimates {table}" in err
    assert table.read_bytes() == est.read_bytes()
    rc, err = _run(capsys, "smooth", "--estimates", table, "--height", "1.65", "--out", out,
                   "--summary", out)
    assert rc == 2 and f"--out {out} and --summary {out} are the same file" in err
    rc, err = _run(capsys, "track", "--estimates", table, "--height", "1.65", "--out", out,
                   "--rerun", out)
    assert rc == 2 and "are the same file" in err and not out.exists()


def test_a_run_that_fails_before_its_first_row_leaves_an_earlier_table(tmp_path, capsys):
    """A camera that does not fit the images (found before the run, naming the camera file;
    at the first frame before that): the table at --out (an earlier run's) had already been
    cut to its header."""
    images = _tiny_images(tmp_path)  # 8×8 frames, a 1280×720 camera
    out = tmp_path / "keep.csv"
    out.write_text("frame,t\n0,0.0\n1,0.1\n")
    before = out.read_bytes()
    rc, err = _run(capsys, "estimate", "--images", images, "--height", "1.5", "--pitch", "3",
                   "--readout-time", "0", "--out", out)
    assert rc == 2 and "the camera is 1280×720 px but the frames of" in err
    assert "are 8×8 px: is it their camera?" in err
    assert out.read_bytes() == before


def test_a_filter_command_without_input_asks_for_one(tmp_path, capsys):
    """`track --out x.csv` alone said '--height must be a positive number, got None'."""
    for command in ("track", "smooth"):
        rc, err = _run(capsys, command, "--out", tmp_path / "x.csv")
        assert rc == 2 and "give exactly one of --estimates EST.csv, --images DIR" in err
        assert "--height" not in err


def test_a_fleet_drive_whose_speed_file_holds_no_sample_says_so(tmp_path):
    """A header-only speed.csv failed the drive with an IndexError from deep inside."""
    from vipm_track.errors import InputError
    from vipm_track.fleet.drive_run import FleetSettings, drive_speed
    from vipm_track.fleet.drives import DriveSpec

    speed = tmp_path / "speed.csv"
    speed.write_text("t,speed_mps\n")
    with pytest.raises(InputError, match=r"speed\.csv: no speed samples"):
        drive_speed(DriveSpec("d", speed_csv=speed), FleetSettings())


def test_live_refuses_a_frame_rate_that_is_not_positive(tmp_path, capsys, nominal):
    """`live --fps -5` ran and dropped every frame (estimate refused the same option)."""
    from conftest import CAR_CAMERA_YAML

    (tmp_path / "cam.yaml").write_text(CAR_CAMERA_YAML)
    rc, err = _run(capsys, "live", "--video", tmp_path / "none.avi", "--camera",
                   tmp_path / "cam.yaml", "--nominal", nominal, "--fps", "-5",
                   "--out", tmp_path / "live.csv")
    assert rc == 2 and "--fps must be a number of frames per second in [0.1, 1000], got -5" in err


def test_a_second_ctrl_c_does_not_cut_what_the_first_left_to_write(tmp_path, capsys, est,
                                                                   monkeypatch):
    """After the first Ctrl-C smooth writes the frames it did not smooth and its summary; a
    second one during that cut the table short (760 of 9,600 rows) and wrote no summary."""
    import vipm_track.filters.track as track_module
    from vipm_track.filters.fixed_lag import FixedLagSmoother

    real_step, real_row = FixedLagSmoother.step, track_module.track_row
    steps, after = [0], [0]  # smoother steps; rows made after the first Ctrl-C

    def step_then_ctrl_c(self, *a, **k):
        steps[0] += 1
        if steps[0] > 60:
            raise KeyboardInterrupt
        return real_step(self, *a, **k)

    def row_then_ctrl_c(*a, **k):
        if steps[0] > 60:
            after[0] += 1
            if after[0] == 3:  # the user presses Ctrl-C again while the rest is written
                os.kill(os.getpid(), signal.SIGINT)
        return real_row(*a, **k)

    monkeypatch.setattr(FixedLagSmoother, "step", step_then_ctrl_c)
    monkeypatch.setattr(track_module, "track_row", row_then_ctrl_c)
    out = tmp_path / "s.csv"
    rc, _ = _run(capsys, "smooth", "--estimates", est, "--height", "1.65", "--lag", "1",
                   "--out", out, "--quiet")
    assert rc == 130 and after[0] > 3
    assert list(read_table(out)["frame"]) == list(range(120))
    summary = json.loads(out.with_suffix(".summary.json").read_text())
    assert summary["status"].startswith("interrupted")
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored


@pytest.mark.parametrize("command", ["estimate", "track"])
def test_an_images_folder_that_is_not_one_is_named(tmp_path, capsys, command):
    """A missing folder was reported as a missing --camera, a file as '(found beside the
    images)' then 'image folder not found'."""
    (tmp_path / "camera.yaml").write_text("x: 1\n")
    for given, message in ((tmp_path / "nope" / "images", "no such folder"),
                           (tmp_path / "camera.yaml", "is a file; give the folder")):
        rc, err = _run(capsys, command, "--images", given, "--height", "1.5",
                       "--out", tmp_path / "o.csv")
        assert rc == 2 and f"--images {given}: {message}" in err and "--camera" not in err


@pytest.mark.parametrize("when", ["rendering", "writing its truth"])
def test_an_interrupted_simulation_is_a_sequence_of_its_own(tmp_path, capsys, monkeypatch,
                                                            when):
    """simulate wrote times.txt, speed.csv and traffic.csv for every frame before rendering;
    interrupted after 5 frames it said 'what was written is complete and kept', and estimate
    then refused the folder: 40 timestamps but 5 images. Now all are cut to the 5 frames,
    also where frame 5's image was written and its truth row not."""
    import vipm_track.sim
    from vipm_track.sources import open_source

    if when == "rendering":
        real = vipm_track.sim.render_trajectory_frame

        def render(tex, camera, traj, k, *a, **kw):
            if k == 5:
                raise KeyboardInterrupt
            return real(tex, camera, traj, k, *a, **kw)

        monkeypatch.setattr(vipm_track.sim, "render_trajectory_frame", render)
    else:
        _interrupt_after(monkeypatch, vipm_track.sim.TableWriter, "write", 5)
    out = tmp_path / "sim"
    rc, err = _run(capsys, "simulate", "--preset", "car", "--frames", "40", "--traffic",
                   "light", "--out", out)
    assert rc == 130 and "interrupted" in err
    times = np.loadtxt(out / "times.txt")
    assert len(times) == 5 == len(list((out / "images").glob("*.png")))
    assert len(open_source(images=out / "images")) == 5  # times.txt and images agree
    gt = np.genfromtxt(out / "gt.csv", delimiter=",", names=True)
    assert len(gt) == 5
    speed = np.genfromtxt(out / "speed.csv", delimiter=",", names=True)
    assert speed["t"].max() <= times[-1] and speed["t"].max() > times[-1] - 0.05
    traffic = np.genfromtxt(out / "traffic.csv", delimiter=",", names=True)
    assert traffic["frame"].max() == 4


def test_track_whose_filter_never_started_exits_1(tmp_path, capsys, est):
    """Seven usable pairs, fewer than the EKF starts on: every row 'waiting for first
    pairs', and it exited 0 as if the drive had been tracked."""
    short = tmp_path / "short.csv"
    short.write_text("".join(est.read_text().splitlines(keepends=True)[:9]))
    rc, err = _run(capsys, "track", "--estimates", short, "--height", "1.65", "--out",
                   tmp_path / "t.csv", "--quiet")
    assert rc == 1
    assert ("short.csv: the filter never started: it starts on 10 usable pairs and the drive "
            "has 7" in err)
    assert "None:" not in err


def test_a_missing_height_and_a_folder_given_as_a_dbc_are_named_as_such(tmp_path, capsys,
                                                                        can_data):
    """`track --images` without --height said '--height must be a positive number of metres,
    got None'; `can-speed --dbc FOLDER` said the output 'is a file of the input --dbc'."""
    images = tmp_path / "images"
    images.mkdir()
    rc, err = _run(capsys, "track", "--images", images, "--pitch", "45", "--out",
                   tmp_path / "t.csv")
    assert rc == 2 and "--height is needed" in err and "None" not in err
    out = tmp_path / "x.csv"
    out.write_text("t,speed_mps\n")
    rc, err = _run(capsys, "can-speed", can_data / "rav4_drive.log", "--dbc", tmp_path,
                   "--out", out)
    assert rc == 2 and f"{tmp_path}: a folder, not a DBC file" in err
    # the summary's Markdown goes beside its JSON: a .md name was 'the same file' as itself
    rc, err = _run(capsys, "smooth", "--estimates", out, "--height", "1.5", "--out",
                   tmp_path / "s.csv", "--summary", tmp_path / "s.md")
    assert rc == 2 and "names the JSON summary" in err
    # the recording's image options are checked before any work, and leave no recording
    rc, err = _run(capsys, "estimate", "--images", images, "--height", "1.5", "--out",
                   tmp_path / "e.csv", "--rerun", tmp_path / "r.rrd", "--rerun-jpeg-quality", "0")
    assert rc == 2 and "--rerun-jpeg-quality must be in 1..100" in err
    assert not (tmp_path / "r.rrd").exists()
    (tmp_path / "empty.blf").write_bytes(b"")  # said "unpack requires a buffer of 72 bytes"
    rc, err = _run(capsys, "can-speed", tmp_path / "empty.blf", "--dbc",
                   can_data / "toyota_2017.dbc", "--out", tmp_path / "s.csv")
    assert rc == 2 and "empty.blf: empty file, no CAN log in it" in err


def test_ctrl_c_inside_a_lazy_import_is_an_interrupt(tmp_path, capsys, est, monkeypatch):
    """Ctrl-C while `track` first imported gtsam came back as "ImportError: initialization
    failed": a traceback, exit 1."""
    from vipm_track.commands import track as track_command

    def importing(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc

    monkeypatch.setattr(track_command, "run", importing)
    rc, err = _run(capsys, "track", "--estimates", est, "--height", "1.65", "--out",
                   tmp_path / "t.csv")
    assert rc == 130 and "interrupted" in err and "Traceback" not in err


def test_ctrl_c_while_the_parquet_is_written_keeps_it(tmp_path, monkeypatch):
    """A Ctrl-C after the last row, while the Parquet table was written (pyarrow's import
    alone takes a while), lost it without a word; it is written, then the interrupt goes on."""
    from vipm_track import table as table_module

    original = table_module.write_parquet

    def interrupted(*args, **kwargs):
        signal.raise_signal(signal.SIGINT)
        return original(*args, **kwargs)

    monkeypatch.setattr(table_module, "write_parquet", interrupted)
    writer = table_module.TableWriter(tmp_path / "t.csv", ["frame", "t"],
                                      parquet_path=tmp_path / "t.parquet")
    writer.write({"frame": 0, "t": 0.0})
    with pytest.raises(KeyboardInterrupt):
        writer.close()
    assert len(read_table(tmp_path / "t.parquet")["frame"]) == 1


def test_ctrl_c_after_the_last_smoothed_frame_keeps_the_summary(tmp_path, capsys, est,
                                                                 monkeypatch):
    """Ctrl-C once every frame was smoothed, while the drive's summary was made: the table
    was complete but the Parquet file and the summary were not written, and nothing said so."""
    from vipm_track.filters import drive_summary

    original = drive_summary.summarize_mount

    def interrupted(*args, **kwargs):
        signal.raise_signal(signal.SIGINT)
        return original(*args, **kwargs)

    monkeypatch.setattr(drive_summary, "summarize_mount", interrupted)
    out = tmp_path / "s.csv"
    rc, _ = _run(capsys, "smooth", "--estimates", est, "--height", "1.65", "--lag", "1",
                   "--out", out, "--parquet", "--quiet")
    assert rc == 130
    assert len(read_table(out)["frame"]) == len(read_table(tmp_path / "s.parquet")["frame"])
    assert json.loads(out.with_suffix(".summary.json").read_text())["status"] == "complete"
