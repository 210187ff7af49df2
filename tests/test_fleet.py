"""``vipm-track fleet`` on a Dask LocalCluster of 2 workers: rendered drives (one whose camera
sits 1° steeper than its nominal, one from an MCAP, broken ones), per-drive results equal to
``smooth`` run alone, resume, partitioned Parquet read by pandas, pyarrow and dask; bad
``--scheduler`` addresses and servers that are no scheduler refused on one line."""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import socket
import threading
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import render_small_drive, write_bag
from distributed import LocalCluster
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vipm_track.cli import main
from vipm_track.errors import InputError
from vipm_track.fleet import cluster as fleet_cluster
from vipm_track.fleet.cluster import fleet_dataset, run_fleet
from vipm_track.fleet.drive_run import FleetSettings
from vipm_track.fleet.drives import find_drives, read_manifest

SETTINGS = FleetSettings(vehicle="cart")


@pytest.fixture(scope="module")
def cluster():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as c:
        yield c


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("fleet") / "drives"
    a = render_small_drive(root / "a", seed=1)
    (a / "drive.yaml").write_text("vehicle: van1\nstarted: '2024-05-01T09:00'\n")
    # the camera was knocked; 3 s of frames (the monitor's first second weighs little)
    b = render_small_drive(root / "b", frames=30, seed=2, pitch_deg=46.0)
    (b / "drive.yaml").write_text("vehicle: van1\nstarted: '2024-05-02T09:00'\n")
    lines = (b / "speed.csv").read_text().splitlines(keepends=True)  # a logger's bad row
    (b / "speed.csv").write_text("".join([*lines[:2], "0.01,nan\n", *lines[2:]]))
    bag = root / "c_bag"
    bag.mkdir()
    write_bag(render_small_drive(root.parent / "c_src", seed=3), bag / "rec", "mcap")
    shutil.copy(root.parent / "c_src" / "nominal.yaml", bag / "nominal.yaml")
    broken = render_small_drive(root / "broken", frames=3, seed=4)
    for png in (broken / "images").glob("*.png"):
        png.write_bytes(b"not a png")
    # a wheel speed on another clock: `smooth` refuses it, the fleet said "ok, wheel speed"
    clock = root / "d_clock"
    shutil.copytree(a, clock)
    speed = pd.read_csv(a / "speed.csv")
    speed["t"] += 1000.0
    speed.to_csv(clock / "speed.csv", index=False)
    (root / "no_nominal").mkdir()
    shutil.copytree(a / "images", root / "no_nominal" / "images")
    shutil.copy(a / "camera.yaml", root / "no_nominal")
    # a complete drive but for its drive.yaml: its own failed row, not the whole fleet's end
    bad_yaml = root / "bad_yaml"
    shutil.copytree(a, bad_yaml)
    (bad_yaml / "drive.yaml").write_text("vehicle: [\n")
    return root


