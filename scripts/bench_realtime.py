"""Speed of the two-frame estimator on real frames (KITTI 07, 1226×370) against feature-
homography peers measured in the same run, and the command line's start-up times.

For each of ``--pairs`` consecutive pairs, tracking mode with default settings and the
nominal pitch given (``--pitch 0.5``, as ``vipm-track estimate`` would run them): the wall
time per frame of the sequence runner (read, preparation and pair), the estimator's own time
(``PairResult.timings`` per stage), pairs per second, share ok and the median
travel-distance / yaw-change errors against KITTI's poses. The peers, on the same frames in
the same run: ORB (2000 features in the image below the horizon, brute-force Hamming
matches, RANSAC homography, ``cv2.decomposeHomographyMat`` with the camera height for
scale, the solution whose plane normal is nearest the road's), once detecting in both frames
of each pair and once keeping each frame's features for the next pair, and SIFT the first
way.
Start-up: ``vipm-track --help``; ``vipm-track estimate --max-frames 2`` up to its first
pair's row and to its exit; wall time from the process's start, medians over ``--repeats``
runs.

    python scripts/bench_realtime.py [--data ../shared/data/kitti07] [--pairs 60]
                                     [--repeats 3] [--out scripts/results/bench_realtime.md]

Timings on a shared machine are noisy: the table gives medians and the ratio of ours to
ORB's measured in the same run.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from eval_kitti import truth_table  # noqa: E402

from vipm_track.allocator import keep_freed_memory  # noqa: E402
from vipm_track.camera import load_camera  # noqa: E402
from vipm_track.estimator_config import EstimatorConfig  # noqa: E402
from vipm_track.evaluate import frame_errors  # noqa: E402
from vipm_track.pipeline import run_sequence  # noqa: E402
from vipm_track.rig import Rig  # noqa: E402
from vipm_track.sources import open_source  # noqa: E402
from vipm_track.workers import set_threads, threads  # noqa: E402

HEIGHT_M = 1.65
PITCH_DEG = 0.5
STAGES = ("poc", "warp", "lm")
#: the feature-homography peers: (detector, features kept for the next pair, table row)
PEERS = (("orb", False, "ORB homography"),
         ("orb", True, "ORB homography, features kept for the next pair"),
         ("sift", False, "SIFT homography"))
DEFAULT_THREADS = threads()


def ours(data: Path, pairs: int, threads: int | None = None, tracking: bool = True,
         config: EstimatorConfig | None = None) -> tuple[list[dict], dict]:
    """Per-pair rows (time, stage times, status) of the estimator (in tracking mode, or cold
    at every pair), and the estimate-table columns its errors are scored from; ``threads``:
    patch-correlation threads (``--threads``; None: the default)."""
    set_threads(threads or DEFAULT_THREADS)
    camera = load_camera(data / "calib.txt")
    source = open_source(images=data / "image_0", max_frames=pairs + 1)
    rows, est = [], {k: [] for k in ("frame", "status", "tx_m", "tz_m", "yaw_deg")}
    last, last_cpu = time.perf_counter(), time.process_time()
    for step in run_sequence(source, Rig(camera, HEIGHT_M, PITCH_DEG),
                             config or EstimatorConfig(), tracking):
        # the wall time since the step before: this frame's read, its preparation (on the
        # read-ahead thread where it did not overlap the pair before) and its pair; and the
        # CPU time of all the process's threads over it
        now, now_cpu = time.perf_counter(), time.process_time()
        wall, cpu = 1e3 * (now - last), 1e3 * (now_cpu - last_cpu)
        last, last_cpu = now, now_cpu
        if step.result is None:
            continue
        r = step.result
        rows.append({"ms": wall, "cpu": cpu, "estimator": 1e3 * step.seconds,
                     "tracked": step.tracked,
                     "status": r.status, **{s: 1e3 * r.timings.get(s, 0.0) for s in STAGES}})
        est["frame"].append(step.frame)
        est["status"].append(r.status)
        est["tx_m"].append(r.motion.tx if r.motion else math.nan)
        est["tz_m"].append(r.motion.tz if r.motion else math.nan)
        est["yaw_deg"].append(math.degrees(r.motion.yaw) if r.motion else math.nan)
    return rows, {k: np.asarray(v) for k, v in est.items()}


def feature_peer(data: Path, pairs: int, kind: str, reuse: bool = False,
                 ) -> tuple[list[dict], dict]:
    """A feature-homography pipeline on the same frames (module doc): per-pair times and the
    motion it gives, in the estimate table's columns (road frame: x right, z forward).
    ``reuse``: each frame's features are detected once and kept for the next pair, as a
    sequence runner would (otherwise each pair detects in both of its frames)."""
    camera = load_camera(data / "calib.txt")
    k = camera.k
    frames = [f.image for f in open_source(images=data / "image_0", max_frames=pairs + 1)]
    grey = [f if f.ndim == 2 else cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]
    top = round(k[1, 2]) + 10  # below the horizon of a level camera
    mask = np.zeros(grey[0].shape, np.uint8)
    mask[top:] = 255
    if kind == "orb":
        detector = cv2.ORB_create(nfeatures=2000)
        matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    else:
        detector = cv2.SIFT_create(nfeatures=2000)
        matcher = cv2.BFMatcher(cv2.NORM_L2, crossCheck=True)
    rows, est = [], {k_: [] for k_ in ("frame", "status", "tx_m", "tz_m", "yaw_deg")}
    features = detector.detectAndCompute(grey[0], mask) if reuse else None
    for i in range(1, len(grey)):
        t0, c0 = time.perf_counter(), time.process_time()
        # without reuse each pair detects in both frames, as a two-frame pipeline would
        prev = features if reuse else detector.detectAndCompute(grey[i - 1], mask)
        features = detector.detectAndCompute(grey[i], mask)
        motion = _homography_motion(prev, features, matcher, k)
        ms, cpu = 1e3 * (time.perf_counter() - t0), 1e3 * (time.process_time() - c0)
        rows.append({"ms": ms, "cpu": cpu, "status": "ok" if motion else "failed"})
        tx, tz, yaw = motion or (math.nan, math.nan, math.nan)
        est["frame"].append(i)
        est["status"].append("ok" if motion else "failed")
        est["tx_m"].append(tx)
        est["tz_m"].append(tz)
        est["yaw_deg"].append(yaw)
    return rows, {k_: np.asarray(v) for k_, v in est.items()}


def _homography_motion(prev, curr, matcher, k: np.ndarray):
    """(tx, tz, yaw°) of the road homography between two frames' features, or None."""
    (kp_p, des_p), (kp_c, des_c) = prev, curr
    if des_p is None or des_c is None or len(kp_p) < 8 or len(kp_c) < 8:
        return None
    matches = matcher.match(des_p, des_c)
    if len(matches) < 8:
        return None
    src = np.float32([kp_p[m.queryIdx].pt for m in matches])
    dst = np.float32([kp_c[m.trainIdx].pt for m in matches])
    h, _ = cv2.findHomography(src, dst, cv2.RANSAC, 2.0)
    if h is None:
        return None
    _, rotations, translations, normals = cv2.decomposeHomographyMat(h, k)
    # the road's normal in the camera frame (y down) is about (0, 1, 0): H = R + t nᵀ/d
    best = int(np.argmax([float(n[1, 0]) for n in normals]))
    r, t = rotations[best], translations[best][:, 0] * HEIGHT_M
    # H maps frame k-1 to frame k: X_k = R X_{k-1} + t, so frame k's centre in frame k-1
    # is -Rᵀt; yaw > 0 turns right (about the camera's y axis, down)
    centre = -r.T @ t
    yaw = math.degrees(math.atan2(r[0, 2], r[2, 2]))
    return float(centre[0]), float(centre[2]), -yaw


