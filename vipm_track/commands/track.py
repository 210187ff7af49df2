"""``vipm-track track``: filtered pitch, roll, height and planar motion (EKF) of a recording,
or of an estimates table; columns in ``filters/track.py``."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..measurement import PairMeasurement, read_measurements
from .common import add_camera_options, add_input_options, add_output_options, add_speed_options

try:  # the estimator's options, where the sequence runner has landed
    from .estimate import add_estimator_options, build_config
except ImportError:  # pragma: no cover - depends on which branches are merged
    add_estimator_options = build_config = None  # type: ignore[assignment]


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "track",
        help="EKF over the two-frame estimates: mount calibration, shaking, motion",
        description="Filter the two-frame estimates of a recording (or of an estimates CSV "
        "from 'vipm-track estimate') with the EKF of filters/ekf.py: the slow mount "
        "(pitch, roll, height: the calibration), the body shaking and the planar motion. "
        "A wheel speed makes the height observable; without one it stays at --height.",
    )
    add_input_options(parser, required=False)
    parser.add_argument("--estimates", metavar="EST.csv",
                        help="skip estimation: filter this estimates table instead of images")
    add_camera_options(parser, camera_required=False)
    add_speed_options(parser)
    add_output_options(parser, "per-frame track CSV")
    group = parser.add_argument_group("filter")
    group.add_argument("--vehicle", choices=("car", "cart"), default="car",
                       help="process-noise preset (default: car)")
    group.add_argument("--gate", type=float, default=0.999, metavar="P",
                       help="chi-square probability of the innovation gate (default 0.999)")
    group.add_argument("--quiet", action="store_true", help="no progress bar, no summary")
    if add_estimator_options is not None:
        add_estimator_options(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from filters.ekf import EkfConfig
    from filters.model import NoiseParams
    from filters.track import track, write_track

    height = args.height
    if not (math.isfinite(height) and height > 0):
        raise InputError(f"--height must be a positive number of metres, got {height}")
    if not 0.5 < args.gate < 1.0:
        raise InputError(f"--gate must be a probability in (0.5, 1), got {args.gate}")
    config = EkfConfig(height_m=height, noise=NoiseParams.for_preset(args.vehicle),
                       gate_probability=args.gate, speed_gate_probability=args.gate)
    speed = load_speed(args)
    if args.estimates:
        if args.images or args.video:
            raise InputError("give --estimates or --images/--video, not both")
        try:
            measurements = read_measurements(args.estimates)
        except ValueError as exc:
            raise InputError(str(exc)) from exc
        stream: Iterator[PairMeasurement] = iter(measurements)
        total: int | None = len(measurements)
    elif args.images or args.video:
        if not args.camera:
            raise InputError("--images/--video need --camera CAMERA.yaml")
        stream, total = _estimate_stream(args, height), None
    else:
        raise InputError("give --images DIR, --video FILE or --estimates EST.csv")

    steps = track(stream, speed, config)
    if not args.quiet:
        from tqdm import tqdm

        steps = tqdm(steps, total=total, desc="track", unit="frame", file=sys.stderr)
    counts = write_track(steps, args.out, parquet=args.parquet)
    if not args.quiet:
        summary = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
        print(f"vipm-track track: {sum(counts.values())} frames ({summary}) → {args.out}",
              file=sys.stderr)
    return 0


def load_speed(args: argparse.Namespace):
    """Wheel speed on the camera clock from ``--speed-csv`` / ``--can`` (None: no speed)."""
    try:
        from filters.wheel_speed import speed_from_args
    except ImportError:
        speed_from_args = None
    if speed_from_args is not None:
        return speed_from_args(args, progress=not getattr(args, "quiet", False))
    if args.can:
        raise InputError("--can needs the CAN wheel-speed module (filters/wheel_speed.py), "
                         "absent from this build; give --speed-csv t,speed_mps instead")
    if not args.speed_csv:
        return None
    return read_speed_csv(args.speed_csv, args.speed_scale, args.clock_offset)


class _Speed:
    def __init__(self, t: np.ndarray, v: np.ndarray) -> None:
        self.t, self.speed_mps = t, v


def read_speed_csv(path: str | Path, scale: float = 1.0, clock_offset: float = 0.0) -> _Speed:
    """Speed samples from a CSV with columns ``t`` (s) and ``speed_mps`` (m/s); rows with
    empty or non-finite values are dropped; times must increase. Returns camera-clock times
    (``t + clock_offset``) and speeds times ``scale``."""
    from ..table import read_table

    if not (math.isfinite(scale) and scale > 0):
        raise InputError(f"--speed-scale {scale!r} must be a positive number")
    cols = read_table(path, required=("t", "speed_mps"))
    t, v = cols["t"], cols["speed_mps"]
    good = np.isfinite(t) & np.isfinite(v)
    t, v = t[good], v[good]
    if len(t) < 2:
        raise InputError(f"{path}: fewer than two usable speed rows")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        raise InputError(f"{path}: column 't' does not increase at data row {int(bad[0]) + 2}")
    return _Speed(t + clock_offset, v * scale)


def _estimate_stream(args: argparse.Namespace, height: float) -> Iterator[PairMeasurement]:
    """Measurements of the images/video through the sequence runner."""
    try:
        from ..pipeline import run_sequence
        from ..sources import open_source
    except ImportError as exc:
        raise InputError("image input needs the sequence runner (vipm_track/pipeline.py), "
                         "absent from this build; give --estimates EST.csv") from exc
    from ..camera import load_camera

    camera = load_camera(args.camera)
    est_config = build_config(args, camera) if build_config is not None else None
    source = open_source(images=args.images, video=args.video, fps=args.fps)
    nan7, nan77 = np.full(7, np.nan), np.full((7, 7), np.nan)
    for step in run_sequence(source, camera, height, est_config):
        if step.result is not None and step.status == "ok":
            yield step.result.to_measurement(step.frame, step.t)
        else:
            yield PairMeasurement(step.frame, step.t, nan7, nan77, height, step.status)
