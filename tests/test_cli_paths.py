"""User-facing paths of the CLI that nothing else runs: ``--video``, ``--no-tracking``,
``--subset-seed``, ``--roll``, ``--parquet`` on track/smooth/monitor (and without pyarrow),
``--rerun-connect`` to an address nobody listens on, ``can-speed --bus/--duration`` on a
python-can virtual bus, ``--combine``, ``report --gt`` and the installed wheel's data path.
Each on a few rendered frames or a short simulated drive; truths are computed here."""

from __future__ import annotations

import csv
import dataclasses
import os
import shutil
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import can
import cantools
import cv2
import numpy as np
import pytest
from conftest import shared_data, write_drive_inputs

from vipm_track.cli import main
from vipm_track.filters.drive_sim import DriveConfig, simulate_drive
from vipm_track.sim import PRESETS, simulate_sequence
from vipm_track.table import read_table

ROOT = Path(__file__).resolve().parents[1]
POSE_COLUMNS = ("pitch_deg", "roll_deg", "prev_pitch_deg", "prev_roll_deg", "tx_m", "tz_m",
                "yaw_deg")


@pytest.fixture(scope="module")
def cart(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Five rendered cart frames (pose changing) and the same frames as a lossless video."""
    folder = tmp_path_factory.mktemp("cart")
    simulate_sequence("cart", 5, folder, seed=3, profile="gradual")
    writer = cv2.VideoWriter(str(folder / "drive.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 10.0,
                             (800, 600), False)
    if not writer.isOpened():
        pytest.skip("this OpenCV cannot write FFV1 video")
    for path in sorted((folder / "images").glob("*.png")):
        writer.write(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
    writer.release()
    return folder


def _estimate(cart: Path, out: Path, *extra: str, code: int = 0) -> dict[str, np.ndarray]:
    """``estimate`` on the cart; ``code``: the exit code expected (1: no usable pair)."""
    source = [] if "--video" in extra else ["--images", str(cart / "images")]
    assert main(["estimate", *source, "--camera", str(cart / "camera.yaml"), "--height", "0.7",
                 "--out", str(out), "--quiet", *extra]) == code
    return read_table(out)


def _max_error(est: dict, truth: dict, column: str) -> float:
    ok = np.asarray(est["status"]) == "ok"
    frames = np.asarray(est["frame"])[ok]
    t_idx = np.searchsorted(np.asarray(truth["frame"]), frames)
    return float(np.max(np.abs(np.asarray(est[column])[ok] - np.asarray(truth[column])[t_idx])))


# --- estimate ----------------------------------------------------------------------------------


def test_video_gives_the_answer_of_its_frames(cart: Path, tmp_path: Path) -> None:
    images = _estimate(cart, tmp_path / "images.csv")
    video = _estimate(cart, tmp_path / "video.csv", "--video", str(cart / "drive.avi"),
                      "--fps", "10")
    assert list(video["status"]) == list(images["status"]) == ["first frame"] + ["ok"] * 4
    np.testing.assert_allclose(video["t"], np.arange(5) / 10.0, atol=1e-9)
    for column in POSE_COLUMNS:  # lossless video: the very same pixels
        np.testing.assert_array_equal(video[column], images[column])


def test_no_tracking_starts_every_pair_cold(cart: Path, tmp_path: Path) -> None:
    # A cold pair hardly depends on the pairs before it: started at frame 2, the later rows
    # are those of the whole run (measured 5e-6°: rounding carried over from the previous
    # frame). Tracked, frame 3 is seeded by pair 2 in the whole run and starts cold in the
    # shorter one, and ends elsewhere (measured 0.0037° pitch, 0.0071° roll).
    truth = read_table(cart / "gt.csv")
    diff = {}
    for name, flag in (("tracked", ()), ("cold", ("--no-tracking",))):
        whole = _estimate(cart, tmp_path / f"{name}.csv", *flag)
        later = _estimate(cart, tmp_path / f"{name}_later.csv", *flag, "--start", "2")
        assert list(later["frame"]) == [2, 3, 4]
        diff[name] = max(np.max(np.abs(later[c][1:] - whole[c][3:]))
                         for c in ("pitch_deg", "roll_deg"))
        # both ways right: measured ≤ 0.008° (pitch and roll)
        assert _max_error(whole, truth, "pitch_deg") < 0.03
        assert _max_error(whole, truth, "roll_deg") < 0.03
    assert diff["cold"] < 1e-4 and diff["tracked"] > 1e-3, diff


def test_subset_seed_is_a_reproducible_draw(cart: Path, tmp_path: Path) -> None:
    default = _estimate(cart, tmp_path / "default.csv")
    seed0 = _estimate(cart, tmp_path / "seed0.csv", "--subset-seed", "0")
    seed1 = _estimate(cart, tmp_path / "seed1.csv", "--subset-seed", "1")
    again = _estimate(cart, tmp_path / "again.csv", "--subset-seed", "1")
    truth = read_table(cart / "gt.csv")
    for column in POSE_COLUMNS:
        np.testing.assert_array_equal(seed0[column], default[column])  # 0 is the default
        np.testing.assert_array_equal(again[column], seed1[column])  # deterministic
    # another draw moves the answer a little (measured 2.3e-5°), not its accuracy
    assert 0 < np.nanmax(np.abs(seed1["pitch_deg"] - default["pitch_deg"])) < 1e-3
    assert _max_error(seed1, truth, "pitch_deg") < 0.03


@pytest.fixture(scope="module")
def rolled_cart(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three frames of a cart whose camera is rolled 30° (the default cold start assumes 0)."""
    folder = tmp_path_factory.mktemp("rolled")
    simulate_sequence(dataclasses.replace(PRESETS["cart"], roll_deg=30.0), 3, folder, seed=3,
                      profile="static")
    return folder


def test_roll_option_starts_the_cold_start_at_the_given_roll(rolled_cart: Path,
                                                             tmp_path: Path) -> None:
    truth = read_table(rolled_cart / "gt.csv")
    given = _estimate(rolled_cart, tmp_path / "given.csv", "--roll", "30", "--no-tracking")
    assert list(given["status"]) == ["first frame", "ok", "ok"]
    # measured: pitch 0.012°, roll 0.010°, travel 0.009 %
    assert _max_error(given, truth, "pitch_deg") < 0.04
    assert _max_error(given, truth, "roll_deg") < 0.04
    # from 0° (the default) the pairs are not solved, and say so (exit 1: nothing usable)
    default = _estimate(rolled_cart, tmp_path / "default.csv", "--no-tracking", code=1)
    assert list(default["status"]) == ["first frame"] + ["no nominal pose"] * 2
    # a roll of the wrong sign does not converge
    wrong = _estimate(rolled_cart, tmp_path / "wrong.csv", "--roll", "-30", "--no-tracking",
                      code=1)
    assert "ok" not in list(wrong["status"])


def test_explicit_roll_0_reports_no_wrong_minimum(rolled_cart: Path, tmp_path: Path,
                                                  capsys) -> None:
    # an explicit --roll 0 is not the default (None): on this cart frame 1 came out 'ok' with
    # pitch 38.5°, roll 27° and travel 40 % off (a wrong minimum the default's cold start
    # rejects); the plausible roll (--max-roll, 10° about --roll) now rejects it, and the
    # level minimum the search then finds (pitch 4.4°) contradicts the travel 45° off axis
    truth = read_table(rolled_cart / "gt.csv")
    out = tmp_path / "zero.csv"
    code = main(["estimate", "--images", str(rolled_cart / "images"), "--camera",
                 str(rolled_cart / "camera.yaml"), "--height", "0.7", "--out", str(out),
                 "--quiet", "--roll", "0", "--no-tracking"])
    zero = read_table(out)
    assert code == (0 if "ok" in list(zero["status"]) else 1)
    if "ok" in list(zero["status"]):
        assert _max_error(zero, truth, "pitch_deg") < 1.0
        assert _max_error(zero, truth, "roll_deg") < 1.0
    else:  # the search's level second minimum contradicts the travel, and says so
        assert "nominal pose was not determined" in capsys.readouterr().err


# --- filters: Parquet, rerun ------------------------------------------------------------------


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("drive")
    run = simulate_drive(DriveConfig.preset("cart", duration_s=8.0), 0)
    est, speed, _ = write_drive_inputs(run, folder)
    return est, speed


@pytest.mark.parametrize("command", ["track", "smooth", "monitor"])
def test_parquet_beside_the_csv_holds_the_same_table(drive, tmp_path: Path,
                                                     command: str) -> None:
    est, speed = drive
    out = tmp_path / f"{command}.csv"
    extra = ["--nominal", str(ROOT / "data" / "nominal_cart.yaml")] if command == "monitor" else []
    assert main([command, "--estimates", str(est), "--speed-csv", str(speed), "--height", "0.7",
                 "--out", str(out), "--quiet", "--parquet", *extra]) == 0
    table, parquet = read_table(out), read_table(out.with_suffix(".parquet"))
    assert list(parquet) == list(table) and len(table["frame"]) == 81
    for column, values in table.items():
        if values.dtype == object:
            assert list(parquet[column]) == list(values), column
        else:
            # the CSV holds 15 significant digits (docs/formats.md), the Parquet the doubles
            np.testing.assert_allclose(parquet[column], values, rtol=1e-14, atol=0,
                                       err_msg=column)


@pytest.mark.parametrize("command", ["track", "smooth", "monitor"])
def test_parquet_without_pyarrow_fails_before_any_work(drive, tmp_path: Path, monkeypatch,
                                                       capsys, command: str) -> None:
    est, _ = drive
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # import pyarrow → ImportError
    out = tmp_path / f"{command}.csv"
    extra = ["--nominal", str(ROOT / "data" / "nominal_cart.yaml")] if command == "monitor" else []
    code = main([command, "--estimates", str(est), "--height", "0.7", "--out", str(out),
                 "--quiet", "--parquet", *extra])
    assert code == 2  # an input error, not a traceback
    assert "Parquet output needs pyarrow: pip install" in capsys.readouterr().err
    assert not out.exists()


def test_a_parquet_of_an_earlier_run_is_pointed_out(drive, tmp_path: Path, capsys) -> None:
    est, _ = drive
    out = tmp_path / "track.csv"
    args = ["track", "--estimates", str(est), "--height", "0.7", "--out", str(out), "--quiet"]
    assert main([*args, "--parquet"]) == 0
    assert "earlier run" not in capsys.readouterr().err
    assert main(args) == 0  # the CSV rewritten, the Parquet beside it not
    assert (f"{out.with_suffix('.parquet')} is from an earlier run; this run writes {out} only"
            in capsys.readouterr().err)


def test_rerun_connect_to_nobody_finishes(drive, tmp_path: Path) -> None:
    est, _ = drive
    out = tmp_path / "track.csv"
    cmd = [sys.executable, "-m", "vipm_track", "track", "--estimates", str(est), "--height",
           "0.7", "--out", str(out), "--quiet", "--rerun-connect", "127.0.0.1:9"]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=30, cwd=ROOT)
    except subprocess.TimeoutExpired:
        rows = len(read_table(out)["frame"]) if out.exists() else 0
        pytest.fail(f"still running after 30 s ({rows} rows written)")
    assert done.returncode == 0, done.stderr
    assert len(read_table(out)["frame"]) == 81
    # one line of ours, at once (rerun's own retries took 19 s and printed four log lines)
    assert done.stderr.splitlines() == [
        "vipm-track: warning: --rerun-connect 127.0.0.1:9: no rerun viewer answers (Connection "
        "refused); nothing is streamed to it"], done.stderr


