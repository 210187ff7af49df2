"""Dashboards: rerun recordings read back with rerun's chunk reader, plot reports, the CLI."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from vipm_track import estimator
from vipm_track.cli import main
from vipm_track.commands.rerun_options import sink_from_args
from vipm_track.errors import InputError
from vipm_track.filters import drive_sim
from vipm_track.measurement import PairMeasurement
from vipm_track.rig import DEFAULT_PITCH_DEG, Rig
from vipm_track.sim import (
    GT_EXTRA_COLUMNS,
    PRESETS,
    gt_rows,
    make_trajectory,
    simulate_sequence,
)
from vipm_track.sinks.rerun_blueprint import default_blueprint
from vipm_track.sinks.rerun_open import grpc_url
from vipm_track.sinks.rerun_read import recording_entities
from vipm_track.sinks.rerun_sink import RerunSink
from vipm_track.sinks.trajectory import planar_path
from vipm_track.table import read_table, write_table

# --- helpers ---------------------------------------------------------------------------------


def entity_rows(path: Path, entity: str, component: str) -> dict[int, np.ndarray]:
    """frame → values of one component of one entity in a recording (temporal rows)."""
    from rerun.chunk import RrdReader

    out: dict[int, np.ndarray] = {}
    for chunk in RrdReader(path).stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        frames = batch.column("frame").to_pylist()
        values = batch.column(component).to_pylist()
        for f, v in zip(frames, values, strict=True):
            out[int(f)] = np.asarray(v, dtype=float)
    return out


def truth_table(tmp_path: Path, profile: str = "turn", n: int = 40, seed: int = 3) -> Path:
    traj = make_trajectory(profile, n, preset="cart", seed=seed)
    path = tmp_path / "gt.csv"
    write_table(path, gt_rows(traj), GT_EXTRA_COLUMNS)
    return path


def noisy_track(truth: dict, tmp_path: Path, sigma_deg: float = 0.2, seed: int = 1,
                monitor: bool = True) -> Path:
    """A track table: truth + Gaussian noise of ``sigma_deg`` on pitch/roll, std columns,
    a failed row and (optionally) a monitor state column."""
    rng = np.random.default_rng(seed)
    n = len(truth["frame"])
    rows = []
    for i in range(n):
        row = {c: truth[c][i] for c in ("frame", "t", "height_m", "tx_m", "tz_m", "yaw_deg")}
        row["pitch_deg"] = truth["pitch_deg"][i] + rng.normal(0, sigma_deg)
        row["roll_deg"] = truth["roll_deg"][i] + rng.normal(0, sigma_deg)
        row["pitch_std_deg"] = row["roll_std_deg"] = sigma_deg
        row["status"] = "ok"
        if monitor:
            row["monitor_state"] = ("UNCALIBRATED", "CALIBRATED", "DRIFTING")[min(2, i // 15)]
            row["monitor_statistic"] = i / n
        rows.append(row)
    rows[10] = {"frame": truth["frame"][10], "t": truth["t"][10], "status": "too few inliers"}
    path = tmp_path / "track.csv"
    extra = ["pitch_std_deg", "roll_std_deg"] + (
        ["monitor_state", "monitor_statistic"] if monitor else [])
    write_table(path, rows, extra)
    return path


@dataclass
class FakeStage:
    """The estimator's PatchField fields the sink reads."""

    plane: str
    centres: np.ndarray
    displacements: np.ndarray
    peaks: np.ndarray
    inliers: np.ndarray
    sizes: np.ndarray


@dataclass
class FakeResult:
    """The estimator's PairResult fields the sink reads (the real one is tested below)."""

    status: str
    z: np.ndarray
    stages: list = field(default_factory=list)
    ipm_images: tuple | None = None
    timings: dict = field(default_factory=dict)
    residual_px: float = 0.5
    reason: str = ""

    def to_measurement(self, frame: int, t: float) -> PairMeasurement:
        cov = np.diag(np.full(7, 1e-4)) if self.status == "ok" else np.full((7, 7), np.nan)
        z = self.z if self.status == "ok" else np.full(7, np.nan)
        return PairMeasurement(frame, t, z, cov, 0.7, self.status, 30)


