"""Inputs shared by the filter commands (``track``, ``smooth``, ``monitor``): the per-frame
pair measurements, from an estimates table or through the sequence runner, and the wheel
speed, from the shared command-line options. One implementation each, so the three commands
read the same files the same way."""

from __future__ import annotations

import argparse
import math
import sys
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from vipm_track.filters.wheel_speed import SpeedSeries, read_speed_csv

from ..camera import CameraModel, load_camera, states_image_size
from ..errors import InputError, NothingUsable, interrupted_in
from ..measurement import PairMeasurement, in_sequence, read_measurements
from ..statuses import counts_text
from ..table import first_data_row
from .common import ONE_INPUT, check_images_folder, frame_window

if TYPE_CHECKING:
    from vipm_track.filters.clock_offset import ClockOffsetFit

    from ..estimator_config import EstimatorConfig
    from ..rig import Rig
    from ..sources import FrameSource


def load_speed(args: argparse.Namespace) -> SpeedSeries | None:
    """Wheel speed [t on the camera clock in s, m/s] from ``--speed-csv`` or ``--can``
    (:func:`speed_from_args`); None when neither is given. Its decode summary goes to
    stderr, under ``--quiet`` only where rows or frames were skipped."""
    quiet = getattr(args, "quiet", False)
    held: list[str] = []
    try:
        series = speed_from_args(args, progress=not quiet, report=held.append if quiet else None)
    except ValueError as exc:  # InputError is a ValueError; anything else becomes one
        if isinstance(exc, InputError):
            raise
        raise InputError(str(exc)) from exc
    if series is not None and series.summary is not None and series.summary.bad:
        for line in held:  # --quiet keeps the decode summary, not what was skipped
            print(line, file=sys.stderr)
    return series


def speed_from_args(args: argparse.Namespace, progress: bool = True,
                    report: Callable[[str], None] | None = None) -> SpeedSeries | None:
    """Speed series [t in the camera clock, m/s] from the shared CLI options
    (``add_speed_options``), or None when neither ``--speed-csv`` nor ``--can`` is given.

    ``--clock-offset`` is already added to ``t`` (``auto`` adds nothing: the offset is then
    found against the pairs, ``filters.clock_offset``) and ``--speed-scale`` applied; the
    decode summary is written through ``report`` (default: stderr)."""
    report = report or (lambda line: print(line, file=sys.stderr))
    speed_csv, log = getattr(args, "speed_csv", None), getattr(args, "can", None)
    dbc, signals = getattr(args, "dbc", None), getattr(args, "signals", None)
    # `or 1.0` would read --speed-scale 0 as no scale at all
    scale = float(getattr(args, "speed_scale", 1.0))
    offset = getattr(args, "clock_offset", 0.0) or 0.0
    offset = 0.0 if offset == "auto" else float(offset)
    if speed_csv and log:
        raise InputError("give either --speed-csv or --can, not both")
    # a decoding option with nothing to decode was silently ignored
    decoding = [name for name, given in (
        ("--dbc", dbc), ("--signals", signals),
        ("--can-channel", getattr(args, "can_channel", None) is not None),
        ("--combine", getattr(args, "combine", "mean") != "mean")) if given]
    if not speed_csv and not log:
        if decoding:
            raise InputError(f"{'/'.join(decoding)} decode a CAN log: give --can LOG")
        timing = [name for name, given in (
            ("--speed-scale", scale != 1.0),
            ("--clock-offset", getattr(args, "clock_offset", 0.0) not in (0.0, None))) if given]
        if timing:
            raise InputError(f"{'/'.join(timing)} apply to a wheel speed: give --speed-csv "
                             "or --can")
        return None
    if speed_csv and decoding:
        raise InputError(f"{'/'.join(decoding)} decode a CAN log (--can); --speed-csv "
                         f"{speed_csv} is a speed already")
    if speed_csv:
        if not (math.isfinite(scale) and scale > 0):
            raise InputError(f"--speed-scale {scale!r} must be a positive number")
        series = read_speed_csv(speed_csv).scaled(scale)
    else:
        if not dbc:
            raise InputError(f"--can {log} needs --dbc DBC to decode it")
        # imported here: cantools and python-can cost every other command's start 0.2 s
        from vipm_track.filters.speed_decoder import decode_can_log

        series, _ = decode_can_log(log, dbc, signals, combine=getattr(args, "combine", "mean"),
                                   channel=getattr(args, "can_channel", None), scale=scale,
                                   progress=progress)
    if series.summary is not None:
        for line in series.summary.lines():
            report(line)
        if series.summary.interrupted:
            raise KeyboardInterrupt
    series = series.with_samples()
    return series.shifted(offset) if offset else series