# --- wheel speed -------------------------------------------------------------------------------


def test_can_speed_from_a_virtual_bus(tmp_path: Path, capsys) -> None:
    dbc = shared_data("comma2k19_can", "toyota_2017.dbc")
    db = cantools.database.load_file(str(dbc), strict=False)
    message = db.get_message_by_name("WHEEL_SPEEDS")
    channel = f"vipm-test-{os.getpid()}"
    stop = threading.Event()
    sent: list[float] = []

    def send() -> None:
        with can.Bus(interface="virtual", channel=channel, receive_own_messages=False) as bus:
            k = 0
            while not stop.is_set():
                kmh = 20.0 + 0.25 * (k % 40)
                data = message.encode({"WHEEL_SPEED_FL": kmh, "WHEEL_SPEED_FR": kmh,
                                       "WHEEL_SPEED_RL": kmh, "WHEEL_SPEED_RR": kmh + 1.0,
                                       "WHEEL_SPEED_FL_FAULT": 0, "WHEEL_SPEED_FR_FAULT": 0,
                                       "WHEEL_SPEED_RL_FAULT": 0, "WHEEL_SPEED_RR_FAULT": 0})
                bus.send(can.Message(arbitration_id=message.frame_id, data=data,
                                     is_extended_id=False))
                sent.append(kmh)
                k += 1
                time.sleep(0.01)

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    out = tmp_path / "speed.csv"
    try:
        t0 = time.monotonic()
        rc = main(["can-speed", "--bus", f"virtual:{channel}", "--duration", "1.0", "--dbc",
                   str(dbc), "--out", str(out)])
        listened = time.monotonic() - t0
    finally:
        stop.set()
        sender.join(5)
    assert rc == 0
    assert 0.9 < listened < 3.0  # --duration: about a second
    rows = list(csv.DictReader(out.open()))
    assert 40 <= len(rows) <= len(sent)
    # the default signals are the rear wheels, combined by their mean: kmh + 0.5
    possible = (np.array(sorted(set(sent))) + 0.5) / 3.6
    speeds = np.array([float(r["speed_mps"]) for r in rows])
    assert np.abs(speeds[:, None] - possible[None]).min(axis=1).max() < 0.01 / 3.6
    assert np.all(np.diff([float(r["t"]) for r in rows]) > 0)
    # named as given (the summary said "bus unknown" for a udp_multicast bus)
    assert f"bus virtual:{channel}: " in capsys.readouterr().err


