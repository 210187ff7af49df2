"""Forward cameras in traffic: per-frame pose, its stated uncertainty and travel, with and
without ``--pitch``, on rendered traffic scenes (exact truth) and on KITTI 07 (real frames).

Every run goes through the CLI as a user types it (``vipm-track simulate … --traffic``,
then ``vipm-track estimate``, ``track`` and ``smooth``; the commands are in the results).
The pose truth: the render's own. KITTI's poses give none against the road; there the pitch
is the one at which the poses' direction of travel lies in the ground plane (a car's camera
moves parallel to the road: the body's pitch on its suspension, not the road's grade), and
the roll is the summed roll changes plus a 4-s median of what the estimate rows say beyond
them (the mount and the road's camber): the rows' fast roll error is scored, their slow
roll error does not show. One truth per run, for the rows and the filters alike. Per run:

- ok share of the moving pairs, the ``ok`` pairs whose pitch or roll is more than 1.5° from
  the truth, and of those the confidently wrong: also more than three of their own stated
  standard deviations off;
- the ground-normal error (the angle between the estimated and true road normal in the
  camera frame, mean over ok pairs) and the RMS error of the pose change within the pair
  (``pitch − prev_pitch``, exact on KITTI too);
- z RMS: error over the stated standard deviation (pitch and roll; their change within the
  pair, whose variance comes from the full covariance the table holds);
- travel distance error (median, p95, % of the true distance) and yaw error (median); the
  distance's z RMS (its error over its stated standard deviation, from the travel's
  covariance) and the ``ok`` rows whose distance is more than 10 % and 3σ off;
- the median stated standard deviation of the ok rows' pitch and roll, and the share of
  ok rows whose 3σ is within 1.5° in both (σ ≤ 0.5°): what a row can promise;
- in a second table, the filters on the same estimates, the online filter (``track``) and
  the batch smoother (``smooth``): their frames more than 1.5° off, per-frame ground-normal
  error, z RMS of their stated pitch and roll standard deviations (the smoother's pitch
  and roll RMS error too); the travel distance error of the smoother's frames and of
  ``smooth --motion-given-pose`` (the pair's motion corrected by the smoothed pose); the
  smoother's drive mount against the true mount (KITTI: pitch only).

Targets (issue 33): no ok pair beyond 1.5°, ground-normal error ≤ 0.3° mean, z RMS of pitch
and roll 0.8–1.25, distance median ≤ 2 % and p95 ≤ 8 %, yaw ≤ 0.05° median, ≥ 95 % of moving
pairs ok, the smoother's mount within 0.1° pitch / 0.15° roll.

    python scripts/bench_traffic.py [--frames 60] [--seeds 2] [--no-kitti] [--out out/bench_traffic]

``--preset kitti`` renders KITTI's own camera (1241×376, level, 1.65 m, 10 fps) in slow
dense traffic instead (``KITTI_RIG_SCENES``; results ``bench_traffic_kitti_rig.md``): the
camera of the real drives the project is measured on, whose short view a vehicle ahead
fills.
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.cli import main as cli_main  # noqa: E402
from vipm_track.geometry import rotation_ground_from_camera  # noqa: E402
from vipm_track.kitti import read_poses  # noqa: E402
from vipm_track.sim import PRESETS  # noqa: E402
from vipm_track.table import read_table  # noqa: E402
from vipm_track.travel_direction import travel_pitch  # noqa: E402

KITTI = ROOT.parent / "shared" / "data" / "kitti07"
WRONG_DEG = 1.5

#: rendered scenes: name → (simulate options); each run with and without --pitch
SCENES: dict[str, list[str]] = {
    "dense city traffic, 3 m/s, gradual": ["--traffic", "dense", "--profile", "gradual",
                                           "--speed", "3"],
    "dense city traffic, 3 m/s, shaking": ["--traffic", "dense", "--profile", "shaking",
                                           "--speed", "3"],
    "mixed traffic, 12 m/s, shaking": ["--traffic", "mix", "--profile", "shaking"],
    "light traffic, 12 m/s, turn": ["--traffic", "light", "--profile", "turn"],
}
#: scenes of KITTI's camera (``--preset kitti``), each with and without --pitch
KITTI_RIG_SCENES: dict[str, list[str]] = {
    "dense city traffic, 2.5 m/s, body still": ["--traffic", "dense", "--profile", "static",
                                                "--speed", "2.5"],
    "dense city traffic, 2 m/s, gradual": ["--traffic", "dense", "--profile", "gradual",
                                           "--speed", "2"],
    "dense city traffic, 1 m/s, gradual": ["--traffic", "dense", "--profile", "gradual",
                                           "--speed", "1"],
}
PRESET_SCENES = {"car": SCENES, "kitti": KITTI_RIG_SCENES}


def run(argv: list[str]) -> tuple[str, float]:
    """Run the CLI; its command line and wall time [s] (exit on failure)."""
    t0 = time.perf_counter()
    rc = cli_main(argv)
    if rc:
        raise SystemExit(f"vipm-track {shlex.join(argv)}: exit code {rc}")
    return "vipm-track " + shlex.join(argv), time.perf_counter() - t0


def scene_folder(out: Path, scene: str, seed: int) -> Path:
    """The folder of ``out`` that :func:`render_scene` renders ``scene`` with ``seed`` into."""
    return out / f"{''.join(c if c.isalnum() else '_' for c in scene)}_{seed}"


def render_scene(out: Path, scene: str, seed: int, frames: int, preset: str = "car",
                 ) -> tuple[Path, str]:
    """Render the ``preset``'s scene (``PRESET_SCENES``) with ``seed`` into its
    :func:`scene_folder`; the folder and the command line."""
    seq = scene_folder(out, scene, seed)
    cmd, _ = run(["simulate", "--preset", preset, "--frames", str(frames), "--seed", str(seed),
                  "--out", str(seq), *PRESET_SCENES[preset][scene]])
    return seq, cmd


def _normal(pitch_deg: np.ndarray, roll_deg: np.ndarray) -> np.ndarray:
    """Road normal in the camera frame, (n, 3)."""
    return np.array([rotation_ground_from_camera(math.radians(p), math.radians(r))[1]
                     for p, r in zip(pitch_deg, roll_deg, strict=True)]).reshape(-1, 3)


def _change_std(est: dict, angle: str, rows: np.ndarray) -> np.ndarray:
    """Stated standard deviation of ``angle − prev_angle`` [deg] from the table's covariance."""
    s, sp = est[f"{angle}_std_deg"][rows], est[f"prev_{angle}_std_deg"][rows]
    rho = est[f"corr_prev_{angle}__{angle}"][rows]
    return np.sqrt(np.maximum(s**2 + sp**2 - 2 * rho * s * sp, 1e-12))


