"""Real data: a few KITTI 07 frames through ``vipm-track estimate``, checked against poses.txt."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import shared_data
from vipm_track.cli import main
from vipm_track.evaluate import frame_errors
from vipm_track.kitti import planar_motion, read_poses
from vipm_track.table import read_table


def test_kitti_ground_truth_motion_is_planar_and_forward() -> None:
    poses = read_poses(shared_data("kitti07", "poses.txt"))
    gt = planar_motion(poses, math.radians(1.0))
    assert poses.shape == (160, 4, 4) and gt.tz.size == 159
    # The README: 0.1-0.85 m per frame, driving forward.
    assert 0.08 < gt.distance.min() and gt.distance.max() < 0.9 and np.all(gt.tz > 0)
    # Frame 1 from the file: t = (-0.0046, -0.0020, 0.0915) in camera 0 (level, 1° pitch).
    assert gt.tz[0] == pytest.approx(0.0915, abs=1e-3)
    assert gt.tx[0] == pytest.approx(-0.0046, abs=1e-4)
    assert abs(np.degrees(gt.yaw)).max() < 4.0
    # Pitch changes between frames are small (< 0.8°; braking near frame 137).
    np.testing.assert_allclose(np.degrees(gt.pitch), 1.0, atol=0.8)
    assert abs(np.median(np.degrees(gt.pitch)) - 1.0) < 0.1


#: Same options as scripts/eval_kitti.py (the documented KITTI command).
KITTI_OPTIONS = ["--height", "1.65", "--pitch", "1.0", "--no-vertical-motion"]
START, FRAMES = 60, 6


def test_kitti_frames_through_the_cli(tmp_path: Path) -> None:
    data = shared_data("kitti07")
    out = tmp_path / "est.csv"
    rc = main(["estimate", "--images", str(data / "image_0"), "--camera", str(data / "calib.txt"),
               *KITTI_OPTIONS, "--start", str(START), "--max-frames", str(FRAMES),
               "--out", str(out), "--quiet"])
    assert rc == 0
    est = read_table(out)
    assert list(est["frame"]) == list(range(START, START + FRAMES))
    assert est["status"][0] == "first frame"
    assert list(est["status"][1:]) == ["ok"] * (FRAMES - 1)
    gt = planar_motion(read_poses(data / "poses.txt"), math.radians(1.0))
    truth = {"frame": np.arange(1, gt.tx.size + 1), "tx_m": gt.tx, "tz_m": gt.tz,
             "yaw_deg": np.degrees(gt.yaw)}
    errors = frame_errors(est, truth)
    assert errors["frame"].size == FRAMES - 1
    # Issue target over the whole sequence: median <= 3 %. Five pairs after a cold start are
    # held to "a few %" (scripts/results/kitti.md has the full-sequence numbers and why).
    assert np.median(np.abs(errors["distance_pct"])) < 5.0
    assert np.max(np.abs(errors["distance_pct"])) < 15.0
    assert np.median(np.abs(errors["yaw_deg"])) < 0.1


def test_an_odd_first_frame_is_one_bad_frame_not_a_wrong_camera(tmp_path, capsys):
    """calib.txt has no image size: it was taken from frame 0, so a resized frame 0 made
    every other frame 'wrong image size' (exit 1), or a principal point outside the image
    (exit 2). The size is now most of the first five frames', and a first frame of another
    size is a bad frame like any other."""
    import shutil

    import cv2

    data = shared_data("kitti07")
    images = tmp_path / "image_0"
    images.mkdir()
    for k in range(8):
        shutil.copy(data / "image_0" / f"{k:06d}.png", images)
    shutil.copy(data / "calib.txt", tmp_path)
    (tmp_path / "times.txt").write_text(
        "".join((data / "times.txt").read_text().splitlines(keepends=True)[:8]))
    first = cv2.imread(str(images / "000000.png"), cv2.IMREAD_GRAYSCALE)
    for size in ((1240, 376), (600, 200)):
        cv2.imwrite(str(images / "000000.png"), cv2.resize(first, size))
        out = tmp_path / "e.csv"
        assert main(["estimate", "--images", str(images), "--height", "1.65", "--pitch", "1",
                     "--readout-time", "0", "--out", str(out), "--quiet"]) == 0
        status = list(read_table(out)["status"])
        assert status[0].startswith(f"wrong image size {size[0]}×{size[1]} (camera 1226×370)")
        assert status[1] == "first frame" and status[2:] == ["ok"] * 6
    capsys.readouterr()


@pytest.mark.parametrize(("pitch", "warned"), [("8", True), ("-5", True), ("1", False)])
def test_a_given_pitch_the_travel_contradicts_is_questioned(tmp_path, capsys, pitch, warned):
    """A level camera's rows follow the nominal pitch they start from: with `--pitch -5` every
    KITTI pair came out `ok` at -5.1 ± 1.2° (travel +78 %), with no word. The direction of
    travel (0.5°) now questions a given pitch 2° and more away; 1° (the documented option)
    passes."""
    data = shared_data("kitti07")
    rc = main(["estimate", "--images", str(data / "image_0"), "--camera",
               str(data / "calib.txt"), "--height", "1.65", "--pitch", pitch,
               "--readout-time", "0", "--max-frames", "30", "--out", str(tmp_path / "e.csv"),
               "--quiet"])
    assert rc == 0
    err = capsys.readouterr().err
    assert (f"--pitch {float(pitch):g}° but the direction of travel" in err) == warned, err
    if warned:
        assert "puts the camera at pitch 0.5°" in err


#: ``vipm-track estimate`` on all 160 frames of KITTI 07 with the options above (seed 0),
#: kept so the filters can be checked on real estimates without re-running the estimator.
#: Made by ``python scripts/eval_kitti.py --seeds 1 --out DIR`` (``DIR/estimates.csv``); on
#: this code it scores 154/159 ok, median 3.25 %, p95 8.57 % (one draw: see kitti.md)
KITTI_ESTIMATES = Path(__file__).parent / "data" / "kitti07_estimates.csv"


def _kitti_truth() -> dict[str, np.ndarray]:
    gt = planar_motion(read_poses(shared_data("kitti07", "poses.txt")), math.radians(1.0))
    return {"frame": np.arange(1, gt.tx.size + 1), "tx_m": gt.tx, "tz_m": gt.tz,
            "yaw_deg": np.degrees(gt.yaw)}


def test_stored_kitti_estimates_score_as_stated():
    # The pairs every filter row below is measured against (the numbers in the comment above).
    errors = frame_errors(read_table(KITTI_ESTIMATES), _kitti_truth())
    dist = np.abs(errors["distance_pct"])
    assert errors["frame"].size == 154
    assert np.median(dist) == pytest.approx(3.25, abs=0.01)
    assert np.percentile(dist, 95) == pytest.approx(8.57, abs=0.01)


def _travel_pitch_truth(table: dict) -> np.ndarray:
    """KITTI 07's pitch against the road per frame [deg]: scripts/bench_traffic.py's, the
    pitch at which the poses' direction of travel lies in the ground plane."""
    from tests.conftest import load_script
    from vipm_track.kitti import kitti_truth_table

    bench = load_script("bench_traffic")
    poses = shared_data("kitti07", "poses.txt")
    _, truth = bench.score(table, kitti_truth_table(poses, 0.0), read_poses(poses))
    return truth["pitch"]