def speed_on_camera_clock(
    args: argparse.Namespace,
    speed: SpeedSeries | None,
    measurements: list[PairMeasurement],
) -> tuple[SpeedSeries | None, ClockOffsetFit | None]:
    """``speed`` on the camera clock: with ``--clock-offset auto`` shifted by the offset
    ``filters.clock_offset`` finds against ``measurements`` (said on stderr unless
    ``--quiet``), else as :func:`load_speed` gave it; and the fit, or None."""
    if speed is None:
        return None, None
    if getattr(args, "clock_offset", 0.0) != "auto":
        check_speed_overlap(speed, [m.t for m in measurements], strict=True)
        warn_speed_sign(speed, measurements)
        warn_speed_fit(speed, measurements)
        return speed, None
    from vipm_track.filters.clock_offset import estimate_clock_offset

    fit = estimate_clock_offset(measurements, speed)
    if not getattr(args, "quiet", False):
        assumed = next((m.height_assumed for m in measurements if m.ok), float("nan"))
        print(f"vipm-track: {fit.line()}; the wheel speed puts the camera "
              f"{fit.height_m(assumed):.3f} m above the ground (assumed {assumed:.3f} m)",
              file=sys.stderr)
    shifted = speed.shifted(fit.offset_s)
    warn_speed_sign(shifted, measurements)
    warn_speed_fit(shifted, measurements, check_clock=False)  # its clock: the fit's
    return shifted, fit


def warn_speed_fit(speed: SpeedSeries, measurements: list[PairMeasurement],
                   check_clock: bool = True) -> None:
    """Warn (stderr, ``--quiet`` or not) where the wheel speed does not fit the pairs' travel:
    the height it implies, its clock unless ``check_clock`` is off (``filters.speed_check``).
    The filters' gates would reject its pairs one by one and keep a confident height."""
    from vipm_track.filters.speed_check import speed_fit_notes

    for note in speed_fit_notes(measurements, speed, check_clock):
        print(f"vipm-track: warning: {note}", file=sys.stderr)


def warn_speed_sign(speed: SpeedSeries, measurements: list[PairMeasurement]) -> None:
    """Warn (stderr) of each span of 2 s or more where the wheel speed says the vehicle
    reverses while the images move forward: the filters then use the speed's magnitude."""
    from vipm_track.filters.model import speed_sign_conflicts

    t = np.array([m.t for m in measurements], dtype=float)
    z = np.array([m.z if m.ok else np.full(7, np.nan) for m in measurements],
                 dtype=float).reshape(-1, 7)
    for first, last in speed_sign_conflicts(t, speed.speed_at(t), z):
        print(f"vipm-track: warning: {speed.source or 'wheel speed'}: negative (reversing) "
              f"from t={first:.2f} to {last:.2f} s while the images move forward; its "
              "magnitude is used (a speed signed the other way round?)", file=sys.stderr)


def check_speed_overlap(speed: SpeedSeries, frame_times: list[float], strict: bool) -> None:
    """Say when the speed's samples [s, camera clock] cover none of ``frame_times`` (an
    :class:`InputError` if ``strict``, else a warning on stderr: the frames are already
    written), or fewer than half of them (a warning)."""
    covered, spans = speed.overlap(frame_times)
    if covered * 2 >= len(frame_times):
        return
    if covered == 0:
        message = speed.none_covered(spans, "set --clock-offset to the camera time minus the "
                                     "speed time, or to 'auto'")
        if strict:
            raise InputError(message)
        print(f"vipm-track: warning: {message}", file=sys.stderr)
        return
    print(f"vipm-track: warning: {speed.source or 'wheel speed'}: only {covered} of "
          f"{len(frame_times)} frames have a wheel speed ({spans})", file=sys.stderr)


