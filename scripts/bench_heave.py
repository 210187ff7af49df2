"""Do the frames' height intervals hold the true height when the body heaves? Rendered drives
with wheel speed, the EKF, the fixed-lag and the batch smoother, each frame's height σ with
the heave term (``filters.heave``) and without it (the mount's σ alone), same run.

Renders each case of ``CASES`` for ``--seeds`` seeds (``bench_verdicts``' renders and cache:
the preset's camera, `estimate` with the true nominal pitch and height), filters it with its
rendered wheel speed (``speed.csv``: 50 Hz, 0.5 % noise, 0.01 km/h steps) and the CLI's
defaults for the preset, and scores every frame after the first ``SETTLE_S`` seconds against
the rendered camera height of that frame: the RMS error, the RMS of the error over its σ
(z) and the share of frames whose 95 % interval holds the truth; the same for the frame's
metric forward travel. Without wheel speed the
height is the assumed one at its prior's 5 %, which no heave here reaches.

Then the drive's height as the smoothers' summaries state it (``summarize_mount``, as
``smooth`` and ``fleet`` write it) against the mean rendered height of the drive's frames:
its error, its 95 % half-width and whether it holds the truth, with the summary's check
against the heights the pairs measure with the wheel speed and without it (before), same run.

    python scripts/bench_heave.py [--seeds 3] [--jobs 2] [--out FILE.md]
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

from bench_camera_pitch import write_report  # noqa: E402
from bench_verdicts import Case, _folder, render_and_estimate, scores_by_case  # noqa: E402

from vipm_track.filters import heave  # noqa: E402
from vipm_track.filters.drive_summary import summarize_mount  # noqa: E402
from vipm_track.filters.ekf import run_filter  # noqa: E402
from vipm_track.filters.ekf_state import EkfConfig  # noqa: E402
from vipm_track.filters.model import NoiseParams  # noqa: E402
from vipm_track.filters.smoother_config import SmootherConfig  # noqa: E402
from vipm_track.filters.smoothing import smooth  # noqa: E402
from vipm_track.filters.wheel_speed import read_speed_csv  # noqa: E402
from vipm_track.measurement import read_measurements  # noqa: E402
from vipm_track.sim import PRESETS  # noqa: E402
from vipm_track.table import read_table  # noqa: E402

#: cases whose names match ``bench_mount_steps``' share its renders (same length)
CASES: tuple[Case, ...] = (
    *(Case(f"cart {p}", "cart", p, 12.0) for p in ("static", "turn", "shaking", "height")),
    Case("cart shaking 0.5 m/s", "cart", "shaking", 12.0, speed=0.5),
    *(Case(f"car {p}", "car", p, 8.0) for p in ("static", "turn", "shaking", "height")),
)
FILTERS = ("EKF", "fixed lag 2 s", "batch")
SETTLE_S = 2.0


def _filtered(ms, speed, preset: str) -> dict[str, list]:
    """The three filters' frames of one drive, as `track` / `smooth` make them."""
    h = PRESETS[preset].height_m
    noise = NoiseParams.for_preset(preset)
    return {
        "EKF": run_filter(ms, speed, EkfConfig(height_m=h, noise=noise)),
        "fixed lag 2 s": smooth(ms, speed, SmootherConfig(height_m=h, noise=noise, lag_s=2.0)),
        "batch": smooth(ms, speed, SmootherConfig(height_m=h, noise=noise)),
    }


def score(case: Case, seed: int, cache: Path) -> dict[str, tuple[np.ndarray, ...]]:
    """One drive: per filter, the frames' height and forward travel errors [m] and their σ
    with and without the heave term [m] (without: the same filters with ``heave.widen``
    leaving each frame as it is)."""
    render_and_estimate(case, seed, cache)
    folder = _folder(case, seed, cache)
    gt = read_table(folder / "gt.csv")
    ms = read_measurements(folder / "est.csv")
    speed = read_speed_csv(folder / "speed.csv")
    runs = _filtered(ms, speed, case.preset)
    widen = heave.widen
    heave.widen = lambda estimate, *_: estimate
    try:
        before = _filtered(ms, speed, case.preset)
    finally:
        heave.widen = widen
    out = {}
    truth = float(np.mean(gt["height_m"][[f.frame for f in runs["batch"]]]))
    for name in FILTERS[1:]:
        steps = SmootherConfig().mount_steps if name == "batch" else None
        out[f"summary {name}"] = tuple(
            _summary_height(summarize_mount(runs[name], ms, steps, given), truth)
            for given in (speed, None))
    for name, frames in runs.items():
        rows = []
        for f, b in zip(frames, before[name], strict=True):
            if f.pose is None or f.t < SETTLE_S or not np.all(np.isfinite(f.motion[:2])):
                continue
            rows.append((f.pose[2] - gt["height_m"][f.frame], np.sqrt(f.pose_cov[2, 2]),
                         np.sqrt(b.pose_cov[2, 2]), f.motion[1] - gt["tz_m"][f.frame],
                         np.sqrt(f.motion_cov[1, 1]), np.sqrt(b.motion_cov[1, 1])))
        out[name] = tuple(np.array(c) for c in zip(*rows, strict=True))
    return out