@pytest.mark.parametrize(
    ("method", "frames", "median_ratio", "p95_ratio", "yaw_ratio", "pitch_ratio", "z_max"),
    [("ekf", 150, 1.02, 1.4, 1.6, 1.3, 1.6), ("fixed-lag 2 s", 159, 0.92, 1.06, 1.3, 0.95, 2.0),
     ("batch", 159, 0.92, 1.06, 1.3, 0.85, 1.6)],
)
def test_filters_follow_the_real_kitti_drive(method: str, frames: int, median_ratio: float,
                                             p95_ratio: float, yaw_ratio: float,
                                             pitch_ratio: float, z_max: float):
    # Real driving: a turn at 30°/s from standstill, then hard acceleration. The camera sits
    # ahead of the axle the car turns about, and the estimator's covariance is optimistic,
    # so a filter that trusts its motion model gates the pairs after the turn and keeps the
    # old motion (fixed lag before: median travel error 27 %, EKF 7 %, p95 39 %). Each
    # filter is held against the pairs it is built from (same table, same truth). Measured,
    # filter / pairs: EKF median 0.97, p95 1.28, yaw median 1.32 (on this drive the EKF's
    # motion is no better than the pairs: this row checks that it does no harm; the
    # simulated tests check what it adds); fixed-lag 2 s 0.85 / 0.98 / 1.05, batch
    # 0.86 / 0.98 / 1.09, and the smoothers fill the 5 failed pairs (159 frames), so a
    # smoother that passed the pairs through would fail here. The EKF starts once it has
    # measured the body's shaking on 10 good pairs (150 frames).
    from vipm_track.filters.ekf import run_filter
    from vipm_track.filters.ekf_state import EkfConfig
    from vipm_track.filters.smoother_config import SmootherConfig
    from vipm_track.filters.smoothing import smooth
    from vipm_track.filters.track import track_row
    from vipm_track.measurement import measurements_from_table

    table = read_table(KITTI_ESTIMATES)
    truth = _kitti_truth()
    pairs = frame_errors(table, truth)
    ms = measurements_from_table(table)
    if method == "ekf":
        states = run_filter(ms, None, EkfConfig(height_m=1.65))
    else:
        lag = 2.0 if method.startswith("fixed") else 0.0
        states = smooth(ms, None, SmootherConfig(height_m=1.65, lag_s=lag))
    rows = [track_row(f, m, None) for f, m in zip(states, ms, strict=True)]
    est = {k: np.array([r.get(k, np.nan) for r in rows]) for k in ("frame", "tx_m", "tz_m",
                                                                   "yaw_deg")}
    est["status"] = np.array([r.get("status", "skipped") for r in rows], dtype=object)
    errors = frame_errors(est, truth)
    assert errors["frame"].size == frames
    dist, dist_pairs = np.abs(errors["distance_pct"]), np.abs(pairs["distance_pct"])
    assert np.median(dist) < median_ratio * np.median(dist_pairs)
    assert np.percentile(dist, 95) < p95_ratio * np.percentile(dist_pairs, 95)
    assert (np.median(np.abs(errors["yaw_deg"]))
            < yaw_ratio * np.median(np.abs(pairs["yaw_deg"])))
    # The pose, against the poses' direction of travel (bench_traffic.py): the drive's
    # mount within 0.15° and 2.5 of its own σ of the travel's median pitch (measured: 0.03 /
    # 0.11 / 0.08° off, 0.6 / 1.7 / 1.3σ), and the frames' pitch against the drive's final
    # mount held for every frame (0.49–0.50° RMS): the batch follows the body (0.37°), the
    # fixed lag a little (0.44°); the EKF's frames are worse than its mount (0.61°, the
    # pairs 0.82°): its body follows the pairs' correlated errors (docs/traffic.md).
    true_pitch = _travel_pitch_truth(table)
    mount = math.degrees(states[-1].mount[0])
    mount_std = math.degrees(states[-1].mount_std[0])
    off = mount - np.median(true_pitch)
    assert abs(off) < 0.15 and abs(off) < 2.5 * mount_std, (off, mount_std)
    pitch = np.array([math.degrees(s.pose[0]) if s.pose is not None else np.nan
                      for s in states])
    frame = np.array([s.frame for s in states])
    known = np.isfinite(pitch) & (frame >= 1)
    rms = np.sqrt(np.mean((pitch[known] - true_pitch[frame[known]]) ** 2))
    held = np.sqrt(np.mean((mount - true_pitch[frame[known]]) ** 2))
    assert rms < pitch_ratio * held, (rms, held)
    # and the frames' stated σ: the pairs' errors run on from frame to frame, which the
    # filters' σ takes in (filters/row_correlation.py; z RMS 1.22 / 1.60 / 1.18, 3–4 before)
    std = np.array([math.degrees(s.pose_std[0]) if s.pose is not None else np.nan
                    for s in states])
    z = np.sqrt(np.mean(((pitch[known] - true_pitch[frame[known]]) / std[known]) ** 2))
    assert z < z_max, z