def fake_stage(plane: str, rng: np.random.Generator, n: int = 12) -> FakeStage:
    centres = rng.uniform(100, 500, (n, 2))
    disp = rng.normal(0, 5, (n, 2))
    disp[0] = np.nan  # not measured
    inliers = np.arange(n) % 3 != 1
    inliers[0] = False
    return FakeStage(plane, centres, disp, np.full(n, 0.5), inliers, np.full(n, 64))


# --- rerun -----------------------------------------------------------------------------------


def test_recording_entities_rows_and_values(tmp_path: Path) -> None:
    """Pairs, a filtered track, ground truth and monitor outputs written and read back: entity
    paths, row counts, logged numbers (degrees from radians, ±2σ band, scaled arrows)."""
    rng = np.random.default_rng(0)
    gt = read_table(truth_table(tmp_path, n=12))
    rrd = tmp_path / "run.rrd"
    sink = RerunSink.to_file(rrd, image_every=2, max_image_side=400)
    z_true = {}
    image = rng.integers(0, 255, (600, 800), dtype=np.uint8)  # downscaled by 0.5 when logged
    stages = {}
    for k in range(1, 7):
        z = np.array([0.78, 0.01, 0.79 + 0.001 * k, -0.02, 0.0, 0.12, 0.003])
        status = "too few inliers" if k == 4 else "ok"
        stages[k] = [fake_stage("image", rng), fake_stage("ipm", rng)]
        ipm = (rng.random((900, 700)).astype(np.float32) * 255, np.full((900, 700), np.nan))
        result = FakeResult(status, z, stages[k], ipm, {"poc": 0.01, "lm": 0.02})
        sink.log_pair(k, 0.1 * k, result, image)
        z_true[k] = z
    sink.log_gt(gt)
    for i in range(len(gt["frame"])):
        sink.log_track_row({c: gt[c][i] for c in gt}, "filtered")

    @dataclass
    class Out:  # the monitor's MonitorOutput fields the sink reads
        frame: int
        t: float
        state: str
        reason: str
        statistic: np.ndarray
        deviation: np.ndarray
        estimate: np.ndarray | None = None
        event: dict | None = None

    for k in range(6):
        state = "CALIBRATED" if k < 4 else "RECALIBRATE"
        est = np.array([0.8, 0.0, 0.7]) if state == "RECALIBRATE" else None
        event = {"state": state} if k in (0, 4) else None
        sink.log_monitor(Out(k, 0.1 * k, state, "pitch +1.2°" if k == 4 else "",
                             np.array([0.1 * k, 0.0, np.nan]), np.array([0.01, 0.0, 0.0]),
                             est, event))
    sink.finish()
    sink.finish()  # idempotent

    rows = recording_entities(rrd)
    ok_pairs, shown = 5, 3  # pairs 1..6 minus the failed one; images of pairs 1, 3, 5
    assert rows["/series/pitch/per_frame"] == ok_pairs
    assert rows["/series/pitch/per_frame_band"] == ok_pairs
    assert rows["/motion/tz/per_frame"] == ok_pairs
    assert rows["/trajectory/per_frame"] == ok_pairs
    assert rows["/camera/image"] == shown
    assert rows["/camera/patches"] == rows["/camera/displacements"] == shown
    assert rows["/ipm/prev/image"] == rows["/ipm/curr/image"] == rows["/ipm/curr/matches"] == shown
    assert rows["/timing/poc"] == 6
    assert rows["/series/pitch/truth"] == 12 and rows["/motion/tz/truth"] == 11
    assert rows["/trajectory/truth"] == 11
    assert rows["/series/roll/filtered"] == 12 and rows["/motion/yaw/filtered"] == 11
    assert rows["/monitor/state"] == 2  # state changes only
    assert rows["/monitor/state_code"] == 6 and rows["/monitor/statistic/pitch"] == 6
    assert "/monitor/statistic/height" not in rows  # NaN statistics are not logged
    assert rows["/series/pitch/monitor"] == 2
    assert rows["/log"] == 1 + 2  # the failed pair, two monitor events
    static = recording_entities(rrd, static=True)
    assert "/series/pitch/per_frame" in static  # series styles are static

    pitch = entity_rows(rrd, "/series/pitch/per_frame", "Scalars:scalars")
    assert sorted(pitch) == [1, 2, 3, 5, 6]
    for k, v in pitch.items():
        assert v[0] == pytest.approx(math.degrees(z_true[k][2]))
    band = entity_rows(rrd, "/series/pitch/per_frame_band", "Scalars:scalars")
    sigma = math.degrees(1e-2)
    assert band[2] == pytest.approx(pitch[2][0] + np.array([-2 * sigma, 2 * sigma]))
    arrows = entity_rows(rrd, "/camera/displacements", "Arrows2D:vectors")
    disp = stages[3][0].displacements
    np.testing.assert_allclose(arrows[3].reshape(-1, 2), 0.5 * disp[1:], rtol=1e-6)
    truth_pitch = entity_rows(rrd, "/series/pitch/truth", "Scalars:scalars")
    np.testing.assert_allclose([truth_pitch[k][0] for k in range(12)], gt["pitch_deg"])


