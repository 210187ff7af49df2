"""``vipm-track demo``: a camera knocked out of its calibration during a drive, and the toolkit
catching it, scored against the truth.

Renders a deterministic drive from the textures in ``data/`` (``cart``: the paper's rig, h 0.7
m looking 45° down at walking speed, 25 s; ``car``: a dashcam, 20 s) with wheel speed, whose
camera mount is knocked by 1° in pitch at 40 % of the drive; estimates every pair, filters
them (EKF), smooths them, and monitors the calibration against the nominal one. Prints the
per-frame accuracy, the mount before and after the knock with 95 % intervals, the camera
height, the monitor's timeline and how long after the knock it flagged; writes the tables,
the events, a PNG and a rerun recording into DIR. Everything is ``vipm_track.demo``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace

from ..camera import load_camera
from ..errors import InputError
from .common import add_rerun_options, check_output_dir, check_rerun_output
from .estimator_options import add_estimator_options, build_config, build_rig
from .option_types import whole_number

MAX_FRAMES = 2000


def register(subparsers: argparse._SubParsersAction) -> None:
    from ..demo import PRESET, PROFILE, SECONDS, SEED

    parser = subparsers.add_parser(
        "demo",
        help="a drive whose camera is knocked out of calibration: estimate, filter, smooth, "
        "monitor, scored against the truth",
        description=__doc__.split("\n\n")[1].replace("\n", " ").replace("``", ""),
    )
    parser.add_argument("--out", default="out/demo", metavar="DIR",
                        help="folder for the drive, the tables, events, demo.png and demo.rrd "
                        "(default out/demo)")
    parser.add_argument("--preset", choices=sorted(SECONDS), default=PRESET,
                        help=f"simulated rig (default {PRESET})")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="frames to render (default: "
                        + ", ".join(f"{k} {v:g} s" for k, v in SECONDS.items())
                        + " at the preset's frame rate)")
    parser.add_argument("--seed", type=whole_number(0), default=SEED,
                        help="random seed of the scene, >= 0")
    parser.add_argument("--profile", default=PROFILE,
                        choices=("knock", "static", "shaking", "drift", "turn", "gradual",
                                 "height"),
                        help=f"camera motion profile (default {PROFILE}: the mount knocked)")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        metavar="N", help="processes estimating the drive's two halves (default: "
                        "2 where there are 2 cores; the numbers do not depend on it)")
    parser.add_argument("--no-tracking", action="store_true",
                        help="cold-start every pair")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    add_estimator_options(parser)
    add_rerun_options(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..demo import default_frames, render_drive, run_demo
    from ..demo_text import demo_lines, files_lines
    from ..sim import PRESETS
    from ..sources import open_source
    from .inputs import with_searched_readout
    from .rerun_options import sink_from_args

    _check_rerun_images(args)
    out = check_output_dir(args.out)
    frames = default_frames(args.preset) if args.frames is None else args.frames
    if not 2 <= frames <= MAX_FRAMES:
        raise InputError(f"--frames must be between 2 and {MAX_FRAMES}, got {frames}")
    if args.workers < 1:
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    args.rerun = args.rerun or str(out / "demo.rrd")
    check_rerun_output(args)
    preset = PRESETS[args.preset]
    # the cold start is seeded with the preset's nominal pose unless --pitch / --roll say else
    config = build_config(args, preset.camera())
    rig = build_rig(args, preset.camera(), preset.height_m, preset.pitch_deg, preset.roll_deg)
    progress = not args.quiet and sys.stderr.isatty()

    start = time.perf_counter()
    drive = render_drive(out / "sequence", args.preset, frames, args.seed, args.profile,
                         progress=progress)
    rendered = time.perf_counter() - start
    rig = with_searched_readout(args, open_source(images=drive.images),
                                replace(rig, camera=load_camera(drive.camera_file)), config)
    # a demo is short: every pair's images unless the options say otherwise
    images = {} if args.rerun_image_every is not None else {"image_every": 1}
    sink = sink_from_args(args, "vipm-track demo", layout="drift", **images)
    try:
        result = run_demo(drive, out, config, rig=rig, tracking=not args.no_tracking,
                          workers=args.workers, sink=sink, progress=progress,
                          render_seconds=rendered)
    finally:
        if sink is not None:
            sink.finish()
    print("\n".join(demo_lines(result)))
    print()
    print("\n".join(files_lines(result, args.rerun)))
    print(f"Done in {time.perf_counter() - start:.1f} s.")
    return 0


def _check_rerun_images(args: argparse.Namespace) -> None:
    """The rerun image options checked before the drive is rendered (the sink that checks
    them opens after it)."""
    from ..sinks.rerun_sink import check_image_options

    check_image_options(args.rerun_image_every, args.rerun_jpeg_quality)
