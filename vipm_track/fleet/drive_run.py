"""One drive of a fleet, start to end: estimate every pair, smooth the drive in one batch
(or with a sliding window), summarise its mount and monitor it against its nominal
calibration; the tables go to ``OUT/drive=NAME/`` and one summary row comes back.

The steps are the library's own (``runs.sequence_steps``, ``filters.smoothing``,
``filters.drive_summary``, ``filters.monitor_inputs``), so a drive's rows are those of
``vipm-track smooth --pitch P --roll R --height H`` with the drive's nominal P, R, H.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
import traceback
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from vipm_track import __version__, json_text
from vipm_track.filters.drive_summary import summarize_mount, summary_warnings
from vipm_track.filters.ekf_state import EkfConfig
from vipm_track.filters.model import NoiseParams
from vipm_track.filters.monitor_inputs import frame_rate, monitor_frames
from vipm_track.filters.monitor_table import MONITOR_TABLE, monitor_row
from vipm_track.filters.monitor_types import MonitorConfig
from vipm_track.filters.nominal import NominalCalibration, load_nominal
from vipm_track.filters.smoother_config import SmootherConfig
from vipm_track.filters.smoothing import smoothed_rows
from vipm_track.filters.speed_decoder import decode_can_log
from vipm_track.filters.track import TRACK_TABLE
from vipm_track.filters.wheel_speed import SpeedSeries, read_speed_csv

from ..bag_source import BagSource, read_bag_camera, read_bag_speed
from ..camera import CameraModel, load_camera
from ..errors import InputError, NothingUsable, printable
from ..estimator_config import EstimatorConfig
from ..runs import sequence_steps, step_measurement, step_row
from ..sources import FrameSource, first_frame_size, open_source
from ..statuses import counts_text
from ..table import CONCISE, ESTIMATE_TABLE, choose_columns_each, write_table
from .drive_progress import DriveProgress
from .drives import DriveSpec

#: the file in a drive's folder that says its outputs are complete, with their input hash
DONE_FILE = "done.json"
#: what a drive writes before its done file
OUTPUT_FILES = ("estimates.parquet", "smoothed.parquet", "monitor.parquet", "summary.json")
#: the done file's field naming the vipm-track that wrote the outputs: another one redoes them
VERSION_FIELD = "vipm_track_version"


@dataclass(frozen=True)
class FleetSettings:
    """How every drive of a fleet is processed (part of each drive's input hash).

    ``vehicle``: noise preset of ``filters.model`` (``car`` or ``cart``); ``lag_s``: the
    smoother's window, 0 for the whole drive at once; ``chunk_frames``: split a drive's
    estimation into chunks of that many frames, as ``--chunk-frames`` does (None: one
    sequence); ``marginals``: compute the smoothed std columns; the topics: a bag's
    image / camera_info / speed topic (None: found by message type); ``columns``: the
    tables' columns (``all``, ``concise`` or names, ``table.choose_columns_each``)."""

    vehicle: str = "car"
    lag_s: float = 0.0
    chunk_frames: int | None = None
    marginals: bool = True
    image_topic: str | None = None
    camera_info_topic: str | None = None
    speed_topic: str | None = None
    columns: str = CONCISE

    def __post_init__(self) -> None:
        self.tables()  # unknown column names are named before any drive runs
        if self.vehicle not in ("car", "cart"):
            raise InputError(f"--vehicle must be car or cart, got {self.vehicle!r}")
        if not (np.isfinite(self.lag_s) and self.lag_s >= 0):
            raise InputError(f"--lag must be >= 0 seconds, got {self.lag_s}")
        if self.chunk_frames is not None and self.chunk_frames < 2:
            raise InputError(f"--chunk-frames must be >= 2, got {self.chunk_frames}")

    def tables(self) -> dict[str, tuple[tuple[str, ...], tuple[str, ...]]]:
        """Each table's file stem → (its columns after the base ones, those written)."""
        kinds = {"estimates": ESTIMATE_TABLE, "smoothed": TRACK_TABLE, "monitor": MONITOR_TABLE}
        chosen = choose_columns_each(tuple(kinds.values()), self.columns)
        return {name: (t.every, c) for (name, t), c in zip(kinds.items(), chosen, strict=True)}

    def key(self) -> str:
        """The settings as one canonical string (for the input hash)."""
        return json.dumps(asdict(self), sort_keys=True)


def drive_folder(out: str | Path, drive: str) -> Path:
    """``OUT/drive=NAME``: the hive partition of a drive's tables. Parquet readers decode a
    partition's value as a URI segment ("run%41" read back as "runA", the rows of two drives
    under one name), so a '%' in the name is written as "%25"."""
    return Path(out) / f"drive={drive.replace('%', '%25')}"


def run_drive(spec: DriveSpec, out: str | Path, settings: FleetSettings,
              progress_topic: str | None = None) -> dict[str, Any]:
    """Process one drive into ``OUT/drive=NAME/`` (estimates, smoothed and monitor Parquet,
    ``summary.json``, ``done.json``) and return its fleet-summary row; where an earlier run
    is still good (:func:`resume_check`), its row (``skipped`` true). A drive run again
    though it had been done has ``redone``: why. A drive that fails is a row whose
    ``status`` is the error; nothing is raised. ``progress_topic``: the Dask event topic its
    progress goes to (``drive_progress``; None: none sent)."""
    start = time.perf_counter()
    folder = drive_folder(out, spec.drive)
    base = {"drive": spec.drive, "vehicle": spec.vehicle, "started": spec.started}
    rerun = False  # its outputs of an earlier run removed: this run's or none stand
    try:
        if spec.problem:
            raise InputError(spec.problem)
        key = spec.input_hash(settings.key())
        done, redone = resume_check(folder, key)
        if done is not None:
            return {**done, "skipped": True}
        # an earlier run's outputs go first: a drive that now stops part-way must not leave
        # tables that no done.json vouches for
        rerun = True
        remove_outputs(folder)
        row = {**base, **_process(spec, folder, settings, progress_topic), "input_hash": key,
               VERSION_FIELD: __version__}
    except Exception as exc:  # a failed drive is a row of the summary; the fleet goes on
        if rerun or isinstance(exc, (InputError, NothingUsable, FileNotFoundError)):
            # a drive that is no longer what it was (a file missing or broken now, found
            # before the step above): the same; a passing read error leaves its outputs
            remove_outputs(folder)
        if isinstance(exc, (InputError, NothingUsable, OSError)):
            why = printable(exc, 500)
        else:
            where = traceback.extract_tb(exc.__traceback__)[-1]
            why = (f"{type(exc).__name__}: {printable(exc, 400)} "
                   f"({Path(where.filename).name}:{where.lineno})")
        return {**base, "status": f"error: {why}", "wall_s": time.perf_counter() - start,
                "worker": _worker(), "skipped": False}
    row["wall_s"] = time.perf_counter() - start
    row["worker"] = _worker()
    _write_atomic(folder / DONE_FILE, json_text.dumps(row, indent=2) + "\n")
    return {**row, "skipped": False, "redone": redone}


def remove_outputs(folder: Path) -> None:
    """What a run of the drive wrote into ``folder``, its done file first; then the folder
    itself where nothing else is in it (a drive that failed leaves no empty partition)."""
    for name in (DONE_FILE, *OUTPUT_FILES):
        with contextlib.suppress(OSError):
            (folder / name).unlink(missing_ok=True)
    with contextlib.suppress(OSError):  # absent, or holding the user's own files
        folder.rmdir()


def _worker() -> str:
    return f"{os.uname().nodename}:{os.getpid()}"


def done_row(folder: Path, key: str) -> dict[str, Any] | None:
    """The summary row a finished drive left in ``folder`` where it still holds
    (:func:`resume_check`); None otherwise."""
    return resume_check(folder, key)[0]


def resume_check(folder: Path, key: str) -> tuple[dict[str, Any] | None, str]:
    """(the summary row of ``folder``'s done file, "") where that run can be reused: made
    from inputs and settings of hash ``key`` by this vipm-track, its outputs all there;
    else (None, why it is redone), why "" where the drive never finished."""
    try:
        row = json.loads((folder / DONE_FILE).read_text())
    except (OSError, ValueError):
        return None, ""
    if not isinstance(row, dict):
        return None, ""
    made_by = row.get(VERSION_FIELD)
    if made_by != __version__:  # another estimator may give other tables from the same inputs
        by = ("an earlier vipm-track" if made_by is None
              else f"vipm-track {printable(str(made_by), 40)}")
        return None, f"made by {by}, this is {__version__}"
    if row.get("input_hash") != key:
        return None, "inputs or settings changed"
    problem = _outputs_problem(folder)
    return (None, problem) if problem else (row, "")


def _outputs_problem(folder: Path) -> str:
    """Which of a drive's outputs are gone or unreadable ("" where none): a done file alone
    does not vouch for tables removed or broken since."""
    missing = [name for name in OUTPUT_FILES if not (folder / name).is_file()]
    broken = [name for name in OUTPUT_FILES
              if name not in missing and not _readable(folder / name)]
    return "; ".join(f"output {what}: {', '.join(names)}"
                     for what, names in (("missing", missing), ("unreadable", broken)) if names)


def _readable(path: Path) -> bool:
    """Whether a drive's output file reads as what it is: a Parquet file's footer (not its
    rows: a resumed fleet checks every drive's), a JSON object."""
    try:
        if path.suffix == ".parquet":
            pq.read_metadata(path)
            return True
        return isinstance(json.loads(path.read_text()), dict)
    except (OSError, ValueError, pa.ArrowException):
        return False


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _table_atomic(path: Path, rows: list[dict], settings: FleetSettings) -> None:
    # the temporary name starts with '.', which Parquet dataset readers skip
    tmp = path.with_name(f".{path.name}.tmp.parquet")
    every, written = settings.tables()[path.stem]
    write_table(tmp, rows, every, written)
    os.replace(tmp, path)


def open_recording(spec: DriveSpec, settings: FleetSettings
                   ) -> tuple[FrameSource, CameraModel]:
    """The drive's frames and intrinsics (the camera file, else the bag's camera_info)."""
    if spec.bag is not None:
        source: FrameSource = BagSource(spec.bag, settings.image_topic)
        camera = (load_camera(spec.camera) if spec.camera is not None
                  else read_bag_camera(spec.bag, settings.camera_info_topic))
        return source, camera
    source = open_source(images=spec.images, video=spec.video, fps=spec.fps)
    assert spec.camera is not None
    # a KITTI calib.txt has no image size: the frames give it (as estimate does)
    return source, load_camera(spec.camera, first_frame_size(spec.images, spec.video))


def drive_speed(spec: DriveSpec, settings: FleetSettings) -> SpeedSeries | None:
    """The drive's speed [t on its clock s, m/s]: ``speed.csv``, the CAN log decoded with
    its DBC (the DBC's rear wheel speeds), or the bag's twist / odometry topic; None.
    InputError where the file holds no sample (as ``track`` says it)."""
    series = None
    if spec.speed_csv is not None:
        series = read_speed_csv(spec.speed_csv)
    elif spec.can is not None:
        assert spec.dbc is not None
        series, _ = decode_can_log(spec.can, spec.dbc)
    elif spec.bag is not None:
        found = read_bag_speed(spec.bag, settings.speed_topic)
        if found is not None:
            series = SpeedSeries(found.t, found.speed_mps, source=found.source)
    return None if series is None else series.with_samples()


def smoother_config(height_m: float, settings: FleetSettings) -> SmootherConfig:
    """The smoother of ``vipm-track smooth`` with its defaults, at ``height_m``."""
    return SmootherConfig(height_m=height_m, noise=NoiseParams.for_preset(settings.vehicle),
                          lag_s=settings.lag_s, marginals=settings.marginals)


def _process(spec: DriveSpec, folder: Path, settings: FleetSettings,
             progress_topic: str | None) -> dict[str, Any]:
    assert spec.nominal is not None
    nominal = load_nominal(spec.nominal)
    height = nominal.height_m
    source, camera = open_recording(spec, settings)
    speed = drive_speed(spec, settings)
    folder.mkdir(parents=True, exist_ok=True)
    estimate_rows, measurements = [], []
    progress = DriveProgress(spec.drive, _frame_count(source), progress_topic)
    for step in sequence_steps(source, nominal.rig(camera), EstimatorConfig(),
                               chunk_frames=settings.chunk_frames):
        estimate_rows.append(step_row(step, height))
        measurements.append(step_measurement(step, height))
        progress.update("estimate", len(measurements))
    progress.update("smooth", None, final=True)
    _table_atomic(folder / "estimates.parquet", estimate_rows, settings)
    if not any(m.ok for m in measurements):
        counts = counts_text(Counter(m.status for m in measurements))
        raise NothingUsable(f"{source.description}: no frame has a usable pair estimate "
                            f"({counts})")
    if speed is not None:
        covered, spans = speed.overlap([m.t for m in measurements])
        if covered == 0:  # as `smooth`: a drive without its speed is no drive with one
            raise InputError(speed.none_covered(
                spans, "the drive's speed is on another clock or of another drive"))
    frames, rows = [], []
    config = smoother_config(height, settings)
    for f, row in smoothed_rows(measurements, speed, config):
        frames.append(f)
        rows.append(row)
    _table_atomic(folder / "smoothed.parquet", rows, settings)
    summary = summarize_mount(frames, measurements,
                              config.mount_steps if config.lag_s == 0 else None, speed)
    progress.update("monitor", None, final=True)
    ekf_config = EkfConfig(height_m=height)
    monitor_config = MonitorConfig.from_noise(ekf_config.noise, fps=frame_rate(measurements))
    monitor_rows, states = [], []
    for m, s, o in monitor_frames(measurements, nominal, speed, monitor_config, ekf_config):
        monitor_rows.append(monitor_row(m, s, o))
        states.append(o)
    _table_atomic(folder / "monitor.parquet", monitor_rows, settings)
    _write_atomic(folder / "summary.json", json_text.dumps(summary, indent=2) + "\n")
    return _row(spec, summary, measurements, states, nominal, speed)


def speed_warnings(speed: SpeedSeries | None) -> list[str]:
    """What the drive's wheel-speed file held that was skipped (rows, log lines, frames),
    with the first few places: ``smooth`` prints it; a fleet row said nothing."""
    summary = None if speed is None else speed.summary
    if summary is None or not summary.bad:
        return []
    where = "; ".join(summary.examples[:3]) or "; ".join(summary.read_errors[:1])
    return [f"{printable(Path(summary.source).name, 80)}: {summary.bad} {summary.unit} of the "
            f"wheel speed skipped" + (f" ({where})" if where else "")]


def _frame_count(source: FrameSource) -> int | None:
    """The recording's number of frames, where its source knows it (a stream may not)."""
    try:
        return len(source) or None
    except (TypeError, NotImplementedError):
        return None


def _row(spec: DriveSpec, summary: dict, measurements: list, outputs: list,
         nominal: NominalCalibration, speed: SpeedSeries | None) -> dict[str, Any]:
    """The fleet-summary numbers of a processed drive (degrees, metres, minutes)."""
    ok = sum(m.ok for m in measurements)
    flagged = next((o for o in outputs if o.state == "RECALIBRATE"), None)
    row: dict[str, Any] = {
        "status": "ok",
        "frames": len(measurements),
        "share_ok": ok / max(len(measurements), 1),
        "duration_s": summary.get("duration_s", 0.0),
        "t_start_s": measurements[0].t if measurements else float("nan"),
        "wheel_speed": speed is not None,
        "nominal_pitch_deg": nominal.pitch_deg,
        "nominal_roll_deg": nominal.roll_deg,
        "nominal_height_m": nominal.height_m,
        "monitor_verdict": outputs[-1].state if outputs else "",
        "first_recalibrate_s": None if flagged is None else flagged.t,
        "monitor_states": ", ".join(f"{s} {n}" for s, n in
                                    Counter(o.state for o in outputs).most_common()),
        # the short drive, a knock within it...: the summary.json's caveats, in the row too
        "warnings": " | ".join(summary_warnings(summary) + speed_warnings(speed)),
    }
    for axis, unit in (("pitch", "deg"), ("roll", "deg"), ("height", "m")):
        d = summary.get(axis) or {}
        row[f"mount_{axis}_{unit}"] = d.get("mean")
        row[f"mount_{axis}_std_{unit}"] = d.get("std")
        low, high = d.get("ci95", (None, None))
        row[f"mount_{axis}_ci95_low_{unit}"] = low
        row[f"mount_{axis}_ci95_high_{unit}"] = high
        row[f"{axis}_drift_{unit}_per_min"] = d.get("drift_per_min")
    return row
