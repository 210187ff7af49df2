"""Benchmark CAN wheel-speed decoding on the real comma2k19 RAV4 log (../shared/data).

Speed: reading + decoding each log format; decoding 100 k in-memory frames (mixed ids, and
all WHEEL_SPEEDS) batch and streaming, against cantools' per-frame ``decode_message``.
Accuracy: against the data set's decoded wheel speeds and its GNSS/INS speed.
Prints a markdown table and writes it to ``scripts/results/bench_can.md``. Timings are
medians over repeats on a shared machine: noisy.

    /work/venv/bin/python scripts/bench_can.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

import can
import cantools
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.filters.speed_decoder import SpeedDecoder, decode_can_log  # noqa: E402
from vipm_track.filters.wheel_speed import align_to_frames, fit_speed_scale  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "comma2k19_can"
ALL_WHEELS = ",".join(f"WHEEL_SPEEDS.WHEEL_SPEED_{w}" for w in ("FL", "FR", "RL", "RR"))


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def tile(messages: list[can.Message], n: int, period: float) -> list[can.Message]:
    """``n`` frames repeating ``messages`` with times shifted by ``period`` each round."""
    out = []
    k = 0
    while len(out) < n:
        for m in messages:
            out.append(can.Message(timestamp=m.timestamp + k * period,
                                   arbitration_id=m.arbitration_id, data=m.data,
                                   channel=m.channel, is_extended_id=m.is_extended_id))
            if len(out) == n:
                break
        k += 1
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_can.md"))
    args = parser.parse_args()
    if not DATA.is_dir():
        print(f"shared data not found at {DATA}", file=sys.stderr)
        return 2
    dbc_path = DATA / "toyota_2017.dbc"
    db = cantools.database.load_file(str(dbc_path), strict=False)
    rows: list[tuple[str, str, str]] = []

    # -- speed -------------------------------------------------------------------------------
    for suffix in ("log", "asc", "blf"):
        path = DATA / f"rav4_drive.{suffix}"
        t_read = median_time(lambda p=path: sum(1 for _ in can.LogReader(str(p))), args.repeats)
        t_all = median_time(lambda p=path: decode_can_log(p, db), args.repeats)
        rows.append((f"read only, python-can LogReader, .{suffix} (98,800 frames)",
                     f"{t_read:.3f} s", f"{98_800 / t_read / 1e3:.0f} k frames/s"))
        rows.append((f"read + decode rear wheels, .{suffix} (98,800 frames)", f"{t_all:.3f} s",
                     f"{98_800 / t_all / 1e3:.0f} k frames/s"))

    log = list(can.LogReader(str(DATA / "rav4_drive.log")))
    mixed = tile(log, 100_000, period=70.0)
    wheel = tile([m for m in log if m.arbitration_id == 0xAA], 100_000, period=70.0)
    t_mixed = median_time(lambda: SpeedDecoder(db).feed_many(mixed), args.repeats)
    rows.append(("decode 100 k in-memory frames, mixed ids (5 % wheel), batch",
                 f"{t_mixed:.3f} s", "target ≤ 3 s"))
    t_wheel = median_time(lambda: SpeedDecoder(db, ALL_WHEELS).feed_many(wheel), args.repeats)
    rows.append(("decode 100 k WHEEL_SPEEDS frames (4 signals), batch (numpy bit decode)",
                 f"{t_wheel:.3f} s", "target ≤ 3 s"))

    def stream():
        dec = SpeedDecoder(db, ALL_WHEELS)
        for m in wheel:
            dec.feed(m)

    t_stream = median_time(stream, max(1, args.repeats // 2))
    rows.append(("decode 100 k WHEEL_SPEEDS frames, streaming feed() per frame",
                 f"{t_stream:.3f} s", f"{t_stream / 100_000 * 1e6:.1f} µs/frame"))
    msg_def = db.get_message_by_name("WHEEL_SPEEDS")
    payloads = [bytes(m.data) for m in wheel]
    t_cantools = median_time(lambda: [msg_def.decode(p) for p in payloads],
                             max(1, args.repeats // 2))
    rows.append(("baseline: cantools Message.decode per frame, 100 k WHEEL_SPEEDS",
                 f"{t_cantools:.3f} s", f"{t_cantools / 100_000 * 1e6:.1f} µs/frame"))

    # -- accuracy ----------------------------------------------------------------------------
    ref = np.genfromtxt(DATA / "reference_wheel_speeds.csv", delimiter=",", names=True)
    worst = 0.0
    for w in ("FL", "FR", "RL", "RR"):
        s = SpeedDecoder(db, f"WHEEL_SPEEDS.WHEEL_SPEED_{w}").feed_many(log)
        worst = max(worst, float(np.max(np.abs(s.speed_mps - ref[f"{w.lower()}_mps"]))) * 3.6)
    rows.append(("max |wheel speed − reference_wheel_speeds| (4 wheels, 4974 frames)",
                 f"{worst:.4f} km/h", "target ≤ 0.01 km/h"))
    gnss = np.genfromtxt(DATA / "reference_speed.csv", delimiter=",", names=True)
    t, v = gnss["t"], gnss["gnss_ins_speed_mps"]
    rear = SpeedDecoder(db).feed_many(log)
    raw = align_to_frames(rear, t)
    rows.append(("median |rear-wheel mean − GNSS/INS|, scale 1 (1199 frames)",
                 f"{np.nanmedian(np.abs(raw.speed_mps - v)):.3f} m/s",
                 f"median ratio GNSS/wheel {np.nanmedian(v / raw.speed_mps):.4f}"))
    half = t.size // 2
    scale = fit_speed_scale(rear, t[:half], v[:half])
    fixed = align_to_frames(rear.scaled(scale), t[half:])
    rows.append((f"same, tyre scale {scale:.4f} fitted on the first 30 s, checked on the last 30 s",
                 f"{np.nanmedian(np.abs(fixed.speed_mps - v[half:])):.3f} m/s",
                 "target ≤ 0.1 m/s"))

    machine = platform.processor() or platform.machine()
    few = max(1, args.repeats // 2)
    header = (f"# CAN wheel-speed benchmark\n\nMachine: {machine}, Python "
              f"{platform.python_version()}, shared 2-core host; timings are medians of "
              f"{args.repeats} repeats (streaming and cantools rows: {few}).\n"
              "Data: comma2k19 Toyota RAV4 log, 60 s, 98,800 frames "
              "(`../shared/data/comma2k19_can`).\n\n")
    table = "| measurement | value | note |\n| --- | --- | --- |\n" + "\n".join(
        f"| {a} | {b} | {c} |" for a, b, c in rows) + "\n"
    print(table)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(header + table)
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