def read_estimates(path: str, notes: list[str] | None = None) -> list[PairMeasurement]:
    """The pair measurements of an estimates table (``vipm-track estimate``) that form a
    sequence (``measurement.in_sequence``: a repeated frame, a frame or time going backwards
    is left out; a row saying ok without its numbers is read as no estimate), what was left
    out said on stderr with its row numbers, ``--quiet`` or not (and appended to ``notes``).
    InputError naming the file when it is missing, empty or lacks a column."""
    try:
        measurements = read_measurements(path)
    except ValueError as exc:  # TableError is an InputError; a missing column is not
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{path}: {exc}") from exc
    if not measurements:
        raise InputError(f"{path}: no rows")
    rows = len(measurements)
    measurements, issues = in_sequence(measurements, first_data_row(path))
    issues.check_a_sequence(str(path), rows)
    lines = issues.lines(str(path)) if issues else []
    if notes is not None:
        notes.extend(lines)
    for line in lines:
        print(f"vipm-track: warning: {line}", file=sys.stderr)
    return measurements


def estimator_setup(
    args: argparse.Namespace,
    camera: CameraModel,
    height: float,
    pitch_deg: float | None = None,
    roll_deg: float | None = None,
) -> tuple[Rig, EstimatorConfig]:
    """The rig (``build_rig``: ``camera`` at ``height`` [m], ``pitch_deg``/``roll_deg`` the
    nominal pose unless ``--pitch``/``--roll`` are given, e.g. the monitor's nominal
    calibration) and the estimator configuration of the estimator options in ``args``
    (where the command has them)."""
    from ..estimator_config import EstimatorConfig
    from .estimator_options import build_config, build_rig

    config = build_config(args, camera) if hasattr(args, "grid") else EstimatorConfig()
    return build_rig(args, camera, height, pitch_deg, roll_deg), config


def with_searched_nominal(
    args: argparse.Namespace,
    source: FrameSource,
    rig: Rig,
    config: EstimatorConfig,
) -> tuple[Rig, EstimatorConfig]:
    """``rig`` at the nominal pose ``nominal_search.search_nominal_pose`` finds on the first
    frames of ``source`` where the cold start from the rig's pitch fails (a forward-looking
    camera) or converges far from it (a camera 35° down), with ``config``; where the drive
    does not determine the pose, ``config`` says so (``nominal_undetermined``); unchanged
    otherwise. Says so on stderr unless ``--quiet``. Call it only where the user gave no
    ``--pitch`` (nor a nominal calibration)."""
    from ..nominal_search import NominalNotFound, search_nominal_pose

    found = search_nominal_pose(source, rig, config)
    if found is None:
        return rig, config
    if isinstance(found, NominalNotFound):  # said --quiet or not: every pair may fail
        print(f"vipm-track: warning: {found.line()}", file=sys.stderr)
        return rig, config
    if not found.determined:
        print(f"vipm-track: warning: {found.line()}", file=sys.stderr)
        return rig, replace(config, nominal_undetermined=found.undetermined)
    if not getattr(args, "quiet", False):
        print(f"vipm-track: {found.line()}", file=sys.stderr)
    roll = found.roll_deg if getattr(args, "roll", None) is None else None
    return rig.with_pose(found.pitch_deg, roll), config


def with_searched_setup(
    args: argparse.Namespace,
    source: FrameSource,
    rig: Rig,
    config: EstimatorConfig,
    search_pose: bool,
) -> tuple[Rig, EstimatorConfig]:
    """``rig`` and ``config`` with what the user left to the data: the nominal pose where
    ``search_pose`` (no ``--pitch``: :func:`with_searched_nominal`) and the rolling shutter's
    readout (:func:`with_searched_readout`, from that nominal pose); where both were searched
    and the readout found is not the rig's, the nominal pose is searched again under it."""
    check_readout_within_frames(source, rig)
    searched = with_searched_nominal(args, source, rig, config) if search_pose else (rig, config)
    with_readout = with_searched_readout(args, source, *searched)
    unchanged = searched[0] is rig and searched[1] is config
    if unchanged or with_readout.readout_s == searched[0].readout_s:
        return with_readout, searched[1]
    return with_searched_nominal(args, source, rig.with_readout(with_readout.readout_s), config)


#: the message where neither --camera nor a camera file beside the images is there
CAMERA_NOT_FOUND = ("--camera not given: give --camera CAMERA.yaml (a camera.yaml or calib.txt "
                    "is found beside --images, not beside a --video)")