def test_recording_from_real_estimator(tmp_path: Path) -> None:
    """Two rendered pairs through the real estimator: camera image, patches, IPM images and
    series land with one row per pair (series only for pairs the estimator got)."""
    from vipm_track.sim import preset_texture, render_trajectory_frame

    preset = PRESETS["cart"]
    traj = make_trajectory("shaking", 3, preset="cart", seed=7)
    camera = preset.camera()
    texture = preset_texture(preset, seed=7)
    images = [render_trajectory_frame(texture, camera, traj, k) for k in range(3)]
    est = estimator.TwoFrameEstimator(Rig(camera, preset.height_m, DEFAULT_PITCH_DEG),
                                      estimator.EstimatorConfig(keep_images=True))
    rrd = tmp_path / "pairs.rrd"
    results = {}
    with RerunSink.to_file(rrd) as sink:
        for k in (1, 2):
            results[k] = est.estimate(images[k - 1], images[k])
            sink.log_pair(k, float(traj.t[k]), results[k], images[k])
    rows = recording_entities(rrd)
    assert rows["/camera/image"] == 2
    assert rows["/camera/patches"] == rows["/camera/displacements"] == 2
    n_ok = sum(r.status == "ok" for r in results.values())
    n_ipm = sum(r.ipm_images is not None for r in results.values())
    assert n_ok >= 1, [r.reason for r in results.values()]
    for entity in ("/series/pitch/per_frame", "/series/roll/per_frame", "/trajectory/per_frame"):
        assert rows.get(entity) == n_ok, entity
    for entity in ("/ipm/prev/image", "/ipm/prev/displacements", "/ipm/curr/image"):
        assert rows.get(entity) == n_ipm, entity
    assert rows.get("/log", 0) == 2 - n_ok
    arrows = entity_rows(rrd, "/camera/displacements", "Arrows2D:vectors")
    field = results[1].stages[0]
    measured = np.all(np.isfinite(field.displacements), axis=1)
    np.testing.assert_allclose(arrows[1].reshape(-1, 2), field.displacements[measured],
                               rtol=1e-6)
    pitch = entity_rows(rrd, "/series/pitch/per_frame", "Scalars:scalars")
    for k, v in pitch.items():
        assert v[0] == pytest.approx(math.degrees(results[k].pose_curr.pitch))
        assert v[0] == pytest.approx(math.degrees(traj.pitch[k]), abs=5.0)


