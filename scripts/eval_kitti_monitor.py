"""The drift monitor on a real drive whose camera did not move: KITTI 07 through
``vipm-track monitor --estimates``, with and without the road-tilt model (``--road-std``).

KITTI's camera is bolted to the car for the whole recording, so every RECALIBRATE here is a
false alarm. Its pose against the road is not recorded, so two nominal calibrations are
tried: the one the estimator is started from (pitch 1°, roll 0°) and the drive's own mean
mount from ``vipm-track smooth`` (a calibration the drive agrees with by construction).
Tolerances as ``data/nominal_car.yaml`` (0.1°). Reads the estimates tables
``scripts/eval_kitti.py --seeds N`` writes.

    python scripts/eval_kitti_monitor.py [--estimates EST.csv ...]
        [--out scripts/results/kitti_monitor.md]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from eval_kitti import KITTI_HEIGHT, existing_tables, seed_tables, write_results  # noqa: E402

from vipm_track.cli import main as cli_main  # noqa: E402
from vipm_track.table import read_table  # noqa: E402

#: (label, extra monitor options)
ROAD_MODELS: list[tuple[str, list[str]]] = [
    ("flat (default)", []),
    ("road 0.25° / 2 s", ["--road-std", "0.25", "--road-tau", "2"]),
    ("road 0.5° / 2 s", ["--road-std", "0.5", "--road-tau", "2"]),
    ("road 0.5° / 5 s", ["--road-std", "0.5", "--road-tau", "5"]),
    ("road 1° / 2 s", ["--road-std", "1", "--road-tau", "2"]),
]


def _cli(args: list[str]) -> None:
    rc = cli_main(args)
    if rc != 0:
        raise SystemExit(f"vipm-track {' '.join(args)} failed (exit {rc})")


def _nominal_file(path: Path, pitch: float, roll: float) -> Path:
    path.write_text(f"pitch_deg: {pitch:.4f}\nroll_deg: {roll:.4f}\nheight_m: {KITTI_HEIGHT}\n"
                    "tolerances: {pitch_deg: 0.1, roll_deg: 0.1, height_m: 0.005}\n")
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--estimates", nargs="+", default=seed_tables(ROOT / "out" / "kitti"))
    ap.add_argument("--out", default=str(ROOT / "scripts" / "results" / "kitti_monitor.md"))
    args = ap.parse_args(argv)
    ests = existing_tables(args.estimates)
    lines = [
        "# KITTI 07: the drift monitor on a camera that did not move",
        "",
        f"`vipm-track monitor --estimates EST --height {KITTI_HEIGHT}` on the {len(ests)} "
        "estimates tables of `scripts/eval_kitti.py` (subset-sampler seeds), tolerances 0.1° "
        "(as `data/nominal_car.yaml`); every RECALIBRATE is a false alarm. *first RECALIBRATE*: "
        "seconds into the 16 s drive, per table; *DRIFTING*: share of frames; *last state*: "
        "at the end of the drive (most common over the tables).",
        "",
        "| nominal (pitch / roll) | monitor | first RECALIBRATE s | DRIFTING | last state |",
        "| --- | --- | --- | --- | --- |",
    ]
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        nominals: list[tuple[str, list[Path]]] = [
            ("1.0° / 0.0° (the estimator's start)",
             [_nominal_file(tmp / "start.yaml", 1.0, 0.0)] * len(ests))]
        own = []
        for i, est in enumerate(ests):
            _cli(["smooth", "--estimates", str(est), "--height", str(KITTI_HEIGHT), "--quiet",
                  "--out", str(tmp / f"smooth{i}.csv"), "--summary", str(tmp / f"sum{i}.json")])
            s = json.loads((tmp / f"sum{i}.json").read_text())
            own.append(_nominal_file(tmp / f"own{i}.yaml", s["pitch"]["mean"], s["roll"]["mean"]))
        nominals.append(("the drive's smoothed mean mount", own))
        for label, files in nominals:
            for model, options in ROAD_MODELS:
                first, drifting, last = [], [], []
                for i, (est, nominal) in enumerate(zip(ests, files, strict=True)):
                    out = tmp / f"mon{i}.csv"
                    _cli(["monitor", "--estimates", str(est), "--height", str(KITTI_HEIGHT),
                          "--nominal", str(nominal), "--out", str(out), "--quiet", *options])
                    table = read_table(out)
                    state = np.asarray(table["monitor_state"], dtype=object)
                    t = np.asarray(table["t"], dtype=float)
                    hit = np.flatnonzero(state == "RECALIBRATE")
                    first.append(f"{t[hit[0]]:.1f}" if hit.size else "never")
                    drifting.append(float(np.mean(state == "DRIFTING")))
                    last.append(str(state[-1]))
                lines.append(f"| {label} | {model} | {', '.join(first)} | "
                             f"{100 * np.mean(drifting):.0f} % | "
                             f"{Counter(last).most_common(1)[0][0]} |")
    lines += [
        "",
        "The pairs of the slow start (under 0.25 camera heights per frame, the first ~4 s) "
        "are not judged: a forward camera's pitch reads low there (`filters/forward_slow.py`; "
        "judging them, the flat-ground monitor called RECALIBRATE at 2.3–2.6 s on every "
        "table). The flat-ground monitor (the default; right for renders and test tracks) "
        "may still take the road's slow excursions for a moved camera. Told of them "
        "(`--road-std 0.5 --road-tau 2`, what `scripts/bench_monitor.py`'s road rows "
        "simulate) it raises no RECALIBRATE on this drive; what that costs in delay is in "
        "`bench_monitor.md`.",
    ]
    write_results(lines, args.out, "eval_kitti_monitor.py")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
