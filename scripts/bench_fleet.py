"""A fleet of drives on Dask (``vipm-track fleet``) against the sequential loop over the
same drives, on this machine.

Renders ``--drives`` ``cart`` drives (``vipm_track.sim``, 800×600, ``shaking`` profile,
``--frames`` each, with wheel speed and a nominal calibration), then processes them all
(estimate → batch smooth → drive summary → monitor, ``fleet.drive_run.run_drive``) once in
a plain loop in this process and once with ``fleet.cluster.run_fleet`` on a
``LocalCluster`` of ``--workers`` processes (``worker_environ``) started
once (as ``--scheduler`` uses a running cluster; its start-up is reported apart: a fixed cost
per fleet, not per drive), alternately ``--repeats`` times into fresh outputs. Reports the
median wall time, drives per hour, the wall and CPU seconds (every thread) per hour of video, the
machine's load during the runs, and whether both give the same mount for every drive.

    python scripts/bench_fleet.py [--drives 6] [--frames 40] [--workers 2] [--repeats 3]
                                  [--out scripts/results/bench_fleet.md]

Timings on a shared machine are noisy; the speed-up is bounded by its cores
(``os.cpu_count()`` in the caption).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import dask  # noqa: E402
from distributed import Client, LocalCluster  # noqa: E402

from vipm_track.filters.nominal import load_nominal, write_nominal  # noqa: E402
from vipm_track.fleet.cluster import run_fleet, worker_environ  # noqa: E402
from vipm_track.fleet.drive_run import FleetSettings, run_drive  # noqa: E402
from vipm_track.fleet.drives import find_drives  # noqa: E402
from vipm_track.resources import data_path  # noqa: E402
from vipm_track.sim import simulate_sequence  # noqa: E402


def render(root: Path, drives: int, frames: int) -> Path:
    nominal = load_nominal(data_path("nominal_cart.yaml"))
    for i in range(drives):
        folder = root / f"drive{i:02d}"
        simulate_sequence("cart", frames, folder, seed=i, profile="shaking")
        write_nominal(nominal, folder / "nominal.yaml")
    return root


def _workers_cpu(client: Client) -> float:
    """CPU seconds (all threads) the cluster's worker processes have used so far."""
    return sum(client.run(time.process_time).values())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drives", type=int, default=6)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=str(ROOT / "scripts/results/bench_fleet.md"))
    args = parser.parse_args(argv)
    settings = FleetSettings(vehicle="cart")
    with tempfile.TemporaryDirectory() as tmp:
        specs = find_drives(render(Path(tmp) / "drives", args.drives, args.frames))
        times: dict[str, list[float]] = {"sequential loop": [], f"fleet, {args.workers} "
                                         "workers": []}
        mounts: dict[str, dict[str, float]] = {}
        start = time.perf_counter()
        with dask.config.set({"distributed.nanny.pre-spawn-environ":
                              worker_environ(args.workers)}):
            cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1,
                                   dashboard_address=None)
        startup = time.perf_counter() - start
        load: list[float] = []
        cpu: dict[str, list[float]] = {name: [] for name in times}
        fleet = f"fleet, {args.workers} workers"
        with cluster, Client(cluster) as client:
            for r in range(args.repeats):
                start, cpu0 = time.perf_counter(), time.process_time()
                rows = [run_drive(s, Path(tmp) / f"seq{r}", settings) for s in specs]
                times["sequential loop"].append(time.perf_counter() - start)
                cpu["sequential loop"].append(time.process_time() - cpu0)
                mounts["seq"] = {row["drive"]: row["mount_pitch_deg"] for row in rows}
                start, cpu0 = time.perf_counter(), _workers_cpu(client)
                rows = run_fleet(specs, Path(tmp) / f"fleet{r}", settings,
                                 scheduler=cluster.scheduler_address, progress=False)
                times[fleet].append(time.perf_counter() - start)
                cpu[fleet].append(_workers_cpu(client) - cpu0)
                mounts["fleet"] = {row["drive"]: row["mount_pitch_deg"] for row in rows}
                assert all(row["status"] == "ok" for row in rows), rows
                load.append(os.getloadavg()[0])
        video_s = sum(float(row["duration_s"]) + 0.1 for row in rows)
    same = mounts["seq"] == mounts["fleet"]
    base = statistics.median(times["sequential loop"])
    lines = [
        f"{args.drives} rendered cart drives of {args.frames} frames (800×600, 10 Hz; "
        f"{video_s:.0f} s of video in all), estimate → batch smooth → summary → monitor; "
        f"median of {args.repeats} runs; {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, load average {statistics.median(load):.1f} during the runs "
        "(other jobs share the cores).", "",
        "| run | wall s | drives / h | speed-up | wall s per h of video "
        "| CPU s per h of video |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name, walls in times.items():
        wall = statistics.median(walls)
        lines.append(f"| {name} | {wall:.1f} | {3600 * args.drives / wall:.0f} | "
                     f"{base / wall:.2f}× | {3600 * wall / video_s:.0f} | "
                     f"{3600 * statistics.median(cpu[name]) / video_s:.0f} |")
    lines += ["", f"Same mount pitch for every drive in both: {'yes' if same else 'NO'}. "
              f"Starting the local cluster ({args.workers} worker processes): {startup:.1f} s "
              "once per fleet, not in the times above."]
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).write_text("# Fleet on Dask against the sequential loop\n\n" + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