def test_smoothed_summary_interval_is_honest_on_the_real_drive():
    # On KITTI 07 the measured pitch/roll wander by 1–2° over seconds (road camber and
    # slope, the front end's tracking correlation): 1 s means scatter 10–20× more than the
    # model says. The model alone gave about ±0.1° for the drive's mean mount (σ 0.07°); the
    # data's batch means widen it (±0.4–0.5°), which is what a 16 s drive can tell. The
    # model's σ, widened by the pairs' measured autocorrelation as each frame's is
    # (row_correlation), now agrees with the data's: 0.19 / 0.21° pitch, 0.17 / 0.20° roll.
    from vipm_track.filters.drive_summary import summarize_mount
    from vipm_track.filters.smoother_config import SmootherConfig
    from vipm_track.filters.smoothing import smooth
    from vipm_track.measurement import measurements_from_table

    ms = measurements_from_table(read_table(KITTI_ESTIMATES))
    frames = smooth(ms, None, SmootherConfig(height_m=1.65))
    s = summarize_mount(frames, ms)
    for axis in ("pitch", "roll"):
        d = s[axis]
        assert d["interval_from"] == "data"
        assert 0.7 * d["std_data"] < d["std_model"] < 1.3 * d["std_data"]
        assert 0.3 < (d["ci95"][1] - d["ci95"][0]) / 2 < 1.0


