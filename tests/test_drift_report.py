"""The drift report read back: what ``report.md``, ``drift.png`` and ``report.html`` say about
the calibration, held against the truth of a rendered drive with a mount step.

Fixtures ``tests/data/knock_cart_*``: ``vipm-track demo --frames 180`` (the cart camera
rendered over 17.9 s, its mount knocked +1° in pitch at 7.2 s; ``gt.csv`` has the true mount):
the estimates, the batch smoother's and the monitor's tables, the truth and the wheel speed.
"""

from __future__ import annotations

import base64
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vipm_track.cli import main
from vipm_track.errors import InputError
from vipm_track.filters.nominal import load_nominal
from vipm_track.kitti import is_kitti_poses, kitti_truth_table
from vipm_track.sinks.drift_summary import MIN_RATE_SPAN_S, summarize_drift
from vipm_track.sinks.report import write_report
from vipm_track.table import read_table, write_table

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
NOMINAL = ROOT / "data" / "nominal_cart.yaml"
GT = DATA / "knock_cart_gt.csv"
KITTI = ROOT.parent / "shared" / "data" / "kitti07"


def true_knock_s() -> float:
    truth = read_table(GT)
    pitch = np.asarray(truth["mount_pitch_deg"], float)
    return float(truth["t"][np.flatnonzero(pitch != pitch[0])[0]])


def test_a_monitor_tables_change_is_dated_by_its_frames_not_its_slow_mount() -> None:
    """The monitor's table of the knocked cart: its EKF mount follows the knock at its own
    pace, and the halfway rule put a knock at 7.2 s (flagged within a second) several seconds
    late; the frames' own pitch steps at the knock."""
    from vipm_track.sinks.drift_summary import summarize_drift

    drift = summarize_drift(read_table(DATA / "knock_cart_monitor.csv"),
                            load_nominal(NOMINAL))
    assert drift is not None
    assert abs(drift.axes["pitch"].changed_at_s - true_knock_s()) <= 0.3


def calibration_row(text: str, axis: str) -> list[str]:
    """Cells of the calibration table's row of ``axis`` in report.md."""
    row = next(x for x in text.splitlines() if x.startswith(f"| {axis} ["))
    return [c.strip() for c in row.strip("|").split("|")]


def _non_blank_png(path: Path) -> None:
    import matplotlib.image as mpimg

    pixels = mpimg.imread(path)
    assert pixels.shape[0] > 400 and pixels[..., :3].std() > 0.05


def test_smoothed_knock_report_says_the_truth(tmp_path: Path) -> None:
    """The smoother's table: pitch now ≈ 46° (truth inside the interval), changed by +1° at
    the knock, beyond tolerance for sure; roll and height unchanged; no drift rate over a
    17.9 s table; the figure and the HTML page hold what report.md says."""
    report = write_report(DATA / "knock_cart_smoothed.csv", tmp_path, gt=GT,
                          nominal=load_nominal(NOMINAL), html=True)
    pitch, roll = report.drift.axes["pitch"], report.drift.axes["roll"]
    assert pitch.true_current == 46.0 and pitch.covers_truth
    assert pitch.change == pytest.approx(1.0, abs=0.05)
    assert abs(pitch.changed_at_s - true_knock_s()) <= 0.3
    assert pitch.p_beyond > 0.999 and roll.p_beyond < 0.05
    assert np.isnan(roll.changed_at_s) and roll.covers_truth
    assert report.drift.axes["height"].covers_truth
    text = report.markdown.read_text()
    cells = calibration_row(text, "pitch")
    current, lo, hi = (float(v) for v in re.findall(r"-?\d+\.\d+", cells[1]))
    assert lo <= 46.0 <= hi and current == pytest.approx(pitch.current, abs=1e-3)
    change = float(cells[3].split("±")[0])
    assert change == pytest.approx(1.0, abs=0.05) and cells[5] == "> 99.9 %"
    assert float(cells[6].removesuffix(" s")) == pytest.approx(true_knock_s(), abs=0.3)
    assert cells[7].startswith("not given") and "< 60 s" in cells[7]
    assert calibration_row(text, "roll")[6] == "no change"
    assert not re.search(r"\de[-+]\d", text), "scientific notation in the report"
    _non_blank_png(report.plots["drift"])
    page = report.html.read_text()
    assert "<table>" in page and "46.0" in page and 'src="drift.png"' not in page
    embedded = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    assert base64.b64decode(embedded[0]) == (tmp_path / "drift.png").read_bytes()
    assert len(embedded) == len(report.plots)