@pytest.fixture(scope="module")
def fleet(drives, cluster, tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    rows = run_fleet(find_drives(drives), out, SETTINGS, scheduler=cluster.scheduler_address,
                     progress=False)
    return out, {r["drive"]: r for r in rows}


def test_drives_ok_and_broken_ones_are_rows(fleet, drives):
    out, rows = fleet
    assert list(rows) == ["a", "b", "bad_yaml", "broken", "c_bag", "d_clock", "no_nominal"]
    for name, frames in (("a", 12), ("b", 30), ("c_bag", 12)):
        assert rows[name]["status"] == "ok", rows[name]["status"]
        assert rows[name]["frames"] == frames and rows[name]["share_ok"] > 0.9
        assert abs(rows[name]["mount_height_m"] - 0.7) < 0.005  # the wheel speed scales it
    assert "no frame has a usable pair estimate" in rows["broken"]["status"]
    assert "no nominal.yaml" in rows["no_nominal"]["status"]
    assert "no frame has a wheel speed" in rows["d_clock"]["status"]
    assert rows["bad_yaml"]["status"] == (
        f"error: {drives / 'bad_yaml' / 'drive.yaml'}: line 2, column 1: not valid YAML "
        "(expected the node content, but found '<stream end>')")
    # a drive that failed leaves no partition folder, empty or not
    assert sorted(p.name for p in out.glob("drive=*")) == ["drive=a", "drive=b", "drive=c_bag"]
    assert abs(rows["a"]["mount_pitch_deg"] - 45.0) < 0.05
    assert abs(rows["b"]["mount_pitch_deg"] - 46.0) < 0.05
    lo, hi = rows["a"]["mount_pitch_ci95_low_deg"], rows["a"]["mount_pitch_ci95_high_deg"]
    assert lo < 45.0 < hi
    assert rows["b"]["monitor_verdict"] in ("RECALIBRATE", "INVALID", "SUSPECT")
    summary = pd.read_csv(out / "fleet_summary.csv")
    assert list(summary["drive"]) == list(rows)
    assert pd.read_parquet(out / "fleet_summary.parquet").shape == summary.shape


def test_tables_read_as_a_partitioned_dataset(fleet):
    import dask.dataframe as dd

    from vipm_track.fleet.cluster import DRIVE_PARTITIONING

    out, _ = fleet
    files = sorted(str(p) for p in out.glob("drive=*/smoothed.parquet"))
    by_pandas = pd.read_parquet(files)
    by_arrow = fleet_dataset(out, "smoothed").to_table().to_pandas()
    by_dask = dd.read_parquet(str(out / "drive=*" / "smoothed.parquet"),  # docs/fleet.md's
                              dataset={"partitioning": DRIVE_PARTITIONING}).compute()
    for table in (by_pandas, by_arrow, by_dask):
        assert sorted(set(table["drive"].astype(str))) == ["a", "b", "c_bag"]
        assert len(table) == 12 + 30 + 12
    one = by_pandas[by_pandas["drive"] == "b"]
    assert abs(one["mount_pitch_deg"].mean() - 46.0) < 0.05


def test_drive_equals_smooth_alone(fleet, drives, tmp_path):
    out, _ = fleet
    a = drives / "a"
    assert main(["smooth", "--images", str(a / "images"), "--pitch", "45", "--roll", "0",
                 "--height", "0.7", "--vehicle", "cart", "--speed-csv", str(a / "speed.csv"),
                 "--out", str(tmp_path / "s.csv"), "--parquet", "--quiet"]) == 0
    alone = pd.read_parquet(tmp_path / "s.parquet")
    pd.testing.assert_frame_equal(pd.read_parquet(out / "drive=a" / "smoothed.parquet"), alone)
    summary = json.loads((tmp_path / "s.summary.json").read_text())
    mine = json.loads((out / "drive=a" / "summary.json").read_text())
    assert mine["pitch"] == summary["pitch"] and mine["height"] == summary["height"]


def test_report_shows_the_moved_camera(fleet, drives):
    out, rows = fleet
    from vipm_track.sinks.fleet_report import write_fleet_report

    md, png = write_fleet_report(list(rows.values()), out)
    text = md.read_text()
    line_b = next(line for line in text.splitlines() if line.startswith("| b |"))
    assert "**pitch**" in line_b
    line_a = next(line for line in text.splitlines() if line.startswith("| a |"))
    assert "**" not in line_a
    assert "## Vehicle van1" in text and "## Failed drives" in text
    assert png.stat().st_size > 10_000
    # a 1.2-s drive's caveat was in its summary.json only, not in the fleet's summary/report
    assert "the drive spans 1.1 s" in rows["a"]["warnings"]
    assert "## Warnings" in text and "- **a**: the drive spans 1.1 s" in text
    # a bad wheel-speed row was skipped without a word (smooth names it)
    assert f"speed.csv: 1 rows of the wheel speed skipped ({drives}/b/speed.csv:3: not " \
        "finite" in rows["b"]["warnings"]
    assert "wheel speed skipped" not in rows["a"]["warnings"]


def test_resume_skips_what_is_done(fleet, drives, cluster, tmp_path):
    out, _ = fleet
    again = tmp_path / "out"
    shutil.copytree(out, again)
    before = (again / "drive=a" / "smoothed.parquet").stat().st_mtime_ns
    speed = drives / "b" / "speed.csv"
    original = speed.read_text()
    try:
        speed.write_text(original)  # rewritten unchanged: same hash, nothing runs
        rows = {r["drive"]: r for r in run_fleet(find_drives(drives), again, SETTINGS,
                                                 scheduler=cluster.scheduler_address,
                                                 progress=False)}
        assert rows["a"]["skipped"] and rows["b"]["skipped"] and rows["c_bag"]["skipped"]
        assert not rows["broken"]["skipped"]  # a failed drive is tried again
        assert (again / "drive=a" / "smoothed.parquet").stat().st_mtime_ns == before
        lines = original.splitlines()
        speed.write_text("\n".join(lines[:-1]) + "\n")  # b's inputs change: b runs again
        rows = {r["drive"]: r for r in run_fleet(find_drives(drives), again, SETTINGS,
                                                 scheduler=cluster.scheduler_address,
                                                 progress=False)}
        assert rows["a"]["skipped"] and not rows["b"]["skipped"]
        assert rows["b"]["status"] == "ok"
    finally:
        speed.write_text(original)


def test_cli(drives, cluster, tmp_path, capsys):
    assert main(["fleet", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")]) == 2
    assert "not found" in capsys.readouterr().err
    # an OUT inside DRIVES was taken for a failed drive 'results: no recording' next time
    assert main(["fleet", str(drives), "--out", str(drives / "results")]) == 2
    assert "inside the DRIVES folder" in capsys.readouterr().err
    assert not (drives / "results").exists()
    only_broken = tmp_path / "only_broken"
    only_broken.mkdir()
    shutil.copytree(drives / "broken", only_broken / "broken")
    out = tmp_path / "o"
    assert main(["fleet", str(only_broken), "--out", str(out), "--scheduler",
                 cluster.scheduler_address, "--quiet"]) == 1
    assert "no drive ok" in capsys.readouterr().err
    assert (out / "fleet_summary.csv").is_file() and (out / "fleet_report.md").is_file()


@pytest.mark.parametrize(("content", "why"), [
    (b"vehicle: [\n", "line 2, column 1: not valid YAML"),
    (b"- van1\n", "expected a mapping with 'vehicle' and/or 'started'"),
    (b"vehicle: van1\ncolour: red\n", "unknown key(s) ['colour']; expected 'vehicle' and/or"),
    (b"vehicle: \xff\n", "not a text file (byte 9"),
    (b"started: monday\n", "started 'monday' is no ISO 8601 date or time"),
    (b"started: 2024-02-30\n", "not valid YAML (day is out of range for month)"),
])
def test_a_bad_drive_yaml_is_that_drives_problem(tmp_path, content, why):
    """A drive.yaml that cannot be read makes its drive a failed row; the other drives and
    the rest of the bad drive's files are found as before."""
    for name in ("bad", "good"):
        (tmp_path / name / "images").mkdir(parents=True)
        (tmp_path / name / "images" / "000000.png").write_bytes(b"")
        (tmp_path / name / "camera.yaml").write_text("")
        (tmp_path / name / "nominal.yaml").write_text("")
    (tmp_path / "good" / "drive.yaml").write_text("vehicle: van1\n")
    (tmp_path / "bad" / "drive.yaml").write_bytes(content)
    bad, good = find_drives(tmp_path)
    assert bad.problem.startswith(f"{tmp_path / 'bad' / 'drive.yaml'}: {why}"), bad.problem
    assert "\n" not in bad.problem
    assert bad.images == tmp_path / "bad" / "images" and bad.vehicle == ""
    assert good.problem == "" and good.vehicle == "van1"


@pytest.fixture
def one_drive(tmp_path) -> Path:
    """A folder of one (empty) drive: enough for the fleet to get to its cluster."""
    (tmp_path / "drives" / "x").mkdir(parents=True)
    return tmp_path / "drives"


def test_relative_paths_reach_the_workers_absolute(one_drive, tmp_path, monkeypatch):
    """A scheduler's workers run in their own folders: DRIVES and --out given relative to
    this one made every drive fail there ("No such file or directory: 'drives/x/...'")."""
    from vipm_track.fleet import cluster

    seen = {}

    def fake_run(specs, out, settings, **kwargs):
        seen.update(specs=specs, out=out)
        return []

    monkeypatch.setattr(cluster, "run_fleet", fake_run)
    (one_drive / "x" / "camera.yaml").write_text("")
    monkeypatch.chdir(tmp_path)
    assert main(["fleet", "drives", "--out", "o", "--quiet"]) == 1
    assert seen["out"] == tmp_path / "o"
    assert seen["specs"][0].camera == tmp_path / "drives" / "x" / "camera.yaml"


@pytest.mark.parametrize(("address", "why"), [
    ("127.0.0.1", "missing port number"),
    ("nonsense", "missing port number"),
    ("tcp://:8786", "no host"),
    ("tcp://head:99999", "port 99999 is not in 1-65535"),
    ("udp://head:8786", "unknown address scheme 'udp'"),
])
def test_a_malformed_scheduler_address_is_refused_first(one_drive, tmp_path, capsys,
                                                        address, why):
    out = tmp_path / "o"
    assert main(["fleet", str(one_drive), "--out", str(out), "--scheduler", address,
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"vipm-track fleet: error: --scheduler {address}: not a scheduler "
                          f"address ({why}")
    assert err.count("\n") == 1 and not out.exists()  # refused before any work


@pytest.fixture
def short_connect(monkeypatch):
    """Connecting gives up after 1 s instead of 10."""
    monkeypatch.setattr(fleet_cluster, "CONNECT_TIMEOUT_S", 1.0)


@pytest.fixture
def closed_port():
    """A local port bound but not listening: connecting to it is refused."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        yield sock.getsockname()[1]


@pytest.fixture
def silent_port():
    """A local port that accepts connections (the kernel's backlog) and never answers, as a
    web server waits for the end of a request line Dask never sends."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen(8)
        yield sock.getsockname()[1]


@pytest.fixture
def http_port():
    """A local port that answers every connection as a web server does, with an HTTP error."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)

    def answer() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:  # closed: the test is over
                return
            with conn, contextlib.suppress(OSError):  # the client may have closed first
                conn.sendall(b"HTTP/1.0 400 Bad request\r\nContent-Length: 0\r\n\r\n")
                while conn.recv(4096):
                    pass

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    yield server.getsockname()[1]
    server.shutdown(socket.SHUT_RDWR)
    server.close()
    thread.join(5)


@pytest.mark.parametrize(("port", "why"), [
    ("closed_port", "Connection refused"),
    ("silent_port", "no Dask scheduler answered within 1 s"),
    ("http_port", "what answers there is not a Dask scheduler"),
])
def test_no_scheduler_there_is_one_line(one_drive, tmp_path, capsys, short_connect,
                                        request, port, why):
    """Nothing listening, a server that never answers and one whose reply Dask misreads:
    exit 2 within the connect timeout, the address and the reason on one line."""
    address = f"tcp://127.0.0.1:{request.getfixturevalue(port)}"
    assert main(["fleet", str(one_drive), "--out", str(tmp_path / "o"), "--scheduler",
                 address, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"vipm-track fleet: error: --scheduler {address}: cannot connect "
                          f"({why}"), err
    assert err.count("\n") == 1


def test_manifest(drives, tmp_path):
    manifest = tmp_path / "m.csv"
    manifest.write_text(f"drive,images,camera,nominal,speed_csv,vehicle\n"
                        f"x,{drives}/a/images,{drives}/a/camera.yaml,{drives}/a/nominal.yaml,"
                        f"{drives}/a/speed.csv,van1\n"
                        f"y,{drives}/a/missing,{drives}/a/camera.yaml,{drives}/a/nominal.yaml,,\n")
    x, y = find_drives(manifest)
    assert x.problem == "" and x.vehicle == "van1" and x.speed_csv == drives / "a" / "speed.csv"
    assert "line 3: not found: images" in y.problem
    manifest.write_bytes(b"\xef\xbb\xbf" + manifest.read_bytes())  # saved as Excel's CSV UTF-8
    assert [s.drive for s in find_drives(manifest)] == ["x", "y"]
    manifest.write_text("drive,colour\nx,red\n")
    with pytest.raises(InputError, match=r"m.csv: line 1: unknown column\(s\) \['colour'\]"):
        find_drives(manifest)
    manifest.write_text("drive,fps\nx,fast\n")
    with pytest.raises(InputError, match="line 2: column fps"):
        find_drives(manifest)
    manifest.write_text("drive,fps\nx,1e-9\n")
    with pytest.raises(InputError, match=r"line 2: column fps must be a number of frames per "
                       r"second in \[0.1, 1000\], got 1e-09"):
        find_drives(manifest)
    manifest.write_text("drive,started\nx,2024-05-01\ny,02/05/2024\n")
    with pytest.raises(InputError, match="line 3: column started: started '02/05/2024' is no"):
        find_drives(manifest)


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.text(max_size=200) | st.binary(max_size=200))
def test_bad_manifests_are_input_errors(tmp_path, content):
    path = tmp_path / "m.csv"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content, encoding="utf-8", errors="surrogatepass")
    try:
        specs = read_manifest(path)
    except InputError:
        return
    assert all(s.problem for s in specs)  # nothing in tmp_path is a drive


def test_interrupt_keeps_every_drive_in_the_summary(fleet, drives, cluster, tmp_path):
    """Ctrl-C after the first drive: the summary has a row for every drive (finished ones
    from their done.json, the rest saying they were interrupted), and resuming completes it."""
    out, _ = fleet
    again = tmp_path / "out"
    shutil.copytree(out, again)
    (again / "fleet_summary.csv").unlink()
    shutil.rmtree(again / "drive=b")  # b has to run again
    # as a worker killed part-way leaves it: a table, no done.json (fleet.md: a drive that
    # did not finish leaves no folder)
    (again / "drive=d_clock").mkdir(exist_ok=True)
    shutil.copy(out / "drive=a" / "estimates.parquet", again / "drive=d_clock")
    seen: list[str] = []

    def interrupt(row):
        seen.append(row["drive"])
        if len(seen) == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_fleet(find_drives(drives), again, SETTINGS, scheduler=cluster.scheduler_address,
                  progress=False, on_row=interrupt)
    summary = pd.read_csv(again / "fleet_summary.csv")
    names = [s.drive for s in find_drives(drives)]
    assert list(summary["drive"]) == names and sorted(seen) == sorted(names)
    status = dict(zip(summary["drive"], summary["status"], strict=True))
    assert status["a"] == "ok" and status["c_bag"] == "ok"  # done before: kept
    assert status["b"] == "ok" or "interrupted" in status["b"]
    assert status["no_nominal"].startswith("error:") and "interrupted" not in status["no_nominal"]
    unfinished = [d for d, st in status.items() if "interrupted" in st]
    assert "d_clock" in unfinished or status["d_clock"].startswith("error:")
    # this scheduler outlives the run: the drives its workers had begun end first (a local
    # cluster's are stopped with it)
    # (a task cancelled while it runs goes on in its worker's thread, unknown to the scheduler)
    deadline = time.monotonic() + 120.0
    while (any(w.state.executing_count for w in cluster.workers.values())
           and time.monotonic() < deadline):
        time.sleep(0.2)
    # no tables that no done.json vouches for: the half-written drive is gone
    half = [p.name for p in again.glob("drive=*") if not (p / "done.json").exists()]
    assert half == [], half


def test_a_drive_with_a_kitti_calib_takes_its_size_from_the_frames(tmp_path):
    """calib.txt holds no image size; fleet took KITTI's raw 1241×376 and refused KITTI 07's
    1226×370 frames kept in images/, which `estimate --images` reads fine."""
    import cv2
    import numpy as np
    from conftest import shared_data

    from vipm_track.fleet.drive_run import FleetSettings, open_recording
    from vipm_track.fleet.drives import DriveSpec

    calib = tmp_path / "calib.txt"  # in a drive folder: no image_0/ beside it
    calib.write_bytes(shared_data("kitti07", "calib.txt").read_bytes())
    images = tmp_path / "images"
    images.mkdir()
    for k in range(2):
        cv2.imwrite(str(images / f"{k:06d}.png"), np.zeros((370, 1226), np.uint8))
    _, camera = open_recording(DriveSpec("k", images=images, camera=calib, fps=10.0),
                               FleetSettings())
    assert (camera.width, camera.height) == (1226, 370)


def test_a_running_drive_shows_its_frames(drives, cluster, tmp_path, capsys, monkeypatch):
    """The bar counted finished drives only: a long drive was silence until it ended. The
    worker now sends its drive's stage and frames; the bar shows them while it runs."""
    from vipm_track import progress as progress_module
    from vipm_track.fleet import drive_progress

    monkeypatch.setattr(drive_progress, "EVENT_INTERVAL_S", 0.0)  # an event every frame
    monkeypatch.setattr(progress_module, "LOG_INTERVAL_S", 0.0)  # a log line every redraw
    only_a = tmp_path / "only_a"
    only_a.mkdir()
    shutil.copytree(drives / "a", only_a / "a")
    rows = run_fleet(find_drives(only_a), tmp_path / "o", SETTINGS,
                     scheduler=cluster.scheduler_address, progress=True)
    assert rows[0]["status"] == "ok"
    frames = len(list((only_a / "a" / "images").glob("*.png")))
    err = capsys.readouterr().err
    shown = [int(k) for k in re.findall(rf"a: estimate (\d+)/{frames} frames", err)]
    assert shown and min(shown) < frames // 2, err  # seen while the drive's pairs ran
    assert "a: smooth" in err or "a: monitor" in err


def test_progress_text_names_the_running_drives():
    from vipm_track.fleet.drive_progress import SHOWN_DRIVES, FleetProgress

    running = FleetProgress()
    for k in range(SHOWN_DRIVES + 2):
        running.on_event((0.0, {"drive": f"d{k}", "stage": "estimate", "done": 10 * k,
                                "frames": 100}))
    running.on_event((0.0, {"drive": "d1", "stage": "smooth", "done": None, "frames": 100}))
    running.finished("d0")
    running.on_event((0.0, {"drive": "d0", "stage": "monitor", "done": None, "frames": 100}))
    assert running.text() == ("d1: smooth, d2: estimate 20/100 frames, d3: estimate 30/100 "
                              "frames; 1 more running")


@pytest.mark.parametrize("break_it", ["garbled", "missing"])
def test_a_drive_that_now_fails_leaves_no_tables(fleet, drives, cluster, tmp_path, break_it):
    """Run again after b's nominal file broke (or went missing: found before the old tables
    were removed): b is a failed row, and its tables of the run before are gone (the
    dataset served them beside the summary's error)."""
    out, _ = fleet
    again, root = tmp_path / "out", tmp_path / "drives"
    shutil.copytree(out, again)
    for name in ("a", "b"):
        shutil.copytree(drives / name, root / name)
    if break_it == "garbled":
        (root / "b" / "nominal.yaml").write_text("pitch_deg: [\n")
    else:
        (root / "b" / "nominal.yaml").unlink()
    rows = {r["drive"]: r for r in run_fleet(find_drives(root), again, SETTINGS,
                                             scheduler=cluster.scheduler_address,
                                             progress=False)}
    assert rows["a"]["skipped"] and rows["b"]["status"].startswith("error:")
    assert not any((again / "drive=b").glob("*.parquet"))
    assert not (again / "drive=b" / "summary.json").exists()
    # what the dataset serves matches the summary: b's tables neither here nor from before
    table = fleet_dataset(again, "smoothed").to_table().to_pandas()
    assert "b" not in set(table["drive"].astype(str))
    # a drive's tables without its done.json (stopped part-way) are not served either
    (again / "drive=a" / "done.json").unlink()
    table = fleet_dataset(again, "smoothed").to_table().to_pandas()
    assert table.empty  # no drive left to serve: not even a schema


def test_the_dataset_serves_the_last_runs_drives(fleet, drives, cluster, tmp_path):
    """OUT reused for a run of drive a alone: b's and c_bag's folders of the run before, done
    and all, stay on disk but are not this fleet's (its summary has one row); the dataset
    served all three."""
    out, _ = fleet
    again, root = tmp_path / "out", tmp_path / "drives"
    shutil.copytree(out, again)
    shutil.copytree(drives / "a", root / "a")
    rows = run_fleet(find_drives(root), again, SETTINGS, scheduler=cluster.scheduler_address,
                     progress=False)
    assert [r["drive"] for r in rows] == ["a"] and rows[0]["status"] == "ok"
    assert (again / "drive=b" / "done.json").is_file()
    for table in ("estimates", "smoothed", "monitor"):
        served = fleet_dataset(again, table).to_table().to_pandas()
        assert set(served["drive"].astype(str)) == {"a"} and len(served) == 12
    with pytest.raises(InputError, match=r"no fleet_summary\.parquet"):
        fleet_dataset(tmp_path / "drives")


def test_drive_names_with_percent_signs_stay_apart(drives, cluster, tmp_path):
    """'run%41' was read back as 'runA' by every Parquet reader (a partition value is a URI
    segment): 24 rows under one name, each frame twice."""
    root = tmp_path / "drives"
    for name in ("runA", "run%41"):
        shutil.copytree(drives / "a", root / name)
    rows = run_fleet(find_drives(root), tmp_path / "out", SETTINGS,
                     scheduler=cluster.scheduler_address, progress=False)
    assert all(r["status"] == "ok" for r in rows)
    table = fleet_dataset(tmp_path / "out", "estimates").to_table().to_pandas()
    counts = table["drive"].astype(str).value_counts().to_dict()
    assert counts == {"runA": 12, "run%41": 12}


def test_report_orders_drives_by_the_instant_they_started():
    """10:00+02:00 (08:00 UTC) is before 09:00+00:00; as text it sorted after it, and the
    "moved since previous" column compared the drives the wrong way round."""
    from vipm_track.sinks.fleet_report import by_vehicle, fleet_markdown

    rows = [{"drive": d, "vehicle": "v", "status": "ok", "started": when}
            for d, when in (("d2", "2024-05-02T09:00:00+00:00"),
                            ("d1", "2024-05-02T10:00:00+02:00"),
                            ("d0", "2024-05-01"), ("d3", "2024-05-02 09:30:00+00:00"))]
    assert [r["drive"] for r in by_vehicle(rows)["v"]] == ["d0", "d1", "d2", "d3"]
    assert "those without are taken as UTC" in fleet_markdown(rows)
    assert "taken as UTC" not in fleet_markdown(rows[:2])


def test_drives_without_a_vehicle_are_grouped_by_their_nominal():
    """A cart's and a car's drives, no drive.yaml: one group "(none)" had marked the car's
    drive "moved since previous" against the cart's camera."""
    from vipm_track.sinks.fleet_report import by_vehicle, fleet_markdown

    def row(drive, pitch, height, low, high):
        return {"drive": drive, "status": "ok", "nominal_pitch_deg": pitch,
                "nominal_roll_deg": 0.0, "nominal_height_m": height,
                "mount_pitch_ci95_low_deg": low, "mount_pitch_ci95_high_deg": high}

    rows = [row("a", 45.0, 0.7, 44.9, 45.1), row("b", 45.0, 0.7, 44.95, 45.05),
            row("c", 3.0, 1.5, 2.9, 3.1)]
    groups = by_vehicle(rows)
    assert sorted(len(g) for g in groups.values()) == [1, 2]
    assert "(none; nominal 45°, 0°, 0.7 m)" in groups
    assert "**pitch**" not in fleet_markdown(rows)


def test_ctrl_c_removes_the_tables_of_a_drive_it_stopped(fleet, drives, tmp_path, monkeypatch):
    """A worker killed part-way leaves tables no done.json vouches for (a `drive=*` glob read
    them): Ctrl-C removes them, and the drive's row says it was interrupted."""
    out, _ = fleet
    again = tmp_path / "out"
    (again / "drive=b").mkdir(parents=True)
    shutil.copy(out / "drive=b" / "estimates.parquet", again / "drive=b")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(fleet_cluster, "_run_all", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_fleet(find_drives(drives), again, SETTINGS, progress=False)
    assert not (again / "drive=b").exists()
    status = dict(pd.read_csv(again / "fleet_summary.csv")[["drive", "status"]].values)
    assert "interrupted before the drive finished" in status["b"]


def test_resume_redoes_a_drive_whose_outputs_are_gone(fleet, drives, cluster, tmp_path,
                                                      capsys):
    """a's monitor table removed, c_bag's estimates garbled after a complete run: the rerun
    said "unchanged, skipped" off done.json alone, and the dataset lacked a's rows."""
    out, _ = fleet
    again, root = tmp_path / "out", tmp_path / "drives"
    shutil.copytree(out, again)
    for name in ("a", "b", "c_bag"):
        shutil.copytree(drives / name, root / name)
    (again / "drive=a" / "monitor.parquet").unlink()
    (again / "drive=c_bag" / "estimates.parquet").write_bytes(b"not parquet")
    rows = {r["drive"]: r for r in run_fleet(find_drives(root), again, SETTINGS,
                                             scheduler=cluster.scheduler_address,
                                             progress=True)}
    err = capsys.readouterr().err
    assert not rows["a"]["skipped"] and not rows["c_bag"]["skipped"] and rows["b"]["skipped"]
    assert all(r["status"] == "ok" for r in rows.values())
    assert "output missing: monitor.parquet, redone)" in err, err
    assert "output unreadable: estimates.parquet, redone)" in err, err
    served = fleet_dataset(again, "monitor").to_table().to_pandas()
    assert served["drive"].value_counts().to_dict() == {"a": 12, "b": 30, "c_bag": 12}
    pd.testing.assert_frame_equal(pd.read_parquet(again / "drive=a" / "monitor.parquet"),
                                  pd.read_parquet(out / "drive=a" / "monitor.parquet"))


def test_resume_redoes_a_drive_another_version_made(fleet, drives, cluster, tmp_path, capsys):
    """The input hash left the version out: after an upgrade the old tables were reused."""
    from vipm_track import __version__
    from vipm_track.fleet.drive_run import VERSION_FIELD, resume_check

    out, _ = fleet
    again, root = tmp_path / "out", tmp_path / "drives"
    shutil.copytree(out, again)
    shutil.copytree(drives / "a", root / "a")
    done = again / "drive=a" / "done.json"
    row = json.loads(done.read_text())
    assert row[VERSION_FIELD] == __version__
    row[VERSION_FIELD] = "0.0.1"
    done.write_text(json.dumps(row))
    rows = run_fleet(find_drives(root), again, SETTINGS, scheduler=cluster.scheduler_address,
                     progress=True)
    assert rows[0]["status"] == "ok" and not rows[0]["skipped"]
    err = capsys.readouterr().err
    assert f"made by vipm-track 0.0.1, this is {__version__}, redone)" in err, err
    row = json.loads(done.read_text())
    assert row[VERSION_FIELD] == __version__
    # a done.json of before the version was written down: redone too
    del row[VERSION_FIELD]
    done.write_text(json.dumps(row))
    assert resume_check(done.parent, row["input_hash"]) == (
        None, f"made by an earlier vipm-track, this is {__version__}")


def test_numeric_drive_names_stay_apart_and_text(fleet, tmp_path):
    """Drives '01', '1' and '07' (KITTI's names): the partition was inferred as an integer,
    '01' and '1' read back as one drive 1 and '07' as 7."""
    import dask.dataframe as dd

    from vipm_track.fleet.cluster import DRIVE_PARTITIONING, write_summary
    from vipm_track.fleet.drive_run import drive_folder

    out, rows = fleet
    again = tmp_path / "out"
    names = ("01", "1", "07")
    for name in names:  # as run_drive writes drive a's outputs under each name
        shutil.copytree(out / "drive=a", drive_folder(again, name))
    write_summary(again, [{**rows["a"], "drive": name} for name in names])
    served = fleet_dataset(again, "monitor").to_table().to_pandas()
    assert served["drive"].value_counts().to_dict() == {"01": 12, "1": 12, "07": 12}
    # docs/fleet.md's dask example
    by_dask = dd.read_parquet(str(again / "drive=*" / "monitor.parquet"),
                              dataset={"partitioning": DRIVE_PARTITIONING}).compute()
    assert by_dask["drive"].astype(str).value_counts().to_dict() == {"01": 12, "1": 12,
                                                                      "07": 12}


def test_a_stray_log_beside_speed_csv_is_left_alone(drives, tmp_path):
    """A notes.log beside a good speed.csv made the drive fail "CAN log notes.log without a
    .dbc"; without a speed.csv it still is that mistake, with a .dbc a CAN log."""
    root = tmp_path / "drives"
    for name in ("a", "no_speed", "with_dbc"):
        shutil.copytree(drives / "a", root / name)
    plain = find_drives(root)[0]
    for name in ("a", "no_speed", "with_dbc"):
        (root / name / "notes.log").write_text("picked up the cart at 9\n")
    (root / "no_speed" / "speed.csv").unlink()
    (root / "with_dbc" / "car.dbc").write_text("")
    a, no_speed, with_dbc = find_drives(root)
    assert a.problem == "" and a.can is None and a.speed_csv == root / "a" / "speed.csv"
    assert a.input_hash(SETTINGS.key()) == plain.input_hash(SETTINGS.key())  # notes: no rerun
    assert no_speed.problem == (f"{root / 'no_speed'}: CAN log notes.log without a .dbc to "
                                "decode it")
    assert with_dbc.can == root / "with_dbc" / "notes.log"
    assert with_dbc.dbc == root / "with_dbc" / "car.dbc"
