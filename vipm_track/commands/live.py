"""``vipm-track live``: onboard monitoring of a camera (or stream, or a video played as one)
and a wheel speed in real time (``vipm_track.live_run.run_live``): one row per processed
pair (the monitor's columns, ``prev_frame``, ``dropped``, ``latency_s``), state changes as
JSON lines and on stdout, a summary at the end."""

from __future__ import annotations

import argparse
import math

from ..camera import load_camera
from ..errors import InputError, NothingUsable
from ..live_monitor import LIVE_TABLE
from ..statuses import counts_text
from ..table import choose_columns
from .common import (
    add_can_decoding_options,
    add_output_options,
    add_rerun_options,
    check_output,
    check_rerun_output,
    check_writable,
)
from .estimator_options import add_estimator_options
from .inputs import estimator_setup, load_speed
from .monitor import add_monitor_test_options, check_monitor_test_options


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "live",
        help="monitor a camera and a CAN bus in real time: rows, state changes, summary",
        description="Judge the calibration live: frames from a camera (--video 0), a stream "
        "(--video rtsp://...) or a file (--realtime: at its frame rate), wheel speed from a "
        "CAN bus (--bus) or a recording replayed beside the video. Frames the estimator has "
        "no time for are dropped and counted; camera or wheel speed silent -> HOLD.",
    )
    parser.add_argument("--video", required=True, metavar="SOURCE",
                        help="camera index (0), stream URL (rtsp://, http://) or video file")
    parser.add_argument("--realtime", action="store_true",
                        help="play a video file at its frame rate, as a camera delivers it "
                        "(default: as fast as it is read)")
    parser.add_argument("--fps", type=float, default=None,
                        help="frame rate timing a video file's frames [Hz]")
    parser.add_argument("--camera", required=True, metavar="CAMERA.yaml",
                        help="intrinsics: ROS camera_info YAML, OpenCV FileStorage YAML or "
                        "KITTI calib.txt")
    parser.add_argument("--height", type=float, default=None, metavar="H",
                        help="camera height [m]; default and only allowed value: the nominal "
                        "file's")
    parser.add_argument("--nominal", required=True, metavar="CALIB.yaml",
                        help="nominal calibration: pitch_deg, roll_deg, height_m, tolerances, "
                        "limits (see data/nominal_car.yaml)")
    add_output_options(parser, "per-pair live monitor CSV")
    parser.add_argument("--events", metavar="EVENTS.jsonl",
                        help="write one JSON line per state change")
    speed = parser.add_argument_group("wheel speed")
    source = speed.add_mutually_exclusive_group()
    source.add_argument("--bus", metavar="INTERFACE:CHANNEL",
                        help="live python-can bus, e.g. socketcan:can0")
    source.add_argument("--speed-csv", metavar="FILE",
                        help="recorded t,speed_mps replayed in step with a video file")
    source.add_argument("--can", metavar="LOG",
                        help="recorded CAN log replayed in step with a video file")
    add_can_decoding_options(speed)
    watch = parser.add_argument_group("watchdog")
    watch.add_argument("--camera-timeout", type=float, default=1.0, metavar="S",
                       help="camera silent this long -> HOLD (default 1)")
    watch.add_argument("--speed-timeout", type=float, default=1.0, metavar="S",
                       help="wheel speed silent this long -> HOLD (default 1)")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop a camera or stream after S seconds (default: at Ctrl-C)")
    add_monitor_test_options(parser)
    parser.add_argument("--quiet", action="store_true", help="no summary on stderr")
    add_estimator_options(parser)
    add_rerun_options(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from vipm_track.filters.nominal import load_nominal

    from ..frame_rates import fps_problem
    from ..live_run import run_live
    from ..sources import first_frame_size
    from .monitor import nominal_height
    from .rerun_options import sink_from_args

    out = check_output(args.out, args.parquet)
    columns = choose_columns(LIVE_TABLE, args.columns)
    if args.events:
        check_writable(args.events, "--events")
    check_rerun_output(args)
    for name in ("camera_timeout", "speed_timeout"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"--{name.replace('_', '-')} must be > 0, got {value}")
    check_monitor_test_options(args)
    if args.fps is not None and (problem := fps_problem(args.fps)):
        raise InputError(f"--fps must be {problem}")
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration must be > 0 seconds, got {args.duration}")
    try:
        nominal = load_nominal(args.nominal)
    except UnicodeDecodeError as exc:
        raise InputError(f"{args.nominal}: not a text file (undecodable byte at offset "
                         f"{exc.start}); a nominal calibration is YAML") from None
    height = nominal_height(args.height, nominal.height_m, args.nominal)
    size = first_frame_size(video=args.video)
    camera = load_camera(args.camera, size)
    if size is not None:  # every frame would be HOLD 'wrong image size': say so at once
        try:
            camera.check_image((size[1], size[0]), f"--video {args.video}")
        except ValueError as exc:
            raise InputError(f"{exc} ({args.camera})") from None
    if args.readout_time == "auto":  # estimator_setup would take it as a global shutter
        raise InputError("--readout-time auto fits the readout over the first 300 frames of a "
                         "recorded drive; live, give it in seconds (found by 'vipm-track "
                         "estimate --readout-time auto' on a recording of this camera)")
    rig, config = estimator_setup(args, camera, height, pitch_deg=nominal.pitch_deg,
                                  roll_deg=nominal.roll_deg)
    if args.clock_offset == "auto":
        raise InputError("--clock-offset auto needs the whole drive; live, give the offset in "
                         "seconds")
    if args.bus and args.clock_offset:
        raise InputError("--clock-offset is for a recorded speed; a live bus is put on the "
                         "camera's clock by its time stamps")
    speed = None if args.bus else load_speed(args)
    sink = sink_from_args(args, "vipm-track live")
    stats = run_live(
        args.video, rig, nominal, out, config=config, realtime=args.realtime, fps=args.fps,
        speed=speed, bus=args.bus, dbc=args.dbc, signals=args.signals, combine=args.combine,
        can_channel=args.can_channel, speed_scale=args.speed_scale, events=args.events,
        parquet=args.parquet, columns=columns, camera_timeout_s=args.camera_timeout,
        speed_timeout_s=args.speed_timeout, duration_s=args.duration,
        monitor_options={"false_alarms_per_hour": args.false_alarms_per_hour,
                         "road_std_deg": args.road_std, "road_tau_s": args.road_tau},
        sink=sink, quiet=args.quiet,
    )
    if not stats.statuses["ok"]:
        counts = counts_text(stats.statuses) or "no pair of frames"
        raise NothingUsable(f"{out}: no pair gave an estimate ({counts}); the table holds its "
                            "rows as written")
    return 0
