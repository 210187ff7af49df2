"""Benchmark the cost of rerun logging against the two-frame estimator it records.

Renders a short simulated sequence (``vipm_track.sim``), estimates every pair once (tracking
mode, IPM images kept), then logs the same results to a rerun recording file several times:
every image (``--rerun-image-every 1``), every 10th image, and scalars only. Reports per pair
the estimator's time, the logging time, the overhead in % of the estimator time (target
≤ 10 %), and the recording size. Prints a markdown table and writes it to
``scripts/results/bench_rerun.md``. Timings are medians over repeats on a shared machine
(noisy); the estimator is timed once per pair, median over pairs.

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
from vipm_track.sim import (  # noqa: E402
    PRESETS,
    make_trajectory,
    preset_texture,
    render_trajectory_frame,
)
from vipm_track.sinks.rerun_sink import RerunSink  # noqa: E402

SETTINGS = (("every image", {"image_every": 1}), ("every 10th image", {"image_every": 10}),
            ("scalars only", {"image_every": 0}))


def estimate_pairs(preset_name: str, pairs: int, seed: int) -> tuple[list, list, list[float]]:
    """Images, pair results (tracking, IPM images kept) and estimator seconds per pair."""
    preset = PRESETS[preset_name]
    camera = preset.camera()
    traj = make_trajectory("shaking", pairs + 1, preset=preset, seed=seed)
    texture = preset_texture(preset, seed=seed)
    images = [render_trajectory_frame(texture, camera, traj, k) for k in range(pairs + 1)]
    config = EstimatorConfig(keep_images=True, initial_pitch_deg=preset.pitch_deg)
    est = TwoFrameEstimator(camera, preset.height_m, config)
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
    parser.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_rerun.md"))
    args = parser.parse_args()

    lines = [
        "| preset | pairs ok | estimator ms/pair | logging | logging ms/pair | overhead % "
        "| recording KiB/pair |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name in args.presets.split(","):
        images, results, seconds = estimate_pairs(name, args.pairs, args.seed)
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
    table = header + "\n".join(lines) + "\n"
    print(table)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