def test_monitor_knock_report_timeline(tmp_path: Path) -> None:
    """The monitor's table: RECALIBRATE now, first alarm within 1 s after the knock and none
    before, the new extrinsics' interval holds the true 46°."""
    report = write_report(DATA / "knock_cart_monitor.csv", tmp_path, gt=GT,
                          nominal=load_nominal(NOMINAL))
    monitor = report.drift.monitor
    assert monitor.final_state == "RECALIBRATE"
    assert 0.0 <= monitor.first_alarm[1] - true_knock_s() <= 1.0
    pitch = report.drift.axes["pitch"]
    assert pitch.interval_from == "monitor" and pitch.covers_truth
    text = report.markdown.read_text()
    # the state named: the monitor's own line names its first RECALIBRATE, later
    assert "Monitor: now **RECALIBRATE**; first alarm (DRIFTING) at frame" in text
    assert "CALIBRATED → DRIFTING" in text and "## Monitor" not in text


def test_report_window_and_cli(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """``--start``/``--max-frames`` window the rows; a window before the knock shows no
    change; without ``--nominal`` the change is since the first mount."""
    assert main(["report", str(DATA / "knock_cart_smoothed.csv"), "--out", str(tmp_path),
                 "--start", "10", "--max-frames", "50", "--html"]) == 0
    assert "report.html" in capsys.readouterr().err
    text = (tmp_path / "report.md").read_text()
    assert "(50 rows, frames 10–59)" in text
    cells = calibration_row(text, "pitch")
    assert "(start)" in cells[2] and cells[6] == "no change"
    # no tolerance, so no probability of being beyond it (it said > 99.9 % for no change)
    assert cells[4] == "–" and cells[5] == "–"
    # a title with markup is text in the page, as in its <title> (it went into the <h1> raw)
    assert main(["report", str(DATA / "knock_cart_smoothed.csv"), "--out", str(tmp_path),
                 "--title", "KL <b>x</b> & y", "--html"]) == 0
    page = (tmp_path / "report.html").read_text()
    assert "<b>x</b>" not in page and page.count("KL &lt;b&gt;x&lt;/b&gt; &amp; y") == 2
    assert main(["report", str(DATA / "knock_cart_smoothed.csv"), "--out", str(tmp_path),
                 "--max-frames", "0"]) == 2
    assert "--max-frames" in capsys.readouterr().err
    assert main(["report", str(DATA / "knock_cart_smoothed.csv"), "--out", str(tmp_path),
                 "--nominal", str(tmp_path / "none.yaml")]) == 2


def ramp_table(minutes: float, rate_deg_per_min: float, seed: int = 0) -> dict:
    """A smoothed-like table at 10 Hz: a mount pitch ramp with 0.01° of wander on it and a
    per-frame σ of 0.02°."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0 * minutes, 0.1)
    mount = 3.0 + rate_deg_per_min * t / 60.0 + np.cumsum(rng.normal(0, 0.0005, t.size))
    return {"frame": np.arange(t.size), "t": t, "pitch_deg": mount + rng.normal(0, 0.3, t.size),
            "mount_pitch_deg": mount, "mount_pitch_std_deg": np.full(t.size, 0.02)}


def test_truth_of_another_drive_is_refused(tmp_path: Path, capsys) -> None:
    """Truth whose frames are at other times than the table's (another drive, another clock)
    is an error, not a frame-by-frame score of the wrong drive (it printed a pitch bias of
    42°); truth lacking a column says so instead of leaving it out silently."""
    from vipm_track.table import read_table, write_table

    table = DATA / "knock_cart_smoothed.csv"
    gt = read_table(DATA / "knock_cart_gt.csv")
    other = {**gt, "t": gt["t"] * 0.5}
    rows = [{c: other[c][i] for c in other} for i in range(len(other["frame"]))]
    write_table(tmp_path / "other.csv", rows, [c for c in other if c not in ("frame", "t")])
    assert main(["report", str(table), "--gt", str(tmp_path / "other.csv"), "--out",
                 str(tmp_path / "r1")]) == 2
    err = capsys.readouterr().err
    assert "other.csv: frame 1 is at t = " in err and "not the truth of this drive" in err
    no_pitch = [c for c in gt if c not in ("frame", "t", "pitch_deg")]
    rows = [{c: gt[c][i] for c in gt if c != "pitch_deg"} for i in range(len(gt["frame"]))]
    write_table(tmp_path / "nopitch.csv", rows, no_pitch)
    assert main(["report", str(table), "--gt", str(tmp_path / "nopitch.csv"), "--out",
                 str(tmp_path / "r2")]) == 0
    assert "nopitch.csv: no values in column(s) pitch_deg: not scored" in capsys.readouterr().err


def test_an_infinite_number_is_named_not_left_out(tmp_path: Path, capsys) -> None:
    """An `inf` pitch in the table (or the truth) was taken as a missing value and the report
    written as if the row had none; it is an error naming row, frame and column."""
    table = read_table(DATA / "knock_cart_smoothed.csv")
    columns = [c for c in table if c not in ("frame", "t")]
    rows = [{c: table[c][i] for c in table} for i in range(len(table["frame"]))]
    rows[5]["mount_pitch_deg"] = float("inf")
    write_table(tmp_path / "inf.csv", rows, columns)
    assert main(["report", str(tmp_path / "inf.csv"), "--out", str(tmp_path / "r1")]) == 2
    frame = int(table["frame"][5])
    assert (f"inf.csv: row 7 (frame {frame}): mount_pitch_deg = inf is not a finite number"
            in capsys.readouterr().err)
    assert not (tmp_path / "r1" / "report.md").exists()
    # an infinite time too (it was left out as "t not a number"), named by the file's row
    # even where an earlier row repeats a frame
    rows[5]["mount_pitch_deg"] = table["mount_pitch_deg"][5]
    rows[7]["t"] = float("inf")
    rows.insert(2, dict(rows[1]))
    write_table(tmp_path / "tinf.csv", rows, columns)
    assert main(["report", str(tmp_path / "tinf.csv"), "--out", str(tmp_path / "r3")]) == 2
    assert (f"tinf.csv: row 10 (frame {int(table['frame'][7])}): t = inf is not a finite "
            "number" in capsys.readouterr().err)
    gt = read_table(DATA / "knock_cart_gt.csv")
    rows = [{c: gt[c][i] for c in gt} for i in range(len(gt["frame"]))]
    rows[2]["pitch_deg"] = float("-inf")
    write_table(tmp_path / "gt.csv", rows, [c for c in gt if c not in ("frame", "t")])
    assert main(["report", str(DATA / "knock_cart_smoothed.csv"), "--gt",
                 str(tmp_path / "gt.csv"), "--out", str(tmp_path / "r2")]) == 2
    assert "gt.csv: row 4 (frame " in capsys.readouterr().err


def test_drift_rate_only_over_long_spans() -> None:
    """A 0.05°/min creep over 10 min is found within 3σ; over 30 s no rate is given."""
    s = summarize_drift(ramp_table(10.0, 0.05))
    pitch = s.axes["pitch"]
    assert np.isfinite(pitch.rate_std_per_min) and pitch.rate_std_per_min < 0.02
    assert abs(pitch.rate_per_min - 0.05) <= 3 * pitch.rate_std_per_min
    short = summarize_drift(ramp_table(0.5, 0.05)).axes["pitch"]
    assert np.isnan(short.rate_per_min) and f"< {MIN_RATE_SPAN_S:.0f} s" in short.rate_note


def test_estimates_table_has_no_calibration_section(tmp_path: Path, capsys) -> None:
    report = write_report(DATA / "knock_cart_est.csv", tmp_path)
    assert report.drift is None and "## Calibration" not in report.markdown.read_text()
    # a nominal given for it is said to be unused (it was dropped without a word)
    assert main(["report", str(DATA / "knock_cart_est.csv"), "--nominal", str(NOMINAL),
                 "--out", str(tmp_path / "r")]) == 0
    assert "no mount (calibration) to hold against the nominal" in capsys.readouterr().err


@pytest.mark.skipif(not (KITTI / "poses.txt").is_file(),
                    reason="../shared/data/kitti07 absent (KITTI 07 poses)")
def test_report_against_kitti_poses(tmp_path: Path) -> None:
    """``--gt poses.txt``: travel and yaw scored against KITTI, pitch/roll only as changes."""
    assert main(["report", str(DATA / "kitti07_estimates.csv"), "--gt",
                 str(KITTI / "poses.txt"), "--out", str(tmp_path)]) == 0
    report = write_report(DATA / "kitti07_estimates.csv", tmp_path,
                          gt=KITTI / "poses.txt")
    assert "pitch_deg" not in report.errors and "pitch_change_deg" in report.errors
    assert report.errors["distance_pct"]["median_abs"] < 5.0
    assert report.errors["yaw_deg"]["median_abs"] < 0.1


def test_kitti_poses_bad_line_named(tmp_path: Path) -> None:
    path = tmp_path / "poses.txt"
    path.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n")
    assert is_kitti_poses(path)
    with pytest.raises(InputError, match=r"poses.txt: line 2: 11 numbers"):
        kitti_truth_table(path)
    write_table(tmp_path / "gt.csv", [{"frame": 0, "t": 0.0, "pitch_deg": 1.0}])
    assert not is_kitti_poses(tmp_path / "gt.csv")
    # its times.txt: a bad line is named (a bare float() gave a traceback), and one time per
    # pose is needed (a short file dropped the times, and with them the check of the clock)
    path.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    (tmp_path / "times.txt").write_text("0.0\ngarbage\n0.2\n")
    with pytest.raises(InputError, match=r"times.txt: line 2: not a timestamp in seconds"):
        kitti_truth_table(path)
    (tmp_path / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(InputError, match=r"times.txt: 2 times for the 3 poses"):
        kitti_truth_table(path)
    (tmp_path / "times.txt").write_text("0.0\n0.1\n0.2\n")
    assert list(kitti_truth_table(path)["t"]) == [0.1, 0.2]


def test_a_truth_without_times_is_said_to_be_matched_by_frame(tmp_path: Path, capsys) -> None:
    """KITTI poses without a times.txt cannot be checked against the table's clock: a cart's
    table was scored against KITTI 07's poses without a word. Now the report says so."""
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 200)
    assert main(["report", str(DATA / "knock_cart_est.csv"), "--gt", str(poses),
                 "--out", str(tmp_path / "r")]) == 0
    assert "poses.txt: no times (a times.txt beside it)" in capsys.readouterr().err


