"""``vipm-track demo`` end to end: a knocked cart camera rendered, estimated, filtered,
smoothed and monitored; what it prints and writes, held against the rendered truth.

One drive for the whole module, run once through the CLI: 180 frames (18 s) of the demo's
``knock`` cart, the mount knocked +1° in pitch at 40 % of the drive — shorter than the
default 25 s to keep the suite fast, long enough that the monitor has settled and the
smoother's mount-change test has measured its yardstick before the knock.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from vipm_track.cli import main
from vipm_track.demo import FLAGS
from vipm_track.evaluate import error_stats, frame_errors
from vipm_track.filters.monitor_table import MONITOR_TABLE
from vipm_track.filters.track import TRACK_TABLE
from vipm_track.sinks.rerun_read import recording_entities
from vipm_track.table import BASE_COLUMNS, CONCISE, ESTIMATE_TABLE, choose_columns, read_table

FRAMES = 180
NUM = r"(-?\d+\.\d+)"


@dataclass(frozen=True)
class Run:
    out: Path
    text: str
    summary: dict
    truth: dict

    @property
    def knock_s(self) -> float:
        """When the true mount first changed (from gt.csv, not from the demo)."""
        pitch = np.asarray(self.truth["mount_pitch_deg"], float)
        return float(self.truth["t"][np.flatnonzero(pitch != pitch[0])[0]])

    def line(self, start: str) -> str:
        found = [ln for ln in self.text.splitlines() if ln.strip().startswith(start)]
        assert len(found) == 1, f"one line starting {start!r} expected in:\n{self.text}"
        return found[0]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    out = tmp_path_factory.mktemp("demo") / "out"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        rc = main(["demo", "--out", str(out), "--frames", str(FRAMES), "--quiet"])
    assert rc == 0
    return Run(out, stdout.getvalue(), json.loads((out / "summary.json").read_text()),
               read_table(out / "sequence" / "gt.csv"))


def test_the_knock_is_flagged_after_it_and_nothing_before(run: Run) -> None:
    knock = run.knock_s
    assert 0.38 * (FRAMES / 10) < knock < 0.42 * (FRAMES / 10)
    monitor = read_table(run.out / "monitor.csv")
    t, state = np.asarray(monitor["t"], float), np.asarray(monitor["monitor_state"])
    assert len(t) == FRAMES
    before, after = state[t < knock], state[t >= knock]
    assert not np.isin(before, FLAGS).any(), "flagged before the knock"
    assert "CALIBRATED" in set(before), "never calibrated before the knock"
    flagged = t[t >= knock][np.isin(after, FLAGS)]
    assert len(flagged) and flagged[0] - knock < 3.0, "the knock was not flagged within 3 s"
    recalibrate = t[(t >= knock) & (state == "RECALIBRATE")]
    assert len(recalibrate)
    # the printed verdict: the knock's time, the delays and 'no flag before it'
    verdict = run.line("knock at t =")
    m = re.match(rf"\s*knock at t = {NUM} s: (\w+) {NUM} s after it, RECALIBRATE {NUM} s "
                 r"after it; no flag before it", verdict)
    assert m, verdict
    assert float(m[1]) == pytest.approx(knock, abs=0.005)
    assert m[2] == state[t >= knock][np.isin(after, FLAGS)][0]
    assert float(m[3]) == pytest.approx(flagged[0] - knock, abs=0.005)
    assert float(m[4]) == pytest.approx(recalibrate[0] - knock, abs=0.005)
    # the events say the same
    events = [json.loads(x) for x in (run.out / "events.jsonl").read_text().splitlines()]
    assert [e["state"] for e in events if e["t"] < knock][-1] == "CALIBRATED"
    first = next(e for e in events if e["state"] == "RECALIBRATE")
    assert first["t"] == pytest.approx(recalibrate[0])
    assert f"t = {first['t']:6.2f} s  RECALIBRATE" in run.text


def test_the_mount_before_and_after_lies_within_its_interval(run: Run) -> None:
    knock = run.knock_s
    steps = run.summary["mount_steps_s"]
    assert len(steps) == 1 and abs(steps[0] - knock) < 0.5
    true_pitch = np.asarray(run.truth["mount_pitch_deg"], float)
    for name, truth in (("before knock", true_pitch[0]), ("after knock", true_pitch[-1])):
        m = re.search(rf"{name}\s+{NUM}–\s*{NUM} s: pitch {NUM}° \[{NUM}, {NUM}\], truth "
                      rf"{NUM}° \((\w+)\); roll {NUM}° \[{NUM}, {NUM}\], truth {NUM}° \((\w+)\)",
                      run.text)
        assert m, f"no '{name}' line in:\n{run.text}"
        pitch, lo, hi, printed_truth = (float(m[i]) for i in (3, 4, 5, 6))
        assert printed_truth == pytest.approx(truth, abs=5e-4)
        assert lo <= truth <= hi and m[7] == "in"
        assert hi - lo < 0.5  # an interval that says something
        assert abs(pitch - truth) < 0.1
        roll_lo, roll_hi = float(m[9]), float(m[10])
        assert roll_lo <= float(run.truth["mount_roll_deg"][0]) <= roll_hi and m[12] == "in"
    spans = run.summary["mount_spans"]
    assert spans[0]["end_s"] < knock <= spans[1]["start_s"]
    assert all(s[a]["covers"] for s in spans for a in ("pitch_deg", "roll_deg", "height_m"))


def test_the_height_through_the_wheel_speed(run: Run) -> None:
    line = run.line("Camera height through the wheel speed")
    m = re.search(rf": {NUM} m \[{NUM}, {NUM}\], truth {NUM} m \(in;", line)
    assert m, line
    value, lo, hi, truth = (float(m[i]) for i in range(1, 5))
    assert truth == pytest.approx(float(np.median(run.truth["mount_height_m"])), abs=1e-4)
    assert lo <= truth <= hi and hi - lo < 0.02
    assert abs(value - truth) < 0.005


def test_the_printed_accuracy_is_the_tables_against_the_truth(run: Run) -> None:
    est = read_table(run.out / "estimates.csv")
    errors = frame_errors(est, run.truth)
    pitch, roll = error_stats(errors["pitch_deg"]), error_stats(errors["roll_deg"])
    line = run.line("estimator")
    assert f"({pitch.n}/{FRAMES - 1} pairs ok)" in line and pitch.n >= 0.95 * (FRAMES - 1)
    assert f"pitch {pitch.median:.4f} / {pitch.p95:.4f}°" in line
    assert f"roll {roll.median:.4f} / {roll.p95:.4f}°" in line
    assert pitch.p95 < 0.1 and roll.p95 < 0.1
    for stage in ("EKF", "smoother"):
        assert run.summary["accuracy"][stage]["pitch_deg"]["p95"] < 0.1
        assert run.summary["accuracy"][stage]["height_m"]["p95"] < 0.005


def test_it_writes_its_files_and_says_where(run: Run) -> None:
    out = run.out
    concise = {"estimates.csv": ESTIMATE_TABLE, "track.csv": TRACK_TABLE,
               "smoothed.csv": TRACK_TABLE, "monitor.csv": MONITOR_TABLE}
    for name in ("estimates.csv", "track.csv", "smoothed.csv", "monitor.csv"):
        table = read_table(out / name)
        assert len(table["frame"]) == FRAMES, name
        # each with the columns its command writes by default (smoothed and monitor had all)
        header = (out / name).read_text().splitlines()[0].split(",")
        written = {c for c in header if c not in BASE_COLUMNS}
        assert set(choose_columns(concise[name], CONCISE)) <= written, name
        if name in ("smoothed.csv", "monitor.csv"):
            assert written == set(choose_columns(concise[name], CONCISE)), name
        assert str(out / name) in run.text or name in run.text
    assert (out / "demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "events.jsonl").stat().st_size > 0
    assert f"rerun {out / 'demo.rrd'}" in run.text
    rows = recording_entities(out / "demo.rrd")
    assert rows["/series/pitch/truth"] == FRAMES
    assert rows["/series/pitch/per_frame"] >= 0.95 * (FRAMES - 1)
    assert rows["/series/pitch/smoothed"] == rows["/series/pitch/mount"] == FRAMES
    assert rows["/series/pitch/mount_truth"] == FRAMES
    ekf = np.isfinite(np.asarray(read_table(out / "track.csv")["pitch_deg"], float))
    assert rows["/series/pitch/filtered"] == int(ekf.sum()) >= FRAMES - 20
    assert rows["/camera/image"] == rows["/camera/patches"] >= 0.95 * (FRAMES - 1)
    assert rows["/monitor/state"] >= 3  # UNCALIBRATED, CALIBRATED, ... RECALIBRATE


def test_the_filters_path_covers_the_frames_before_it_started(run: Run) -> None:
    """The EKF's first frames (waiting for pairs) have no motion of its own: its dashboard
    path left out their travel and ended 12 % short of the truth's. The pairs' own motion
    fills them in."""
    from vipm_track.sinks.trajectory import planar_path

    track = read_table(run.out / "track.csv")
    assert not np.isfinite(np.asarray(track["tz_m"], float)[:5]).any()  # waiting rows
    ekf = planar_path(track)
    truth = planar_path(run.truth)
    end = np.hypot(*(ekf[-1] - ekf[0])), np.hypot(*(truth[-1] - truth[0]))
    assert abs(end[0] / end[1] - 1.0) < 0.01, end
