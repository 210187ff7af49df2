"""Benchmark ``vipm-track live`` on this machine: a rendered cart drive (320×240, the
``knock`` profile: mount pitch +1° at 40 % of the drive) encoded as an MJPG video and played
in real time (``run_live(..., realtime=True)``) with its wheel speed replayed beside it, at
10, 20 and 30 fps. Reports per run: processed pairs per second, frames dropped, CPU share
(process CPU time over wall time; 100 % = one core), latency from frame arrival to row
p50 / p95, how long after the knock RECALIBRATE came, flags before the knock, and how long
after the video's last frame the run ended. Prints a markdown table and writes it to
``scripts/results/bench_live.md``. One run per setting on a shared machine: noisy.

    python scripts/bench_live.py [--fps 10,20,30] [--seconds 14] [--seeds 7]
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from vipm_track.camera import load_camera  # noqa: E402
from vipm_track.filters.nominal import load_nominal  # noqa: E402
from vipm_track.filters.wheel_speed import read_speed_csv  # noqa: E402
from vipm_track.live_run import run_live  # noqa: E402
from vipm_track.resources import data_path  # noqa: E402
from vipm_track.sim import PRESETS, knock_time, simulate_sequence  # noqa: E402
from vipm_track.table import read_table  # noqa: E402

FLAGS = ("DRIFTING", "RECALIBRATE", "INVALID")


def render(folder: Path, fps: float, seconds: float, seed: int) -> Path:
    """Render the drive into ``folder`` and encode it as ``drive.avi``; its path."""
    preset = dataclasses.replace(PRESETS["cart"], name="cart_320", width=320, height=240,
                                 fx=729.0 * 320 / 800)
    simulate_sequence(preset, round(seconds * fps), folder, seed=seed, profile="knock",
                      fps=fps)
    video = folder / "drive.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), fps,
                             (preset.width, preset.height))
    for f in sorted((folder / "images").glob("*.png")):
        writer.write(cv2.imread(str(f)))
    writer.release()
    return video


def run_once(folder: Path, video: Path, fps: float, seconds: float) -> dict:
    out = folder / "live.csv"
    start = time.monotonic()
    nominal = load_nominal(data_path("nominal_cart.yaml"))
    stats = run_live(str(video), nominal.rig(load_camera(folder / "camera.yaml")),
                     nominal, out, realtime=True,
                     speed=read_speed_csv(folder / "speed.csv"), quiet=True,
                     stdout=io.StringIO())
    wall = time.monotonic() - start
    rows = read_table(out)
    t = np.asarray(rows["t"], dtype=float)
    state = np.asarray(rows["monitor_state"], dtype=object)
    knock = knock_time(np.arange(round(seconds * fps)) / fps)
    recal = t[(state == "RECALIBRATE") & (t >= knock)]
    early = int(np.sum(np.isin(state, FLAGS) & (t < knock)))
    return {"fps": fps, "pairs_s": stats.processed / stats.wall_s, "seen": stats.seen,
            "processed": stats.processed, "dropped": stats.dropped,
            "cpu": 100 * stats.cpu_share, "p50": 1e3 * stats.latency(0.5),
            "p95": 1e3 * stats.latency(0.95),
            "flag": float(recal[0] - knock) if recal.size else float("nan"),
            "early": early, "tail": stats.tail_s, "wall": wall, "video": seconds}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fps", default="10,20,30")
    parser.add_argument("--seconds", type=float, default=14.0)
    parser.add_argument("--seeds", default="7")
    parser.add_argument("--out", default=str(ROOT / "scripts/results/bench_live.md"))
    args = parser.parse_args()
    results = []
    for seed in [int(s) for s in args.seeds.split(",")]:
        for fps in [float(f) for f in args.fps.split(",")]:
            with tempfile.TemporaryDirectory() as tmp:
                folder = Path(tmp)
                video = render(folder, fps, args.seconds, seed)
                r = run_once(folder, video, fps, args.seconds)
                r["seed"] = seed
                results.append(r)
                print(r, file=sys.stderr)
    lines = [
        "# live monitoring in real time",
        "",
        f"A rendered cart drive (320×240, mount pitch +1° at 40 % of {args.seconds:g} s) "
        "played as an MJPG video at its frame rate with its wheel speed replayed beside it "
        "(`run_live(..., realtime=True)`), one run per row. Shared "
        f"{platform.machine()} machine, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}: noisy. CPU: process CPU time over wall time "
        "(100 % = one core). Latency: frame arrival → row (the first 5 rows wait for the "
        "monitor's frame rate to be measured). Flag: first RECALIBRATE after the step; "
        "early: flagged frames before it. Ended: seconds after the video's last frame.",
        "",
        "| fps | seed | frames | pairs processed | pairs/s | dropped | CPU % | latency p50 ms "
        "| latency p95 ms | flag after step s | early flags | ended after video s |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        lines.append(
            f"| {r['fps']:g} | {r['seed']} | {r['seen']} | {r['processed']} | "
            f"{r['pairs_s']:.2f} | {r['dropped']} | {r['cpu']:.0f} | {r['p50']:.0f} | "
            f"{r['p95']:.0f} | {r['flag']:.2f} | {r['early']} | {r['tail']:.2f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
