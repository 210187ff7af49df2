"""Rows out of order: only the rows that break the longest increasing run are left out."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vipm_track.cli import main
from vipm_track.increasing import longest_increasing
from vipm_track.measurement import sequence_rows


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, 6), max_size=9))
def test_longest_increasing_is_the_earliest_longest_run(values):
    """Against brute force: the longest strictly increasing subsequence, and of several the
    one of the earliest rows."""
    v = np.array(values, dtype=float)
    expected: list[int] = []
    for size in range(len(v), -1, -1):
        found = next((list(c) for c in itertools.combinations(range(len(v)), size)
                      if all(v[a] < v[b] for a, b in itertools.pairwise(c))), None)
        if found is not None:
            expected = found
            break
    assert longest_increasing(v).tolist() == expected


@pytest.mark.parametrize("where", [0, 10, 30])
def test_one_corrupt_time_or_frame_drops_only_its_row(where):
    """A time of 100 s in row 10 of a 4-s table dropped the 30 rows after it (each 'not
    after' the corrupt one); now it is the only row left out, and named."""
    frames = np.arange(40.0)
    times = 0.1 * frames
    times[where] = 100.0
    keep, issues = sequence_rows(frames, times)
    assert keep == [i for i in range(40) if i != where]
    assert [row for row, *_ in issues.backwards] == [where + 2]
    frames[where] = 100000.0
    keep, issues = sequence_rows(frames, 0.1 * np.arange(40.0))
    assert keep == [i for i in range(40) if i != where]
    assert [row for row, *_ in issues.out_of_order] == [where + 2]


def test_track_and_a_speed_csv_keep_the_rows_around_a_corrupt_one(tmp_path, capsys):
    import csv

    from vipm_track.filters.wheel_speed import read_speed_csv

    est = tmp_path / "est.csv"
    rows = [["frame", "t", "pitch_deg", "roll_deg", "height_m", "tx_m", "tz_m", "yaw_deg",
             "status", "prev_pitch_deg", "prev_roll_deg", "pitch_std_deg", "roll_std_deg",
             "prev_pitch_std_deg", "prev_roll_std_deg", "tx_std_m", "tz_std_m", "yaw_std_deg"]]
    rows.append([0, 0.0, "", "", 0.7, "", "", "", "first frame"] + [""] * 9)
    for k in range(1, 40):
        rows.append([k, 0.1 * k, 45.0, 0.0, 0.7, 0.0, 0.12, 0.0, "ok", 45.0, 0.0, 0.1, 0.1,
                     0.1, 0.1, 0.002, 0.002, 0.05])
    rows[11][1] = 100.0  # frame 10's time
    with est.open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    out = tmp_path / "track.csv"
    assert main(["track", "--estimates", str(est), "--height", "0.7", "--out", str(out),
                 "--quiet"]) == 0
    written = list(csv.DictReader(out.open()))
    assert [int(r["frame"]) for r in written] == [k for k in range(40) if k != 10]
    assert "row 12" in capsys.readouterr().err
    speed = tmp_path / "speed.csv"
    speed.write_text("t,speed_mps\n" + "".join(
        f"{1000.0 if k == 5 else 0.02 * k},1.2\n" for k in range(50)))
    series = read_speed_csv(speed)
    assert series.t.size == 49 and series.summary.non_monotonic == 1
    assert any("speed.csv:7: t 1000.0 out of order (between kept 0.08 and 0.12)"
               in line for line in series.summary.examples), series.summary.examples


def test_a_frame_repeated_after_its_corrupt_first_row_is_kept():
    """Frames 0, 5, 1, ..., 7: the early 5 is the corrupt row; the later, real frame 5 was
    thrown away as its repeat (frame 5 lost entirely). Now the run decides first, a row is a
    repeat only of an earlier kept one, and a row out of order is named by its kept
    neighbours."""
    keep, issues = sequence_rows(np.array([0, 5, 1, 2, 3, 4, 5, 6, 7], dtype=float))
    assert keep == [0, 2, 3, 4, 5, 6, 7, 8]
    assert not issues.duplicated
    assert issues.lines("x.csv") == ["x.csv: 1 rows have a frame out of order with the rows "
                                     "around it (or none), left out: row 3 frame 5 (between "
                                     "kept 0 and 1)"]
    keep, issues = sequence_rows(np.array([0, 1, 1, 2], dtype=float))
    assert keep == [0, 1, 3] and issues.duplicated == ((4, 1, 3),)
    _, issues = sequence_rows(np.array([100000, 1, 2], dtype=float))
    assert "row 2 frame 100000 (before kept 1)" in issues.lines("x.csv")[0]


@pytest.mark.parametrize("command", ["track", "report"])
def test_a_table_whose_times_never_increase_is_bad_input(tmp_path, capsys, command):
    """Every time 5.0: 79 of 80 rows were left out and `track` said "no frame has a usable
    pair estimate ... give --pitch" (exit 1); it is no sequence of frames (exit 2)."""
    from pathlib import Path

    lines = (Path(__file__).parent / "data" / "knock_cart_est.csv").read_text().splitlines()
    header = lines[0].split(",")
    col = header.index("t")
    bad = [lines[0]] + [",".join(c if i != col else "5.0" for i, c in enumerate(line.split(",")))
                        for line in lines[1:81]]
    est = tmp_path / "same.csv"
    est.write_text("\n".join(bad) + "\n")
    argv = (["track", "--estimates", str(est), "--height", "0.7", "--out",
             str(tmp_path / "o.csv")] if command == "track"
            else ["report", str(est), "--out", str(tmp_path / "r")])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "79 of 80 rows repeat a frame or have a frame or time out of order" in err, err
    assert "not a sequence of frames" in err and "--pitch" not in err
