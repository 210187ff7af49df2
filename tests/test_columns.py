"""Concise default columns and ``--columns all|concise|A,B,...`` (``table.choose_columns``):
the sets, round trips, ``all`` writing the full table byte for byte, the filters giving the
same rows on a concise estimates table as on the full one (rendered cart frames, and a knocked
cart drive with its wheel speed), bad ``--columns`` named with exit 2, and the stored fixtures
still read."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vipm_track.cli import main
from vipm_track.errors import InputError
from vipm_track.filters.monitor_table import MONITOR_TABLE
from vipm_track.filters.track import TRACK_TABLE
from vipm_track.fleet.drive_run import FleetSettings
from vipm_track.live_monitor import LIVE_TABLE
from vipm_track.measurement import read_measurements
from vipm_track.sim import simulate_sequence
from vipm_track.table import (
    BASE_COLUMNS,
    CORRELATION_COLUMNS,
    ESTIMATE_TABLE,
    TableWriter,
    choose_columns,
    choose_columns_each,
    read_table,
    write_table,
)

DATA = Path(__file__).parent / "data"
NOMINAL = Path(__file__).resolve().parents[1] / "data" / "nominal_cart.yaml"
TABLES = (ESTIMATE_TABLE, TRACK_TABLE, MONITOR_TABLE, LIVE_TABLE)
#: what the filters and the monitor read from an estimates table (measurement.py)
READ_BACK = ("prev_pitch_deg", "prev_roll_deg", "pitch_std_deg", "roll_std_deg",
             "prev_pitch_std_deg", "prev_roll_std_deg", "tx_std_m", "tz_std_m", "yaw_std_deg",
             "inliers", *CORRELATION_COLUMNS)


def test_concise_sets_are_shorter_subsets_that_keep_what_is_read_back():
    for table in TABLES:
        assert set(table.concise) < set(table.every), table.name
        assert choose_columns(table, "all") == table.every
        assert choose_columns(table) == table.concise
    assert set(READ_BACK) <= set(ESTIMATE_TABLE.concise)
    assert {"patches", "residual_px"}.isdisjoint(ESTIMATE_TABLE.concise)
    # the drift report and the dashboards read the mount with its std from the track table
    assert {"mount_pitch_deg", "mount_pitch_std_deg", "mount_height_std_m",
            "height_std_m", "speed_mps", "wheel_speed_mps"} <= set(TRACK_TABLE.concise)
    assert {"monitor_state", "reason", "new_pitch_lo_deg", "mount_roll_deg"} <= set(
        MONITOR_TABLE.concise)
    # an interrupted smooth keeps the pairs it had not smoothed in meas_*: nothing lost
    assert {c for c in TRACK_TABLE.every if c.startswith("meas_")} <= set(TRACK_TABLE.concise)
    assert len(TRACK_TABLE.concise) == 24 and len(MONITOR_TABLE.concise) == 14


def test_explicit_names_keep_the_table_order_and_the_base_columns():
    chosen = choose_columns(TRACK_TABLE, " nis ,mount_pitch_deg,pitch_deg,nis")
    assert chosen == ("mount_pitch_deg", "nis")
    assert choose_columns(TRACK_TABLE, ["yaw_rate_dps", "x_m"]) == ("yaw_rate_dps", "x_m")
    # a fleet's three tables: each takes the named columns it has
    est, smoothed, monitor = choose_columns_each(
        (ESTIMATE_TABLE, TRACK_TABLE, MONITOR_TABLE), "residual_px,nis,stat_pitch")
    assert (est, smoothed, monitor) == (("residual_px",), ("nis",), ("stat_pitch",))
    tables = FleetSettings(columns="all").tables()
    assert tables["monitor"] == (MONITOR_TABLE.every, MONITOR_TABLE.every)
    assert FleetSettings().tables()["estimates"][1] == ESTIMATE_TABLE.concise


_ROW = {"frame": 3, "t": 0.3, "pitch_deg": 45.1, "roll_deg": -0.2, "height_m": 0.7,
        "tx_m": 0.01, "tz_m": 0.2, "yaw_deg": 0.5, "status": "ok"}


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_round_trip_of_a_chosen_set(tmp_path: Path, suffix: str):
    pytest.importorskip("pyarrow")
    rows = []
    for k in range(4):
        row = {**_ROW, "frame": k, "t": 0.1 * k}
        row.update({c: 0.05 + ((7 * i + k) % 17) / 20  # correlations within [-1, 1]
                    for i, c in enumerate(ESTIMATE_TABLE.every)})
        rows.append(row)
    full, short = tmp_path / f"full{suffix}", tmp_path / f"short{suffix}"
    write_table(full, rows, ESTIMATE_TABLE.every)
    write_table(short, rows, ESTIMATE_TABLE.every, choose_columns(ESTIMATE_TABLE))
    a, b = read_table(full), read_table(short)
    assert list(b) == [*BASE_COLUMNS, *ESTIMATE_TABLE.concise]
    assert list(a) == [*BASE_COLUMNS, *ESTIMATE_TABLE.every]
    for c in b:
        np.testing.assert_array_equal(b[c], a[c], err_msg=c)
    # the measurements read back are the same, full covariance included
    for m, n in zip(read_measurements(full), read_measurements(short), strict=True):
        np.testing.assert_array_equal(m.covariance, n.covariance)
        assert (m.frame, m.inliers) == (n.frame, n.inliers)


def test_all_is_the_full_table_byte_for_byte(tmp_path: Path):
    rows = [{**_ROW, "mount_pitch_deg": 45.0, "nis": 3.2, "gated": "pose", "x_m": 1.0}]
    for name, columns in (("default", None), ("all", choose_columns(TRACK_TABLE, "all"))):
        with TableWriter(tmp_path / f"{name}.csv", TRACK_TABLE.every, columns=columns) as w:
            for row in rows:
                w.write(row)
    assert (tmp_path / "all.csv").read_bytes() == (tmp_path / "default.csv").read_bytes()
    with TableWriter(tmp_path / "c.csv", TRACK_TABLE.every, columns=TRACK_TABLE.concise) as w:
        w.write(rows[0])
        with pytest.raises(KeyError, match="not_a_column"):  # a programming error still shows
            w.write({**_ROW, "not_a_column": 1.0})
    assert read_table(tmp_path / "c.csv")["mount_pitch_deg"][0] == 45.0
    assert "nis" not in read_table(tmp_path / "c.csv")


def _filtered(est: Path, out: Path, speed: Path | None) -> dict[str, bytes]:
    """track, smooth and monitor of ``est`` with every column: the tables' bytes."""
    wheel = ["--speed-csv", str(speed)] if speed is not None else []
    out.mkdir()
    runs = {
        "track": ["track", "--vehicle", "cart", *wheel],
        "smooth": ["smooth", "--vehicle", "cart", *wheel],
        "monitor": ["monitor", "--nominal", str(NOMINAL), *wheel],
    }
    for name, argv in runs.items():
        rc = main([*argv, "--estimates", str(est), "--height", "0.7", "--out",
                   str(out / f"{name}.csv"), "--columns", "all", "--quiet"])
        # a drive too short for the EKF to start: track exits 1, its rows all waiting
        waiting = name == "track" and set(read_table(out / "track.csv")["status"]) == {
            "waiting for first pairs"}
        assert rc == (1 if waiting else 0)
    return {name: (out / f"{name}.csv").read_bytes() for name in runs}


