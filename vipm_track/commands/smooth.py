"""``vipm-track smooth``: factor-graph smoothing (gtsam) of a recording or of an estimates table,
offline (whole drive) or with a sliding window; same columns as ``vipm-track track``."""

from __future__ import annotations

import argparse
import math
import sys
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

from vipm_track.filters.factors import LOSSES
from vipm_track.filters.smoother_config import SmootherConfig

from .. import json_text
from ..errors import InputError, interrupts_deferred, interrupts_held
from .common import (
    add_filter_inputs,
    add_output_options,
    add_rerun_options,
    check_height,
    check_output,
    check_rerun_output,
    check_writable,
)
from .estimator_options import add_estimator_options, add_parallel_options
from .inputs import load_speed, measurements_from_args, speed_on_camera_clock


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "smooth",
        help="smooth the two-frame estimates with a factor graph (gtsam): best calibration",
        description="Smooth the two-frame estimates of a recording (or of an estimates CSV from "
        "'vipm-track estimate', so a drive is estimated once and smoothed many times) with the "
        "factor graph of filters/smoother.py: the EKF's model (mount calibration, body "
        "shaking, planar motion) with every measurement of the drive (--lag 0, default) or "
        "of a sliding window. Writes the track table, and a summary of the drive's mount "
        "extrinsics (mean, 95 % interval, drift) as JSON and Markdown.",
    )
    add_filter_inputs(parser, "smooth", height_required=False)
    add_output_options(parser, "per-frame smoothed CSV")
    parser.add_argument(
        "--summary",
        metavar="FILE.json",
        help="drive summary (JSON; a .md beside it); default OUT.summary.json",
    )
    group = parser.add_argument_group("smoother")
    group.add_argument(
        "--lag",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="sliding-window length; 0 = the whole drive at once (default)",
    )
    group.add_argument(
        "--vehicle",
        choices=("car", "cart"),
        default="car",
        help="noise preset of filters/model.py (default: car)",
    )
    group.add_argument(
        "--loss",
        choices=LOSSES,
        default=SmootherConfig.loss,
        help="robust loss of the pair factors (default: %(default)s; redescending, so a strong "
        "outlier pair pulls the trajectory far less than with cauchy; cauchy, geman-mcclure "
        "and tukey start from two huber steps)",
    )
    group.add_argument(
        "--motion-given-pose",
        action=argparse.BooleanOptionalAction,
        default=SmootherConfig.motion_given_pose,
        help="use each pair's motion given its angles (the estimator's tz is correlated ~-0.95 "
        "with its pitch), so the smoothed frame pose corrects the pair's motion, as far as the "
        "pair's angles are trusted (default: off, each pair's own motion; measured in "
        "docs/filters.md)",
    )
    group.add_argument(
        "--body-window",
        type=float,
        default=SmootherConfig.body_window_s,
        metavar="S",
        help="seconds of pairs over which the body shaking's std is matched to the data "
        "(at least --body-std; 0: fixed at --body-std; default: %(default)s)",
    )
    group.add_argument(
        "--loss-probability",
        type=float,
        default=0.99,
        metavar="P",
        help="the loss is quadratic up to the whitened norm √χ²(P, dof) of a "
        "pair block (default 0.99)",
    )
    group.add_argument(
        "--mount-angle-rw",
        type=float,
        metavar="DEG_PER_SQRT_S",
        help="random-walk rate of the mount pitch/roll (preset: 0.002)",
    )
    group.add_argument(
        "--mount-height-rw",
        type=float,
        metavar="M_PER_SQRT_S",
        help="random-walk rate of the mount height (preset: 0.0002)",
    )
    group.add_argument(
        "--body-tau",
        type=float,
        metavar="S",
        help="time constant of the body shaking (Gauss–Markov; preset)",
    )
    group.add_argument(
        "--body-std", type=float, metavar="DEG", help="stationary std of the body shaking (preset)"
    )
    group.add_argument(
        "--lever-arm-std",
        type=float,
        metavar="M",
        help="how far the camera may sit from the axle the vehicle turns about: a turning "
        "pair's sideways motion gets that much more variance, and the prior of the lever arms "
        "fitted to the frames' sideways motion (default 2; 0 trusts the no-side-slip model)",
    )
    group.add_argument(
        "--no-std",
        action="store_true",
        help="skip the marginal covariances (std columns empty; faster)",
    )
    group.add_argument("--quiet", action="store_true",
                       help="no progress bar, no summary print (its warnings are still said)")
    add_estimator_options(parser)
    add_parallel_options(parser)
    add_rerun_options(parser)
    parser.set_defaults(handler=run)


