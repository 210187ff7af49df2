"""Speed of ``vipm-track estimate`` per frame pair on the ``cart`` and ``car`` presets.

Renders a few frames of each preset with ``vipm_track.sim`` first (render time excluded),
then runs the sequence runner (the code behind ``vipm-track estimate``) cold-start and in
tracking mode with 0, 1 and 2 virtual-IPM refinements. Reports, as medians over the pairs,
pairs per second, wall time per pair and the estimator's per-stage breakdown
(``PairResult.timings``: POC, warps, LM), with the share of pairs ok and the median travel
distance error against the rendered ground truth. Rows with a readout time are the same
preset rendered with a rolling shutter (``--readout``, a fraction of the frame interval)
and estimated with that readout (``--readout-time``), tracking mode.

A second table gives the cost of ``--rerun`` logging (``vipm_track.sinks.rerun_sink``) in
tracking mode with the estimator's default refinements: the same steps the runner yields,
with their images (an ``ImageTap``, as the commands do), logged to an .rrd file with every
image and with every 10th image; overhead = logging time (flush included) / estimator time,
summed over the pairs (target ≤ 10 %).

    python scripts/bench_speed.py [--frames 8] [--repeats 1] [--log-every 1,10]
                                  [--readout 0.66] [--out FILE.md]

Timings on a shared machine are noisy: they are medians over all pairs of all repeats.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.allocator import keep_freed_memory  # noqa: E402
from vipm_track.estimator import TwoFrameEstimator  # noqa: E402
from vipm_track.estimator_config import EstimatorConfig  # noqa: E402
from vipm_track.pipeline import run_sequence  # noqa: E402
from vipm_track.render import Effects  # noqa: E402
from vipm_track.rig import Rig  # noqa: E402
from vipm_track.sim import PRESETS, simulate_sequence  # noqa: E402
from vipm_track.sinks.rerun_sequence import ImageTap  # noqa: E402
from vipm_track.sinks.rerun_sink import RerunSink  # noqa: E402
from vipm_track.sources import ArraySource, open_source  # noqa: E402
from vipm_track.table import read_table  # noqa: E402

STAGES = ("poc", "warp", "lm")
PROFILE = {"cart": "shaking", "car": "static"}


def render(preset: str, frames: int, folder: Path, readout: float = 0.0,
           ) -> tuple[ArraySource, dict]:
    """Frames of a preset in memory (rendered once; ``readout``: a rolling shutter's, in
    frame intervals) and their ground-truth table."""
    simulate_sequence(preset, frames, folder, seed=1, profile=PROFILE[preset],
                      effects=Effects(rolling_shutter=readout) if readout else None)
    frames_list = list(open_source(images=folder / "images"))
    source = ArraySource([f.image for f in frames_list], [f.t for f in frames_list], preset)
    return source, read_table(folder / "gt.csv")


def bench_case(preset: str, source: ArraySource, truth: dict, refinements: int,
               tracking: bool, repeats: int, readout_s: float = 0.0) -> dict:
    """Median timings and accuracy of one (preset, refinements, mode, readout) case."""
    p = PRESETS[preset]
    camera = p.camera()
    config = EstimatorConfig(refinements=refinements)
    rig = Rig(camera, p.height_m, p.pitch_deg, readout_s=readout_s)
    estimator = TwoFrameEstimator(rig, config)
    wall, stages, ok, dist_err = [], {s: [] for s in STAGES}, 0, []
    pairs = 0
    for _ in range(repeats):
        for step in run_sequence(source, rig, config, tracking, estimator):
            if step.result is None:
                continue
            pairs += 1
            wall.append(step.seconds)
            for s in STAGES:
                stages[s].append(step.result.timings.get(s, np.nan))
            if step.ok:
                ok += 1
                m = step.result.motion
                k = int(np.flatnonzero(truth["frame"] == step.frame)[0])
                d_true = math.hypot(truth["tx_m"][k], truth["tz_m"][k])
                dist_err.append(100.0 * abs(m.distance - d_true) / d_true)
    med = float(np.median(wall))
    return {
        "preset": preset, "mode": "tracking" if tracking else "cold", "refinements": refinements,
        "readout_ms": 1e3 * readout_s, "fps": 1.0 / med, "pair_ms": 1e3 * med,
        **{f"{s}_ms": 1e3 * float(np.nanmedian(stages[s])) for s in STAGES},
        "ok": f"{ok}/{pairs}",
        "dist_err_pct": float(np.median(dist_err)) if dist_err else float("nan"),
    }


def bench_logging(preset: str, source: ArraySource, image_every: int, repeats: int,
                  folder: Path) -> dict:
    """Estimator and rerun-logging time of a tracking run (``EstimatorConfig`` defaults, IPM
    images kept), logging every ``image_every``-th pair's images; sums over all pairs."""
    p = PRESETS[preset]
    camera = p.camera()
    config, rig = EstimatorConfig(keep_images=True), Rig(camera, p.height_m, p.pitch_deg)
    estimator = TwoFrameEstimator(rig, config)
    est_s = log_s = 0.0
    pairs = size = 0
    for r in range(repeats):
        path = folder / f"{preset}_{image_every}_{r}.rrd"
        sink = RerunSink.to_file(path, image_every=image_every)
        tap = ImageTap(source, camera)
        for step in run_sequence(tap, rig, config, True, estimator):
            start = time.perf_counter()
            sink.log_step(step, tap.image(step.frame))
            log_s += time.perf_counter() - start
            est_s += step.seconds
            pairs += step.result is not None
        start = time.perf_counter()
        sink.finish()
        log_s += time.perf_counter() - start
        size += path.stat().st_size
    return {
        "preset": preset, "logging": "every image" if image_every == 1
        else f"every {image_every}th image" if image_every else "scalars only",
        "pairs": pairs, "est_ms": 1e3 * est_s / max(pairs, 1),
        "log_ms": 1e3 * log_s / max(pairs, 1),
        "overhead_pct": 100.0 * log_s / est_s if est_s > 0 else float("nan"),
        "kib_per_pair": size / 1024 / max(pairs, 1),
    }