def load_frames_camera(path: str, images: str | None, video: str | None) -> CameraModel:
    """The camera file at ``path`` for the frames of ``images`` or ``video`` (a KITTI
    calib.txt takes their size); InputError naming the file where its image size is not
    theirs (said at the first frame before, without naming the camera file)."""
    from ..sources import first_frame_size

    size = first_frame_size(images, video)
    camera = load_camera(path, size)
    if size is not None and size != (camera.width, camera.height):
        raise InputError(f"{path}: the camera is {camera.width}×{camera.height} px but the "
                         f"frames of {images or video} are {size[0]}×{size[1]} px: is it "
                         "their camera?")
    off = (abs(camera.cx / camera.width - 0.5), abs(camera.cy / camera.height - 0.5))
    sizeless = not states_image_size(path)
    if max(off) > OFF_CENTRE_WARNING or (sizeless and off[0] > SIZELESS_OFF_CENTRE_WARNING):
        # a KITTI calib.txt has no size to refuse: another camera's file on these frames
        # gave `ok` rows 4-7° off at σ 0.007°, as did its own on resized frames
        print(f"vipm-track: warning: {path}: the principal point ({camera.cx:g}, "
              f"{camera.cy:g}) lies {100 * max(off):.0f} % of the image from the centre of "
              f"the {camera.width}×{camera.height} frames: is it their camera"
              + (" (the file states no image size: were the frames resized or cropped "
                 "since it was calibrated?)" if sizeless else "") + "?",
              file=sys.stderr)
    return camera


#: a principal point further than this share of the image's width or height from its centre
#: is questioned (calibrated lenses: a few per cent; a cropped image's may be more)
OFF_CENTRE_WARNING = 0.2
#: the same across the width for a camera file that states no image size (KITTI calib.txt):
#: frames are cropped in height (a hood), seldom in width, so across the width a resize shows
SIZELESS_OFF_CENTRE_WARNING = 0.1


def check_readout_within_frames(source: FrameSource, rig: Rig) -> None:
    """InputError where the rig's rolling-shutter readout is longer than the recording's
    first frame interval: a sensor reads a frame out within its interval, and every pair
    of such a run "did not converge" without saying why."""
    if not rig.readout_s:
        return
    try:
        times = [frame.t for frame in source.frames(0, 2)]
    except NotImplementedError:  # a stream: its frames are read once, by the run
        return
    if len(times) == 2 and 0 < times[1] - times[0] < rig.readout_s:
        raise InputError(f"--readout-time {rig.readout_s:g} s is longer than the frame "
                         f"interval of {source.description} ({times[1] - times[0]:g} s between "
                         "its first two frames): a rolling shutter reads a frame out within it")


#: a given nominal pitch this far from the direction of travel's (beyond 3 of its standard
#: errors) is questioned [deg]: KITTI 07's pairs scatter 0.74° about the poses' travel
GIVEN_PITCH_TOLERANCE_DEG = 2.0


def warn_given_pitch(args: argparse.Namespace, source: FrameSource, rig: Rig) -> None:
    """Where ``--pitch`` was given: a warning on stderr if the direction of travel over pairs
    spread over the first 300 frames (``nominal_search.travel_pitch_over``) puts the camera at
    another pitch. A level camera's rows follow the nominal pose they start from (KITTI 07
    with ``--pitch -5``: every pair ``ok`` at −5.1 ± 1.2°, travel +78 %). Called after a run
    (its first row is not delayed)."""
    if getattr(args, "pitch", None) is None:
        return
    from ..nominal_search import LEVEL_PITCH_DEG, travel_pitch_over
    from ..travel_direction import AGREE_DEG

    travel = travel_pitch_over(source, rig.camera, 300, math.radians(rig.roll_deg))
    # a steep camera's rows find its pitch from any start: only a level one's follow it
    if not travel.determined or min(travel.pitch_deg, rig.pitch_deg) >= LEVEL_PITCH_DEG:
        return
    off = rig.pitch_deg - travel.pitch_deg
    if abs(off) <= GIVEN_PITCH_TOLERANCE_DEG + 3.0 * travel.standard_error_deg:
        return
    print(f"vipm-track: warning: --pitch {args.pitch:g}° but the direction of travel over "
          f"{travel.pairs} pairs spread over the drive's first frames puts the camera at pitch "
          f"{travel.pitch_deg:.1f}° ({travel.agreeing} pairs within {AGREE_DEG:g}°): a "
          "level camera's rows follow the nominal pose they start from, their pitch and "
          f"travel with it ({off:+.1f}° here); check --pitch, or leave it out to take the "
          "travel's", file=sys.stderr)