def _summary_height(summary: dict, truth: float) -> tuple[float, float]:
    """(error [m], 95 % half-width [m]) of a summary's height against ``truth`` [m]."""
    h = summary["height"]
    return h["mean"] - truth, 0.5 * (h["ci95"][1] - h["ci95"][0])


def _summary_cells(scores: list[dict], name: str) -> list[str]:
    cells = []
    for i in range(2):
        err, half = np.array([s[f"summary {name}"][i] for s in scores]).T
        cells.append(f"{1000 * np.max(np.abs(err)):.1f} / {1000 * np.median(half):.1f} / "
                     f"{int(np.sum(np.abs(err) <= half))} of {len(err)}")
    return cells


def _cells(scores: list[dict], name: str) -> list[str]:
    cols = [np.concatenate([s[name][i] for s in scores]) for i in range(6)]
    cells = []
    for err, std, before in (cols[:3], cols[3:]):
        cells.append(f"{1000 * np.sqrt(np.mean(err**2)):.1f}")
        for sigma in (std, before):
            z = err / sigma
            cells.append(f"{np.sqrt(np.mean(z**2)):.2f} / {100 * np.mean(np.abs(z) <= 1.96):.0f}")
    return cells


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=2, help="processes rendering and estimating")
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "vipm_bench_verdicts"))
    ap.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_heave.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    header = ("| drive | filter | height error RMS mm | z RMS / 95 % coverage %, with the heave "
              "| without it (the mount's σ) | forward travel error RMS mm | z RMS / coverage "
              "%, with | without |")
    lines = [
        "# The frames' height and travel intervals on heaving bodies",
        "",
        f"Rendered drives (seeds 0–{args.seeds - 1} per row; cart 12 s at 10 fps, car 8 s at "
        "20 fps; `shaking`: three 1–3 Hz heaves of 0.5 % of the height each with the pitch "
        "and roll shaking, `height`: ±10 % over 6 s), `estimate` with the true nominal pitch "
        "and height, filtered with the rendered wheel speed (`speed.csv`) and the CLI's "
        f"defaults; every frame after {SETTLE_S:g} s against the rendered height of that "
        "frame: RMS error, RMS of error / σ (z) and the share of frames whose 95 % interval "
        "holds the truth, with the frames' height σ as the filters now state it (the mount's "
        "and the heave measured from the pairs' heights, `filters/heave.py`) and as the same "
        "filters state it without the heave term (the mount's σ alone, before); the same for "
        "the frame's metric forward travel (`tz_m`), which a pair measures in units of its "
        "first frame's height. Renders and estimates are cached "
        "(`--cache`); the wall time below is this run's.",
        "",
        header, "|" + " --- |" * 8,
    ]
    print(header)
    results = list(zip(CASES, scores_by_case(score, CASES, args.seeds, args.jobs, cache),
                       strict=True))
    for case, scores in results:
        for name in FILTERS:
            row = f"| {case.name} | {name} | " + " | ".join(_cells(scores, name)) + " |"
            print(row, flush=True)
            lines.append(row)
    header = ("| drive | smoother | with the pairs' heights: largest error mm / median "
              "half-width mm / holds the mean height | without (before) |")
    lines += ["", "The drive's height in the smoothers' summaries against the drive's mean "
              "rendered height (largest error and median 95 % half-width over the seeds):", "",
              header, "|" + " --- |" * 4]
    print(header)
    for case, scores in results:
        for name in FILTERS[1:]:
            row = f"| {case.name} | {name} | " + " | ".join(_summary_cells(scores, name)) + " |"
            print(row, flush=True)
            lines.append(row)
    write_report(lines, args.out, t0, "python scripts/bench_heave.py " + " ".join(argv or
                                                                                 sys.argv[1:]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
