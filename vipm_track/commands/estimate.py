"""``vipm-track estimate``: per-frame pitch, roll and planar motion of a recording."""

from __future__ import annotations

import argparse
import sys
from collections import Counter

from ..camera import load_camera
from ..errors import InputError, NothingUsable
from ..statuses import counts_text
from ..table import ESTIMATE_TABLE, choose_columns
from .common import (
    add_camera_options,
    add_input_options,
    add_output_options,
    add_rerun_options,
    check_height,
    check_images_folder,
    check_output,
    check_rerun_output,
)
from .estimator_options import (
    add_estimator_options,
    add_parallel_options,
    build_config,
    build_rig,
    parallel_settings,
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "estimate",
        help="pitch, roll and planar motion for every consecutive frame pair",
        description="Run the two-frame estimator on every consecutive pair of a video or an "
        "image folder and write one row per frame (CONVENTIONS.md columns + std, inliers).",
    )
    add_input_options(parser, bag=True)
    add_camera_options(parser, camera_required=False)
    add_output_options(parser, "per-frame estimates CSV")
    add_estimator_options(parser)
    add_run_options(parser)
    add_parallel_options(parser)
    add_rerun_options(parser)
    parser.set_defaults(handler=run)




def add_run_options(parser: argparse.ArgumentParser) -> None:
    """``--no-tracking``, ``--start``, ``--max-frames``, ``--quiet``."""
    group = parser.add_argument_group("run")
    group.add_argument("--no-tracking", action="store_true",
                       help="cold-start every pair instead of seeding it from the previous one")
    group.add_argument("--start", type=int, default=0, metavar="K",
                       help="first frame index to process (default 0)")
    group.add_argument("--max-frames", type=int, default=None, metavar="N",
                       help="process at most N frames")
    group.add_argument("--quiet", action="store_true",
                       help="no progress bar and no summary line")


def run(args: argparse.Namespace) -> int:
    from ..runs import estimate_sequence
    from ..sources import open_source
    from .inputs import (
        CAMERA_NOT_FOUND,
        load_frames_camera,
        warn_given_pitch,
        warn_readout_stake,
        with_searched_setup,
    )

    out = check_output(args.out, args.parquet)
    columns = choose_columns(ESTIMATE_TABLE, args.columns)
    check_rerun_output(args)
    check_images_folder(args)
    if not args.camera and not args.bag:
        raise InputError(CAMERA_NOT_FOUND)
    height = check_height(args.height)
    if args.bag:
        from ..bag_source import BagSource, read_bag_camera

        camera = (load_camera(args.camera) if args.camera
                  else read_bag_camera(args.bag, args.camera_info_topic))
    else:
        camera = load_frames_camera(args.camera, args.images, args.video)
    # bad options are named before the input is read
    config, rig = build_config(args, camera), build_rig(args, camera, height)
    if args.bag:
        source = BagSource(args.bag, args.image_topic, start=args.start,
                           max_frames=args.max_frames)
    else:
        source = open_source(images=args.images, video=args.video, fps=args.fps,
                             start=args.start, max_frames=args.max_frames)
    parallel = parallel_settings(args)
    rig, config = with_searched_setup(args, source, rig, config, search_pose=args.pitch is None)
    from ..sinks.rerun_sequence import run_logging
    from .rerun_options import sink_from_args

    logging = run_logging(sink_from_args(args, "vipm-track estimate"), source, camera, config)
    try:
        summary = estimate_sequence(
            logging.source, rig, out, logging.config, tracking=not args.no_tracking,
            parquet=args.parquet, progress=not args.quiet, columns=columns,
            on_step=logging.on_step, **parallel,
        )
    finally:
        logging.finish()
    if not args.quiet:
        print(f"{out}: {summary.line()}", file=sys.stderr)
    if summary.ok > 0:
        from vipm_track.filters.forward_slow import slow_drive_note

        from ..measurement import read_measurements

        # said under --quiet too: the rows' σ do not cover a bias one way over the stretch
        try:
            note = slow_drive_note(read_measurements(out))
        except InputError:  # a --columns choice without the pose or travel
            note = ""
        if note:
            print(f"vipm-track estimate: warning: {note}", file=sys.stderr)
        warn_readout_stake(args, source, rig, config)
        warn_given_pitch(args, source, rig)
    if summary.ok == 0:
        kinds = Counter(s.split(":")[0] for s in summary.statuses.elements())
        counts = counts_text(kinds)
        raise NothingUsable(f"{out}: no frame has an estimate ({counts or 'no frames'}); the "
                            "table holds each frame's status")
    return 0


# --- option parsing (each raises InputError naming the option) --------------------------------