def build_config(args: argparse.Namespace):
    """``SmootherConfig`` of the command-line options (InputError on a bad value)."""
    from vipm_track.filters.model import NoiseParams

    height = check_height(args.height)
    if not (math.isfinite(args.lag) and args.lag >= 0):
        raise InputError(f"--lag must be >= 0 seconds, got {args.lag}")
    if not 0.5 < args.loss_probability < 1.0:
        raise InputError(f"--loss-probability must be in (0.5, 1), got {args.loss_probability}")
    noise = NoiseParams.for_preset(args.vehicle)
    # (option, NoiseParams field, value, zero allowed, the largest a vehicle could need: beyond
    # it the solver's information underflows and it failed with a traceback, not an answer)
    options = [
        ("--mount-angle-rw", "mount_angle_rw_deg_per_sqrt_s", args.mount_angle_rw, False, 10.0),
        ("--mount-height-rw", "mount_height_rw_m_per_sqrt_s", args.mount_height_rw, False, 1.0),
        ("--body-tau", "body_tau_s", args.body_tau, False, 3600.0),
        ("--body-std", "body_std_deg", args.body_std, False, 45.0),
        ("--lever-arm-std", "lever_arm_std_m", args.lever_arm_std, True, 100.0),
    ]
    for flag, _, value, zero_ok, most in options:
        if value is None:
            continue
        if not (math.isfinite(value) and (value > 0 or (zero_ok and value == 0))
                and value <= most):
            what = "a number in [0, " if zero_ok else "a positive number up to "
            raise InputError(f"{flag} must be {what}{most:g}{']' if zero_ok else ''}, got "
                             f"{value}")
    noise = replace(noise, **{field: v for _, field, v, _, _ in options if v is not None})
    if not (math.isfinite(args.body_window) and 0 <= args.body_window <= 3600):
        raise InputError(f"--body-window must be a number of seconds in [0, 3600], got "
                         f"{args.body_window}")
    return SmootherConfig(
        height_m=height,
        noise=noise,
        lag_s=args.lag,
        loss=args.loss,
        loss_probability=args.loss_probability,
        motion_given_pose=args.motion_given_pose,
        body_window_s=args.body_window,
        marginals=not args.no_std,
    )


