"""Reproduce the paper's Table I on synthetic sequences, beside a feature-homography baseline.

For each profile of the ``cart`` preset (static, gradual, shaking; and the weak-texture
corridor with highlights) every consecutive pair is estimated from a cold start (two frames
only, initial pitch 60°, as in the paper) with two virtual-IPM refinements. The table gives
mean (std) of the absolute errors of pitch and roll of frame k [deg] and of the travel
distance [mm] after the initial estimate and after the 1st and 2nd refinements, for the
SIFT + RANSAC homography baseline on the same frames, and (``--paper-model``) for the paper's
method as published: 7 parameters (no vertical motion), every patch weighted alike, one
refinement.

    /work/venv/bin/python scripts/bench_accuracy.py [--frames 30] [--paper-model] [--out FILE]

Prints the table and writes it (Markdown) to ``scripts/results/bench_accuracy.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.baseline import homography_baseline  # noqa: E402
from vipm_track.estimator import TwoFrameEstimator  # noqa: E402
from vipm_track.estimator_config import REFINEMENT_WEIGHTING, EstimatorConfig  # noqa: E402
from vipm_track.render import Effects  # noqa: E402
from vipm_track.rig import DEFAULT_PITCH_DEG, Rig  # noqa: E402
from vipm_track.sim import (  # noqa: E402
    PRESETS,
    make_trajectory,
    preset_texture,
    render_trajectory_frame,
)

#: (row label, profile, texture or None, effects)
ROWS = (
    ("Static", "static", None, None),
    ("Gradual", "gradual", None, None),
    ("Shaking", "shaking", None, None),
    ("Weak texture (corridor + highlights)", "static", "corridor", Effects(highlights=6)),
)
COLUMNS = (
    "Initial", "1st refine", "2nd refine", "Paper's method (7 p., uniform), 1 refine",
    "Baseline (SIFT H)",
)


@dataclass
class Errors:
    """Absolute errors per column: pitch and roll [deg], distance [mm]; failures counted."""

    pitch: dict[str, list[float]] = field(default_factory=lambda: {c: [] for c in COLUMNS})
    roll: dict[str, list[float]] = field(default_factory=lambda: {c: [] for c in COLUMNS})
    dist: dict[str, list[float]] = field(default_factory=lambda: {c: [] for c in COLUMNS})
    failed: dict[str, int] = field(default_factory=lambda: dict.fromkeys(COLUMNS, 0))

    def add(self, column: str, pose_curr, motion, truth_pose, truth_motion) -> None:
        self.pitch[column].append(abs(np.degrees(pose_curr.pitch - truth_pose.pitch)))
        self.roll[column].append(abs(np.degrees(pose_curr.roll - truth_pose.roll)))
        self.dist[column].append(abs(motion.distance - truth_motion.distance) * 1e3)


def run_row(profile: str, texture: str | None, effects: Effects | None, pairs: int, seed: int,
            paper_model: bool) -> tuple[Errors, list[float]]:
    """Errors of every column over ``pairs`` consecutive pairs; estimator total times [s]."""
    preset = PRESETS["cart"]
    traj = make_trajectory(profile, pairs + 1, preset=preset, seed=seed)
    tex = preset_texture(preset, texture, seed)
    cam = preset.camera()
    cfg = EstimatorConfig(refinements=2)
    cfg_paper = EstimatorConfig(refinements=1, vertical_motion=False, moved_ipm=False,
                                blur_invariant_ipm=False, **REFINEMENT_WEIGHTING["uniform"])
    errs = Errors()
    times = []
    prev = render_trajectory_frame(tex, cam, traj, 0, effects)
    for k in tqdm(range(1, pairs + 1), desc=f"{profile}/{texture or preset.texture}",
                  unit="pair", file=sys.stderr, leave=False):
        curr = render_trajectory_frame(tex, cam, traj, k, effects)
        h = float(traj.height[k - 1])
        truth_pose, truth_motion = traj.pose(k), traj.motion(k)
        est = TwoFrameEstimator(Rig(cam, h, DEFAULT_PITCH_DEG), cfg)
        res = est.estimate(prev, curr)
        times.append(res.timings["total"])
        for col, i in zip(COLUMNS[:3], range(3), strict=True):
            if res.ok and len(res.stage_estimates) > i:
                errs.add(col, res.stage_estimates[i].pose_curr, res.stage_estimates[i].motion,
                         truth_pose, truth_motion)
            else:
                errs.failed[col] += 1
        if paper_model:
            res7 = TwoFrameEstimator(Rig(cam, h, DEFAULT_PITCH_DEG), cfg_paper).estimate(prev, curr)
            if res7.ok:
                errs.add(COLUMNS[3], res7.pose_curr, res7.motion, truth_pose, truth_motion)
            else:
                errs.failed[COLUMNS[3]] += 1
        base = homography_baseline(prev, curr, cam, h, preset.pose(), mask=est.roi)
        if base.ok:
            errs.add(COLUMNS[4], base.pose_curr, base.motion, truth_pose, truth_motion)
        else:
            errs.failed[COLUMNS[4]] += 1
        prev = curr
    return errs, times


def _cell(values: list[float], failed: int) -> str:
    if not values:
        return f"all {failed} failed"
    text = f"{np.mean(values):.3f} ({np.std(values):.3f})"
    return text + (f" [{failed} failed]" if failed else "")


def format_table(results: list[tuple[str, Errors]], pairs: int, columns: tuple[str, ...]) -> str:
    lines = [
        f"Absolute errors, mean (std) over {pairs} cold-start pairs per row, `cart` preset "
        "(800×600, f = 729 px, h = 0.7 m, pitch 45°, 10 fps, 1.2 m/s ≈ 0.12 m/frame). "
        "Pitch and roll of frame k [deg], travel distance [mm].",
        "",
        "| Sequence | Quantity | " + " | ".join(columns) + " |",
        "|---|---|" + "---|" * len(columns),
    ]
    for label, e in results:
        for name, data in (("Pitch [deg]", e.pitch), ("Roll [deg]", e.roll),
                           ("Dist. [mm]", e.dist)):
            cells = [_cell(data[c], e.failed[c]) for c in columns]
            lines.append(f"| {label} | {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="pairs per sequence (default 30)")
    ap.add_argument("--seed", type=int, default=1, help="trajectory/texture seed")
    ap.add_argument("--paper-model", action="store_true",
                    help="add the paper's method (7 parameters, uniform weights) (slower)")
    ap.add_argument("--out", type=Path, default=ROOT / "scripts" / "results" / "bench_accuracy.md")
    args = ap.parse_args(argv)
    columns = tuple(c for c in COLUMNS if args.paper_model or c != COLUMNS[3])
    results, all_times = [], []
    t0 = time.perf_counter()
    for label, profile, texture, effects in ROWS:
        errs, times = run_row(profile, texture, effects, args.frames, args.seed,
                              args.paper_model)
        results.append((label, errs))
        all_times += times
    table = format_table(results, args.frames, columns)
    flags = f"--frames {args.frames} --seed {args.seed}" + (" --paper-model" * args.paper_model)
    footer = (
        f"\n\nEstimator (2 refinements) wall time per pair: median {np.median(all_times):.2f} s "
        f"on a shared 2-core machine (noisy); whole benchmark {time.perf_counter() - t0:.0f} s "
        f"(`{flags}`)"
        ".\n"
        "Targets (issue 4): pitch/roll ≤ 0.1°, distance ≤ 0.1 mm static and gradual; ≤ 0.2° and "
        "≤ 0.2 mm shaking; weak texture ≤ 0.3°. The paper (real rig, room): pitch 0.35°, roll "
        "0.61°, distance 0.17 mm after the 2nd refinement.\n\n"
        "Notes. \"Initial\" is the image-plane estimate (coarse-to-fine POC, LM on 50 random "
        "subsets of 60 %); the refinements are the virtual-IPM stages (the estimator's default "
        "for a steep camera is one). Beyond the paper, a steep camera's refinement estimates "
        "the camera's vertical motion within the pair (an 8th parameter; the `shaking` profile "
        "moves the camera by millimetres between frames), weights each IPM patch by its "
        "modelled noise (far-field patches, magnified by the IPM, and shrunk ones are noisier), "
        "matches patches a second time with the windows re-centred on the measured shift, and "
        "tightens its inlier threshold to 6× the inliers' median residual, and matches the IPM "
        "patches on frame k's plane moved onto frame k-1's by the estimate. The paper's method "
        "column switches all of these off. The SIFT baseline fits a full 8-DOF homography over "
        "the same region of interest.\n"
    )
    print(table + footer)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    title = "# Accuracy: the paper's Table I on synthetic sequences\n\n"
    args.out.write_text(title + table + footer)
    print(f"written to {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