def test_can_speed_bus_needs_interface_and_channel(tmp_path: Path, capsys) -> None:
    dbc = shared_data("comma2k19_can", "toyota_2017.dbc")
    assert main(["can-speed", "--bus", "virtual", "--dbc", str(dbc), "--out",
                 str(tmp_path / "s.csv")]) == 2
    assert "expected INTERFACE:CHANNEL" in capsys.readouterr().err


def test_combine_rules_on_the_real_log(tmp_path: Path) -> None:
    # Truth decoded here, message by message, with python-can and cantools.
    data = shared_data("comma2k19_can")
    db = cantools.database.load_file(str(data / "toyota_2017.dbc"), strict=False)
    wheels = [f"WHEEL_SPEEDS.WHEEL_SPEED_{w}" for w in ("FL", "FR", "RL", "RR")]
    frame_id = db.get_message_by_name("WHEEL_SPEEDS").frame_id
    expected = []
    for msg in can.LogReader(str(data / "rav4_drive.log")):
        if msg.arbitration_id == frame_id:
            values = db.decode_message(frame_id, msg.data)
            expected.append([values[w.split(".")[1]] / 3.6 for w in wheels])
            if len(expected) == 400:
                break
    expected = np.array(expected)
    rules = {"mean": np.mean, "median": np.median, "min": np.min, "max": np.max}
    for rule, fn in rules.items():
        out = tmp_path / f"{rule}.csv"
        assert main(["can-speed", str(data / "rav4_drive.log"), "--dbc",
                     str(data / "toyota_2017.dbc"), "--signals", ",".join(wheels),
                     "--combine", rule, "--out", str(out)]) == 0
        got = np.array([float(r["speed_mps"]) for r in csv.DictReader(out.open())])[:400]
        # the CSV keeps 1e-5 m/s
        np.testing.assert_allclose(got, fn(expected, axis=1), rtol=0, atol=5.1e-6, err_msg=rule)
    # the four wheels differ, so the rules differ
    assert np.max(expected.max(axis=1) - expected.min(axis=1)) > 0.05