def centred_median(values: np.ndarray, half: int) -> np.ndarray:
    """Running median over ``values[i - half : i + half + 1]``, the window cut at the ends
    (no padded copies of the first or last value, which would hide their errors)."""
    return np.array([np.median(values[max(0, i - half):i + half + 1])
                     for i in range(len(values))])


def travel_pitch_truth(poses: np.ndarray, roll_deg: np.ndarray, half: int = 5) -> np.ndarray:
    """KITTI's pitch against the road [deg] per frame: the pitch at which the direction of
    travel (the camera's displacement from frame k-half to k+half in frame k's camera frame,
    from the poses) lies in the ground plane, at roll ``roll_deg``. A car's camera moves
    parallel to the road, so this follows the body's pitch on its suspension and not the
    road's grade; its constant part rests on KITTI's IMU-to-camera calibration."""
    rotation, position = poses[:, :3, :3], poses[:, :3, 3]
    last = len(poses) - 1
    out = np.empty(len(poses))
    for k in range(len(poses)):
        chord = position[min(k + half, last)] - position[max(k - half, 0)]
        out[k] = math.degrees(travel_pitch(rotation[k].T @ chord / np.linalg.norm(chord),
                                           math.radians(roll_deg[k])))
    return out


def kitti_pose_truth(est: dict, truth: dict, rows: np.ndarray, poses: np.ndarray
                     ) -> dict[str, np.ndarray]:
    """KITTI's stand-in for the pose against the road [deg], per frame of the drive, one per
    run for the estimate rows and the filters' tables alike. Pitch: :func:`travel_pitch_truth`.
    Roll: the poses give only each pair's change, so the summed changes plus a 4-s (41-row)
    median of what the estimate rows ``rows`` say beyond them (the mount and the road's
    camber): the rows' fast roll error shows, their slow roll error does not."""
    frames = np.asarray(est["frame"], int)[rows]
    order = np.argsort(frames)
    out: dict[str, np.ndarray] = {"frame": np.arange(len(poses))}
    summed = summed_change(truth, "roll", len(poses) - 1)
    rest = (est["roll_deg"][rows] - summed[frames])[order]
    out["roll"] = summed + np.interp(out["frame"], frames[order], centred_median(rest, 20))
    out["pitch"] = travel_pitch_truth(poses, out["roll"])
    return out


