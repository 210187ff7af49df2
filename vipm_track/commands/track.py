"""``vipm-track track``: filtered pitch, roll, height and planar motion (EKF) of a recording,
or of an estimates table; columns in ``filters/track.py``."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, NothingUsable
from ..measurement import PairMeasurement
from ..table import choose_columns
from .common import (
    add_filter_inputs,
    add_output_options,
    add_rerun_options,
    check_height,
    check_output,
    check_rerun_output,
    frame_window,
)
from .estimator_options import (
    add_estimator_options,
    add_parallel_options,
    check_no_estimating_options,
)
from .inputs import (
    check_speed_overlap,
    estimate_stream,
    frame_total,
    load_speed,
    measurements_from_args,
    read_estimates,
    require_usable,
    speed_on_camera_clock,
    warn_speed_fit,
    warn_speed_sign,
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "track",
        help="EKF over the two-frame estimates: mount calibration, shaking, motion",
        description="Filter the two-frame estimates of a recording (or of an estimates CSV "
        "from 'vipm-track estimate') with the EKF of filters/ekf.py: the slow mount "
        "(pitch, roll, height: the calibration), the body shaking and the planar motion. "
        "A wheel speed makes the height observable; without one it stays at --height.",
    )
    add_filter_inputs(parser, "filter", height_required=False)
    add_output_options(parser, "per-frame track CSV")
    group = parser.add_argument_group("filter")
    group.add_argument("--vehicle", choices=("car", "cart"), default="car",
                       help="process-noise preset (default: car)")
    group.add_argument("--gate", type=float, default=0.999, metavar="P",
                       help="chi-square probability of the innovation gate (default 0.999)")
    group.add_argument("--quiet", action="store_true", help="no progress bar, no summary")
    add_estimator_options(parser)
    add_parallel_options(parser)
    add_rerun_options(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from vipm_track.filters.ekf import ExtrinsicsEKF
    from vipm_track.filters.ekf_state import EkfConfig
    from vipm_track.filters.forward_slow import slow_share_note
    from vipm_track.filters.model import NoiseParams
    from vipm_track.filters.mount_change import short_drive_note, unfollowed_steps_note
    from vipm_track.filters.mount_steps import untested_drive_note
    from vipm_track.filters.track import TRACK_TABLE, track, write_track

    out = check_output(args.out, args.parquet)
    columns = choose_columns(TRACK_TABLE, args.columns)
    check_rerun_output(args)
    height = check_height(args.height)
    if not 0.5 < args.gate < 1.0:
        raise InputError(f"--gate must be a probability in (0.5, 1), got {args.gate}")
    config = EkfConfig(height_m=height, noise=NoiseParams.for_preset(args.vehicle),
                       gate_probability=args.gate, speed_gate_probability=args.gate)
    speed = load_speed(args)
    from ..sinks.rerun_filters import log_track_steps
    from .rerun_options import sink_from_args

    sink = sink_from_args(args, "vipm-track track", layout="drift")
    streamed = False
    if args.clock_offset == "auto" and speed is not None:
        # the offset is found against every pair, so the estimates come first here
        measurements = measurements_from_args(args, height, sink=sink, progress=not args.quiet)
        speed, _ = speed_on_camera_clock(args, speed, measurements)
        stream: Iterator[PairMeasurement] = iter(measurements)
        total: int | None = len(measurements)
    elif args.estimates:
        if args.images or args.video:
            raise InputError("give --estimates or --images/--video, not both")
        check_no_estimating_options(args)
        measurements = frame_window(read_estimates(args.estimates),
                                    lambda m: m.frame, args.start, args.max_frames,
                                    args.estimates)
        require_usable(measurements, args.estimates)
        speed, _ = speed_on_camera_clock(args, speed, measurements)
        stream = iter(measurements)
        total = len(measurements)
    elif args.images or args.video:
        stream, total = estimate_stream(args, height, sink=sink), frame_total(args)
        streamed = True
    else:
        raise InputError("give --images DIR, --video FILE or --estimates EST.csv")

    frame_times: list[float] = []
    usable = _Usable()
    stream = _noting_times(stream, frame_times, usable)
    ekf = ExtrinsicsEKF(config, speed_series=speed)
    steps = log_track_steps(sink, track(stream, speed, config, ekf))
    if not args.quiet:
        from ..progress import progress_bar

        steps = progress_bar(steps, total=total, desc="track", unit="frame")
    counts = write_track(steps, out, parquet=args.parquet, columns=columns)
    if speed is not None and not args.quiet:
        check_speed_overlap(speed, frame_times, strict=False)
    if speed is not None and streamed:
        # estimated as it filtered: the speed is held to the pairs' travel once they are known
        # (a video's wrong frame rate, say)
        warn_speed_sign(speed, usable.pairs)
        warn_speed_fit(speed, usable.pairs)
    if not args.quiet:
        summary = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
        print(f"vipm-track track: {sum(counts.values())} frames ({summary}) → {args.out}",
              file=sys.stderr)
    times = [t for t in frame_times if math.isfinite(t)]
    # a knock before the EKF's test is armed (6 s) is left to the check of the pairs' steps
    # below, which needs 8 blocks of frames: between the two, a knock went unsaid
    short = ((short_drive_note(times[-1] - times[0]) if len(times) > 1 else "")
             or untested_drive_note(np.array(usable.t), tests="the check for steps of the "
                                    "pairs that the mount did not follow"))
    for note in (short,
                 slow_share_note(np.array(usable.pitch_deg), np.array(usable.slow)),
                 unfollowed_steps_note(np.array(usable.t), np.radians(np.column_stack(
                     [usable.pitch_deg, usable.roll_deg]).reshape(-1, 2)),
                     ekf.mount_changes)):
        if note:  # said under --quiet too: the mount intervals do not cover it
            print(f"vipm-track track: warning: {note}", file=sys.stderr)
    source = args.estimates or args.images or args.video
    if not usable.pitch_deg:
        raise NothingUsable(f"{source}: no frame has a usable pair estimate; {args.out} holds "
                            "the filter's priors only")
    if set(counts) <= {"waiting"}:  # usable pairs, but too few for the filter to start
        from vipm_track.filters.body_scale import pairs_to_start

        start = pairs_to_start(config.init_pairs, config.body_window_s,
                               config.body_window_min_pairs)
        raise NothingUsable(
            f"{source}: the filter never started: it starts on {start} usable "
            f"pairs and the drive has {len(usable.pitch_deg)}; every row of {args.out} is "
            "'waiting for first pairs'")
    return 0


#: usable pairs kept for the wheel speed's check after a streamed run: an hour of a 30 fps
#: camera would otherwise keep 100,000 measurements; every other one is let go each time
KEPT_PAIRS = 20_000


@dataclass
class _Usable:
    """The usable pairs seen: each one's pitch [deg], whether it was slow
    (``forward_slow``), its time [s] and roll [deg]; and the pairs themselves, every
    ``stride``-th of them, at most :data:`KEPT_PAIRS` (:meth:`keep`)."""

    pitch_deg: list[float] = field(default_factory=list)
    slow: list[bool] = field(default_factory=list)
    t: list[float] = field(default_factory=list)
    roll_deg: list[float] = field(default_factory=list)
    pairs: list[PairMeasurement] = field(default_factory=list)
    stride: int = 1

    def keep(self, m: PairMeasurement) -> None:
        """Keep ``m`` if it is the next ``stride``-th usable pair, thinning the kept ones by
        half whenever they reach :data:`KEPT_PAIRS` (spread over the whole run)."""
        if (len(self.t) - 1) % self.stride:
            return
        self.pairs.append(m)
        if len(self.pairs) >= KEPT_PAIRS:
            self.pairs = self.pairs[::2]
            self.stride *= 2


def _noting_times(stream: Iterator[PairMeasurement], times: list[float], usable: _Usable,
                  ) -> Iterator[PairMeasurement]:
    """``stream`` unchanged, each measurement's time appended to ``times`` and the usable
    ones noted in ``usable`` as they pass."""
    from vipm_track.filters.forward_slow import slow_pairs

    for m in stream:
        times.append(m.t)
        if m.ok:
            usable.t.append(m.t)
            usable.keep(m)
            usable.roll_deg.append(math.degrees(m.z[3]))
            usable.pitch_deg.append(math.degrees(m.z[2]))
            usable.slow.append(bool(slow_pairs(m.z[None, :], np.array([m.height_assumed]))[0]))
        yield m