def test_monitor_on_the_real_drive_measures_its_errors_correlation(tmp_path: Path):
    # KITTI's camera did not move, so any DRIFTING or RECALIBRATE is a false alarm. The
    # tracked pairs' errors run on from frame to frame (lag-1 autocorrelation 0.7–0.8): taken
    # as independent, the flat-ground test read them as a moved camera (DRIFTING, or
    # RECALIBRATE at 4.2 s on another draw of the drive). Measured, they widen the test: no
    # alarm, and no CALIBRATED either (12 s of such frames put the mean within ±0.4°, not
    # 0.25°). A nominal 2° off is still RECALIBRATE. The slow start (under 0.25 heights per
    # frame) is held, not judged (it called RECALIBRATE at 2.9 s).
    from vipm_track.commands.inputs import read_estimates
    from vipm_track.filters.monitor_inputs import frame_rate, monitor_measurements
    from vipm_track.filters.monitor_types import MonitorConfig
    from vipm_track.filters.nominal import NominalCalibration

    def states(pitch_deg: float, *extra: str) -> np.ndarray:
        nominal = tmp_path / "nominal.yaml"
        nominal.write_text(f"pitch_deg: {pitch_deg}\nroll_deg: 0.0\nheight_m: 1.65\n"
                           "tolerances: {pitch_deg: 0.1, roll_deg: 0.1, height_m: 0.005}\n")
        out = tmp_path / "monitor.csv"
        assert main(["monitor", "--estimates", str(KITTI_ESTIMATES), "--height", "1.65",
                     "--nominal", str(nominal), "--out", str(out), "--quiet", *extra]) == 0
        table = read_table(out)
        reasons = np.asarray(table["reason"], dtype=object)
        slow = reasons == "slow for a forward camera"
        assert slow.sum() > 30 and np.asarray(table["t"])[slow].max() < 6.0
        return np.asarray(table["monitor_state"], dtype=object)

    assert set(states(1.0)) == {"HOLD", "UNCALIBRATED"}
    assert not {"DRIFTING", "RECALIBRATE"} & set(states(1.0, "--road-std", "0.5"))
    assert "RECALIBRATE" in set(states(3.0))
    measurements = read_estimates(str(KITTI_ESTIMATES))
    white = MonitorConfig(fps=frame_rate(measurements), correlation_tau_s=0.0)
    _, out = monitor_measurements(measurements, NominalCalibration(1.0, 0.0, 1.65), config=white)
    assert {"DRIFTING", "RECALIBRATE"} & {o.state for o in out}


def test_each_pairs_direction_of_travel_follows_the_poses() -> None:
    """Pairs two frames apart (frames 40-80) against the poses' displacement over the pair,
    with the default fit (RANSAC) and MAGSAC++: every pair gives a direction, MAGSAC++'s
    within about a tenth of a degree of each other in pitch (MAD about the median; RANSAC
    0.20°) and a tenth or two in yaw (RANSAC 0.39°). On KITTI's calibration, whose K is read
    as a view of its P: OpenCV 5's USAC estimators found no essential matrix on the strided
    matrix until ``CameraModel`` made it contiguous."""
    import cv2

    from tests.conftest import load_script
    from vipm_track.camera import load_camera
    from vipm_track.sources import open_source
    from vipm_track.travel_direction import ESSENTIAL_METHOD

    data = shared_data("kitti07")
    bench = load_script("bench_travel_direction")
    camera = load_camera(data / "calib.txt")
    images = [f.image for f in open_source(images=data / "image_0", max_frames=82)]
    truth = [t for t in bench.kitti_truth((2,)) if 40 <= t[0] and t[1] < 80]
    assert len(truth) == 38
    default = bench.score(images, camera, truth, ESSENTIAL_METHOD)
    assert default["gave"] == 38
    assert default["p_mad"] < 0.3 and default["y_mad"] < 0.5
    magsac = bench.score(images, camera, truth, cv2.USAC_MAGSAC)
    assert magsac["gave"] == 38
    assert magsac["p_mad"] < 0.14 and magsac["p_rms"] < 0.25
    assert magsac["y_mad"] < 0.25 and magsac["y_rms"] < 0.4