@settings(max_examples=60, deadline=None)
@given(st.text(max_size=300))
def test_kitti_poses_bad_input_fuzz(text: str) -> None:
    """Any text: a truth table or an InputError naming the file, never another exception."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "poses.txt"
        path.write_text(text, encoding="utf-8", errors="replace")
        if not is_kitti_poses(path):
            return
        try:
            table = kitti_truth_table(path)
        except InputError as exc:
            assert "poses.txt" in str(exc)
        else:
            assert len(table["frame"]) >= 1


def test_times_keep_a_20_fps_frame_apart():
    """At 20 fps frames are 0.05 s apart: the report's times must tell them apart (1 decimal
    put frame 1 at 0.1 s and made a one-frame state last 0.1 s)."""
    from vipm_track.sinks.drift_report import fmt

    assert [fmt(t, "s") for t in (0.05, 0.1, 8.15)] == ["0.05", "0.10", "8.15"]


def test_a_monitor_tables_change_is_dated_without_a_nominal() -> None:
    """A monitor table has no mount σ at its start: without --nominal the report said "no
    change" and "± –" beside a 1° knock. Its new-extrinsics interval now stands for the
    step's: the knock at 7.2 s is dated, its change ± 0.06°."""
    drift = summarize_drift(read_table(DATA / "knock_cart_monitor.csv"))
    pitch = drift.axes["pitch"]
    assert abs(pitch.change - 1.0) < 0.05 and 0.02 < pitch.change_std < 0.1
    assert abs(pitch.changed_at_s - 7.2) < 0.3


