"""Speed of the factor-graph smoother (estimation excluded) on a long simulated drive.

Times ``filters.smoother.smooth_batch`` (graph build, iSAM2 Gauss–Newton, marginals +
output) and the fixed-lag smoother (``filters.fixed_lag``: gtsam's
``IncrementalFixedLagSmoother``, per-frame joint marginal covariances; where its time goes)
on a ``drive_sim`` car drive, median of ``--repeats`` runs, and the EKF on the same
measurements for reference; and one iteration of gtsam's ``LevenbergMarquardtOptimizer`` on
the batch's graph of short drives, against one iSAM2 step (why the batch runs on iSAM2).
Prints a table and writes it as Markdown.

    python scripts/bench_smoother.py [--minutes 10] [--lag-minutes 10] [--repeats 3] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import vipm_track.filters.smoother as smoother_module  # noqa: E402
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
            stages = {}
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
                for k, v in sm.timings.items():
                    stages.setdefault(k, []).append(v)
            med = float(np.median(totals))
            detail = ", ".join(f"{k} {1e3 * np.median(v) / n_lag:.3f}" for k, v in stages.items()
                               if k != "marginals" or marg)
            rows.append(
                (
                    label(f"fixed-lag {lag:g} s", marg, given),
                    n_lag,
                    med,
                    n_lag / med,
                    f"window of {round(lag * run.config.fps) + 1}+ frames, up to "
                    f"{SmootherConfig().lag_max_iterations} iSAM2 "
                    f"updates per frame; ms/frame: {detail}",
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
        f"{args.repeats} runs on a shared 2-core machine (noisy: the EKF's row says how busy "
        "it was). Target: ≥ 300 frames/s (ten times real time at 30 fps).",
        "",
        "| method | frames | seconds | frames / s | notes |",
        "| --- | --- | --- | --- | --- |",
    ]
    for name, frames, sec, fps, note in rows:
        lines.append(f"| {name} | {frames} | {sec:.2f} | {fps:.0f} | {note} |")
    lines += ["", *optimizer_table(args.repeats), "",
              f"Command: `python scripts/bench_smoother.py --minutes {args.minutes:g} "
              f"--lag-minutes {args.lag_minutes:g} --repeats {args.repeats}`."]
    text = "\n".join(lines) + "\n"
    print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("# Smoother speed\n\n" + text)
    print(f"written {out}", file=sys.stderr)
    return 0


def optimizer_table(repeats: int) -> list[str]:
    """One iteration of gtsam's Levenberg–Marquardt on the batch's graph against one iSAM2
    step (``smoother.optimize``'s), on car drives of growing length: LM hands each Python
    callback a copy of every value (per-frame time grows with the drive), iSAM2 does not."""
    lines = [
        "One step on the batch's graph (the dead-reckoned start), ms per frame, median of "
        f"{repeats}: gtsam's `LevenbergMarquardtOptimizer.iterate()` against an iSAM2 update "
        "that relinearises everything (`smoother.optimize`).",
        "",
        "| drive | frames | LM iteration | iSAM2 step |",
        "| --- | --- | --- | --- |",
    ]
    for seconds in (15.0, 60.0):
        run = simulate_drive(DriveConfig.preset("car", duration_s=seconds, height_m=1.53,
                                                height_assumed_m=1.5), 0)
        ms = run.measurements
        graph, values = _batch_graph(ms, speeds_at_frames(ms, run.speed), run.config.noise)
        lm, isam = [], []
        for _ in range(repeats):
            opt = gtsam.LevenbergMarquardtOptimizer(graph, values)
            t0 = time.perf_counter()
            opt.iterate()
            lm.append(time.perf_counter() - t0)
            solver = gtsam.ISAM2(smoother_module._batch_params())
            t0 = time.perf_counter()
            with smoother_module.held_linearization_point(solver):
                solver.update(graph, values)
            isam.append(time.perf_counter() - t0)
        n = len(ms)
        lines.append(f"| car, {seconds:g} s | {n} | {1e3 * np.median(lm) / n:.2f} | "
                     f"{1e3 * np.median(isam) / n:.2f} |")
    return lines


def _batch_graph(ms, speeds, noise) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The graph and initial values ``smooth_batch`` builds (taken from its call to
    ``smoother.optimize``, which is stopped there)."""
    got = {}

    class _Stop(Exception):
        pass

    def capture(graph, values, *args, **kwargs):
        got["graph"], got["values"] = graph, values
        raise _Stop

    original = smoother_module.optimize
    smoother_module.optimize = capture
    try:
        smooth_batch(ms, speeds, SmootherConfig(height_m=1.5, noise=noise))
    except _Stop:
        pass
    finally:
        smoother_module.optimize = original
    return got["graph"], got["values"]


if __name__ == "__main__":
    raise SystemExit(main())