def run(args: argparse.Namespace) -> int:
    from vipm_track.filters.drive_summary import (
        summarize_mount,
        summary_markdown,
        summary_warnings,
    )
    from vipm_track.filters.smoothing import smoothed_rows
    from vipm_track.filters.track import TRACK_COLUMNS, TRACK_TABLE

    from ..table import TableWriter, choose_columns

    config = build_config(args)
    out = check_output(args.out, args.parquet)
    columns = choose_columns(TRACK_TABLE, args.columns)
    summary_path = Path(args.summary) if args.summary else out.with_suffix(".summary.json")
    check_writable(summary_path, "--summary")
    check_writable(summary_path.with_suffix(".md"), "--summary")
    check_rerun_output(args)
    speed = load_speed(args)
    from ..sinks.rerun_filters import log_filter_run
    from .rerun_options import sink_from_args

    sink = sink_from_args(args, "vipm-track smooth", layout="drift")
    measurements = measurements_from_args(args, config.height_m, sink=sink,
                                          progress=not args.quiet)
    speed, clock_fit = speed_on_camera_clock(args, speed, measurements)
    pq = out.with_suffix(".parquet") if args.parquet else None
    rows: list[dict] = []
    frames: list = []
    interrupted: str | None = None
    if getattr(args, "interrupted_at", None) is not None:
        interrupted = (f"interrupted while estimating: smoothed over the frames up to "
                       f"{args.interrupted_at}")
    held = ExitStack()
    late = None
    with held:
        with TableWriter(out, TRACK_COLUMNS, parquet_path=pq, columns=columns) as writer:
            try:
                for f, row in smoothed_rows(measurements, speed, config, not args.quiet):
                    writer.write(row)
                    frames.append(f)
                    rows.append(row)
            except KeyboardInterrupt as stop:
                # from here on a second Ctrl-C would cut the rest of the table and the summary
                held.enter_context(interrupts_held())
                interrupted = _write_interrupted(writer, measurements, frames, rows)
                if str(stop):  # the batch's estimate kept, without its σ
                    interrupted = f"{interrupted}; {stop}"
            else:
                # every frame smoothed: a Ctrl-C now waits for the Parquet table and the
                # summary (it lost both), then ends the run as interrupted
                late = held.enter_context(interrupts_deferred())
        if sink is not None:
            log_filter_run(sink, measurements, rows, "smoothed")
            sink.finish()
        summary = summarize_mount(
            frames, measurements[: len(frames)],
            config.mount_steps if config.lag_s == 0 else None, speed) if frames else {}
        summary["status"] = interrupted or "complete"
        summary["input_notes"] = getattr(args, "input_notes", [])
        summary["smoother"] = {
            "lag_s": config.lag_s,
            "loss": config.loss,
            "motion_given_pose": config.motion_given_pose,
            "body_window_s": config.body_window_s,
            "wheel_speed": speed is not None,
            "clock_offset_s": None if speed is None else speed.clock_offset,
            "clock_offset_std_s": None if clock_fit is None else clock_fit.std_s,
            "source": _source_name(args),
        }
        write_text(summary_path, json_text.dumps(summary, indent=2) + "\n")
        text = summary_markdown(summary) if frames else ""
        if interrupted:
            text = f"**{interrupted}**\n\n" + text
        write_text(summary_path.with_suffix(".md"), "# Drive summary\n\n" + text)
        if not args.quiet:
            print(text, file=sys.stderr)
            print(f"vipm-track smooth: {len(rows)} frames → {out}; summary → {summary_path}",
                  file=sys.stderr)
        elif frames:
            # said under --quiet too (as track does): the numbers do not say these on their own
            for note in summary_warnings(summary):
                print(f"vipm-track smooth: warning: {note}", file=sys.stderr)
        if interrupted or (late is not None and late.requested):
            raise KeyboardInterrupt
    return 0


#: ``status`` of the frames an interrupt left unsmoothed (their measurements are written).
NOT_SMOOTHED = "interrupted: not smoothed"


def _write_interrupted(writer, measurements, frames: list, rows: list[dict]) -> str:
    """After an interrupt: one row per frame not yet written, holding its measurement with
    :data:`NOT_SMOOTHED`; the summary's status line."""
    from vipm_track.filters.track import track_row

    done = len(rows)
    idle = SimpleNamespace(initialised=False, status="interrupted", nis=float("nan"), gated="",
                           standstill=False, reset_reason="")
    for m in measurements[done:]:
        row = track_row(_at_frame(idle, m), m, None)
        row["status"] = NOT_SMOOTHED
        writer.write(row)
        rows.append(row)
    if done == len(measurements):
        return f"interrupted: all {done} frames smoothed"
    return (f"interrupted: {done} of {len(measurements)} frames smoothed, the rest written "
            f"with status '{NOT_SMOOTHED}'")


def _at_frame(state: SimpleNamespace, m) -> SimpleNamespace:
    """``state`` placed at the frame and time of measurement ``m``."""
    return SimpleNamespace(**{**vars(state), "frame": m.frame, "t": m.t})


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` with ``\\n`` line ends."""
    with path.open("w", newline="\n") as fh:
        fh.write(text)


def _source_name(args: argparse.Namespace) -> str:
    return str(args.estimates or args.images or args.video)
