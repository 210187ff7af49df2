"""Speed of ``vipm-track estimate`` per frame pair on the ``cart`` and ``car`` presets.

Renders a few frames of each preset with ``vipm_track.sim`` first (render time excluded),
then runs the sequence runner (the code behind ``vipm-track estimate``) cold-start and in
tracking mode with 0, 1 and 2 virtual-IPM refinements. Reports, as medians over the pairs,
pairs per second, wall time per pair and the estimator's per-stage breakdown
(``PairResult.timings``: POC, warps, LM), with the share of pairs ok and the median travel
distance error against the rendered ground truth.

    python scripts/bench_speed.py [--frames 8] [--repeats 1] [--results FILE.md]

Timings on a shared machine are noisy: they are medians over all pairs of all repeats.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.estimator import EstimatorConfig, TwoFrameEstimator  # noqa: E402
from vipm_track.pipeline import config_with, run_sequence  # noqa: E402
from vipm_track.sim import PRESETS, simulate_sequence  # noqa: E402
from vipm_track.sources import ArraySource, open_source  # noqa: E402
from vipm_track.table import read_table  # noqa: E402

STAGES = ("poc", "warp", "lm")
PROFILE = {"cart": "shaking", "car": "static"}


def render(preset: str, frames: int, folder: Path) -> tuple[ArraySource, dict]:
    """Frames of a preset in memory (rendered once) and their ground-truth table."""
    simulate_sequence(preset, frames, folder, seed=1, profile=PROFILE[preset])
    frames_list = list(open_source(images=folder / "images"))
    source = ArraySource([f.image for f in frames_list], [f.t for f in frames_list], preset)
    return source, read_table(folder / "gt.csv")


def bench_case(preset: str, source: ArraySource, truth: dict, refinements: int,
               tracking: bool, repeats: int) -> dict:
    """Median timings and accuracy of one (preset, refinements, mode) case."""
    p = PRESETS[preset]
    camera = p.camera()
    config = config_with(EstimatorConfig(), refinements=refinements,
                         initial_pitch_deg=p.pitch_deg)
    estimator = TwoFrameEstimator(camera, p.height_m, config)
    wall, stages, ok, dist_err = [], {s: [] for s in STAGES}, 0, []
    pairs = 0
    for _ in range(repeats):
        for step in run_sequence(source, camera, p.height_m, config, tracking, estimator):
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
        "fps": 1.0 / med, "pair_ms": 1e3 * med,
        **{f"{s}_ms": 1e3 * float(np.nanmedian(stages[s])) for s in STAGES},
        "ok": f"{ok}/{pairs}",
        "dist_err_pct": float(np.median(dist_err)) if dist_err else float("nan"),
    }


def table(rows: list[dict]) -> str:
    head = ("| preset | mode | refinements | pairs/s | ms/pair | POC ms | warp ms | LM ms | ok "
            "| median distance error % |")
    lines = [head, "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(
            f"| {r['preset']} | {r['mode']} | {r['refinements']} | {r['fps']:.2f} | "
            f"{r['pair_ms']:.0f} | {r['poc_ms']:.0f} | {r['warp_ms']:.0f} | {r['lm_ms']:.0f} | "
            f"{r['ok']} | {r['dist_err_pct']:.2f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=8, help="frames rendered per preset")
    parser.add_argument("--repeats", type=int, default=1, help="passes over the frames")
    parser.add_argument("--presets", default="cart,car")
    parser.add_argument("--refinements", default="0,1,2")
    parser.add_argument("--results", type=Path,
                        default=ROOT / "scripts" / "results" / "bench_speed.md")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for preset in args.presets.split(","):
            source, truth = render(preset, args.frames, Path(tmp) / preset)
            for refinements in (int(r) for r in args.refinements.split(",")):
                for tracking in (False, True):
                    row = bench_case(preset, source, truth, refinements, tracking, args.repeats)
                    rows.append(row)
                    print(f"{preset} {row['mode']} r={refinements}: {row['fps']:.2f} pairs/s",
                          file=sys.stderr)
    text = (
        "# Speed of `vipm-track estimate` (sequence runner + two-frame estimator)\n\n"
        + table(rows)
        + f"\n\nMedians over {args.frames - 1} pairs × {args.repeats} pass(es) per case; "
        "ms/pair is the estimator's wall time per pair (undistortion and I/O excluded, "
        "rendering excluded); stage columns are `PairResult.timings` medians. "
        f"cart: 800×600, {PROFILE['cart']} profile; car: 1280×720, {PROFILE['car']} profile, "
        "cold start seeded with the preset's nominal pitch. "
        f"Machine: {platform.processor() or platform.machine()}, "
        f"{platform.python_implementation()} {platform.python_version()}, shared by other "
        "jobs, so timings are noisy.\n\n"
        f"Command: `python scripts/bench_speed.py --frames {args.frames} "
        f"--repeats {args.repeats}`\n"
    )
    print(text)
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
