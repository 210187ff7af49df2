"""Benchmark of the synthetic-sequence renderer: speed and ground-truth consistency.

Prints a markdown table and writes it to ``scripts/results/sim.md``.

- Speed: median wall time per rendered frame over repeats (noisy on a shared machine: the
  median of ``--repeats`` renders is quoted), per preset, clean and with all effects.
- GT consistency: frame k rendered, brought back into frame k-1 with the ground-truth pair
  homography, and registered against frame k-1 with ECC (translation) on 64×64 windows; the
  residual should be far below a pixel. Median and 95th percentile over windows and pairs.

Usage: ``python scripts/bench_sim.py [--repeats 15] [--pairs 4]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from vipm_track import geometry as g
from vipm_track.render import Effects
from vipm_track.sim import PRESETS, make_trajectory, preset_texture, render_trajectory_frame
from vipm_track.texture import load_texture

ALL_EFFECTS = Effects(noise_sigma=2.0, exposure_drift=0.15, vignetting=0.8, highlights=3,
                      motion_blur=0.3, obstacle=True)


def render_times(preset: str, repeats: int, effects: Effects | None) -> float:
    p = PRESETS[preset]
    camera, tex = p.camera(), preset_texture(p)
    traj = make_trajectory("shaking", repeats + 1, preset=p, seed=0)
    times = []
    for k in range(1, repeats + 1):
        t0 = time.perf_counter()
        render_trajectory_frame(tex, camera, traj, k, effects)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def gt_residuals(preset: str, profile: str, pairs: int, window: int = 64) -> np.ndarray:
    p = PRESETS[preset]
    camera, tex = p.camera(), preset_texture(p)
    traj = make_trajectory(profile, pairs + 1, preset=p, seed=11)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    out = []
    prev = render_trajectory_frame(tex, camera, traj, 0).astype(np.float32)
    top = camera.height * (0.6 if preset == "car" else 0.12)
    for k in range(1, pairs + 1):
        curr = render_trajectory_frame(tex, camera, traj, k).astype(np.float32)
        pose0, pose1, motion = traj.pose(k - 1), traj.pose(k), traj.motion(k)
        h01 = g.pair_homography(camera.k, pose0, pose1, motion)
        warped = cv2.warpPerspective(curr, h01, (camera.width, camera.height),
                                     flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        u, v = np.meshgrid(np.linspace(60, camera.width - 60, 10),
                           np.linspace(top, camera.height - 60, 6))
        for x, y in np.stack([u.ravel(), v.ravel()], axis=1).astype(int):
            half = window // 2 + 4
            corners = np.array([[x - half, y - half], [x + half, y - half], [x - half, y + half],
                                [x + half, y + half]], float)
            c1 = g.predict_pixels(camera.k, pose0, pose1, motion, corners)
            if not (np.all(np.isfinite(c1)) and np.all((c1 > 0) & (c1 < [camera.width - 1,
                                                                          camera.height - 1]))):
                continue
            sl = np.s_[y - window // 2:y + window // 2, x - window // 2:x + window // 2]
            warp = np.eye(2, 3, dtype=np.float32)
            try:
                _, warp = cv2.findTransformECC(prev[sl], warped[sl], warp,
                                               cv2.MOTION_TRANSLATION, criteria, None, 1)
            except cv2.error:
                continue
            out.append(np.hypot(*warp[:, 2]))
        prev = curr
    return np.array(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--pairs", type=int, default=4)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "sim.md"))
    args = parser.parse_args()

    lines = ["# Synthetic sequences: renderer benchmark", "",
             f"Median over {args.repeats} frames per row (shared 2-core machine, noisy).", "",
             "| preset | size | texture build [s] | render clean [ms] | render all effects [ms] |",
             "| --- | --- | --- | --- | --- |"]
    for preset in ("cart", "car"):
        p = PRESETS[preset]
        load_texture.cache_clear()
        t0 = time.perf_counter()
        preset_texture(p)
        build = time.perf_counter() - t0
        clean = render_times(preset, args.repeats, None)
        fx = render_times(preset, args.repeats, ALL_EFFECTS)
        lines.append(f"| {preset} | {p.width}×{p.height} | {build:.2f} | {1e3 * clean:.1f} | "
                     f"{1e3 * fx:.1f} |")
    lines += ["", "Ground-truth consistency (residual after the GT pair homography, ECC on "
              "64×64 windows, px):", "",
              "| preset | profile | windows | median | p95 | max |",
              "| --- | --- | --- | --- | --- | --- |"]
    for preset, profile in (("cart", "static"), ("cart", "shaking"), ("cart", "turn"),
                            ("cart", "height"), ("car", "gradual"), ("car", "turn")):
        r = gt_residuals(preset, profile, args.pairs)
        lines.append(f"| {preset} | {profile} | {len(r)} | {np.median(r):.4f} | "
                     f"{np.percentile(r, 95):.4f} | {r.max():.4f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