def scored(est: dict, data: Path) -> dict:
    """Median travel-distance error % and yaw-change error ° of the ok pairs."""
    truth = truth_table(data)
    errors = frame_errors(est, truth)
    ok = est["status"] == "ok"
    dist = np.asarray(errors["distance_pct"], float)
    yaw = np.asarray(errors["yaw_deg"], float)
    return {"ok": int(ok.sum()), "pairs": len(ok),
            "distance_pct": float(np.nanmedian(np.abs(dist))) if dist.size else math.nan,
            "yaw_deg": float(np.nanmedian(np.abs(yaw))) if yaw.size else math.nan}


def _lines(path: Path) -> int:
    """Lines written to ``path`` so far (0 before it exists)."""
    return path.read_text().count("\n") if path.exists() else 0


def startup(data: Path, repeats: int) -> dict[str, float]:
    """Median wall seconds of ``vipm-track --help``, of ``estimate`` up to its first pair's
    row (the table's rows are flushed one at a time: the file is polled every 5 ms) and of
    the same ``estimate --max-frames 2`` to its exit (the warnings after a run included)."""
    exe = [sys.executable, "-m", "vipm_track"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out: dict[str, list[float]] = {"--help": [], "estimate, first pair's row": [],
                                   "estimate --max-frames 2, to its exit": []}
    with tempfile.TemporaryDirectory() as tmp:
        table = Path(tmp) / "e.csv"
        for _ in range(repeats):
            t0 = time.perf_counter()
            subprocess.run([*exe, "--help"], env=env, capture_output=True, check=True)
            out["--help"].append(time.perf_counter() - t0)
            table.unlink(missing_ok=True)
            t0 = time.perf_counter()
            log = Path(tmp) / "stderr.txt"
            with log.open("w") as stderr:
                run = subprocess.Popen([*exe, "estimate", "--images", str(data / "image_0"),
                                        "--height", str(HEIGHT_M), "--pitch", str(PITCH_DEG),
                                        "--max-frames", "2", "--out", str(table)],
                                       env=env, stdout=subprocess.DEVNULL, stderr=stderr)
                first_row = None
                while run.poll() is None:
                    # header, frame 0 ("first frame"), frame 1: the first pair
                    if first_row is None and _lines(table) >= 3:
                        first_row = time.perf_counter() - t0
                    time.sleep(0.005)
                ended = time.perf_counter() - t0
            if run.returncode != 0 or _lines(table) < 3:
                raise RuntimeError(f"estimate exited with {run.returncode}, "
                                   f"{_lines(table)} lines written: {log.read_text()[-500:]}")
            # a row written in the last poll's interval counts at the exit
            out["estimate, first pair's row"].append(ended if first_row is None else first_row)
            out["estimate --max-frames 2, to its exit"].append(ended)
    return {k: statistics.median(v) for k, v in out.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "kitti07"))
    parser.add_argument("--pairs", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_realtime.md"))
    args = parser.parse_args(argv)
    keep_freed_memory()  # as the command line does
    data = Path(args.data)
    if not (data / "image_0").is_dir():
        print(f"KITTI frames not found at {data}", file=sys.stderr)
        return 2
    half = EstimatorConfig(ipm_poc_level=1)
    variants = (("vipm-track (ours)", None, True, None), ("vipm-track, 1 thread", 1, True, None),
                ("vipm-track, cold start every pair", None, False, None),
                ("vipm-track, `--refinement-resolution half`", None, True, half))
    runs: dict[str, list[list[dict]]] = {
        **{name: [] for name, *_ in variants}, **{name: [] for _, _, name in PEERS}}
    accuracy: dict[str, dict] = {}
    for _ in range(args.repeats):  # interleaved, so that load spikes hit all alike
        for name, n, tracking, config in variants:
            rows, est = ours(data, args.pairs, n, tracking, config)
            runs[name].append(rows)
            accuracy[name] = scored(est, data)
        for kind, reuse, name in PEERS:
            rows, est = feature_peer(data, args.pairs, kind, reuse)
            runs[name].append(rows)
            accuracy[name] = scored(est, data)
    medians = {name: statistics.median(r["ms"] for rep in reps for r in rep)
               for name, reps in runs.items()}
    orb = medians["ORB homography"]
    lines = [
        "# Speed on real frames: KITTI 07, against feature-homography peers",
        "",
        "| pipeline | ms/pair | pairs/s | ÷ ORB | ÷ ORB, features kept | CPU ms | "
        "estimator ms | POC ms | warp ms | LM ms | ok | median distance error % | "
        "median yaw error ° |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    orb_kept = medians["ORB homography, features kept for the next pair"]
    for name, reps in runs.items():
        flat = [r for rep in reps for r in rep]
        stage = [f"{statistics.median(r[s] for r in flat):.0f}" if s in flat[0] else "—"
                 for s in ("cpu", "estimator", *STAGES)]
        a = accuracy[name]
        lines.append(f"| {name} | {medians[name]:.0f} | {1e3 / medians[name]:.1f} | "
                     f"{medians[name] / orb:.2f} | {medians[name] / orb_kept:.2f} | "
                     f"{' | '.join(stage)} | {a['ok']}/{a['pairs']} "
                     f"| {a['distance_pct']:.2f} | {a['yaw_deg']:.3f} |")
    times = startup(data, args.repeats)
    lines += [
        "",
        f"Medians over {args.pairs} pairs × {args.repeats} runs, interleaved; ours in tracking "
        f"mode with default settings ({DEFAULT_THREADS} correlation threads; the 1-thread row: "
        "`--threads 1`; the cold row: no tracking, `--no-tracking`; the half row: the "
        "refinements correlating on halved bird's-eye planes) and "
        f"`--pitch {PITCH_DEG}` "
        "(ms/pair: wall time from one frame's row to the next as `run_sequence` yields "
        "them, the frame's read and preparation included — with two threads they are made "
        "on a read-ahead thread while the pair before is estimated; CPU ms: the process's "
        "CPU time over the same span, all threads, so ms/pair on two cores is at least "
        "half of it; estimator ms: "
        "`TwoFrameEstimator.estimate` alone, retries included; stage columns from "
        "`PairResult.timings`). "
        "Peers (frames read beforehand, not timed): 2000 features below the horizon in both "
        "frames of each pair (or, in the kept row, in the new frame only), cross-checked "
        "brute-force matches, RANSAC homography (2 px), `cv2.decomposeHomographyMat` scaled by "
        f"the {HEIGHT_M} m camera height. Errors against KITTI's poses, ok pairs only. "
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, CPython "
        f"{platform.python_version()}, shared by other jobs.",
        "",
        "## Start-up",
        "",
        "| command | seconds (median) |",
        "| --- | --- |",
        *[f"| `vipm-track {k}` | {v:.2f} |" for k, v in times.items()],
        "",
        f"Command: `python scripts/bench_realtime.py --pairs {args.pairs} --repeats "
        f"{args.repeats}`",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