def test_sink_from_args_and_urls(tmp_path: Path) -> None:
    args = argparse.Namespace(rerun=None, rerun_spawn=False, rerun_connect=None)
    assert sink_from_args(args, "t") is None
    args.rerun = str(tmp_path / "sub" / "x.rrd")
    sink = sink_from_args(args, "t", image_every=3)
    assert sink is not None and sink.image_every == 3
    sink.log_text(0, 0.0, "hello")
    sink.finish()
    assert recording_entities(args.rerun) == {"/log": 1}
    args.rerun = str(tmp_path)
    with pytest.raises(InputError, match="folder"):
        sink_from_args(args, "t")
    assert grpc_url("10.0.0.2:9000") == "rerun+http://10.0.0.2:9000/proxy"
    assert grpc_url("rerun+http://h:1/proxy") == "rerun+http://h:1/proxy"
    with pytest.raises(InputError, match="port"):
        grpc_url("host:abc")
    with pytest.raises(InputError, match="jpeg"):
        RerunSink(None, jpeg_quality=0)
    assert default_blueprint() is not None
    with pytest.raises(InputError, match="not found"):
        recording_entities(tmp_path / "missing.rrd")


# --- trajectory ------------------------------------------------------------------------------


def test_planar_path_chains_motions_to_world_positions(tmp_path: Path) -> None:
    """Chaining gt.csv's motions reproduces its world positions (a turning drive)."""
    gt = read_table(truth_table(tmp_path, "turn", 60))
    world = planar_path(gt)
    np.testing.assert_allclose(world, np.stack([gt["world_x_m"], gt["world_z_m"]], 1))
    chained = planar_path({k: v for k, v in gt.items() if not k.startswith("world_")})
    np.testing.assert_allclose(chained, world - world[0], atol=1e-9)
    assert abs(world[-1, 0]) > 0.2  # the turn bends the path
    assert planar_path({"frame": gt["frame"]}) is None


# --- report ----------------------------------------------------------------------------------


def _non_trivial_png(path: Path) -> None:
    import matplotlib.image as mpimg

    assert path.is_file() and path.stat().st_size > 15_000, path
    pixels = mpimg.imread(path)
    assert pixels.shape[0] > 200 and pixels.shape[1] > 400
    assert pixels[..., :3].std() > 0.05  # not a blank canvas
    assert len(np.unique(pixels[..., :3].reshape(-1, 3), axis=0)) > 50


def test_report_with_ground_truth(tmp_path: Path) -> None:
    """Plots exist and are non-trivial; the summary's errors match the injected noise."""
    from vipm_track.sinks.report import write_report

    gt_path = truth_table(tmp_path, "gradual", 200, seed=5)
    truth = read_table(gt_path)
    track = noisy_track(truth, tmp_path, sigma_deg=0.2)
    report = write_report(track, tmp_path / "rep", gt=gt_path, title="test drive")
    assert set(report.plots) == {"pitch_roll_height", "errors", "motion", "monitor"}
    for path in report.plots.values():
        _non_trivial_png(path)
    assert report.errors["pitch_deg"]["n"] == 199
    assert report.errors["pitch_deg"]["rms"] == pytest.approx(0.2, rel=0.15)
    assert report.errors["roll_deg"]["rms"] == pytest.approx(0.2, rel=0.15)
    assert report.errors["height_m"]["max_abs"] == pytest.approx(0.0, abs=1e-9)
    assert report.errors["distance_m"]["max_abs"] == pytest.approx(0.0, abs=1e-9)
    text = report.markdown.read_text()
    assert "## Error against ground truth" in text and "too few inliers × 1" in text
    assert "UNCALIBRATED → CALIBRATED" in text and "CALIBRATED → DRIFTING" in text
    assert "![errors](errors.png)" in text


def test_report_drift_and_without_truth(tmp_path: Path) -> None:
    """A known linear pitch drift is reported as such; no GT → no errors plot."""
    from vipm_track.sinks.report import write_report

    t = np.arange(0, 120, 0.5)
    rows = [{"frame": i, "t": ti, "pitch_deg": 3.0 + 0.5 * ti / 60.0, "roll_deg": 0.1,
             "height_m": 1.5, "tx_m": 0.0, "tz_m": 5.0, "yaw_deg": 0.0, "status": "ok"}
            for i, ti in enumerate(t)]
    write_table(tmp_path / "track.csv", rows)
    report = write_report(tmp_path / "track.csv", tmp_path / "rep")
    assert set(report.plots) == {"pitch_roll_height", "motion"}
    for path in report.plots.values():
        _non_trivial_png(path)
    pitch = report.summary["pitch_deg"]
    assert pitch["slope_per_min"] == pytest.approx(0.5, rel=1e-6)
    assert pitch["slope_std_per_min"] == pytest.approx(0.0, abs=1e-9)
    assert pitch["end_minus_start"] == pytest.approx(0.5 * (t[-12] - t[11]) / 60, rel=0.05)
    assert report.summary["roll_deg"]["std"] == pytest.approx(0.0, abs=1e-12)