@pytest.mark.parametrize("first_s, last_s", [(3.5, 11.0), (6.0, 10.0), (2.0, 9.0)])
def test_a_short_drives_knock_is_dated_by_its_frames(first_s, last_s):
    """Drives shorter than the step test's 8 s fell back on the filter's mount crossing
    halfway, seconds late (a knock at 3.2 s of an 8-s drive was put at 7.8 s); the frames'
    own pose splits at the knock (7.2 s)."""
    table = read_table(DATA / "knock_cart_monitor.csv")
    t = np.asarray(table["t"], float)
    keep = (t >= first_s) & (t <= last_s)
    short = {k: np.asarray(v)[keep] for k, v in table.items()}
    pitch = summarize_drift(short, load_nominal(ROOT / "data" / "nominal_cart.yaml")).axes["pitch"]
    assert abs(pitch.changed_at_s - true_knock_s()) <= 0.3, pitch.changed_at_s


def test_a_table_edited_by_hand_is_said_so(tmp_path: Path) -> None:
    """What the report showed as fact from a hand-cut table: 'ok × 180' without a status
    column, ok rows without numbers, a monitor state no monitor writes, a mount axis gone
    from the calibration without a word. Each is a note now; the tables vipm-track writes
    give none."""
    for name in ("monitor", "smoothed", "est"):
        notes: list[str] = []
        write_report(DATA / f"knock_cart_{name}.csv", tmp_path / name, notes=notes)
        assert notes == [], (name, notes)
    table = read_table(DATA / "knock_cart_monitor.csv")
    cut = {k: v for k, v in table.items() if k not in ("status", "mount_roll_deg")}
    cut["monitor_state"] = np.asarray(cut["monitor_state"], dtype=object).copy()
    cut["monitor_state"][40] = "BOGUS"
    pd.DataFrame(cut).to_csv(tmp_path / "cut.csv", index=False)
    notes = []
    report = write_report(tmp_path / "cut.csv", tmp_path / "cut", notes=notes)
    assert "- statuses: no status column" in report.markdown.read_text()
    frame = int(table["frame"][40])
    assert notes == [
        f"{tmp_path / 'cut.csv'}: no status column: the report counts no statuses",
        f"{tmp_path / 'cut.csv'}: monitor states vipm-track does not write ('BOGUS'): row 42 "
        f"frame {frame}",
        f"{tmp_path / 'cut.csv'}: no column mount_roll_deg: the calibration has no roll row",
    ]
    table = read_table(DATA / "knock_cart_smoothed.csv")
    ok = np.flatnonzero(np.asarray(table["status"], dtype=object) == "ok")
    blank = dict(table)
    for column, row in (("pitch_deg", ok[5]), ("tz_m", ok[9])):
        blank[column] = np.asarray(blank[column], float).copy()
        blank[column][row] = np.nan
    pd.DataFrame(blank).to_csv(tmp_path / "blank.csv", index=False)
    notes = []
    write_report(tmp_path / "blank.csv", tmp_path / "blank", notes=notes)
    rows = ", ".join(f"row {r + 2} frame {int(table['frame'][r])}" for r in (ok[5], ok[9]))
    assert notes == [f"{tmp_path / 'blank.csv'}: rows say ok but lack numbers: {rows}"]


