"""Benchmark the cost of rerun logging against the two-frame estimator it records.

Renders a short simulated sequence (``vipm_track.sim``), estimates every pair once (tracking
mode, IPM images kept), then logs the same results to a rerun recording file several times:
every image (``--rerun-image-every 1``), every 10th image, and scalars only. Reports per pair
the estimator's time, the logging time, the overhead in % of the estimator time (target
≤ 10 %), and the recording size. Then the cost of an hour: the same results logged as a
30 fps recording of ``--hour-pairs`` pairs (cycled) with the default image decimation (one
pair's images every ``IMAGE_PERIOD_S`` s), every image and scalars only; the file's bytes
per pair × 108 000 pairs (target ≤ 1 GB per hour by default). Prints markdown tables and
writes them to ``scripts/results/bench_rerun.md``. Timings are medians over repeats on a
shared machine (noisy); the estimator is timed once per pair, median over pairs.

    /work/venv/bin/python scripts/bench_rerun.py [--presets cart,car] [--pairs 8] [--repeats 3]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.estimator import TwoFrameEstimator  # noqa: E402
from vipm_track.estimator_config import EstimatorConfig  # noqa: E402
from vipm_track.pair_result import PairGuess  # noqa: E402
from vipm_track.rig import Rig  # noqa: E402
from vipm_track.sim import (  # noqa: E402
    PRESETS,
    make_trajectory,
    preset_texture,
    render_trajectory_frame,
)
from vipm_track.sinks.rerun_sink import IMAGE_PERIOD_S, RerunSink  # noqa: E402

SETTINGS = (("every image", {"image_every": 1}), ("every 10th image", {"image_every": 10}),
            ("scalars only", {"image_every": 0}))
#: (label, sink options, share of --hour-pairs logged: every image is slow to log)
HOUR_SETTINGS = ((f"default (images every {IMAGE_PERIOD_S:g} s)", {"image_every": None}, 1.0),
                 ("every image (--rerun-all-images)", {"image_every": 1}, 0.1),
                 ("scalars only", {"image_every": 0}, 1.0))
HOUR_FPS = 30.0


def hour_bytes(images: list, results: list, options: dict, pairs: int) -> float:
    """Bytes of an hour's recording at ``HOUR_FPS``: ``pairs`` pairs logged (the results
    cycled, timestamps at the frame rate) and their file's size scaled to 3600 s."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "hour.rrd"
        sink = RerunSink.to_file(path, **options)
        for k in range(1, pairs + 1):
            i = (k - 1) % len(results)
            sink.log_pair(k, k / HOUR_FPS, results[i], images[i + 1])
        sink.finish()
        size = path.stat().st_size
    return size / pairs * HOUR_FPS * 3600.0


def estimate_pairs(preset_name: str, pairs: int, seed: int) -> tuple[list, list, list[float]]:
    """Images, pair results (tracking, IPM images kept) and estimator seconds per pair."""
    preset = PRESETS[preset_name]
    camera = preset.camera()
    traj = make_trajectory("shaking", pairs + 1, preset=preset, seed=seed)
    texture = preset_texture(preset, seed=seed)
    images = [render_trajectory_frame(texture, camera, traj, k) for k in range(pairs + 1)]
    config = EstimatorConfig(keep_images=True)
    est = TwoFrameEstimator(Rig(camera, preset.height_m, preset.pitch_deg), config)
    results, seconds, previous = [], [], None
    for k in range(1, pairs + 1):
        guess = PairGuess.from_previous(previous) if previous is not None else None
        start = time.perf_counter()
        result = est.estimate(images[k - 1], images[k], guess)
        seconds.append(time.perf_counter() - start)
        results.append(result)
        previous = result
    return images, results, seconds


def log_seconds(images: list, results: list, options: dict, repeats: int) -> tuple[float, int]:
    """Median over repeats of the logging time per pair [s] (finish included), file bytes."""
    times, size = [], 0
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            path = Path(tmp) / f"run{r}.rrd"
            start = time.perf_counter()
            sink = RerunSink.to_file(path, **options)
            for k, result in enumerate(results, start=1):
                sink.log_pair(k, 0.1 * k, result, images[k])
            sink.finish()
            times.append((time.perf_counter() - start) / len(results))
            size = path.stat().st_size
    return statistics.median(times), size


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--presets", default="cart,car")
    parser.add_argument("--pairs", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--hour-pairs", type=int, default=1800,
                        help="pairs logged to measure an hour's recording (default 1800: 60 s)")
    parser.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_rerun.md"))
    args = parser.parse_args()

    lines = [
        "| preset | pairs ok | estimator ms/pair | logging | logging ms/pair | overhead % "
        "| recording KiB/pair |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    hour = [f"| preset | images | pairs logged | GB per hour at {HOUR_FPS:g} fps |",
            "| --- | --- | --- | --- |"]
    for name in args.presets.split(","):
        images, results, seconds = estimate_pairs(name, args.pairs, args.seed)
        for label, options, share in HOUR_SETTINGS:
            pairs = max(len(results), int(share * args.hour_pairs))
            size = hour_bytes(images, results, options, pairs)
            hour.append(f"| {name} | {label} | {pairs} | {size / 1e9:.2f} |")
            print(hour[-1], file=sys.stderr)
        est_ms = 1000 * statistics.median(seconds)
        n_ok = sum(r.status == "ok" for r in results)
        for label, options in SETTINGS:
            log_s, size = log_seconds(images, results, options, args.repeats)
            lines.append(
                f"| {name} | {n_ok}/{len(results)} | {est_ms:.0f} | {label} | "
                f"{1000 * log_s:.1f} | {100 * 1000 * log_s / est_ms:.1f} | "
                f"{size / 1024 / len(results):.0f} |"
            )
            print(lines[-1], file=sys.stderr)
    header = (
        "# rerun logging overhead\n\n"
        f"Logging of the same pair results (tracking, IPM images kept) to an .rrd file, "
        f"median of {args.repeats} repeats, against the estimator's median time per pair. "
        f"Shared {platform.machine()} machine, Python {platform.python_version()}: noisy.\n"
        "Images: JPEG quality 75, longer side ≤ 800 px (camera and both IPM images).\n\n"
    )
    table = header + "\n".join(lines) + "\n" + (
        "\n## The cost of an hour\n\n"
        f"The same pair results logged as a {HOUR_FPS:g} fps recording (per pair: the pose and "
        "motion series, quality, stage timings, and the images where the setting logs them); "
        "the file's bytes per pair × 3600 s × the frame rate. Target: ≤ 1 GB per hour by "
        "default.\n\n" + "\n".join(hour) + "\n")
    print(table)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