def test_report_cli_and_errors(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    gt_path = truth_table(tmp_path, "static", 20)
    track = noisy_track(read_table(gt_path), tmp_path, monitor=False)
    assert main(["report", str(track), "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r" / "report.md").is_file()
    assert "report.md" in capsys.readouterr().err
    assert main(["report", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "r")]) == 2
    assert "nope.csv" in capsys.readouterr().err
    (tmp_path / "bad.csv").write_text("frame,t,speed\n0,0.0,1\n")
    assert main(["report", str(tmp_path / "bad.csv"), "--out", str(tmp_path / "r")]) == 2
    assert "no pose or motion column" in capsys.readouterr().err
    # motion but no pose: reported, and said (it went by as 'rows with a pose: 0 / n')
    (tmp_path / "motion.csv").write_text("frame,t,tz_m\n0,0.0,0.5\n1,0.1,0.5\n")
    assert main(["report", str(tmp_path / "motion.csv"), "--out", str(tmp_path / "m")]) == 0
    assert "motion.csv: no row has a pitch (pitch_deg missing or empty)" in \
        capsys.readouterr().err
    assert main(["report", str(track), "--out", str(tmp_path / "r")]) == 0
    assert "no row has a pitch" not in capsys.readouterr().err


def test_track_cli_writes_recording(tmp_path: Path) -> None:
    """``track --estimates ... --rerun``: measurements, filtered and mount series per frame."""
    from vipm_track.measurement import measurement_row
    from vipm_track.table import ESTIMATE_COLUMNS

    run = drive_sim.simulate_drive(drive_sim.DriveConfig.preset(
        "car", duration_s=4.0, height_m=1.5, height_assumed_m=1.5), 0)
    est = tmp_path / "est.csv"
    write_table(est, [measurement_row(m) for m in run.measurements], ESTIMATE_COLUMNS)
    out, rrd = tmp_path / "track.csv", tmp_path / "track.rrd"
    assert main(["track", "--estimates", str(est), "--height", "1.5", "--out", str(out),
                 "--quiet", "--rerun", str(rrd)]) == 0
    tab = read_table(out)
    rows = recording_entities(rrd)
    n_filtered = int(np.isfinite(tab["pitch_deg"]).sum())
    n_meas = sum(m.ok for m in run.measurements)
    assert n_filtered > 0.8 * len(tab["frame"])
    assert rows["/series/pitch/filtered"] == rows["/series/pitch/filtered_band"] == n_filtered
    assert rows["/series/roll/mount"] == n_filtered
    assert rows["/series/pitch/per_frame"] == n_meas
    filtered = entity_rows(rrd, "/series/height/mount", "Scalars:scalars")
    ok = np.flatnonzero(np.isfinite(tab["mount_height_m"]))
    np.testing.assert_allclose([filtered[int(tab["frame"][i])][0] for i in ok],
                               tab["mount_height_m"][ok])


# --- --rerun on the other subcommands --------------------------------------------------------


def test_estimate_cli_writes_a_recording(tmp_path: Path) -> None:
    """``estimate --rerun`` on four rendered cart frames: every 2nd pair's image, all pairs'
    series (the demo's recording: tests/test_demo.py)."""
    seq = tmp_path / "sequence"
    simulate_sequence("cart", 4, seq, seed=7, profile="shaking")
    rrd2 = tmp_path / "est.rrd"
    assert main(["estimate", "--images", str(seq / "images"), "--camera",
                 str(seq / "camera.yaml"), "--height", str(PRESETS["cart"].height_m),
                 "--pitch", str(PRESETS["cart"].pitch_deg), "--refinements", "0",
                 "--out", str(tmp_path / "est.csv"), "--quiet", "--rerun", str(rrd2),
                 "--rerun-image-every", "2"]) == 0
    est2 = read_table(tmp_path / "est.csv")
    rows2 = recording_entities(rrd2)
    assert rows2["/series/pitch/per_frame"] == int(np.sum(est2["status"] == "ok")) >= 2
    assert rows2["/camera/image"] == 2  # pairs 1 and 3 of 3
    assert rows2["/timing/total"] == 3
    assert "/series/pitch/truth" not in rows2


@pytest.fixture
def monitor_drive(tmp_path: Path) -> tuple[Path, Path, Path]:
    """Estimates and wheel-speed CSVs of a 20 s car drive whose mount pitch steps by 1° at 8 s,
    a camera file, the shipped nominal."""
    from conftest import write_drive_inputs

    cfg = drive_sim.DriveConfig.preset(
        "car", fps=10.0, duration_s=20.0, mount_random_walk=False, stop_probability=0.0,
        mount_changes=(drive_sim.MountChange(8.0, pitch_deg=1.0),))
    return write_drive_inputs(drive_sim.simulate_drive(cfg, seed=21), tmp_path)


def test_monitor_cli_writes_recording(tmp_path: Path, monitor_drive) -> None:
    """``monitor --rerun``: state changes, events, statistics and deviation per frame, the
    EKF's frame pose and mount with bands; numbers equal the monitor CSV's."""
    est, speed, cam = monitor_drive
    nominal = Path(__file__).resolve().parents[1] / "data" / "nominal_car.yaml"
    out, rrd = tmp_path / "mon.csv", tmp_path / "mon.rrd"
    assert main(["monitor", "--estimates", str(est), "--speed-csv", str(speed), "--camera",
                 str(cam), "--nominal", str(nominal), "--out", str(out), "--quiet",
                 "--rerun", str(rrd), "--columns", "all"]) == 0
    tab = read_table(out)
    rows = recording_entities(rrd)
    n = len(tab["frame"])
    states = tab["monitor_state"]
    changes = 1 + int(np.sum(states[1:] != states[:-1]))
    assert "RECALIBRATE" in set(states)
    assert rows["/monitor/state"] == changes
    assert rows["/monitor/state_code"] == rows["/monitor/statistic/pitch"] == n
    # a deviation only once a frame has measured it (the first frame's is empty)
    assert rows["/monitor/deviation/roll"] == int(np.isfinite(tab["dev_roll_deg"]).sum()) == n - 1
    n_mount = int(np.isfinite(tab["mount_pitch_deg"]).sum())
    assert rows["/series/pitch/mount"] == rows["/series/pitch/mount_band"] == n_mount
    assert rows["/series/pitch/filtered"] == int(np.isfinite(tab["pitch_deg"]).sum())
    assert rows["/series/pitch/monitor"] == int(np.isfinite(tab["new_pitch_deg"]).sum()) > 0
    n_meas = int(np.sum(read_table(est)["status"] == "ok"))
    assert rows["/series/pitch/per_frame"] == n_meas
    stat = entity_rows(rrd, "/monitor/statistic/pitch", "Scalars:scalars")
    np.testing.assert_allclose([stat[int(f)][0] for f in tab["frame"]], tab["stat_pitch"])
    mount = entity_rows(rrd, "/series/pitch/mount", "Scalars:scalars")
    ok = np.flatnonzero(np.isfinite(tab["mount_pitch_deg"]))
    np.testing.assert_allclose([mount[int(tab["frame"][i])][0] for i in ok],
                               tab["mount_pitch_deg"][ok], rtol=1e-9)
    logs = entity_rows_text(rrd, "/log")
    assert any("RECALIBRATE" in text for text in logs)


def entity_rows_text(path: Path, entity: str) -> list[str]:
    """All text-log lines of an entity of a recording."""
    from rerun.chunk import RrdReader

    out: list[str] = []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity and not chunk.is_static:
            batch = chunk.to_record_batch()
            for value in batch.column("TextLog:text").to_pylist():
                out.extend(value if isinstance(value, list) else [value])
    return out


def test_report_of_monitor_table(tmp_path: Path, monitor_drive) -> None:
    """The report of a ``vipm-track monitor`` CSV plots its states, statistics, deviations and
    new extrinsics, and states the last new extrinsics: the 1° pitch step on a 3° nominal."""
    from vipm_track.sinks.report import write_report

    est, speed, cam = monitor_drive
    nominal = Path(__file__).resolve().parents[1] / "data" / "nominal_car.yaml"
    out = tmp_path / "mon.csv"
    assert main(["monitor", "--estimates", str(est), "--speed-csv", str(speed), "--camera",
                 str(cam), "--nominal", str(nominal), "--out", str(out), "--quiet"]) == 0
    report = write_report(out, tmp_path / "rep")
    _non_trivial_png(report.plots["monitor"])
    text = report.markdown.read_text()
    row = next(x for x in text.splitlines() if x.startswith("| pitch [deg] | "))
    value, lo, hi = (float(v) for v in
                     row.split("|")[2].replace("[", "").replace("]", "").replace(",", "").split())
    assert lo <= value <= hi and value == pytest.approx(4.0, abs=0.15)
    assert "Monitor: now **RECALIBRATE**" in text


def test_frame_errors_include_height(tmp_path: Path) -> None:
    """``evaluate.frame_errors`` scores the height (est − truth) of the ok rows."""
    from vipm_track.evaluate import error_table, frame_errors

    gt = read_table(truth_table(tmp_path, "height", 20))
    est = {k: np.array(v, copy=True) for k, v in gt.items()}
    est["height_m"] = est["height_m"] + 0.02
    est["status"] = np.array(["ok"] * 19 + ["too few inliers"], dtype=object)
    errors = frame_errors(est, gt)
    np.testing.assert_allclose(errors["height_m"], 0.02, atol=1e-12)
    assert len(errors["height_m"]) == 19
    assert "| height | m | 19 | 0.0200 |" in error_table(errors, ("height_m",))


def test_smooth_cli_writes_recording(tmp_path: Path, monitor_drive) -> None:
    """``smooth --rerun``: measurements, smoothed frame pose and mount with ±2σ bands (one row
    per frame with numbers; values equal the smoothed CSV's)."""
    est, speed, _ = monitor_drive
    out, rrd = tmp_path / "smooth.csv", tmp_path / "smooth.rrd"
    assert main(["smooth", "--estimates", str(est), "--speed-csv", str(speed), "--height",
                 "1.5", "--out", str(out), "--quiet", "--lag", "3", "--rerun", str(rrd)]) == 0
    tab = read_table(out)
    rows = recording_entities(rrd)
    for name, col in (("pitch", "pitch_deg"), ("roll", "roll_deg"), ("height", "height_m")):
        n = int(np.isfinite(tab[col]).sum())
        assert n > 0.8 * len(tab["frame"])
        assert rows[f"/series/{name}/smoothed"] == n
        std = tab[col.replace("_deg", "_std_deg").replace("_m", "_std_m")]
        assert rows[f"/series/{name}/smoothed_band"] == int(np.isfinite(std).sum())
    n_mount = int(np.isfinite(tab["mount_pitch_deg"]).sum())
    assert rows["/series/pitch/mount"] == rows["/series/pitch/mount_band"] == n_mount
    assert rows["/series/pitch/per_frame"] == int(np.sum(read_table(est)["status"] == "ok"))
    assert rows["/trajectory/smoothed"] >= n_mount - 1
    mount = entity_rows(rrd, "/series/pitch/mount", "Scalars:scalars")
    ok = np.flatnonzero(np.isfinite(tab["mount_pitch_deg"]))
    np.testing.assert_allclose([mount[int(tab["frame"][i])][0] for i in ok],
                               tab["mount_pitch_deg"][ok], rtol=1e-9)
    band = entity_rows(rrd, "/series/pitch/smoothed_band", "Scalars:scalars")
    i = int(ok[len(ok) // 2])
    mid = tab["pitch_deg"][i] + 2 * tab["pitch_std_deg"][i] * np.array([-1.0, 1.0])
    np.testing.assert_allclose(band[int(tab["frame"][i])], mid, rtol=1e-9)