# --- report ------------------------------------------------------------------------------------


def test_report_gt_through_the_cli(cart: Path, tmp_path: Path) -> None:
    est = _estimate(cart, tmp_path / "est.csv")
    assert main(["report", str(tmp_path / "est.csv"), "--gt", str(cart / "gt.csv"), "--out",
                 str(tmp_path / "report")]) == 0
    text = (tmp_path / "report" / "report.md").read_text()
    assert (tmp_path / "report" / "errors.png").stat().st_size > 10_000
    truth = read_table(cart / "gt.csv")
    # the error table's pitch row against |errors| computed here (4 decimals of a degree)
    errors = text.split("## Error against ground truth")[1]
    line = next(row for row in errors.splitlines() if row.startswith("| pitch_deg |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    ok = np.asarray(est["status"]) == "ok"
    err = np.abs(np.asarray(est["pitch_deg"])[ok] - np.asarray(truth["pitch_deg"])[ok])
    assert int(cells[1]) == 4
    assert float(cells[5]) == pytest.approx(np.median(err), abs=5.1e-5)
    assert float(cells[7]) == pytest.approx(err.max(), abs=5.1e-5)


# --- packaging -------------------------------------------------------------------------------


@pytest.mark.slow
def test_installed_wheel_finds_its_data(tmp_path: Path) -> None:
    # Build a wheel from a copy of the tracked files (the checkout stays clean), install it
    # into a folder, and import it from there: data_path must find the embedded data inside
    # the installed package, not in a source checkout.
    backend = subprocess.run([sys.executable, "-c", "import setuptools, wheel; "
                              "print(setuptools.__version__)"], capture_output=True, text=True)
    if backend.returncode or int(backend.stdout.split(".")[0]) < 68:
        pytest.skip("building the wheel offline needs setuptools>=68 and wheel installed")
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                           check=True).stdout.decode().split("\0")
    src = tmp_path / "src"
    for name in filter(None, files):
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    wheels, target = tmp_path / "wheels", tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(wheels),
                    str(src)], check=True, capture_output=True, timeout=300)
    wheel = next(wheels.glob("vipm_track-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    assert "vipm_track/data/nominal_cart.yaml" in names
    assert any(n.startswith("vipm_track/data/textures/") for n in names)
    subprocess.run([*pip, "install", "--no-deps", "--target", str(target), str(wheel)],
                   check=True, capture_output=True, timeout=300)
    probe = ("import vipm_track, vipm_track.resources as r; print(vipm_track.__file__); "
             "print(r.data_path('nominal_cart.yaml')); print(r.data_path('textures'))")
    env = {**os.environ, "PYTHONPATH": str(target)}
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, env=env,
                         capture_output=True, text=True, check=True).stdout.split()
    assert all(line.startswith(str(target)) for line in out), out
    assert "pitch_deg" in Path(out[1]).read_text()


# --- what the data already says -------------------------------------------------------------


@pytest.fixture(scope="module")
def short_cart(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("short")
    simulate_sequence("cart", 8, folder, seed=5, profile="shaking")
    return folder


def test_camera_beside_the_images_and_height_from_the_table_are_used(short_cart: Path,
                                                                      tmp_path: Path, capsys):
    est = tmp_path / "est.csv"
    # no --camera: the simulator's camera.yaml sits beside images/
    assert main(["estimate", "--images", str(short_cart / "images"), "--height", "0.7",
                 "--pitch", "45", "--out", str(est)]) == 0
    assert f"--camera {short_cart / 'camera.yaml'} (found beside the images)" in (
        capsys.readouterr().err)
    given = tmp_path / "given.csv"
    assert main(["estimate", "--images", str(short_cart / "images"), "--height", "0.7",
                 "--pitch", "45", "--camera", str(short_cart / "camera.yaml"), "--out",
                 str(given), "--quiet"]) == 0
    assert est.read_bytes() == given.read_bytes()
    # no --height: the table was estimated at 0.7 m
    inferred, explicit = tmp_path / "a.csv", tmp_path / "b.csv"
    assert main(["smooth", "--estimates", str(est), "--out", str(inferred)]) == 0
    assert "--height 0.7 (the height" in capsys.readouterr().err
    assert main(["smooth", "--estimates", str(est), "--height", "0.7", "--out", str(explicit),
                 "--quiet"]) == 0
    assert inferred.read_bytes() == explicit.read_bytes()


def test_missing_camera_and_height_say_what_to_give(tmp_path: Path, capsys):
    (tmp_path / "images").mkdir()
    assert main(["estimate", "--images", str(tmp_path / "images"), "--height", "1", "--out",
                 str(tmp_path / "e.csv")]) == 2
    assert "give --camera" in capsys.readouterr().err
    table = tmp_path / "t.csv"
    table.write_text("frame,t,status\n0,0.0,first frame\n")
    assert main(["track", "--estimates", str(table), "--out", str(tmp_path / "o.csv")]) == 2
    assert "has no height_m" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["track", "smooth", "monitor"])
def test_start_and_max_frames_window_every_filter(short_cart: Path, tmp_path: Path,
                                                  command: str):
    est = tmp_path / "est.csv"
    assert main(["estimate", "--images", str(short_cart / "images"), "--height", "0.7",
                 "--pitch", "45", "--out", str(est), "--quiet"]) == 0
    out = tmp_path / f"{command}.csv"
    extra = ["--nominal", str(ROOT / "data" / "nominal_cart.yaml")] if command == "monitor" \
        else ["--height", "0.7"]
    # four frames are too few for the EKF to start: track says so (exit 1), its rows kept
    assert main([command, "--estimates", str(est), "--start", "2", "--max-frames", "4",
                 "--out", str(out), "--quiet", *extra]) == (1 if command == "track" else 0)
    assert list(read_table(out)["frame"]) == [2, 3, 4, 5]
    assert main([command, "--estimates", str(est), "--max-frames", "0", "--out", str(out),
                 "--quiet", *extra]) == 2
    # a start beyond the table said "no frame has a usable pair estimate ()", exit 1
    assert main([command, "--estimates", str(est), "--start", "1000", "--out", str(out),
                 "--quiet", *extra]) == 2


@pytest.mark.parametrize("command", ["smooth", "monitor"])
def test_a_table_without_a_usable_pair_points_at_its_statuses(tmp_path, capsys, command):
    """A table whose every pair failed (a cart at 10 m/s, beyond the estimator's range): the
    filters said "For a forward-looking camera give --pitch" to a user who had given it to
    estimate, and whose options they refuse with --estimates."""
    from vipm_track.table import read_table

    table = read_table(Path(__file__).parent / "data" / "knock_cart_est.csv")
    with (tmp_path / "est.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(list(table))
        for k in range(len(table["frame"])):
            writer.writerow([table[c][k] if c in ("frame", "t", "height_m") else
                             "too few inliers" if c == "status" else "" for c in table])
    extra = (["--nominal", str(ROOT / "data" / "nominal_cart.yaml")] if command == "monitor"
             else ["--height", "0.7"])
    assert main([command, "--estimates", str(tmp_path / "est.csv"), "--out",
                 str(tmp_path / "out.csv"), "--quiet", *extra]) == 1
    err = capsys.readouterr().err
    assert "no frame has a usable pair estimate (180× too few inliers)" in err, err
    assert "Its statuses say why; estimate the frames again" in err and "give --pitch" not in err