def lagging_mount_table(true_mount: np.ndarray, lag_s: float, seed: int = 0) -> dict:
    """A track-like table at 10 Hz over 200 s: the frames' pitch is ``true_mount`` (one value
    per row) with 0.1° of noise; the filter's mount follows it ``lag_s`` late (an EKF's slow
    mount state), σ 0.05°."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 200.0, 0.1)
    mount = np.interp(t - lag_s, t, true_mount)
    return {"frame": np.arange(t.size), "t": t,
            "pitch_deg": true_mount + rng.normal(0.0, 0.1, t.size),
            "mount_pitch_deg": mount, "mount_pitch_std_deg": np.full(t.size, 0.05)}


def test_a_mount_catching_up_with_a_knock_is_no_drift() -> None:
    """A 1° knock at 80 s that the filter's mount takes 30 s to follow: the drift since the
    knock was fitted to the mount's catch-up (+0.45 ± 0.08°/min on a rendered cart, 5.7σ from
    none); the frames' own pose has no drift after the knock."""
    t = np.arange(0.0, 200.0, 0.1)
    table = lagging_mount_table(45.0 + (t >= 80.0), 0.0)
    table["mount_pitch_deg"] = 45.0 + np.clip((t - 80.0) / 30.0, 0.0, 1.0)
    pitch = summarize_drift(table, load_nominal(NOMINAL)).axes["pitch"]
    assert abs(pitch.changed_at_s - 80.0) <= 0.5
    assert abs(pitch.rate_per_min) <= 2.0 * pitch.rate_std_per_min < 0.1


def test_a_creeping_mount_is_reported_where_it_is_now() -> None:
    """A 0.6°/min creep that the filter's mount follows 30 s late: the report's current
    pitch was the lagging mount (0.3° short, outside its ± 0.1° interval); it is now the end
    of the drift line through the frames, and the true change time is the creep's middle."""
    t = np.arange(0.0, 200.0, 0.1)
    true = 45.0 + 0.6 * t / 60.0
    truth = {"frame": np.arange(t.size), "t": t, "mount_pitch_deg": true}
    for seed in range(3):
        pitch = summarize_drift(lagging_mount_table(true, 30.0, seed), load_nominal(NOMINAL),
                                truth).axes["pitch"]
        assert pitch.interval_from == "drift fit" and pitch.covers_truth
        assert abs(pitch.rate_per_min - 0.6) <= 3.0 * pitch.rate_std_per_min
        assert abs(pitch.true_changed_at_s - 100.0) <= 0.2
    steady = summarize_drift(lagging_mount_table(np.full(t.size, 45.0), 30.0),
                             load_nominal(NOMINAL)).axes["pitch"]
    assert steady.interval_from == "filter"