def test_filters_give_the_same_rows_on_a_concise_estimate_table(tmp_path: Path):
    """Rendered cart frames estimated twice (default, ``--columns all``); then a knocked
    cart drive's stored full table rewritten concise, with its wheel speed."""
    simulate_sequence("cart", 8, tmp_path / "cart", seed=5, profile="shaking")
    tables = {}
    for choice in ("concise", "all"):
        out = tmp_path / f"est_{choice}.csv"
        assert main(["estimate", "--images", str(tmp_path / "cart" / "images"), "--height",
                     "0.7", "--out", str(out), "--quiet", "--columns", choice]) == 0
        tables[choice] = read_table(out)
    assert list(tables["concise"]) == [*BASE_COLUMNS, *ESTIMATE_TABLE.concise]
    assert list(tables["all"]) == [*BASE_COLUMNS, *ESTIMATE_TABLE.every]
    assert np.sum(tables["all"]["status"] == "ok") >= 6
    for c in tables["concise"]:
        np.testing.assert_array_equal(tables["concise"][c], tables["all"][c], err_msg=c)
    assert (_filtered(tmp_path / "est_concise.csv", tmp_path / "f_concise", None)
            == _filtered(tmp_path / "est_all.csv", tmp_path / "f_all", None))

    full = read_table(DATA / "knock_cart_est.csv")
    assert set(CORRELATION_COLUMNS) <= set(full)
    rows = [{c: _cell(full[c][i]) for c in full} for i in range(len(full["frame"]))]
    write_table(tmp_path / "knock.csv", rows, ESTIMATE_TABLE.every,
                choose_columns(ESTIMATE_TABLE))
    speed = DATA / "knock_cart_speed.csv"
    concise = _filtered(tmp_path / "knock.csv", tmp_path / "k_concise", speed)
    assert concise == _filtered(DATA / "knock_cart_est.csv", tmp_path / "k_all", speed)
    monitor = read_table(tmp_path / "k_concise" / "monitor.csv")
    assert "RECALIBRATE" in set(monitor["monitor_state"])  # the knock is found