def logging_table(rows: list[dict]) -> str:
    lines = ["| preset | logging | pairs | estimator ms/pair | logging ms/pair | overhead % "
             "| recording KiB/pair |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['preset']} | {r['logging']} | {r['pairs']} | {r['est_ms']:.0f} | "
                     f"{r['log_ms']:.1f} | {r['overhead_pct']:.1f} | {r['kib_per_pair']:.0f} |")
    return "\n".join(lines)


def table(rows: list[dict]) -> str:
    head = ("| preset | mode | refinements | readout ms | pairs/s | ms/pair | POC ms | warp ms "
            "| LM ms | ok | median distance error % |")
    lines = [head, "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(
            f"| {r['preset']} | {r['mode']} | {r['refinements']} | {r['readout_ms']:.0f} | "
            f"{r['fps']:.2f} | {r['pair_ms']:.0f} | {r['poc_ms']:.0f} | {r['warp_ms']:.0f} | "
            f"{r['lm_ms']:.0f} | {r['ok']} | {r['dist_err_pct']:.2f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=8, help="frames rendered per preset")
    parser.add_argument("--repeats", type=int, default=1, help="passes over the frames")
    parser.add_argument("--presets", default="cart,car")
    parser.add_argument("--refinements", default="0,1,2")
    parser.add_argument("--readout", type=float, default=0.66,
                        help="rolling-shutter rows: readout as a fraction of the frame "
                             "interval (0: none)")
    parser.add_argument("--log-every", default="1,10",
                        help="rerun logging rows: image decimations to time ('' for none)")
    parser.add_argument("--out", type=Path,
                        default=ROOT / "scripts" / "results" / "bench_speed.md")
    args = parser.parse_args(argv)
    keep_freed_memory()  # as the command line does
    rows, log_rows = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for preset in args.presets.split(","):
            source, truth = render(preset, args.frames, Path(tmp) / preset)
            for refinements in (int(r) for r in args.refinements.split(",")):
                for tracking in (False, True):
                    row = bench_case(preset, source, truth, refinements, tracking, args.repeats)
                    rows.append(row)
                    print(f"{preset} {row['mode']} r={refinements}: {row['fps']:.2f} pairs/s",
                          file=sys.stderr)
            if args.readout:
                readout_s = args.readout / PRESETS[preset].fps
                rs_source, rs_truth = render(preset, args.frames, Path(tmp) / f"{preset}_rs",
                                             args.readout)
                for refinements in (int(r) for r in args.refinements.split(",")):
                    row = bench_case(preset, rs_source, rs_truth, refinements, True,
                                     args.repeats, readout_s)
                    rows.append(row)
                    print(f"{preset} rolling shutter r={refinements}: {row['fps']:.2f} pairs/s",
                          file=sys.stderr)
            for every in (int(n) for n in args.log_every.split(",") if n.strip()):
                row = bench_logging(preset, source, every, args.repeats, Path(tmp))
                log_rows.append(row)
                print(f"{preset} logging {row['logging']}: {row['overhead_pct']:.1f} %",
                      file=sys.stderr)
    text = (
        "# Speed of `vipm-track estimate` (sequence runner + two-frame estimator)\n\n"
        + table(rows)
        + f"\n\nMedians over {args.frames - 1} pairs × {args.repeats} pass(es) per case; "
        "ms/pair is the estimator's wall time per pair (undistortion and I/O excluded, "
        "rendering excluded); stage columns are `PairResult.timings` medians. "
        f"cart: 800×600, {PROFILE['cart']} profile; car: 1280×720, {PROFILE['car']} profile, "
        "cold start seeded with the preset's nominal pitch. Readout ms > 0: the preset rendered "
        f"with a rolling shutter of {args.readout:g} frame intervals and estimated with that "
        "`--readout-time` (the cart's shaking pose changes faster than the frame rate "
        "resolves, which the rolling-shutter model does not cover: its distance error is that "
        "limitation, see bench_rolling_shutter.md). "
        f"Machine: {platform.processor() or platform.machine()}, "
        f"{platform.python_implementation()} {platform.python_version()}, shared by other "
        "jobs, so timings are noisy.\n\n"
        f"Command: `python scripts/bench_speed.py --frames {args.frames} "
        f"--repeats {args.repeats} --readout {args.readout:g}`\n"
    )
    if log_rows:
        text += (
            "\n## Cost of `--rerun` logging\n\n" + logging_table(log_rows)
            + "\n\nTracking mode, the estimator's default refinements, IPM images kept; the "
            "runner's steps and their images logged with `RerunSink.log_step` to an .rrd file "
            "(JPEG quality 75, longer side ≤ 800 px; camera image with patches and arrows, "
            "both IPM images, series, timings). ms/pair: totals over all pairs and passes "
            "divided by the pairs (logging includes the final flush); overhead = logging / "
            "estimator time (target ≤ 10 %). Every 10th image over few pairs logs a larger "
            "share of images than over a long run, so its row is an upper bound.\n"
        )
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