def test_a_camera_off_the_nominal_from_the_start_is_not_no_change(tmp_path: Path) -> None:
    """The mount 1° from the nominal all drive: the report said "no change" beside +1.0°."""
    t = np.arange(0.0, 200.0, 0.1)
    table = lagging_mount_table(np.full(t.size, 46.0), 0.0)
    rows = [{c: table[c][i] for c in table} for i in range(t.size)]
    write_table(tmp_path / "track.csv", rows, [c for c in table if c not in ("frame", "t")])
    assert main(["report", str(tmp_path / "track.csv"), "--nominal", str(NOMINAL), "--out",
                 str(tmp_path / "r")]) == 0
    cells = calibration_row((tmp_path / "r" / "report.md").read_text(), "pitch")
    assert cells[3].startswith("+1.0") and cells[6] == "not found"


@pytest.mark.parametrize("changes", [((100.0, 0.19),), ((50.0, 1.0), (120.0, -0.5))],
                         ids=["knock within the tolerance", "two knocks"])
def test_knocks_are_no_drift_line(changes) -> None:
    """A line through a knock is no creep: a 0.19° knock (within the 0.2° tolerance, so no
    change found) and two knocks read as drifts whose line's end replaced the right mount
    (45.23 for 45.19, P(beyond) 95 %; 45.37 for 45.50), outside its interval."""
    t = np.arange(0.0, 200.0, 0.1)
    true = 45.0 + sum(step * (t >= at) for at, step in changes)
    table = lagging_mount_table(true, 0.0)
    truth = {"frame": np.arange(t.size), "t": t, "mount_pitch_deg": true}
    pitch = summarize_drift(table, load_nominal(NOMINAL), truth).axes["pitch"]
    assert pitch.interval_from == "filter" and pitch.covers_truth


def test_a_track_table_whose_mount_missed_an_early_knock_reports_where_the_frames_sit(
        tmp_path: Path) -> None:
    """A rendered robot (0.3 m, 30°) knocked +1° in pitch at 4.8 s, before the EKF's
    mount-change test was armed: its mount crept to 30.56 ± 0.05° by the end and the report
    said "pitch 30.561 [30.467, 30.656], change +0.561", 9σ from the camera's 31°, without a
    word. `track` now follows the knock (its step watch, ``filters.step_watch``); where a
    table's mount did not (the watch off here), the frames' own pose since their step is
    where the camera sits, and the report says why it is not the filter's mount."""
    from vipm_track.filters.ekf_state import EkfConfig
    from vipm_track.filters.model import NoiseParams
    from vipm_track.filters.mount_steps import StepTestConfig
    from vipm_track.filters.track import track, write_track
    from vipm_track.filters.wheel_speed import read_speed_csv
    from vipm_track.measurement import read_measurements

    truth = read_table(DATA / "robot_early_knock_gt.csv")
    followed = tmp_path / "track.csv"
    assert main(["track", "--estimates", str(DATA / "robot_early_knock_est.csv"), "--vehicle",
                 "cart", "--speed-csv", str(DATA / "robot_early_knock_speed.csv"), "--out",
                 str(followed), "--quiet"]) == 0
    pitch = summarize_drift(read_table(followed), truth=truth).axes["pitch"]
    assert pitch.interval_from == "filter" and pitch.covers_truth, (pitch.lo, pitch.hi)
    assert abs(pitch.current - 31.0) < 0.1

    missed = tmp_path / "missed.csv"
    write_track(track(read_measurements(DATA / "robot_early_knock_est.csv"),
                      read_speed_csv(DATA / "robot_early_knock_speed.csv"),
                      EkfConfig(height_m=0.3, noise=NoiseParams.for_preset("cart"),
                                mount_steps=StepTestConfig(enabled=False))), missed)
    s = summarize_drift(read_table(missed), truth=truth)
    pitch = s.axes["pitch"]
    assert pitch.covers_truth, (pitch.current, pitch.lo, pitch.hi)
    assert pitch.interval_from == "frames since their step"
    assert abs(pitch.changed_at_s - 4.8) < 0.3
    assert s.axes["roll"].interval_from == "filter"  # the axis that did not step keeps it
    out = tmp_path / "report"
    assert main(["report", str(missed), "--out", str(out)]) == 0
    assert "did not follow" in (out / "report.md").read_text()
