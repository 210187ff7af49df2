"""``vipm-track can-speed``: decode a vehicle speed from a CAN log (or a live bus) with a DBC
and write ``t,speed_mps``; optionally resample it at camera frame times."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..errors import InputError
from .common import add_can_decoding_options, check_writable
from .inputs import read_estimates, speed_on_camera_clock
from .option_types import number


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "can-speed", help="decode wheel speed from a CAN log or bus to t,speed_mps CSV",
        description="Decode a vehicle speed from a CAN log (candump .log, Vector .asc/.blf, "
        "PCAN .trc, .csv, .mf4) or a live python-can bus with a DBC, and write t,speed_mps. "
        "Bad frames are counted in the printed summary and skipped.")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("log", nargs="?", metavar="LOG", help="CAN log file")
    src.add_argument("--bus", metavar="INTERFACE:CHANNEL",
                     help="live python-can bus instead of a log, e.g. socketcan:can0")
    p.add_argument("--duration", type=number(0, above=True, what="number of seconds"),
                   default=10.0, help="with --bus: seconds to listen (default 10)")
    add_can_decoding_options(p, dbc_required=True)
    p.add_argument("--frame-times", metavar="times.txt",
                   help="write the speed at these camera frame times (one per line) instead "
                   "of at the CAN frames; frames without a valid speed are left out")
    p.add_argument("--estimates", metavar="EST.csv",
                   help="with --clock-offset auto: the estimates table ('vipm-track estimate') "
                   "of the same drive, whose pairs' travel fixes the offset")
    p.add_argument("--max-gap", type=number(0, above=True, what="number of seconds"),
                   default=0.5,
                   help="longest spacing of speed samples interpolated across [s] (default 0.5)")
    p.add_argument("--out", required=True, metavar="SPEED.csv", help="t,speed_mps CSV to write")
    p.set_defaults(handler=run)


def _read_times(path: str) -> np.ndarray:
    """The camera frame times [s] of ``--frame-times``; InputError naming the file (and the
    line) where it is missing, a folder, malformed or empty."""
    from ..sources import read_times

    if Path(path).is_dir():
        raise InputError(f"--frame-times {path}: is a folder; give a file of times")
    if not Path(path).is_file():
        raise InputError(f"--frame-times {path}: file not found")
    times = read_times(path)
    if not len(times):
        raise InputError(f"--frame-times {path}: no timestamps in it")
    return times


def run(args: argparse.Namespace) -> int:
    from vipm_track.filters.speed_decoder import decode_bus, decode_can_log
    from vipm_track.filters.wheel_speed import SpeedSeries, align_to_frames, write_speed_csv

    # the options and the small files first: a long log is decoded once they are known good
    if args.clock_offset == "auto" and not args.estimates:
        raise InputError("--clock-offset auto needs --estimates EST.csv of the same drive "
                         "(the pairs' travel against the wheel's fixes the offset)")
    if args.estimates and args.clock_offset != "auto":
        raise InputError("--estimates is read only with --clock-offset auto (it fixes the "
                         "offset); give both or neither")
    check_writable(args.out, "--out")
    frame_times = _read_times(args.frame_times) if args.frame_times else None
    measurements = read_estimates(args.estimates) if args.estimates else None
    if args.log is not None:
        series, summary = decode_can_log(args.log, args.dbc, args.signals, combine=args.combine,
                                         channel=args.can_channel, scale=args.speed_scale,
                                         progress=True)
    else:
        from ..live_sources import open_bus

        with open_bus(args.bus) as bus:
            series, summary = decode_bus(bus, args.dbc, args.signals, combine=args.combine,
                                         channel=args.can_channel, scale=args.speed_scale,
                                         duration=args.duration, source=f"bus {args.bus}")
    for line in summary.lines():
        print(line, file=sys.stderr)
    if len(series) == 0:
        raise InputError(f"{summary.source}: no speed samples decoded")
    if measurements is not None:
        series, _ = speed_on_camera_clock(args, series, measurements)
    elif args.clock_offset:
        series = series.shifted(args.clock_offset)
    gaps = series.gaps(args.max_gap)
    for a, b in gaps:
        print(f"  speed gap {a:.3f} .. {b:.3f} s ({b - a:.3f} s)", file=sys.stderr)
    if frame_times is not None:
        aligned = align_to_frames(series, frame_times, max_gap=args.max_gap)
        for line in aligned.lines():
            print(line, file=sys.stderr)
        series = SpeedSeries(aligned.frame_times[aligned.valid], aligned.speed_mps[aligned.valid],
                             source=series.source, signals=series.signals, scale=series.scale,
                             clock_offset=series.clock_offset)
    path = write_speed_csv(series, args.out)
    print(f"wrote {len(series)} speed samples to {path}", file=sys.stderr)
    if summary.interrupted:
        raise KeyboardInterrupt
    return 0
