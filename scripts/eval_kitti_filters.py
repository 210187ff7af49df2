"""The filters on real data: KITTI 07's per-pair estimates through ``vipm-track track`` (EKF)
and ``vipm-track smooth`` (fixed-lag 2 s and batch, each also with ``--motion-given-pose``),
against ``poses.txt``.

Reads the estimates tables ``scripts/eval_kitti.py --seeds N`` writes (one per subset-sampler
seed), runs each filter through the CLI as a user would (no wheel speed: KITTI 07 has none, so
the height stays at the nominal 1.65 m) and scores the filtered per-frame motion as
``eval_kitti`` scores the pairs: travel-distance error (% of the true distance) and yaw-change
error over the frames with status ok. The pairs' own row is the baseline.

    python scripts/eval_kitti_filters.py [--data ../shared/data/kitti07]
        [--estimates out/kitti/estimates.csv out/kitti/estimates_seed1.csv ...]
        [--out scripts/results/kitti_filters.md]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from eval_kitti import KITTI_HEIGHT, evaluate, existing_tables, seed_tables, write_results  # noqa: E402

from vipm_track.cli import main as cli_main  # noqa: E402

#: method → the CLI arguments after ``--estimates EST --height H --out OUT``
METHODS: dict[str, list[str]] = {
    "EKF (`track`)": ["track"],
    "fixed-lag 2 s (`smooth --lag 2`)": ["smooth", "--lag", "2"],
    "batch (`smooth`)": ["smooth"],
    "fixed-lag 2 s, motion given pose (`smooth --lag 2 --motion-given-pose`)":
        ["smooth", "--lag", "2", "--motion-given-pose"],
    "batch, motion given pose (`smooth --motion-given-pose`)":
        ["smooth", "--motion-given-pose"],
}


def run_method(args: list[str], est: Path, out: Path) -> None:
    command, *options = args
    rc = cli_main([command, "--estimates", str(est), "--height", str(KITTI_HEIGHT),
                   "--out", str(out), "--quiet", *options])
    if rc != 0:
        raise SystemExit(f"vipm-track {command} failed on {est} (exit {rc})")


def _scored(errors: dict, headline: dict) -> dict:
    """``headline`` with ``ok`` = the frames scored (status ok and in the truth)."""
    return {**headline, "ok": int(errors["frame"].size)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "kitti07"))
    ap.add_argument("--estimates", nargs="+", default=seed_tables(ROOT / "out" / "kitti"))
    ap.add_argument("--out", default=str(ROOT / "scripts" / "results" / "kitti_filters.md"))
    args = ap.parse_args(argv)
    data = Path(args.data)
    ests = existing_tables(args.estimates)
    rows: dict[str, list[dict]] = {"pairs (`estimate`)": []}
    seconds: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, est in enumerate(ests):
            rows["pairs (`estimate`)"].append(_scored(*evaluate(est, data)))
            for name, cli in METHODS.items():
                out = Path(tmp) / f"{i}_{'_'.join(a.strip('-') for a in cli)}.csv"
                t0 = time.perf_counter()
                run_method(cli, est, out)
                seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - t0
                rows.setdefault(name, []).append(_scored(*evaluate(out, data)))

    lines = [
        "# KITTI odometry 07: the filters on the per-pair estimates",
        "",
        f"Travel-distance and yaw-change errors of the filtered per-frame motion against "
        f"`poses.txt`, frames with status ok, mean over {len(ests)} estimates tables "
        "(subset-sampler seeds) of `scripts/eval_kitti.py`; no wheel speed (height nominal).",
        "",
        "| method | frames ok | distance err median | mean | p95 | bias | yaw median |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, heads in rows.items():
        def mean(key: str, heads: list[dict] = heads) -> float:
            return float(np.mean([h[key] for h in heads]))
        lines.append(
            f"| {name} | {mean('ok'):.0f}/{mean('pairs'):.0f} | "
            f"{mean('distance_pct_median'):.2f} % | {mean('distance_pct_mean'):.2f} % | "
            f"{mean('distance_pct_p95'):.2f} % | {mean('distance_bias_pct'):+.2f} % | "
            f"{mean('yaw_deg_median'):.3f}° |"
        )
    lines += [
        "",
        "Run time of the filters through the CLI (all tables, 2 shared cores): "
        + ", ".join(f"{name.split(' (')[0]} {sec:.1f} s" for name, sec in seconds.items())
        + ".",
    ]
    write_results(lines, args.out, "eval_kitti_filters.py")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
