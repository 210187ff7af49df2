"""``vipm-track monitor``: per-frame calibration verdict (``filters.monitor``) of a recording
or of an estimates table, with the EKF in between; CSV (+ Parquet) and JSON-lines events.

Output columns: the conventions' columns with the EKF's filtered frame pose and motion
(height = the filter's mount height), the measurement's ``status``; then ``monitor_state``,
``reason``, ``stat_pitch``/``stat_roll``/``stat_height`` (largest CUSUM over its threshold,
1 = alarm), ``dev_*`` (1 s average of the measured pose − nominal), ``mount_*`` (the EKF's
mount estimate), and while DRIFTING / RECALIBRATE ``new_*`` with ``new_*_lo``/``new_*_hi``
(the new extrinsics and their 95 % interval).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import Counter
from typing import Any

from vipm_track.filters.monitor_table import MONITOR_COLUMNS, MONITOR_TABLE, monitor_row

from .. import json_text
from ..camera import load_camera
from ..errors import InputError
from ..table import TableWriter, choose_columns
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
from .inputs import (
    estimator_setup,
    load_speed,
    measurements_from_args,
    speed_on_camera_clock,
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "monitor",
        help="is the camera still calibrated? per-frame state and recalibration events",
        description="Estimate (or read) the per-frame pose, filter it, and judge every frame "
        "against a nominal calibration: UNCALIBRATED, CALIBRATED, DRIFTING, RECALIBRATE (with "
        "the new extrinsics and their 95 % interval), INVALID, HOLD.",
    )
    add_filter_inputs(parser, "judge", height_required=False)
    parser.add_argument("--nominal", required=True, metavar="CALIB.yaml",
                        help="nominal calibration: pitch_deg, roll_deg, height_m, tolerances, "
                        "limits (see data/nominal_car.yaml)")
    add_output_options(parser, "per-frame monitor CSV")
    parser.add_argument("--events", metavar="EVENTS.jsonl",
                        help="write one JSON line per state change")
    add_monitor_test_options(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bars or summary")
    add_estimator_options(parser)
    add_parallel_options(parser)
    add_rerun_options(parser)
    parser.set_defaults(handler=run)


def add_monitor_test_options(parser: argparse.ArgumentParser) -> None:
    """The drift test's settings (``monitor`` and ``live``): its false-alarm rate and the
    road's slow tilt that is not a calibration change."""
    parser.add_argument("--false-alarms-per-hour", type=float, default=0.1, metavar="RATE",
                        help="false-alarm rate the test is set for (default 0.1)")
    parser.add_argument("--road-std", type=float, default=0.0, metavar="DEG",
                        help="slow road-relative tilt that is not a calibration change (road "
                        "camber and slope, load): its std on pitch and roll (default 0: flat "
                        "ground; ~0.5 on public roads, see docs/usage.md)")
    parser.add_argument("--road-tau", type=float, default=2.0, metavar="S",
                        help="time constant of that tilt (default 2)")


#: the largest slow road tilt and time constant the drift test takes [deg, s]: beyond them
#: no road tilts, and --road-std 1e200 overflowed into a CALIBRATED verdict
MAX_ROAD_STD_DEG = 10.0
MAX_ROAD_TAU_S = 3600.0


def check_monitor_test_options(args: argparse.Namespace) -> None:
    """InputError naming the first of :func:`add_monitor_test_options`' values out of range."""
    if not (math.isfinite(args.false_alarms_per_hour) and args.false_alarms_per_hour > 0):
        raise InputError(f"--false-alarms-per-hour must be > 0, got {args.false_alarms_per_hour}")
    if not (math.isfinite(args.road_std) and 0 <= args.road_std <= MAX_ROAD_STD_DEG):
        raise InputError(f"--road-std must be in [0, {MAX_ROAD_STD_DEG:g}] degrees, got "
                         f"{args.road_std}")
    if not (math.isfinite(args.road_tau) and 0 < args.road_tau <= MAX_ROAD_TAU_S):
        raise InputError(f"--road-tau must be in (0, {MAX_ROAD_TAU_S:g}] seconds, got "
                         f"{args.road_tau}")