def _cell(v):
    if isinstance(v, float | np.floating) and math.isnan(v):
        return None
    return v.item() if isinstance(v, np.generic) else v


def test_default_and_named_columns_on_the_command_line(tmp_path: Path):
    est = DATA / "knock_cart_est.csv"
    assert main(["monitor", "--estimates", str(est), "--height", "0.7", "--nominal",
                 str(NOMINAL), "--out", str(tmp_path / "m.csv"), "--quiet"]) == 0
    assert list(read_table(tmp_path / "m.csv")) == [*BASE_COLUMNS, *MONITOR_TABLE.concise]
    assert main(["track", "--estimates", str(est), "--height", "0.7", "--out",
                 str(tmp_path / "t.csv"), "--quiet", "--columns", "nis,mount_pitch_deg"]) == 0
    assert list(read_table(tmp_path / "t.csv")) == [*BASE_COLUMNS, "mount_pitch_deg", "nis"]


@pytest.mark.parametrize("names", ["pitch_deg,roll_deg", "status", "pitch_deg,pitch_deg"])
def test_naming_only_base_columns_writes_the_base_columns(tmp_path: Path, names: str):
    """Base columns only (always written) is a valid choice, not 'no column named'."""
    est = DATA / "knock_cart_est.csv"
    for command, extra in (("track", []), ("monitor", ["--nominal", str(NOMINAL)])):
        out = tmp_path / f"{command}.csv"
        assert main([command, "--estimates", str(est), "--height", "0.7", "--out", str(out),
                     "--quiet", "--max-frames", "20", "--columns", names, *extra]) == 0
        assert list(read_table(out)) == list(BASE_COLUMNS)
    assert choose_columns(ESTIMATE_TABLE, ()) == ()


def test_unknown_columns_exit_2_naming_them(tmp_path: Path, capsys: pytest.CaptureFixture):
    code = main(["track", "--estimates", str(DATA / "knock_cart_est.csv"), "--height", "0.7",
                 "--out", str(tmp_path / "t.csv"), "--quiet", "--columns", "nis,pich_deg"])
    err = capsys.readouterr().err
    assert code == 2
    assert "--columns: unknown column(s) pich_deg for the track table" in err
    assert "mount_pitch_deg" in err and "'all'" in err and "Traceback" not in err
    with pytest.raises(InputError, match="unknown column"):
        FleetSettings(columns="pitch_deg,bogus")


_VALID = {*BASE_COLUMNS, *(c for t in TABLES for c in t.every)}


@settings(max_examples=150, deadline=None)
@given(st.lists(st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=12),
                max_size=6),
       st.sampled_from(TABLES))
