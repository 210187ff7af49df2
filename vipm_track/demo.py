"""The demo: a drive whose camera mount is knocked out of its calibration, and the toolkit
catching it, scored against the rendered truth.

:func:`render_drive` renders a deterministic drive from the textures in ``data/`` (the
simulator's ``knock`` profile by default: a fixed mount on a shaking body whose pitch steps
by 1° at 40 % of the drive, with a wheel-speed CSV). :func:`run_demo` runs the whole chain
on it and writes what it found into a folder:

    images → two-frame estimator (tracking; parallel chunks) → EKF (``filters.track``'s
    filter) with the drift monitor judging every frame against the nominal calibration
    (``data/nominal_PRESET.yaml``, ``filters.monitor_inputs.monitor_frames``) → batch
    smoother (``filters.smoother``) whose mount-change test finds the knock

and scores it: per-frame errors of the estimator, the EKF and the smoother; the smoothed
mount with its 95 % interval over each span between the steps the smoother found, against
the true mount; the camera height the wheel speed gives; the monitor's events and how long
after the knock it flagged. ``demo_text.demo_lines`` says all of it in a few lines.

This module sits beside the commands, above the library's floors: it imports the simulator,
the sequence runner, the filters and the sinks, and nothing of the core imports it.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from vipm_track import json_text
from vipm_track.filters.drive_summary import summarize_mount
from vipm_track.filters.ekf import speed_at
from vipm_track.filters.ekf_state import EkfConfig
from vipm_track.filters.monitor import write_events
from vipm_track.filters.monitor_inputs import inputs_from_measurements, monitor_frames
from vipm_track.filters.nominal import NominalCalibration, load_nominal
from vipm_track.filters.smoother import mount_jumps
from vipm_track.filters.smoother_config import SmootherConfig
from vipm_track.filters.smoothing import smooth, speeds_at_frames
from vipm_track.filters.track import TRACK_COLUMNS, TRACK_TABLE, track_row, write_track
from vipm_track.filters.wheel_speed import SpeedSeries, read_speed_csv

from .camera import load_camera
from .errors import InputError
from .estimator_config import EstimatorConfig
from .evaluate import ErrorStats, error_stats, frame_errors
from .filters.monitor_table import MONITOR_COLUMNS, MONITOR_TABLE, monitor_row
from .measurement import PairMeasurement, read_measurements
from .pipeline import SequenceStep
from .resources import data_path
from .rig import Rig
from .runs import estimate_sequence
from .sim import PRESETS, simulate_sequence
from .sinks.demo_figure import write_demo_figure
from .sources import open_source
from .table import CONCISE, TableWriter, choose_columns, read_table

PRESET = "cart"
PROFILE = "knock"
SEED = 7
#: length of the default drive per preset, seconds: long enough that the monitor has settled
#: (CALIBRATED) and the mount-change test has measured its yardstick before the knock at
#: 40 % of the drive, short enough to render and estimate within a minute on two cores (cart)
SECONDS: dict[str, float] = {"cart": 25.0, "car": 20.0}
#: the drive is estimated in this many chunks (``vipm_track.parallel``), whatever the number
#: of worker processes, so that the numbers do not depend on the machine
CHUNKS = 2
#: monitor states that say the camera is no longer calibrated
FLAGS: tuple[str, ...] = ("DRIFTING", "RECALIBRATE", "INVALID")
#: seconds of smoothed frames left out on each side of a mount step when a span's mount is
#: summarised (the step's onset is known to a few frames)
STEP_MARGIN_S = 1.0
#: per-frame errors printed: (error name, label, unit, scale, decimals)
ACCURACY: tuple[tuple[str, str, str, float, int], ...] = (
    ("pitch_deg", "pitch", "°", 1.0, 4), ("roll_deg", "roll", "°", 1.0, 4),
    ("height_m", "height", " mm", 1000.0, 2), ("distance_pct", "distance", " %", 1.0, 3),
    ("yaw_deg", "yaw", "°", 1.0, 4),
)


def default_frames(preset: str) -> int:
    """Frames of the default drive of ``preset`` (:data:`SECONDS` at the preset's rate)."""
    return round(SECONDS[preset] * PRESETS[preset].fps)


# --- the drive -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Drive:
    """A rendered drive: ``folder`` holds ``images/``, ``camera.yaml``, ``gt.csv``,
    ``times.txt`` and ``speed.csv`` (``vipm_track.sim.simulate_sequence``)."""

    folder: Path
    preset: str
    profile: str
    frames: int
    seed: int

    @property
    def images(self) -> Path:
        return self.folder / "images"

    @property
    def camera_file(self) -> Path:
        return self.folder / "camera.yaml"

    @property
    def truth_file(self) -> Path:
        return self.folder / "gt.csv"

    @property
    def speed_file(self) -> Path:
        return self.folder / "speed.csv"


def render_drive(folder: str | Path, preset: str = PRESET, frames: int | None = None,
                 seed: int = SEED, profile: str = PROFILE, progress: bool = False) -> Drive:
    """Render the demo drive into ``folder`` (``frames`` default: :func:`default_frames`)."""
    if preset not in SECONDS:
        raise InputError(f"demo preset must be one of {sorted(SECONDS)}, got {preset!r}")
    frames = default_frames(preset) if frames is None else int(frames)
    simulate_sequence(preset, frames, folder, seed=seed, profile=profile, progress=progress)
    return Drive(Path(folder), preset, profile, frames, seed)


# --- results ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Interval:
    """An estimate with its 95 % interval and the truth it is held against (one unit)."""

    value: float
    lo: float
    hi: float
    truth: float

    @property
    def covers(self) -> bool:
        """Whether the truth lies in the interval (False where either is unknown)."""
        return bool(self.lo <= self.truth <= self.hi)

    def as_dict(self) -> dict[str, Any]:
        return {"value": _num(self.value), "ci95": [_num(self.lo), _num(self.hi)],
                "truth": _num(self.truth), "covers": self.covers}


@dataclass(frozen=True)
class MountSpan:
    """The smoothed mount over ``start_s``–``end_s`` (a span between mount steps): pitch and
    roll in degrees, height in metres, each against the true mount there."""

    start_s: float
    end_s: float
    pitch: Interval
    roll: Interval
    height: Interval

    def as_dict(self) -> dict[str, Any]:
        return {"start_s": self.start_s, "end_s": self.end_s, "pitch_deg": self.pitch.as_dict(),
                "roll_deg": self.roll.as_dict(), "height_m": self.height.as_dict()}


@dataclass(frozen=True)
class DemoResult:
    """What :func:`run_demo` found and wrote (times in seconds of the drive; see the module
    doc). ``knock_s``: when the true mount first changed (None: it never did);
    ``first_flag`` / ``first_recalibrate``: the monitor's first DRIFTING-or-worse /
    RECALIBRATE output at or after the knock; ``flagged_before_knock``: frames flagged before
    it; ``steps_s``: onsets of the mount steps the smoother's test found; ``spans``: the
    smoothed mount between them; ``height``: the smoothed mount height over the whole drive
    (metric through the wheel speed). The per-frame objects are kept for the sinks."""

    drive: Drive
    nominal: NominalCalibration
    nominal_file: Path
    knock_s: float | None
    pairs: int
    pairs_ok: int
    accuracy: dict[str, dict[str, ErrorStats]]
    steps_s: tuple[float, ...]
    spans: tuple[MountSpan, ...]
    height: Interval
    calibrated_s: float | None
    first_flag: Any
    first_recalibrate: Any
    flagged_before_knock: int
    events: tuple[dict[str, Any], ...]
    final: Any
    files: dict[str, Path]
    seconds: dict[str, float]
    measurements: Sequence[PairMeasurement] = field(repr=False, default=())
    ekf_states: Sequence[Any] = field(repr=False, default=())
    smoothed: Sequence[Any] = field(repr=False, default=())
    monitor: Sequence[Any] = field(repr=False, default=())

    @property
    def flag_delay_s(self) -> float | None:
        """Seconds from the knock to the first flag after it (None: no knock or no flag)."""
        if self.knock_s is None or self.first_flag is None:
            return None
        return self.first_flag.t - self.knock_s

    def summary(self) -> dict[str, Any]:
        """The numbers as a JSON-ready dict (``summary.json``)."""

        def output(o: Any) -> dict[str, Any] | None:
            if o is None:
                return None
            return {"t": o.t, "frame": o.frame, "state": o.state, "reason": o.reason,
                    **extrinsics(o)}

        return {
            "drive": {"preset": self.drive.preset, "profile": self.drive.profile,
                      "frames": self.drive.frames, "seed": self.drive.seed,
                      "duration_s": _duration(self.measurements)},
            "nominal": {"file": str(self.nominal_file), "pitch_deg": self.nominal.pitch_deg,
                        "roll_deg": self.nominal.roll_deg, "height_m": self.nominal.height_m},
            "knock_s": self.knock_s,
            "pairs": self.pairs, "pairs_ok": self.pairs_ok,
            "accuracy": {stage: {name: vars(s) for name, s in errs.items()}
                         for stage, errs in self.accuracy.items()},
            "mount_steps_s": list(self.steps_s),
            "mount_spans": [s.as_dict() for s in self.spans],
            "height_m": self.height.as_dict(),
            "monitor": {
                "calibrated_s": self.calibrated_s,
                "flagged_frames_before_knock": self.flagged_before_knock,
                "first_flag": output(self.first_flag),
                "first_recalibrate": output(self.first_recalibrate),
                "flag_delay_s": self.flag_delay_s,
                "final": output(self.final),
                "events": list(self.events),
            },
            "files": {k: str(v) for k, v in self.files.items()},
            "seconds": self.seconds,
        }


# --- the chain -------------------------------------------------------------------------------


def run_demo(
    drive: Drive,
    out: str | Path,
    config: EstimatorConfig | None = None,
    *,
    rig: Rig | None = None,
    tracking: bool = True,
    workers: int = 2,
    chunk_frames: int | None = None,
    sink: Any = None,
    progress: bool = False,
    render_seconds: float = float("nan"),
) -> DemoResult:
    """Run the chain on ``drive`` (module doc) and write into the folder ``out``:
    ``estimates.csv`` (two-frame estimator), ``track.csv`` (EKF), ``smoothed.csv`` (batch
    smoother), ``monitor.csv`` (the monitor's verdict per frame, as ``vipm-track monitor``
    writes it), ``events.jsonl`` (its state changes), ``summary.json`` (the numbers of
    :class:`DemoResult`) and ``demo.png`` (per-frame pose, mount with its bands, monitor state
    over time, the knock marked).

    ``config``: the estimator's (default: its defaults); ``rig``: the camera and the pose,
    height and readout it starts from (default: the drive's camera at the nominal pitch and
    roll, the preset's height);
    ``workers`` processes estimate ``chunk_frames``-frame chunks (default: the drive in
    :data:`CHUNKS` chunks, so the numbers do not depend on ``workers``). ``sink``: a
    ``vipm_track.sinks.rerun_sink.RerunSink`` (or None) that gets the camera images with the
    estimator's patches, the per-frame series of every stage, the truth and the monitor; it
    is left open. ``render_seconds``: time spent rendering, for the timing line."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    preset = PRESETS[drive.preset]
    nominal_file = data_path(f"nominal_{drive.preset}.yaml")
    nominal = load_nominal(nominal_file)
    seconds = {"render": render_seconds}
    files: dict[str, Path] = {}

    clock = time.perf_counter()
    if rig is None:
        rig = nominal.rig(load_camera(drive.camera_file)).with_height(preset.height_m)
    chunk_frames = chunk_frames or max(2, math.ceil(drive.frames / CHUNKS))
    files["estimates"] = out / "estimates.csv"
    estimate_sequence(open_source(images=drive.images), rig,
                      files["estimates"], config, tracking=tracking, progress=progress,
                      on_step=_pair_logger(sink, drive.images), workers=workers,
                      chunk_frames=chunk_frames)
    measurements = read_measurements(files["estimates"])
    speed = read_speed_csv(drive.speed_file)
    truth = read_table(drive.truth_file)
    seconds["estimate"] = _lap(clock)

    clock = time.perf_counter()
    ekf_config = EkfConfig(height_m=nominal.height_m)
    frames = list(monitor_frames(measurements, nominal, speed, ekf_config=ekf_config))
    states = [s for _, s, _ in frames]
    outputs = [o for _, _, o in frames]
    speeds = speed_at(speed, np.array([m.t for m in measurements]))
    files["track"] = out / "track.csv"
    write_track(((s, m, _speed(v)) for (m, s, _), v in zip(frames, speeds, strict=True)),
                files["track"])
    files["monitor"] = out / "monitor.csv"
    # the tables as `monitor` and `smooth` write them by default (the concise columns), as
    # the estimates and track tables are
    with TableWriter(files["monitor"], MONITOR_COLUMNS,
                     columns=choose_columns(MONITOR_TABLE, CONCISE)) as writer:
        for m, s, o in frames:
            writer.write(monitor_row(m, s, o))
    files["events"] = out / "events.jsonl"
    write_events(outputs, files["events"])
    seconds["EKF + monitor"] = _lap(clock)

    clock = time.perf_counter()
    smoother_config = SmootherConfig(height_m=nominal.height_m)
    smoothed = smooth(measurements, speed, smoother_config)
    files["smoothed"] = out / "smoothed.csv"
    with TableWriter(files["smoothed"], TRACK_COLUMNS,
                     columns=choose_columns(TRACK_TABLE, CONCISE)) as writer:
        for f, m, v in zip(smoothed, measurements, speeds, strict=True):
            writer.write(track_row(f, m, _speed(v)))
    steps = _step_times(measurements, speeds_at_frames(measurements, speed), smoother_config)
    seconds["smoother"] = _lap(clock)

    tables = {name: read_table(files[name]) for name in ("estimates", "track", "smoothed")}
    accuracy = {
        stage: {name: error_stats(e)
                for name, e in frame_errors(tables[key], truth, scored="finite").items()
                if name in {a[0] for a in ACCURACY}}
        for stage, key in (("estimator", "estimates"), ("EKF", "track"),
                           ("smoother", "smoothed"))
    }
    knock = _knock_time(truth)
    flags = [o for o in outputs if o.state in FLAGS]
    after = [o for o in flags if knock is not None and o.t >= knock]
    calibrated = next((o.t for o in outputs if o.state == "CALIBRATED"), None)
    result = DemoResult(
        drive=drive, nominal=nominal, nominal_file=nominal_file, knock_s=knock,
        pairs=sum(1 for m in measurements if m.status != "first frame"),
        pairs_ok=sum(1 for m in measurements if m.ok),
        accuracy=accuracy, steps_s=steps,
        spans=_mount_spans(smoothed, measurements, truth, steps, speed),
        height=_whole_height(smoothed, measurements, truth, speed),
        calibrated_s=calibrated,
        first_flag=after[0] if after else None,
        first_recalibrate=next((o for o in after if o.state == "RECALIBRATE"), None),
        flagged_before_knock=sum(1 for o in flags if knock is None or o.t < knock),
        events=tuple(o.event for o in outputs if o.event is not None),
        final=outputs[-1] if outputs else None,
        files=files, seconds=seconds,
        measurements=measurements, ekf_states=states, smoothed=smoothed, monitor=outputs,
    )

    clock = time.perf_counter()
    files["plot"] = out / "demo.png"
    wheel_height = np.array([i.pose[2] for i in inputs_from_measurements(measurements, speed)])
    write_demo_figure(
        files["plot"], estimates=tables["estimates"], smoothed=tables["smoothed"],
        truth=truth, monitor={"t": np.array([o.t for o in outputs]),
                              "monitor_state": np.array([o.state for o in outputs], object)},
        wheel_height={"t": np.array([m.t for m in measurements]), "height_m": wheel_height},
        knock_s=knock, steps_s=steps, title=title(result))
    seconds["plot"] = _lap(clock)
    if sink is not None:
        clock = time.perf_counter()
        log_demo(sink, result, tables, truth)
        seconds["recording"] = _lap(clock)
    files["summary"] = out / "summary.json"
    files["summary"].write_text(json_text.dumps(result.summary(), indent=2) + "\n")
    return result


def log_demo(sink: Any, result: DemoResult, tables: Mapping[str, Mapping[str, NDArray]],
             truth: Mapping[str, NDArray]) -> None:
    """Log the stages' tables, the truth, the monitor and the knock to a rerun ``sink``
    (``RerunSink``): the pairs as ``per_frame``, the EKF's frame pose as ``filtered``, the
    smoother's as ``smoothed`` and its mount (the one the summary reports) as ``mount``, the
    true mount as ``series/{pitch,roll,height}/mount_truth``, the nominal with its
    tolerances."""

    def without_mount(table: Mapping[str, NDArray]) -> dict[str, NDArray]:
        return {k: v for k, v in table.items() if not k.startswith("mount_")}

    sink.log_table(tables["estimates"], "per_frame")
    sink.log_table(without_mount(tables["track"]), "filtered")
    sink.log_table(tables["smoothed"], "smoothed")
    sink.log_gt(without_mount(truth))
    if "mount_pitch_deg" in truth:
        for k, frame in enumerate(np.asarray(truth["frame"])):
            sink.log_scalars(int(frame), float(truth["t"][k]), {
                f"series/{axis}/mount_truth": float(truth[f"mount_{axis}_{unit}"][k])
                for axis, unit in (("pitch", "deg"), ("roll", "deg"), ("height", "m"))})
    sink.log_nominal(truth["frame"], truth["t"], result.nominal)
    for output in result.monitor:
        sink.log_monitor(output)
    if result.knock_s is not None:
        k = int(np.searchsorted(np.asarray(truth["t"], float), result.knock_s))
        sink.log_text(int(truth["frame"][k]), result.knock_s,
                      "truth: the camera mount is knocked here", "WARN")


def _pair_logger(sink: Any, images: Path) -> Callable[[SequenceStep], None] | None:
    """``on_step`` for the sequence runner: each pair's camera image (read back from
    ``images``), patches and displacements to ``sink``."""
    if sink is None:
        return None

    def log(step: SequenceStep) -> None:
        if step.result is None:
            sink.log_step(step)
            return
        image = (cv2.imread(str(images / f"{step.frame:06d}.png"), cv2.IMREAD_UNCHANGED)
                 if sink.image_every else None)
        sink.log_pair_views(step.frame, step.t, step.result, image)

    return log


# --- scoring ---------------------------------------------------------------------------------


def _knock_time(truth: Mapping[str, NDArray]) -> float | None:
    """Time of the first frame whose true mount pitch or roll differs from the first frame's
    (None: no mount columns, or a mount that never changes)."""
    if "mount_pitch_deg" not in truth:
        return None
    mount = np.column_stack([np.asarray(truth["mount_pitch_deg"], float),
                             np.asarray(truth["mount_roll_deg"], float)])
    if not np.all(np.isfinite(mount)):
        return None
    changed = np.flatnonzero(np.any(np.abs(mount - mount[0]) > 1e-9, axis=1))
    return float(truth["t"][changed[0]]) if len(changed) else None


def _step_times(measurements: Sequence[PairMeasurement], speeds: NDArray,
                config: SmootherConfig) -> tuple[float, ...]:
    """Times of the frames where the smoother let its mount jump (``mount_jumps``)."""
    jumps = mount_jumps(measurements, speeds, config)
    return tuple(float(measurements[k].t) for k in sorted(jumps))


def _mount_spans(smoothed: Sequence[Any], measurements: Sequence[PairMeasurement],
                 truth: Mapping[str, NDArray], steps: Sequence[float],
                 speed: SpeedSeries | None = None) -> tuple[MountSpan, ...]:
    """The smoothed mount over each span between the ``steps`` (``summarize_mount``: its mean
    and 95 % interval, its height checked against the pairs' with the wheel ``speed``),
    :data:`STEP_MARGIN_S` left out beside each step, against the true mount's median over
    the same frames."""
    t = np.array([f.t for f in smoothed])
    edges = [-math.inf, *steps, math.inf]
    spans = []
    for lo, hi in itertools.pairwise(edges):
        keep = np.flatnonzero((t >= lo + STEP_MARGIN_S) & (t < hi - STEP_MARGIN_S))
        if len(keep) < 2:
            continue
        s = summarize_mount([smoothed[i] for i in keep], [measurements[i] for i in keep],
                            speed=speed)
        if "pitch" not in s:
            continue
        frames = [measurements[i].frame for i in keep]
        spans.append(MountSpan(
            float(t[keep[0]]), float(t[keep[-1]]),
            *(_interval(s[axis], _true_mount(truth, col, frames)) for axis, col in (
                ("pitch", "pitch_deg"), ("roll", "roll_deg"), ("height", "height_m")))))
    return tuple(spans)


def _whole_height(smoothed: Sequence[Any], measurements: Sequence[PairMeasurement],
                  truth: Mapping[str, NDArray], speed: SpeedSeries | None = None) -> Interval:
    """The smoothed mount height over the whole drive (checked against the pairs' with the
    wheel ``speed``) against the true one (metres)."""
    s = summarize_mount(smoothed, measurements, speed=speed)
    if "height" not in s:
        return Interval(math.nan, math.nan, math.nan, math.nan)
    return _interval(s["height"], _true_mount(truth, "height_m", [m.frame for m in measurements]))


def _interval(axis: Mapping[str, Any], true: float) -> Interval:
    lo, hi = axis["ci95"]
    return Interval(float(axis["mean"]), float(lo), float(hi), true)


def _true_mount(truth: Mapping[str, NDArray], column: str, frames: Sequence[int]) -> float:
    """Median true mount ``mount_<column>`` (or the frame pose ``column`` where the truth has
    no mount) over ``frames``; NaN where unknown."""
    name = f"mount_{column}" if f"mount_{column}" in truth else column
    values = np.asarray(truth[name], float)
    rows = np.isin(np.asarray(truth["frame"]), frames) & np.isfinite(values)
    return float(np.median(values[rows])) if rows.any() else math.nan


def title(r: DemoResult) -> str:
    p = PRESETS[r.drive.preset]
    text = (f"vipm-track demo: {r.drive.preset} camera (h {p.height_m:g} m, pitch "
            f"{p.pitch_deg:g}°), {_duration(r.measurements):.1f} s at ~{p.speed_mps:g} m/s with "
            f"wheel speed, {r.drive.frames} frames ({r.drive.profile}, seed {r.drive.seed})")
    if r.knock_s is not None:
        text += f"; its mount is knocked at t = {r.knock_s:.2f} s"
    return text



def extrinsics(o: Any) -> dict[str, Any]:
    """The new extrinsics of a monitor output as its events spell them (estimate,
    interval95: degrees and metres)."""
    if o.estimate is None:
        return {"estimate": None, "interval95": None}
    e, iv = np.asarray(o.estimate, float), np.asarray(o.interval95, float)
    scale = (math.degrees(1.0), math.degrees(1.0), 1.0)
    names = ("pitch_deg", "roll_deg", "height_m")
    return {"estimate": {k: _num(e[i] * scale[i]) for i, k in enumerate(names)},
            "interval95": {k: [_num(iv[i, 0] * scale[i]), _num(iv[i, 1] * scale[i])]
                           for i, k in enumerate(names)}}



# --- small helpers ---------------------------------------------------------------------------


def _duration(measurements: Sequence[PairMeasurement]) -> float:
    return float(measurements[-1].t - measurements[0].t) if len(measurements) > 1 else 0.0


def _speed(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _num(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _lap(start: float) -> float:
    return time.perf_counter() - start
