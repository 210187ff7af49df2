"""Speed of the factor-graph smoother (estimation excluded) on a long simulated drive.

Times ``filters.smoother.smooth_batch`` (graph build, Gauss–Newton, marginals + output) and
the fixed-lag smoother (``filters.fixed_lag``: sliding-window Gauss–Newton, per-frame marginal
covariances) on a ``drive_sim`` car drive, median of ``--repeats`` runs, and the EKF on the
same measurements for reference. Prints a table and writes it as Markdown.

    python scripts/bench_smoother.py [--minutes 10] [--lag-minutes 10] [--repeats 3] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.filters.drive_sim import DriveConfig, simulate_drive  # noqa: E402
from vipm_track.filters.ekf import run_filter  # noqa: E402
from vipm_track.filters.ekf_state import EkfConfig  # noqa: E402
from vipm_track.filters.fixed_lag import FixedLagSmoother  # noqa: E402
from vipm_track.filters.smoother import smooth_batch  # noqa: E402
from vipm_track.filters.smoother_config import SmootherConfig  # noqa: E402
from vipm_track.filters.smoothing import speeds_at_frames  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="drive length for the batch")
    ap.add_argument("--lag-minutes", type=float, default=10.0, help="drive length, fixed lag")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_smoother.md"))
    args = ap.parse_args(argv)

    run = simulate_drive(
        DriveConfig.preset(
            "car", duration_s=60 * args.minutes, height_m=1.53, height_assumed_m=1.5
        ),
        0,
    )
    ms = run.measurements
    sp = speeds_at_frames(ms, run.speed)
    n = len(ms)
    rows = []
    #: (marginals, motion given the angles): the default, without marginals, with the option
    variants = ((True, False), (False, False), (True, True))

    def label(base: str, marg: bool, given: bool) -> str:
        return (base + ("" if marg else " (no marginals)")
                + (", `--motion-given-pose`" if given else ""))

    for marg, given in variants:
        cfg = SmootherConfig(height_m=1.5, noise=run.config.noise, marginals=marg,
                             motion_given_pose=given)
        stages: dict[str, list[float]] = {}
        totals, iters = [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            _, info = smooth_batch(ms, sp, cfg)
            totals.append(time.perf_counter() - t0)
            iters.append(info.iterations)
            for k, v in info.timings.items():
                stages.setdefault(k, []).append(v)
        med = float(np.median(totals))
        detail = ", ".join(f"{k} {1e3 * np.median(v) / n:.3f}" for k, v in stages.items())
        rows.append(
            (
                label("batch", marg, given),
                n,
                med,
                n / med,
                f"GN iterations {int(np.median(iters))}; ms/frame: {detail}",
            )
        )

    n_lag = min(round(60 * args.lag_minutes * run.config.fps) + 1, n)
    lag_ms = ms[:n_lag]
    for lag in (2.0, 5.0):
        for marg, given in variants if lag == 2.0 else variants[:2]:
            totals = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                sm = FixedLagSmoother(
                    SmootherConfig(height_m=1.5, noise=run.config.noise, lag_s=lag, marginals=marg,
                                   motion_given_pose=given)
                )
                for m, v in zip(lag_ms, sp[:n_lag], strict=True):
                    sm.step(m, float(v))
                sm.finish()
                totals.append(time.perf_counter() - t0)
            med = float(np.median(totals))
            rows.append(
                (
                    label(f"fixed-lag {lag:g} s", marg, given),
                    n_lag,
                    med,
                    n_lag / med,
                    f"sliding window of {round(lag * run.config.fps) + 1} frames, Gauss–Newton "
                    "warm-started per frame" + (", marginal covariance per frame" if marg else ""),
                )
            )

    totals = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        run_filter(ms, run.speed, EkfConfig(height_m=1.5, noise=run.config.noise))
        totals.append(time.perf_counter() - t0)
    med = float(np.median(totals))
    rows.append(("EKF (reference)", n, med, n / med, ""))

    lines = [
        f"Smoother speed on a simulated car drive (20 fps, wheel speed), median of "
        f"{args.repeats} runs on a shared 2-core machine (noisy). Target: ≥ 500 frames/s.",
        "",
        "| method | frames | seconds | frames / s | notes |",
        "| --- | --- | --- | --- | --- |",
    ]
    for name, frames, sec, fps, note in rows:
        lines.append(f"| {name} | {frames} | {sec:.2f} | {fps:.0f} | {note} |")
    text = "\n".join(lines) + "\n"
    print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("# Smoother speed\n\n" + text)
    print(f"written {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