def summed_change(truth: dict, angle: str, last: int) -> np.ndarray:
    """The truth's pose change summed from frame 0, for frames 0…``last`` [deg]."""
    change = np.zeros(last + 1)
    change[np.asarray(truth["frame"], int)] = (truth[f"{angle}_deg"]
                                               - truth[f"prev_{angle}_deg"])
    return np.cumsum(change)


def pose_truth(table: dict, truth: dict, rows: np.ndarray, truth_rows: np.ndarray,
               kitti: dict[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    """True pitch and roll [deg] for ``rows`` of ``table``: the render's own (``kitti`` is
    None), or the run's :func:`kitti_pose_truth`."""
    if kitti is None:
        return {angle: truth[f"{angle}_deg"][truth_rows] for angle in ("pitch", "roll")}
    frames = np.asarray(table["frame"], int)[rows]
    return {angle: kitti[angle][frames] for angle in ("pitch", "roll")}


def pose_errors(table: dict, rows: np.ndarray, true: dict[str, np.ndarray]
                ) -> dict[str, np.ndarray]:
    """Absolute pitch and roll error [deg] of ``rows`` of ``table`` against ``true``."""
    return {angle: np.abs(table[f"{angle}_deg"][rows] - true[angle])
            for angle in ("pitch", "roll")}


def normal_error_deg(pitch_deg: np.ndarray, roll_deg: np.ndarray,
                     true: dict[str, np.ndarray]) -> float:
    """Mean angle [deg] between the estimated and the true road normal."""
    cos = np.clip(np.sum(_normal(pitch_deg, roll_deg) * _normal(true["pitch"], true["roll"]),
                         axis=1), -1, 1)
    return float(np.degrees(np.mean(np.arccos(cos))))


def _moving(truth: dict, truth_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The true travel distance [m] of ``truth_rows`` of ``truth`` and which of them move
    (more than 1 cm)."""
    true = np.hypot(truth["tx_m"][truth_rows], truth["tz_m"][truth_rows])
    return true, np.isfinite(true) & (true > 0.01)


def distance_errors_pct(table: dict, rows: np.ndarray, truth: dict, truth_rows: np.ndarray
                        ) -> np.ndarray:
    """Travel distance error [% of the true distance] of ``rows`` of ``table`` whose true
    travel (``truth_rows`` of ``truth``) is more than 1 cm."""
    true, moving = _moving(truth, truth_rows)
    dist = np.hypot(table["tx_m"][rows], table["tz_m"][rows])[moving]
    return 100.0 * np.abs(dist - true[moving]) / true[moving]


def distance_z(table: dict, rows: np.ndarray, truth: dict, truth_rows: np.ndarray
               ) -> np.ndarray:
    """The travel distance's error over its stated standard deviation (from tx, tz, their σ
    and correlation) for the rows of :func:`distance_errors_pct`, in its order."""
    true, moving = _moving(truth, truth_rows)
    r = rows[moving]
    tx, tz = table["tx_m"][r], table["tz_m"][r]
    dist = np.hypot(tx, tz)
    sx, sz = table["tx_std_m"][r], table["tz_std_m"][r]
    var = (tx**2 * sx**2 + tz**2 * sz**2
           + 2 * tx * tz * table["corr_tx__tz"][r] * sx * sz) / dist**2
    return (dist - true[moving]) / np.sqrt(var)


def score(est: dict, truth: dict, poses: np.ndarray | None = None
          ) -> tuple[dict[str, float], dict[str, np.ndarray] | None]:
    """The run's numbers (module doc) for the frames of ``truth`` that move, and KITTI's
    :func:`kitti_pose_truth` from its ok rows where its ``poses`` are given (None for a
    render: its truth is the render's own)."""
    index = {int(f): i for i, f in enumerate(truth["frame"])}
    frames = np.asarray(est["frame"], int)
    rows = np.array([i for i, f in enumerate(frames) if f in index], int)
    ti = np.array([index[int(frames[i])] for i in rows], int)
    dist_true = np.hypot(truth["tx_m"][ti], truth["tz_m"][ti])
    moving = np.isfinite(dist_true) & (dist_true > 0.01)
    rows, ti = rows[moving], ti[moving]
    ok = np.asarray(est["status"], object)[rows] == "ok"
    r, t = rows[ok], ti[ok]
    out: dict[str, float] = {"pairs": float(len(rows)), "ok_pct": 100.0 * ok.mean()}
    for angle in ("pitch", "roll"):
        e = (est[f"{angle}_deg"][r] - est[f"prev_{angle}_deg"][r]) - (
            truth[f"{angle}_deg"][t] - truth[f"prev_{angle}_deg"][t])
        out[f"{angle}_change_rms_deg"] = float(np.sqrt(np.mean(e**2)))
        out[f"{angle}_change_z_rms"] = float(np.sqrt(np.mean(
            (e / _change_std(est, angle, r)) ** 2)))
    kitti = None if poses is None else kitti_pose_truth(est, truth, r, poses)
    true = pose_truth(est, truth, r, t, kitti)
    wrong = np.zeros(len(r), bool)
    confident = np.zeros(len(r), bool)
    for angle, e in pose_errors(est, r, true).items():
        z = e / est[f"{angle}_std_deg"][r]
        out[f"{angle}_z_rms"] = float(np.sqrt(np.mean(z**2)))
        wrong |= e > WRONG_DEG
        # confidently wrong: beyond 1.5° and beyond three of its own stated σ
        confident |= (e > WRONG_DEG) & (z > 3)
    # what a row can promise: 3σ within 1.5° needs σ ≤ 0.5° (docs/traffic.md)
    sharp = np.ones(len(r), bool)
    for angle in ("pitch", "roll"):
        out[f"{angle}_std_median_deg"] = float(np.median(est[f"{angle}_std_deg"][r]))
        sharp &= est[f"{angle}_std_deg"][r] <= WRONG_DEG / 3
    out["sharp_ok_pct"] = 100.0 * float(np.mean(sharp))
    out["wrong_ok"] = float(np.count_nonzero(wrong))
    out["confident_wrong_ok"] = float(np.count_nonzero(confident))
    out["normal_err_mean_deg"] = normal_error_deg(est["pitch_deg"][r], est["roll_deg"][r], true)
    out["pitch_signed_median_deg"] = float(np.median(est["pitch_deg"][r] - true["pitch"]))
    pct = distance_errors_pct(est, r, truth, t)
    z = distance_z(est, r, truth, t)
    out["dist_median_pct"] = float(np.median(pct))
    out["dist_p95_pct"] = float(np.percentile(pct, 95))
    out["dist_z_rms"] = float(np.sqrt(np.mean(z**2)))
    # confidently wrong travel: more than 10 % and three of its own σ off
    out["dist_confident_wrong"] = float(np.count_nonzero((pct > 10.0) & (np.abs(z) > 3)))
    out["yaw_median_deg"] = float(np.median(np.abs(est["yaw_deg"][r] - truth["yaw_deg"][t])))
    return out, kitti


def kitti_truth() -> dict:
    """KITTI 07's pair motion and pose change (``eval_kitti.truth_table`` at a level
    nominal: the change is what the poses give)."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from eval_kitti import truth_table

    return truth_table(KITTI, 0.0)


#: the filters run on each estimates table: name → command line (after ``vipm-track``)
FILTERS: dict[str, list[str]] = {
    "track": ["track"], "smooth": ["smooth"],
    "given_pose": ["smooth", "--motion-given-pose"],
}


def filtered_errors(out_dir: Path, est_csv: Path, height: float, truth: dict,
                    kitti: dict[str, np.ndarray] | None) -> tuple[dict[str, float], list[str]]:
    """Per-frame errors of the online filter (``track``) and the batch smoother
    (``smooth``, and with ``--motion-given-pose``) run on the estimates (KITTI: against the
    truth the estimate rows were scored on): ground-normal, pitch and roll, travel distance;
    and the smoother's drive mount against the true mount (KITTI: pitch only, against the
    median of :func:`travel_pitch_truth`)."""
    out: dict[str, float] = {}
    commands = []
    index = {int(f): i for i, f in enumerate(truth["frame"])}
    tables = {}
    for name, command in FILTERS.items():
        filtered = out_dir / f"{est_csv.stem}_{name}.csv"
        cmd, _ = run([*command, "--estimates", str(est_csv), "--height", repr(height),
                      "--out", str(filtered), "--quiet"])
        commands.append(cmd)
        table = tables[name] = read_table(filtered)
        rows = np.array([i for i, f in enumerate(table["frame"]) if int(f) in index
                         and np.isfinite(table["pitch_deg"][i])], int)
        ti = np.array([index[int(table["frame"][i])] for i in rows], int)
        true = pose_truth(table, truth, rows, ti, kitti)
        out[f"{name}_normal_err_mean_deg"] = normal_error_deg(
            table["pitch_deg"][rows], table["roll_deg"][rows], true)
        errors = pose_errors(table, rows, true)
        out[f"{name}_wrong"] = float(np.count_nonzero(np.any(
            [e > WRONG_DEG for e in errors.values()], axis=0)))
        for angle, e in errors.items():
            out[f"{name}_{angle}_rms_deg"] = float(np.sqrt(np.mean(e**2)))
            out[f"{name}_{angle}_z_rms"] = float(np.sqrt(np.mean(
                (e / table[f"{angle}_std_deg"][rows]) ** 2)))
        pct = distance_errors_pct(table, rows, truth, ti)
        out[f"{name}_dist_median_pct"] = float(np.median(pct))
        out[f"{name}_dist_p95_pct"] = float(np.percentile(pct, 95))
    mounts = ({"pitch": np.median(kitti["pitch"])} if kitti is not None else
              {angle: np.nanmedian(truth[f"mount_{angle}_deg"]) for angle in ("pitch", "roll")
               if np.all(np.isfinite(truth.get(f"mount_{angle}_deg", [np.nan])))})
    for angle, mount in mounts.items():
        if f"mount_{angle}_deg" in tables["smooth"]:
            out[f"mount_{angle}_err_deg"] = float(abs(
                np.nanmedian(tables["smooth"][f"mount_{angle}_deg"]) - mount))
    return out, commands


#: the two-frame rows' table: (key, header, format)
ROW_COLUMNS = [
    ("ok_pct", "ok %", "{:.1f}"), ("wrong_ok", "ok > 1.5° off", "{:.0f}"),
    ("confident_wrong_ok", "… and > 3σ", "{:.0f}"),
    ("normal_err_mean_deg", "normal err °", "{:.3f}"),
    ("pitch_z_rms", "z pitch", "{:.2f}"), ("roll_z_rms", "z roll", "{:.2f}"),
    ("pitch_change_rms_deg", "Δpitch RMS °", "{:.3f}"),
    ("roll_change_rms_deg", "Δroll RMS °", "{:.3f}"),
    ("pitch_change_z_rms", "z Δpitch", "{:.2f}"), ("roll_change_z_rms", "z Δroll", "{:.2f}"),
    ("dist_median_pct", "dist med %", "{:.2f}"), ("dist_p95_pct", "dist p95 %", "{:.1f}"),
    ("yaw_median_deg", "yaw med °", "{:.3f}"),
    ("pitch_std_median_deg", "σ pitch med °", "{:.2f}"),
    ("roll_std_median_deg", "σ roll med °", "{:.2f}"),
    ("sharp_ok_pct", "ok with σ ≤ 0.5° %", "{:.0f}"),
    ("dist_z_rms", "z dist", "{:.2f}"),
    ("dist_confident_wrong", "dist > 10 % and > 3σ", "{:.0f}"),
]
#: the filters' table (``track``; ``smooth``; ``smooth --motion-given-pose``)
FILTER_COLUMNS = [
    ("track_wrong", "tracked > 1.5° off", "{:.0f}"),
    ("track_normal_err_mean_deg", "tracked normal err °", "{:.3f}"),
    ("track_pitch_z_rms", "tracked z pitch", "{:.2f}"),
    ("track_roll_z_rms", "tracked z roll", "{:.2f}"),
    ("smooth_wrong", "smoothed > 1.5° off", "{:.0f}"),
    ("smooth_normal_err_mean_deg", "smoothed normal err °", "{:.3f}"),
    ("smooth_pitch_rms_deg", "smoothed pitch RMS °", "{:.3f}"),
    ("smooth_roll_rms_deg", "smoothed roll RMS °", "{:.3f}"),
    ("smooth_pitch_z_rms", "smoothed z pitch", "{:.2f}"),
    ("smooth_roll_z_rms", "smoothed z roll", "{:.2f}"),
    ("smooth_dist_median_pct", "smoothed dist med %", "{:.2f}"),
    ("mount_pitch_err_deg", "mount pitch °", "{:.3f}"),
    ("mount_roll_err_deg", "mount roll °", "{:.3f}"),
    ("given_pose_dist_median_pct", "motion given pose: dist med %", "{:.2f}"),
    ("given_pose_dist_p95_pct", "… p95 %", "{:.1f}"),
    ("given_pose_normal_err_mean_deg", "… normal err °", "{:.3f}"),
]


def table(rows: list[tuple[str, dict]], columns: list[tuple[str, str, str]]) -> list[str]:
    head = "| run | " + " | ".join(c[1] for c in columns) + " |"
    lines = [head, "|" + " --- |" * (len(columns) + 1)]
    for name, m in rows:
        cells = [fmt.format(m[key]) if key in m and np.isfinite(m[key]) else "–"
                 for key, _, fmt in columns]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench_traffic")
    parser.add_argument("--preset", choices=sorted(PRESET_SCENES), default="car",
                        help="the rendered camera and its scenes (module doc)")
    parser.add_argument("--results", type=Path, default=None,
                        help="results file (default scripts/results/bench_traffic.md, "
                        "bench_traffic_kitti_rig.md with --preset kitti)")
    parser.add_argument("--no-kitti", action="store_true")
    parser.add_argument("--kitti-seeds", type=int, default=3,
                        help="subset-sampler seeds of the KITTI 07 runs (each seed is a draw: "
                        "the filters' numbers move across them by more than most changes do)")
    args = parser.parse_args()
    if args.results is None:
        name = ("bench_traffic.md" if args.preset == "car"
                else f"bench_traffic_{args.preset}_rig.md")
        args.results = ROOT / "scripts" / "results" / name
    args.out.mkdir(parents=True, exist_ok=True)
    camera_preset = PRESETS[args.preset]
    rows: list[tuple[str, dict]] = []
    commands: list[str] = []
    for scene in PRESET_SCENES[args.preset]:
        for seed in range(args.seeds):
            seq, cmd = render_scene(args.out, scene, seed, args.frames, args.preset)
            commands.append(cmd)
            truth = read_table(seq / "gt.csv")
            height = float(np.nanmedian(truth["height_m"]))
            for label, extra in (("no --pitch", []),
                                 ("--pitch", ["--pitch", f"{camera_preset.pitch_deg:g}"])):
                est_csv = args.out / f"{seq.name}_{'pitch' if extra else 'nopitch'}.csv"
                cmd, _ = run(["estimate", "--images", str(seq / "images"), "--camera",
                              str(seq / "camera.yaml"), "--height", repr(height), *extra,
                              "--out", str(est_csv), "--quiet"])
                commands.append(cmd)
                m, _ = score(read_table(est_csv), truth)
                filtered, cmds = filtered_errors(args.out, est_csv, height, truth, None)
                commands.extend(cmds)
                m.update(filtered)
                rows.append((f"{scene} (seed {seed}, {label})", m))
                print(rows[-1], flush=True)
    # KITTI 07 is the same drive whatever the rendered camera: with the car's renders only
    if args.preset == "car" and not args.no_kitti and KITTI.is_dir():
        truth = kitti_truth()
        poses = read_poses(KITTI / "poses.txt")
        for seed in range(args.kitti_seeds):
            for label, extra in (("no --pitch", []), ("--pitch 1", ["--pitch", "1"])):
                est_csv = args.out / f"kitti07_{'pitch' if extra else 'nopitch'}_{seed}.csv"
                cmd, _ = run(["estimate", "--images", str(KITTI / "image_0"), "--camera",
                              str(KITTI / "calib.txt"), "--height", "1.65", *extra,
                              "--subset-seed", str(seed), "--out", str(est_csv), "--quiet"])
                commands.append(cmd)
                m, kitti = score(read_table(est_csv), truth, poses)
                filtered, cmds = filtered_errors(args.out, est_csv, 1.65, truth, kitti)
                commands.extend(cmds)
                m.update(filtered)
                rows.append((f"KITTI 07 (seed {seed}, {label})", m))
                print(rows[-1], flush=True)
    kitti_ran = any(name.startswith("KITTI 07") for name, _ in rows)
    title = ("Forward cameras in traffic (scripts/bench_traffic.py)" if args.preset == "car"
             else f"Forward cameras in traffic: the {args.preset} preset's camera "
             f"(scripts/bench_traffic.py --preset {args.preset})")
    about_kitti = (
        f"; KITTI 07 with the subset sampler's seeds 0–{args.kitti_seeds - 1} "
        "(`--subset-seed`: each a draw of the same drive). KITTI's poses give no pose against "
        "the road: its pitch truth is the pitch at which the poses' direction of travel "
        "(frames k±5) lies in the ground plane; its roll truth the summed roll changes plus a "
        "4-s median of what the estimate rows say beyond them (their slow roll error does not "
        "show); the same truth for the `track` and `smooth` columns. KITTI's mount pitch: "
        "against the median pitch truth." if kitti_ran else ".")
    text = [f"# {title}", "",
            f"{args.frames} frames per render, {camera_preset.name} preset "
            f"({camera_preset.width}×{camera_preset.height}, pitch {camera_preset.pitch_deg:g}°, "
            f"{camera_preset.height_m:g} m, {camera_preset.fps:g} fps), "
            f"seeds 0–{args.seeds - 1}{about_kitti}",
            "", "The two-frame rows (`estimate`):", "", *table(rows, ROW_COLUMNS), "",
            "The filters on them (`track`, `smooth`, `smooth --motion-given-pose`; z: the "
            "error over the filter's stated standard deviation):", "",
            *table(rows, FILTER_COLUMNS), "",
            "Commands:", "",
            *(f"    {c}" for c in commands), ""]
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text("\n".join(text))
    print("\n".join([*table(rows, ROW_COLUMNS), "", *table(rows, FILTER_COLUMNS)]))
    print(f"wrote {args.results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