def warn_readout_stake(
    args: argparse.Namespace, source: FrameSource, rig: Rig, config: EstimatorConfig,
) -> None:
    """Where no ``--readout-time`` was given: a warning on stderr if a typical rolling
    shutter's readout would move this drive's pose or travel (``readout_stake``); a global
    shutter is assumed either way. Called after a run, so as not to delay its first row."""
    if getattr(args, "readout_time", 0.0) is not None or config.nominal_undetermined:
        return
    from ..readout_stake import readout_stake

    stake = readout_stake(source, rig, config)
    if stake is not None and stake.matters:
        print(f"vipm-track: warning: {stake.line()}", file=sys.stderr)


def with_searched_readout(
    args: argparse.Namespace,
    source: FrameSource,
    rig: Rig,
    config: EstimatorConfig,
) -> Rig:
    """With ``--readout-time auto``: ``rig`` with the readout that
    ``readout_search.search_readout`` finds on pairs of ``source`` that move (said on stderr
    unless ``--quiet``; where none can be fitted or the pairs do not determine it, a warning
    and a global shutter); otherwise ``rig`` itself."""
    if getattr(args, "readout_time", 0.0) != "auto":
        return rig
    from ..readout_search import search_readout

    found = search_readout(source, rig, config)
    if found is None:
        print("vipm-track: warning: --readout-time auto: no readout could be fitted (fewer "
              "than 2 pairs that move were solved at the readouts tried); going on with a "
              "global shutter (give --readout-time SECONDS)", file=sys.stderr)
        return rig.with_readout(0.0)
    if not found.determined:
        print(f"vipm-track: warning: {found.line()}", file=sys.stderr)
        return rig.with_readout(0.0)
    if not getattr(args, "quiet", False):
        print(f"vipm-track: {found.line()}", file=sys.stderr)
    return rig.with_readout(found.readout_s)


def estimate_stream(
    args: argparse.Namespace,
    height: float,
    config: EstimatorConfig | None = None,
    sink: Any = None,
    rig: Rig | None = None,
) -> Iterator[PairMeasurement]:
    """One pair measurement per frame of ``--images``/``--video`` through the sequence runner
    (tracking mode) at the assumed ``height`` [m]; frames without an estimate carry their
    status and NaNs. With a rerun ``sink`` each pair's images, patches and IPM views are
    logged as they come. ``rig`` and ``config`` default to :func:`estimator_setup` of
    ``args`` (the nominal pose searched where no ``--pitch`` is given); a ``rig`` given is
    the caller's nominal and is not searched. The options are checked and the source opened
    here, before the first measurement is asked for (so a bad option stops the command
    before it writes anything)."""
    from ..sources import open_source
    from .estimator_options import parallel_settings

    check_images_folder(args)
    if not args.camera:
        raise InputError(CAMERA_NOT_FOUND)
    parallel = parallel_settings(args)
    search_pose = rig is None and getattr(args, "pitch", None) is None
    if rig is None or config is None:
        camera = load_frames_camera(args.camera, args.images, args.video)
        built_rig, built_config = estimator_setup(args, camera, height)
        rig, config = rig or built_rig, config or built_config
    frame_window([], int, getattr(args, "start", 0), getattr(args, "max_frames", None))
    source = open_source(images=args.images, video=args.video, fps=args.fps,
                         start=getattr(args, "start", 0),
                         max_frames=getattr(args, "max_frames", None))
    rig, config = with_searched_setup(args, source, rig, config, search_pose)

    def at_end(plain: Any = source, rig: Rig = rig, config: EstimatorConfig = config) -> None:
        warn_readout_stake(args, plain, rig, config)

    if sink is not None:
        from ..sinks.rerun_sequence import ImageTap

        source = ImageTap(source, rig.camera)
        config = replace(config, keep_images=True)
    return _measurements(source, rig, config, parallel, height, sink, at_end)