def run(args: argparse.Namespace) -> int:
    from vipm_track.filters.ekf_state import EkfConfig
    from vipm_track.filters.monitor_inputs import frame_rate, monitor_frames
    from vipm_track.filters.monitor_types import MonitorConfig
    from vipm_track.filters.nominal import load_nominal

    out = check_output(args.out, args.parquet)
    columns = choose_columns(MONITOR_TABLE, args.columns)
    if args.events:
        check_writable(args.events, "--events")
    check_rerun_output(args)
    try:
        nominal = load_nominal(args.nominal)
    except UnicodeDecodeError as exc:
        raise InputError(f"{args.nominal}: not a text file (undecodable byte at offset "
                         f"{exc.start}); a nominal calibration is YAML") from None
    height = check_height(nominal_height(args.height, nominal.height_m, args.nominal))
    check_monitor_test_options(args)
    # the camera is needed only to estimate from images (inputs.estimate_stream says so)
    camera = load_camera(args.camera) if args.camera else None
    speed = load_speed(args)
    progress = not args.quiet
    from ..sinks.rerun_filters import log_monitor_run
    from .rerun_options import sink_from_args

    sink = sink_from_args(args, "vipm-track monitor", layout="drift")
    # the cold start of the estimator is seeded with the nominal calibration
    rig, config = (None, None) if args.estimates or camera is None else estimator_setup(
        args, camera, height, pitch_deg=nominal.pitch_deg, roll_deg=nominal.roll_deg)
    measurements = measurements_from_args(args, height, config, sink, rig, progress)
    speed, _ = speed_on_camera_clock(args, speed, measurements)

    ekf_config = EkfConfig(height_m=height)
    config = MonitorConfig.from_noise(
        ekf_config.noise, fps=frame_rate(measurements),
        false_alarms_per_hour=args.false_alarms_per_hour,
        road_std_deg=args.road_std, road_tau_s=args.road_tau,
    )
    states: list[Any] = []
    outputs: list[Any] = []
    n_events = 0
    parquet = out.with_suffix(".parquet") if args.parquet else None
    events = open(args.events, "w", newline="\n") if args.events else None
    try:
        with TableWriter(out, MONITOR_COLUMNS, parquet, columns) as writer:
            for m, s, o in monitor_frames(measurements, nominal, speed, config, ekf_config,
                                          progress):
                writer.write(monitor_row(m, s, o))
                states.append(s)
                outputs.append(o)
                if events is not None and o.event is not None:
                    events.write(json_text.dumps(o.event) + "\n")
                    events.flush()
                    n_events += 1
    finally:
        if events is not None:
            events.close()
    log_monitor_run(sink, measurements, states, outputs, progress, nominal)
    if progress:
        counts = Counter(o.state for o in outputs)
        summary = ", ".join(f"{k} {v}" for k, v in counts.most_common())
        flagged = next((o for o in outputs if o.state == "RECALIBRATE"), None)
        print(f"{out}: {len(outputs)} frames ({summary})"
              + (f"; {n_events} events -> {args.events}" if args.events else ""),
              file=sys.stderr)
        if flagged is not None:
            print(f"first RECALIBRATE at t={flagged.t:.2f} s (frame {flagged.frame}): "
                  f"{flagged.reason}", file=sys.stderr)
        if not any(math.isfinite(o.deviation[2]) for o in outputs):
            why = _untested_height_why(outputs, speed is not None)
            print(f"height not tested: no frame had a metric travel ({why}); the tables' "
                  f"height columns repeat the nominal {nominal.height_m:g} m", file=sys.stderr)
    if getattr(args, "interrupted_at", None) is not None:
        raise KeyboardInterrupt
    return 0


def _untested_height_why(outputs: list, speed_given: bool) -> str:
    """Why no frame tested the height: no wheel speed, the frames held (for most of them one
    reason: slow driving of a forward camera), or wheels that stood or had no sample."""
    if not speed_given:
        return "give wheel speed: --speed-csv or --can"
    held = Counter(o.reason.split(";")[0] for o in outputs if o.state == "HOLD")
    if held:
        reason, n = held.most_common(1)[0]
        if n >= len(outputs) / 2:
            return f"{n} of {len(outputs)} frames held: {reason}"
    return "the wheel speed given says the vehicle stood or had no sample at every moving pair"


def nominal_height(height: float | None, nominal_height_m: float, nominal_file: str) -> float:
    """The one nominal camera height [m]: the nominal file's ``height_m``; ``--height`` may
    repeat it, and an InputError names both where it says otherwise."""
    if height is None or math.isclose(height, nominal_height_m, rel_tol=0, abs_tol=1e-6):
        return nominal_height_m
    raise InputError(f"--height {height:g} m contradicts the nominal calibration "
                     f"{nominal_file}: height_m {nominal_height_m:g} m; give the height in "
                     "one place (without --height the nominal file's is used)")


