"""Camera–wheel-speed clock offset found from the data (``--clock-offset auto``).

1. Simulated drives (``filters.drive_sim``: car 20 fps 5–20 m/s, cart 10 fps 0.8–1.6 m/s, with
   stops and turns; wheel speed at 50 Hz, 0.5 % noise, 0.01 km/h steps), the speed's clock
   offset drawn uniformly in ±2 s, clean and with 10 % outlier pairs and 5 % failed frames:
   how often the offset is found, refused (the data cannot fix it) or wrong (> 0.5 s off), the
   error, and whether the printed 1σ is honest (RMS of error / σ ≈ 1).
2. KITTI 07's real pairs (``tests/data/kitti07_estimates.csv``) against a 50 Hz speed made from
   its ground-truth poses (0.5 % noise) behind the camera clock by a known offset: the offset
   found, and the EKF's (``vipm-track track``) final height with the offset left out, found, and
   true.
3. What the data cannot fix (constant and periodic speed) and run time (an hour's drive; five
   minutes of video inside an hour of CAN log).

    python scripts/bench_clock_offset.py [--drives 20] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.cli import main as cli  # noqa: E402
from vipm_track.errors import InputError  # noqa: E402
from vipm_track.filters.clock_offset import estimate_clock_offset  # noqa: E402
from vipm_track.filters.drive_sim import DriveConfig, DriveProfile, simulate_drive  # noqa: E402
from vipm_track.filters.wheel_speed import SpeedSeries, write_speed_csv  # noqa: E402
from vipm_track.kitti import planar_motion, read_poses  # noqa: E402
from vipm_track.measurement import read_measurements  # noqa: E402

KITTI = ROOT.parent / "shared" / "data" / "kitti07"
KITTI_ESTIMATES = ROOT / "tests" / "data" / "kitti07_estimates.csv"


def _series(run) -> SpeedSeries:
    return SpeedSeries(run.speed.t, run.speed.speed_mps, source="sim")


def simulated_rows(drives: int) -> list[str]:
    """Table 1: one row per preset, duration and data quality."""
    rows = []
    for preset in ("car", "cart"):
        for duration in (30.0, 60.0, 120.0):
            for bad in (False, True):
                err, z, std, ms, refused, wrong = [], [], [], [], 0, 0
                for seed in range(drives):
                    offset = float(np.random.default_rng(1000 + seed).uniform(-2.0, 2.0))
                    cfg = DriveConfig.preset(
                        preset, duration_s=duration, speed_clock_offset_s=offset,
                        outlier_fraction=0.1 if bad else 0.0,
                        failure_fraction=0.05 if bad else 0.01)
                    run = simulate_drive(cfg, seed=seed)
                    t0 = time.perf_counter()
                    try:
                        fit = estimate_clock_offset(run.measurements, _series(run))
                    except InputError:
                        refused += 1
                        continue
                    ms.append(1e3 * (time.perf_counter() - t0))
                    e = fit.offset_s - offset
                    if abs(e) > 0.5:
                        wrong += 1
                        continue
                    err.append(e)
                    z.append(e / fit.std_s)
                    std.append(fit.std_s)
                e_ms = 1e3 * np.abs(np.array(err))
                data = "10 % outliers, 5 % failed" if bad else "clean"
                rows.append(
                    f"| {preset} | {duration:.0f} | {data} | {len(err)}/{drives} | {refused} | "
                    f"{wrong} | {np.sqrt(np.mean(e_ms ** 2)):.1f} | {np.median(e_ms):.1f} | "
                    f"{e_ms.max():.1f} | {1e3 * np.median(std):.1f} | "
                    f"{np.sqrt(np.mean(np.square(z))):.2f} | {np.median(ms):.0f} |")
                print(rows[-1], flush=True)
    return rows


def _kitti_speed(path: Path, offset_s: float, seed: int) -> Path:
    poses = read_poses(KITTI / "poses.txt")
    t = np.loadtxt(KITTI / "times.txt")
    mid, speed = 0.5 * (t[1:] + t[:-1]), planar_motion(poses).distance / np.diff(t)
    ts = np.arange(mid[0], mid[-1], 0.02)
    noise = np.random.default_rng(seed).standard_normal(ts.size)
    write_speed_csv(SpeedSeries(ts - offset_s, np.interp(ts, mid, speed) * (1 + 0.005 * noise)),
                    path)
    return path


def _track_height(speed: Path, offset: str, folder: Path) -> float:
    out = folder / f"track_{offset}.csv"
    rc = cli(["track", "--estimates", str(KITTI_ESTIMATES), "--height", "1.65", "--speed-csv",
              str(speed), "--clock-offset", offset, "--out", str(out), "--quiet"])
    if rc != 0:
        raise RuntimeError(f"vipm-track track failed with {rc}")
    with out.open() as fh:
        return float(list(csv.DictReader(fh))[-1]["height_m"])


def kitti_rows() -> list[str]:
    """Table 2: KITTI 07's real pairs against a ground-truth speed behind by a known offset."""
    if not (KITTI / "poses.txt").is_file():
        return ["| (KITTI 07 not found beside the checkout: ../shared/data/kitti07) |"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for offset in (0.1, 0.3, 0.5, -0.3):
            for seed in (1, 2):
                speed = _kitti_speed(folder / "speed.csv", offset, seed)
                fit = estimate_clock_offset(read_measurements(KITTI_ESTIMATES),
                                            SpeedSeries(*np.loadtxt(speed, delimiter=",",
                                                                    skiprows=1, unpack=True)))
                h = {o: _track_height(speed, o, folder) for o in ("0", "auto", f"{offset}")}
                rows.append(f"| {offset:+.1f} | {seed} | {fit.offset_s:+.3f} | "
                            f"{1e3 * fit.std_s:.0f} | {1e3 * (fit.offset_s - offset):+.0f} | "
                            f"{h['0']:.3f} | {h['auto']:.3f} | {h[f'{offset}']:.3f} |")
                print(rows[-1], flush=True)
    return rows


def limits_rows() -> list[str]:
    """Table 3: refusals and run time."""
    rows = []
    knots = tuple(float(k) for k in range(0, 61, 2))
    cases = {
        "constant 10 m/s, 60 s": DriveProfile((0.0, 60.0), (10.0, 10.0), (0.0, 0.0)),
        "8 ↔ 12 m/s every 2 s, 60 s": DriveProfile(
            knots, tuple(8.0 if i % 2 else 12.0 for i in range(len(knots))), (0.0,) * len(knots)),
    }
    for name, profile in cases.items():
        run = simulate_drive(DriveConfig(duration_s=60.0, speed_clock_offset_s=0.4), seed=3,
                             profile=profile)
        try:
            fit = estimate_clock_offset(run.measurements, _series(run))
            answer = f"{fit.line()} (true +0.400 s)"
        except InputError as exc:
            answer = f"refused: {str(exc).split('clock offset: ', 1)[1]}"
        rows.append(f"| {name} | {answer} |")
    hour = simulate_drive(DriveConfig(duration_s=3600.0, speed_clock_offset_s=0.37), seed=1)
    for name, meas in (("an hour of video, an hour of speed", hour.measurements),
                       ("5 min of video inside an hour of speed",
                        hour.measurements[20 * 1200:20 * 1500])):
        t0 = time.perf_counter()
        fit = estimate_clock_offset(meas, _series(hour))
        rows.append(f"| {name} | {fit.offset_s:+.3f} s ± {1e3 * fit.std_s:.1f} ms (true +0.370 s) "
                    f"in {time.perf_counter() - t0:.2f} s |")
    for row in rows:
        print(row, flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drives", type=int, default=20, help="simulated drives per row")
    ap.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_clock_offset.md"))
    args = ap.parse_args()
    sim = simulated_rows(args.drives)
    kitti = kitti_rows()
    limits = limits_rows()
    text = "\n".join([
        "# Clock offset from the data (`--clock-offset auto`)",
        "",
        f"Simulated drives ({args.drives} per row, offsets uniform in ±2 s, seeds 0…; the whole "
        "range that keeps half the pairs covered is searched): *found* = answered within 0.5 s; "
        "*refused* = the data could not fix it (said so); *wrong* = answered more than 0.5 s "
        "off. Errors over the found drives; *err/σ* is the RMS of error over the printed 1σ "
        "(1 = honest). Run time per drive on a shared 2-core machine.",
        "",
        "| preset | seconds | data | found | refused | wrong | RMS error ms | median ms | "
        "max ms | median σ ms | RMS err/σ | ms / drive |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        *sim,
        "",
        "KITTI 07 (real pairs, 159 frames, 16 s, the car slowing from 8 to 1 m/s and "
        "pulling away): a wheel speed from the ground-truth poses, behind the camera by the "
        "offset; height: the EKF's (`track`) at the last frame, with the offset left out (0), "
        "found (auto) and true (the camera is about 1.65 m up).",
        "",
        "| true offset s | noise seed | found s | σ ms | error ms | height, offset 0 m | "
        "height, auto m | height, true offset m |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
        *kitti,
        "",
        "What the data cannot fix, and run time:",
        "",
        "| case | answer |",
        "| --- | --- |",
        *limits,
        "",
        "Command: `python scripts/bench_clock_offset.py`.",
        "",
    ])
    Path(args.out).write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