def _measurements(source: Any, rig: Rig, config: EstimatorConfig, parallel: dict[str, Any],
                  height: float, sink: Any,
                  at_end: Callable[[], None]) -> Iterator[PairMeasurement]:
    """The pair measurements of :func:`estimate_stream`, as the sequence runner makes them;
    ``at_end`` is called after the last (what the shutter assumed stakes)."""
    from ..runs import sequence_steps, step_measurement

    for step in sequence_steps(source, rig, config, **parallel):
        if sink is not None and step.result is not None:
            sink.log_pair_views(step.frame, step.t, step.result, source.image(step.frame))
        yield step_measurement(step, height)
    at_end()


def frame_total(args: argparse.Namespace) -> int:
    """Frames ``--images`` / ``--video`` hold within ``--start`` / ``--max-frames`` (a
    folder's images, a video's frame count): the total a progress bar counts to."""
    from ..sources import open_source

    return len(open_source(images=args.images, video=args.video, fps=args.fps,
                           start=getattr(args, "start", 0),
                           max_frames=getattr(args, "max_frames", None)))


def measurements_from_args(
    args: argparse.Namespace,
    height: float,
    config: EstimatorConfig | None = None,
    sink: Any = None,
    rig: Rig | None = None,
    progress: bool = False,
) -> list[PairMeasurement]:
    """All pair measurements of the input: ``--estimates`` read, or ``--images``/``--video``
    estimated (:func:`estimate_stream`, with a progress bar on stderr where asked). Exactly
    one input must be given. Sets ``args.input_notes`` (what reading the table left out) and,
    where an interrupt stopped the estimation, ``args.interrupted_at`` (the last frame
    estimated: the measurements are those before it)."""
    given = [o for o in ("estimates", "images", "video") if getattr(args, o, None)]
    if len(given) != 1:
        raise InputError(ONE_INPUT + (f" (got --{' --'.join(given)})" if given else ""))
    if args.estimates:
        from .estimator_options import check_no_estimating_options

        check_no_estimating_options(args)
        args.input_notes = []
        measurements = read_estimates(args.estimates, args.input_notes)
        measurements = frame_window(measurements, lambda m: m.frame,
                                    getattr(args, "start", 0), getattr(args, "max_frames", None),
                                    args.estimates)
        require_usable(measurements, args.estimates)
        return measurements
    stream = estimate_stream(args, height, config, sink, rig)
    if progress:
        from ..progress import progress_bar

        stream = progress_bar(stream, desc="estimate", unit="frame", total=frame_total(args))
    out = collect_until_interrupt(stream)
    if out.interrupted and not any(m.ok for m in out.items):
        raise KeyboardInterrupt  # an interrupted run, not an unusable input
    if not out.items:
        raise InputError(f"{args.images or args.video}: no frames")
    require_usable(out.items, str(args.images or args.video), estimated_here=True)
    if out.interrupted:
        print(f"vipm-track: interrupted while estimating: going on with the {len(out.items)} "
              "frames estimated before it (interrupt again to stop at once)", file=sys.stderr)
        args.interrupted_at = out.items[-1].frame
    return out.items


@dataclass
class Collected:
    """Items of a stream up to its end or an interrupt (``interrupted`` says which)."""

    items: list[Any]
    interrupted: bool = False


def collect_until_interrupt(stream: Iterable[Any]) -> Collected:
    """Every item of ``stream``; on Ctrl-C / SIGTERM the items read before it, with
    ``interrupted`` set (what was computed is kept for the caller to write)."""
    out = Collected([])
    try:
        for item in stream:
            out.items.append(item)
    except KeyboardInterrupt:
        out.interrupted = True
    except SystemError as exc:
        if not interrupted_in(exc):
            raise
        out.interrupted = True
    return out


def require_usable(measurements: list[PairMeasurement], source: str,
                   estimated_here: bool = False) -> None:
    """:class:`NothingUsable` (exit 1) when not one frame of ``source`` has a usable pair:
    the filters would output their priors only, which reads like an answer.
    ``estimated_here``: the pairs were estimated by this run from frames (the estimator's
    options apply), not read from an estimates table (where they are refused)."""
    if any(m.ok for m in measurements):
        return
    counts = Counter(m.status for m in measurements)
    hint = ("For a forward-looking camera give --pitch; see the estimator options."
            if estimated_here else
            "Its statuses say why; estimate the frames again (a forward-looking camera: "
            "with --pitch; the estimator options).")
    raise NothingUsable(
        f"{source}: no frame has a usable pair estimate ({counts_text(counts)}); nothing is "
        f"written. {hint}")