def test_bad_column_lists_are_input_errors(names: list[str], table):
    """Any list of names: the chosen columns, or an InputError naming what was unknown."""
    text = ",".join(names)
    try:
        chosen = choose_columns(table, text)
    except InputError as exc:
        message = str(exc)
        assert message.startswith("--columns: ")
        wanted = [n.strip() for n in text.split(",") if n.strip()]
        bad = [n for n in wanted if n not in (*BASE_COLUMNS, *table.every)]
        assert bad or not wanted
        assert ("unknown column" in message) == bool(wanted)
        return
    assert text.strip().lower() in ("all", "concise") or set(chosen) <= _VALID


def test_stored_fixtures_still_read():
    for path in sorted(p for p in DATA.glob("*.csv") if not p.name.endswith("_speed.csv")):
        table = read_table(path)
        assert len(table["frame"]) > 0, path
        if path.name.endswith(("_est.csv", "_estimates.csv")):
            ms = read_measurements(path)
            # every row the table calls ok reads as a usable measurement (a drive beyond the
            # motion range has fewer than half of them)
            said_ok = int(np.count_nonzero(np.asarray(table["status"], dtype=object) == "ok"))
            assert sum(m.ok for m in ms) == said_ok > 0.3 * len(ms), path


def test_a_status_vipm_track_does_not_write_is_reported(tmp_path: Path, capsys):
    from vipm_track import statuses
    from vipm_track.cli import main

    # every status in the stored tables is one vipm-track writes
    for path in DATA.glob("*_est*.csv"):
        for status in read_table(path)["status"]:
            assert statuses.is_known(str(status)), (path, status)
    assert statuses.is_known("unreadable frame: 000003.png")
    assert statuses.is_known("estimator error: ValueError: x")
    assert not statuses.is_known("weird") and not statuses.is_known("OK")
    # a table from elsewhere: the row is read as not usable, and the run says which
    lines = (DATA / "kitti07_estimates.csv").read_text().splitlines()
    header = lines[0].split(",")
    row = lines[5].split(",")
    row[header.index("status")] = "weird"
    lines[5] = ",".join(row)
    est = tmp_path / "est.csv"
    est.write_text("\n".join(lines) + "\n")
    assert main(["track", "--estimates", str(est), "--height", "1.65",
                 "--out", str(tmp_path / "t.csv"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert (f"1 rows have a status vipm-track does not write, read as not usable: row 6 frame "
            f"{row[header.index('frame')]} 'weird'") in err


def test_json_outputs_are_strict_json(tmp_path):
    """smooth's summary wrote a bare NaN (the height's std_data), which JSON has not: a
    browser's JSON.parse and jq refused the file. Every JSON output goes through
    json_text, which writes null."""
    import json

    from vipm_track.json_text import dumps

    def refuse(name):
        raise AssertionError(f"{name} in JSON")

    assert json.loads(dumps({"a": float("nan"), "b": [1.0, float("inf")], "c": (2,)}),
                      parse_constant=refuse) == {"a": None, "b": [1.0, None], "c": [2]}
    # numbers as the tables write them (a live event's "t": 1.9000000000000001)
    assert dumps({"t": 19 * 0.1, "unix": 1.7e9 + 0.123456789}) == \
        '{"t": 1.9, "unix": 1700000000.1234567}'
    out = tmp_path / "s.csv"
    assert main(["smooth", "--estimates", str(DATA / "knock_cart_est.csv"), "--height", "0.7",
                 "--vehicle", "cart", "--out", str(out), "--quiet"]) == 0
    summary = json.loads(out.with_suffix(".summary.json").read_text(), parse_constant=refuse)
    assert summary["height"]["std_data"] is None


def test_a_parquet_cell_without_a_number_is_null(tmp_path):
    """Parquet stored "no value" as NaN, which readers cannot tell from a number; it is null
    (the CSV's empty cell), and reads back as NaN."""
    import pyarrow.parquet as pq

    from vipm_track.table import write_parquet

    path = tmp_path / "t.parquet"
    write_parquet([{"frame": 0, "t": 0.0, "pitch_deg": None},
                   {"frame": 1, "t": 0.1, "pitch_deg": 1.5}], ["frame", "t", "pitch_deg"], path)
    assert pq.read_table(path).column("pitch_deg").to_pylist() == [None, 1.5]
    assert np.isnan(read_table(path)["pitch_deg"][0])
