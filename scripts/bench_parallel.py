"""Chunked, parallel estimation of a long recording (``estimate --workers N --chunk-frames K``).

Renders one ``cart`` and one ``car`` sequence (``vipm_track.sim``, ``gradual`` profile), then
runs the code behind ``vipm-track estimate`` on each: one sequential run, the same frames in
chunks of ``--chunk-frames`` one after another in this process (``--workers 1``) and in 2 … N
processes. Reports wall time (process start-up and the numba cache load included), pairs
per second, speed-up over the sequential run, frames ok, pitch RMS and median distance error
against the rendered truth, and whether the chunked runs' tables are identical to each other
(they must be: the chunks, not the processes, decide the result).

    python scripts/bench_parallel.py [--frames 240] [--chunk-frames 60] [--workers 1,2]
                                     [--out scripts/results/bench_parallel.md]

Timings on a shared machine are noisy; the speed-up is bounded by the machine's cores
(``os.cpu_count()`` in the table's caption).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.allocator import keep_freed_memory  # noqa: E402
from vipm_track.camera import load_camera  # noqa: E402
from vipm_track.estimator_config import EstimatorConfig  # noqa: E402
from vipm_track.evaluate import frame_errors  # noqa: E402
from vipm_track.rig import Rig  # noqa: E402
from vipm_track.runs import estimate_sequence  # noqa: E402
from vipm_track.sim import PRESETS, simulate_sequence  # noqa: E402
from vipm_track.sources import open_source  # noqa: E402
from vipm_track.table import read_table  # noqa: E402


def run(folder: Path, preset: str, out: Path, workers: int, chunk_frames: int | None) -> dict:
    """One estimate run; its wall time, speed and errors against the truth."""
    p = PRESETS[preset]
    camera = load_camera(folder / "camera.yaml")
    rig = Rig(camera, p.height_m, p.pitch_deg)
    start = time.perf_counter()
    summary = estimate_sequence(open_source(images=folder / "images"), rig, out,
                                EstimatorConfig(), progress=False, workers=workers,
                                chunk_frames=chunk_frames)
    wall = time.perf_counter() - start
    errors = frame_errors(read_table(out), read_table(folder / "gt.csv"))
    return {"wall_s": wall, "pairs_s": summary.pairs / wall, "ok": f"{summary.ok}/{summary.frames}",
            "pitch_rms": float(np.sqrt(np.mean(errors["pitch_deg"] ** 2))),
            "dist_pct": float(np.median(np.abs(errors["distance_pct"]))),
            "table": out.read_bytes()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=240)
    parser.add_argument("--chunk-frames", type=int, default=60)
    parser.add_argument("--workers", default="1,2", help="process counts of the chunked runs")
    parser.add_argument("--presets", default="cart,car")
    parser.add_argument("--out", type=Path,
                        default=ROOT / "scripts" / "results" / "bench_parallel.md")
    args = parser.parse_args(argv)
    keep_freed_memory()  # as the command line does (its worker processes do too)
    lines = ["| preset | run | wall s | pairs/s | speed-up | ok | pitch RMS ° "
             "| distance err % median | table |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    with tempfile.TemporaryDirectory() as tmp:
        for preset in args.presets.split(","):
            folder = Path(tmp) / preset
            simulate_sequence(preset, args.frames, folder, seed=2, profile="gradual")
            seq = run(folder, preset, folder / "seq.csv", 1, None)
            rows = [("sequential", seq)]
            for w in (int(n) for n in args.workers.split(",")):
                rows.append((f"chunks of {args.chunk_frames}, {w} process"
                             + ("es" if w > 1 else ""),
                             run(folder, preset, folder / f"w{w}.csv", w, args.chunk_frames)))
            chunked = [r["table"] for name, r in rows[1:]]
            same = all(t == chunked[0] for t in chunked)
            for name, r in rows:
                table = ("—" if name == "sequential"
                         else "identical across process counts" if same else "DIFFERS")
                lines.append(
                    f"| {preset} | {name} | {r['wall_s']:.1f} | {r['pairs_s']:.2f} | "
                    f"{seq['wall_s'] / r['wall_s']:.2f}× | {r['ok']} | {r['pitch_rms']:.4f} | "
                    f"{r['dist_pct']:.3f} | {table} |")
                print(lines[-1], file=sys.stderr)
    text = (
        "# Chunked, parallel estimation (`estimate --workers N --chunk-frames K`)\n\n"
        + "\n".join(lines)
        + f"\n\n{args.frames} rendered frames per preset (`gradual` profile; cart 800×600, "
        "car 1280×720, `--pitch` the preset's), tracking mode. Wall time of the whole run "
        "(process start-up and the compiled kernels' cache load included); speed-up = the "
        "sequential run's wall time / the row's. Each chunk's first pair starts cold. "
        f"Machine: {os.cpu_count()} CPU cores, {platform.machine()}, "
        f"{platform.python_implementation()} {platform.python_version()}, shared by other "
        "jobs, so timings are noisy.\n\n"
        f"Command: `python scripts/bench_parallel.py --frames {args.frames} "
        f"--chunk-frames {args.chunk_frames} --workers {args.workers}`\n"
    )
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
