"""Rerun dashboard of a run: what the estimator saw, what it measured, what the filters and the
monitor made of it.

One :class:`RerunSink` wraps a ``rerun.RecordingStream`` (not the global one, so a process can
write several recordings). Every call places its data on two timelines: ``frame`` (sequence,
the frame index) and ``time`` (duration, the frame timestamp in seconds). Around it:
``rerun_open`` opens one (file, spawned or remote viewer), ``rerun_sequence`` feeds it a
sequence run, ``rerun_filters`` the filters' and the monitor's runs, ``rerun_blueprint`` lays
out the views and ``rerun_read`` reads a recording back. Entity layout:

=====================================  ==========================================================
``camera/image``                       the camera frame k (JPEG; every ``image_every``-th pair)
``camera/patches``                     image-plane patches of frame k-1 (the paper's Fig. 5):
                                       green inlier, red outlier, grey not measured
``camera/displacements``               their POC displacement to frame k, pixels × ``arrow_scale``
``ipm/prev/{image,patches,displacements}``  virtual IPM of frame k-1 with the refinement's vectors
``ipm/curr/{image,matches}``           virtual IPM of frame k and where each patch was found
``series/{pitch,roll,height}/KIND``    pose of frame k (degrees, metres); KIND is ``per_frame``
                                       (pair measurements), ``filtered``, ``smoothed``, ``mount``
                                       (the filter's slow mount part: the calibration),
                                       ``truth`` or ``monitor`` (its new-extrinsics estimate)
``series/{axis}/KIND_band``            ±2σ band (two series: low, high)
``motion/{tx,tz,yaw}/KIND``            motion k-1 → k (metres, degrees)
``motion/speed/{KIND,wheel}``          filtered and wheel speed, m/s
``trajectory/KIND``                    planar path (x right, −z up: forward is up), metres
``quality/{inliers,residual_px}``      estimator quality; ``timing/*`` its stage times, ms
``monitor/state``                      monitor state (``StateChange``); ``monitor/state_code``
``monitor/statistic/{pitch,...}``      CUSUM statistic over its threshold (1 = alarm)
``monitor/deviation/{pitch,...}``      1 s mean deviation from the nominal (degrees, metres)
``log``                                text: frames without estimate, monitor events
=====================================  ==========================================================

Cost: each logged image is shrunk by an integer factor to ``max_image_side`` and JPEG-encoded
once (the IPM warps are ~1.5k px floats: shrinking them first keeps that cheap); scalars
are single-row logs (``send_columns`` for whole tables). ``scripts/bench_speed.py`` measures
the overhead against the estimator.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..geometry import PlanarMotion, compose_motion
from ..table import float_or_nan
from .rerun_blueprint import AXES, FRAME_TIMELINE, TIME_TIMELINE, default_blueprint
from .trajectory import planar_path

MOTION: tuple[str, ...] = ("tx", "tz", "yaw")
#: Table column of each series (CONVENTIONS.md) and its standard-deviation column.
COLUMNS: dict[str, tuple[str, str]] = {
    "pitch": ("pitch_deg", "pitch_std_deg"),
    "roll": ("roll_deg", "roll_std_deg"),
    "height": ("height_m", "height_std_m"),
    "tx": ("tx_m", "tx_std_m"),
    "tz": ("tz_m", "tz_std_m"),
    "yaw": ("yaw_deg", "yaw_std_deg"),
}
KINDS: tuple[str, ...] = ("per_frame", "filtered", "smoothed", "mount", "truth", "monitor",
                          "wheel", "nominal", "events")
KIND_COLORS: dict[str, tuple[int, int, int]] = {
    "per_frame": (70, 130, 220),
    "filtered": (240, 130, 20),
    "smoothed": (40, 170, 70),
    "mount": (230, 40, 40),
    "truth": (200, 200, 200),
    "monitor": (210, 60, 210),
    "wheel": (120, 120, 255),
    "nominal": (60, 190, 90),
    "events": (255, 200, 0),
}
#: seconds between logged images by default (``image_period_s``): an hour of a 30 fps
#: camera stays within about a gigabyte (``scripts/bench_rerun.py``)
IMAGE_PERIOD_S = 2.0
#: pairs between logged images by default where frames have no time
IMAGE_EVERY_UNTIMED = 20
#: Mount (calibration) columns of a track table (``filters/track.py``) and their std columns.
MOUNT_COLUMNS: dict[str, tuple[str, str]] = {
    "pitch": ("mount_pitch_deg", "mount_pitch_std_deg"),
    "roll": ("mount_roll_deg", "mount_roll_std_deg"),
    "height": ("mount_height_m", "mount_height_std_m"),
}
INLIER_COLOR = (40, 220, 60)
OUTLIER_COLOR = (235, 50, 40)
UNMEASURED_COLOR = (150, 150, 150)
BAND_SIGMA = 2.0
MONITOR_LEVELS = {"RECALIBRATE": "ERROR", "INVALID": "ERROR", "DRIFTING": "WARN"}


#: seconds ``RerunSink.finish`` waits for the recording to reach its sinks
FLUSH_TIMEOUT_S = 5.0


def check_image_options(image_every: int | None, jpeg_quality: int) -> None:
    """InputError for ``--rerun-image-every`` < 0 or ``--rerun-jpeg-quality`` outside
    1..100."""
    if image_every is not None and image_every < 0:
        raise InputError(f"--rerun-image-every must be >= 0, got {image_every}")
    if not 1 <= jpeg_quality <= 100:
        raise InputError(f"--rerun-jpeg-quality must be in 1..100, got {jpeg_quality}")


class RerunSink:
    """Log a run to a rerun recording (see the module doc for the entities).

    Parameters
    ----------
    recording : the stream to log to (its sinks: file, viewer, ... are set by the caller).
    image_every : log the camera image and its patches every n-th pair (0: never; None: by
        time, every ``image_period_s`` seconds, or every ``IMAGE_EVERY_UNTIMED``-th pair of
        frames without a time).
    image_period_s : seconds between logged images where ``image_every`` is None.
    jpeg_quality : JPEG quality of logged images, 1-100.
    max_image_side : images are shrunk by the smallest integer factor that brings their longer
        side to at most this, pixels.
    arrow_scale : displacement arrows are drawn this many times their length.
    log_ipm : log the virtual IPM images (needs ``EstimatorConfig(keep_images=True)``).
    blueprint : send the default layout (``rerun_blueprint.default_blueprint``).
    """

    def __init__(
        self,
        recording: Any,
        image_every: int | None = 1,
        jpeg_quality: int = 75,
        max_image_side: int = 800,
        arrow_scale: float = 1.0,
        log_ipm: bool = True,
        blueprint: bool = True,
        image_period_s: float = IMAGE_PERIOD_S,
        layout: str = "estimate",
    ) -> None:
        check_image_options(image_every, jpeg_quality)
        if max_image_side < 16:
            raise InputError(f"rerun max image side must be >= 16 px, got {max_image_side}")
        self.rec = recording
        if not (math.isfinite(image_period_s) and image_period_s >= 0):
            raise InputError(f"rerun image period must be >= 0 s, got {image_period_s}")
        self.image_every = None if image_every is None else int(image_every)
        self.image_period_s = float(image_period_s)
        self._last_image_t = -math.inf
        self.jpeg_quality = int(jpeg_quality)
        self.max_image_side = int(max_image_side)
        self.arrow_scale = float(arrow_scale)
        self.log_ipm = log_ipm
        self._pairs = 0
        self._styled: set[str] = set()
        self._paths: dict[str, PlanarMotion] = {}
        self._monitor_state: str | None = None
        self._finished = False
        recording.set_log_time_enabled(False)
        recording.set_log_tick_enabled(False)
        if blueprint:
            recording.send_blueprint(default_blueprint(layout))

    # --- construction ------------------------------------------------------------------------

    @classmethod
    def to_file(cls, path: str | Path, app_id: str = "vipm-track", **options: Any) -> RerunSink:
        """A sink writing the recording to ``path`` (.rrd)."""
        import rerun as rr

        path = Path(path)
        if path.is_dir():
            raise InputError(f"--rerun {path}: is a folder; give a .rrd file name")
        path.parent.mkdir(parents=True, exist_ok=True)
        rec = rr.RecordingStream(app_id)
        rec.set_sinks(rr.FileSink(str(path)))
        return cls(rec, **options)

    # --- time --------------------------------------------------------------------------------

    def set_time(self, frame: int, t: float) -> None:
        """Put what follows at frame index ``frame`` and timestamp ``t`` [s] (NaN: frame only)."""
        self.rec.set_time(FRAME_TIMELINE, sequence=int(frame))
        if t is not None and math.isfinite(t):
            self.rec.set_time(TIME_TIMELINE, duration=float(t))

    # --- front end ---------------------------------------------------------------------------

    def log_step(self, step: Any, image: NDArray | None = None) -> None:
        """Log a ``pipeline.SequenceStep``: its pair result, or its status when it has none."""
        if step.result is None:
            self.set_time(step.frame, step.t)
            if step.status not in ("ok", "first frame"):
                self.log_text(step.frame, step.t, f"frame {step.frame}: {step.status}", "WARN")
            return
        self.log_pair(step.frame, step.t, step.result, image)

    def log_pair(self, frame: int, t: float, result: Any, image: NDArray | None = None) -> None:
        """Log an ``estimator.PairResult`` for frame ``frame`` (pair k-1 → k) at ``t`` [s]:
        its measurement as the ``per_frame`` series (a failure as a log line) and
        :meth:`log_pair_views`."""
        self.set_time(frame, t)
        status = getattr(result, "status", "no result")
        if status != "ok":
            reason = getattr(result, "reason", "")
            self.log_text(frame, t, f"frame {frame}: {status}" + (f" ({reason})" if reason else ""),
                          "WARN")
        measurement = result.to_measurement(frame, t) if hasattr(result, "to_measurement") else None
        if measurement is not None:
            self._log_measurement_values(measurement)
        self.log_pair_views(frame, t, result, image)

    def log_pair_views(self, frame: int, t: float, result: Any,
                       image: NDArray | None = None) -> None:
        """Log what the estimator saw for a pair, not its numbers: quality and stage timings;
        every ``image_every``-th pair ``image`` (grey or BGR, the undistorted frame k) with the
        image-plane patches and displacements, and the virtual IPM images with the last
        refinement's vectors when the result kept them."""
        self.set_time(frame, t)
        status = getattr(result, "status", "no result")
        residual = getattr(result, "residual_px", float("nan"))
        if status == "ok" and residual is not None and math.isfinite(residual):
            self._scalar("quality/residual_px", residual)
        for name, seconds in (getattr(result, "timings", None) or {}).items():
            self._scalar(f"timing/{name}", 1000.0 * seconds)
        stages = getattr(result, "stages", None) or []
        show = self._shows_image(t)
        self._pairs += 1
        if not show:
            return
        image_stage = next((s for s in reversed(stages) if s.plane == "image"), None)
        if image is not None:
            scale = self._image("camera/image", image)
            if image_stage is not None:
                self._patches("camera", image_stage, scale)
        ipm_stage = next((s for s in reversed(stages) if s.plane == "ipm"), None)
        ipm_images = getattr(result, "ipm_images", None)
        if self.log_ipm and ipm_images is not None and ipm_stage is not None:
            scale = self._image("ipm/prev/image", ipm_images[0])
            self._patches("ipm/prev", ipm_stage, scale)
            self._image("ipm/curr/image", ipm_images[1])
            ok = np.all(np.isfinite(ipm_stage.displacements), axis=1)
            found = (ipm_stage.centres + ipm_stage.displacements)[ok] * scale
            self.rec.log("ipm/curr/matches", self._rr.Points2D(
                found, colors=_flag_colors(ipm_stage.inliers[ok], ok[ok]), radii=2.0))

    def _shows_image(self, t: float) -> bool:
        """Whether this pair's images are logged (``image_every``, else by time)."""
        if self.image_every is not None:
            return self.image_every > 0 and self._pairs % self.image_every == 0
        if t is None or not math.isfinite(t):
            return self._pairs % IMAGE_EVERY_UNTIMED == 0
        if t - self._last_image_t < self.image_period_s and t >= self._last_image_t:
            return False
        self._last_image_t = t
        return True

    def log_measurement(self, m: Any) -> None:
        """Log a ``measurement.PairMeasurement`` as the ``per_frame`` series."""
        self.set_time(m.frame, m.t)
        if m.status != "ok":
            self.log_text(m.frame, m.t, f"frame {m.frame}: {m.status}", "WARN")
        self._log_measurement_values(m)

    def _log_measurement_values(self, m: Any) -> None:
        z = np.asarray(m.z, dtype=float)
        if not (m.status == "ok" and np.all(np.isfinite(z))):
            return
        std = np.sqrt(np.clip(np.diag(np.asarray(m.covariance, dtype=float)), 0.0, None))
        deg = math.degrees
        self._value("series/pitch", "per_frame", deg(z[2]), deg(std[2]))
        self._value("series/roll", "per_frame", deg(z[3]), deg(std[3]))
        self._value("series/height", "per_frame", m.height_assumed, float("nan"))
        self._value("motion/tx", "per_frame", z[4], std[4])
        self._value("motion/tz", "per_frame", z[5], std[5])
        self._value("motion/yaw", "per_frame", deg(z[6]), deg(std[6]))
        self._step_path("per_frame", PlanarMotion(z[4], z[5], z[6]))
        if getattr(m, "inliers", 0):
            self._scalar("quality/inliers", float(m.inliers))

    # --- filters -----------------------------------------------------------------------------

    def log_track_row(self, row: Mapping[str, Any], kind: str = "filtered") -> None:
        """Log one per-frame table row (CONVENTIONS.md columns, optional ``*_std_*`` columns)
        as the ``kind`` series (``filtered``, ``smoothed``, ``truth``, ``per_frame``); the
        columns with numbers are logged, whatever the status word. A track row's mount
        columns (``filters/track.py``) go to the ``mount`` series, its speeds to
        ``motion/speed``."""
        _check_kind(kind)
        self.set_time(int(row["frame"]), float_or_nan(row.get("t")))
        for name, (col, std_col) in COLUMNS.items():
            value = float_or_nan(row.get(col))
            if math.isfinite(value):
                group = "motion" if name in MOTION else "series"
                self._value(f"{group}/{name}", kind, value, float_or_nan(row.get(std_col)))
        for name, (col, std_col) in MOUNT_COLUMNS.items():
            value = float_or_nan(row.get(col))
            if math.isfinite(value):
                self._value(f"series/{name}", "mount", value, float_or_nan(row.get(std_col)))
        for col, path in (("speed_mps", f"motion/speed/{kind}"),
                          ("wheel_speed_mps", "motion/speed/wheel")):
            value = float_or_nan(row.get(col))
            if math.isfinite(value):
                self._scalar(path, value)
        motion = [float_or_nan(row.get(COLUMNS[n][0])) for n in MOTION]
        if not all(math.isfinite(v) for v in motion):  # the pair's own, as planar_path does
            motion = [float_or_nan(row.get(f"meas_{COLUMNS[n][0]}")) for n in MOTION]
        if all(math.isfinite(v) for v in motion):
            self._step_path(kind, PlanarMotion(motion[0], motion[1], math.radians(motion[2])))

    def log_table(self, columns: Mapping[str, NDArray], kind: str = "smoothed") -> None:
        """Log a whole per-frame table (``table.read_table`` columns) as the ``kind`` series,
        batched with ``send_columns``; rows log the columns where they have numbers. A track
        table's mount columns (``filters/track.py``) go to the ``mount`` series, its speeds to
        ``motion/speed``. A ground-truth table with ``world_x_m``/``world_z_m`` columns gives
        the trajectory directly, otherwise the motions are chained
        (``trajectory.planar_path``)."""
        import rerun as rr

        _check_kind(kind)
        frame = np.asarray(columns["frame"], dtype=np.int64)
        n = len(frame)
        t = np.asarray(columns.get("t", np.full(n, np.nan)), dtype=float)
        valid = np.ones(n, bool)  # rows without an estimate have empty (NaN) numbers
        series = [("motion" if name in MOTION else "series", name, kind, col, std_col)
                  for name, (col, std_col) in COLUMNS.items()]
        series += [("series", name, "mount", col, std_col)
                   for name, (col, std_col) in MOUNT_COLUMNS.items()]
        for group, name, series_kind, col, std_col in series:
            if col not in columns:
                continue
            std = np.asarray(columns[std_col], dtype=float) if std_col in columns else None
            self._send_series(f"{group}/{name}/{series_kind}", series_kind, name, frame, t,
                              np.asarray(columns[col], dtype=float), std)
        for col, path in (("speed_mps", f"motion/speed/{kind}"),
                          ("wheel_speed_mps", "motion/speed/wheel")):
            if col in columns:
                values = np.asarray(columns[col], dtype=float)
                rows = np.isfinite(values)
                if rows.any():
                    self.rec.send_columns(path, indexes=self._indexes(frame[rows], t[rows]),
                                          columns=rr.Scalars.columns(scalars=values[rows]))
        xz = planar_path(columns, valid)
        if xz is not None:
            finite = np.all(np.isfinite(xz), axis=1)
            idx = np.flatnonzero(finite)
            if len(idx) >= 2:
                segments = np.stack([xz[idx[:-1]], xz[idx[1:]]], axis=1) * [1.0, -1.0]
                self.rec.send_columns(
                    f"trajectory/{kind}", indexes=self._indexes(frame[idx[1:]], t[idx[1:]]),
                    columns=rr.LineStrips2D.columns(
                        strips=list(segments), colors=[KIND_COLORS[kind]] * len(segments)),
                )

    def log_gt(self, columns: Mapping[str, NDArray]) -> None:
        """Log a ground-truth table (``gt.csv`` of ``vipm-track simulate``) as ``truth``."""
        self.log_table(columns, "truth")

    def _send_series(self, path: str, kind: str, name: str, frame: NDArray, t: NDArray,
                     values: NDArray, std: NDArray | None) -> None:
        """One series (and its ±2σ band where ``std`` is finite), its finite rows batched."""
        rr = self._rr
        rows = np.isfinite(values)
        if not rows.any():
            return
        self._style_series(path, kind, name)
        self.rec.send_columns(path, indexes=self._indexes(frame[rows], t[rows]),
                              columns=rr.Scalars.columns(scalars=values[rows]))
        if std is None:
            return
        rows &= np.isfinite(std)
        if rows.any():
            band = np.stack([values - BAND_SIGMA * std, values + BAND_SIGMA * std], 1)
            self._style_band(f"{path}_band", kind)
            self.rec.send_columns(
                f"{path}_band", indexes=self._indexes(frame[rows], t[rows]),
                columns=rr.Scalars.columns(scalars=band[rows]).partition(
                    np.full(int(rows.sum()), 2)),
            )

    # --- monitor -----------------------------------------------------------------------------

    def log_monitor(self, output: Any) -> None:
        """Log a ``filters.monitor_types.MonitorOutput``: state, statistics, deviation, events."""
        self.set_time(output.frame, output.t)
        rr = self._rr
        if output.state != self._monitor_state:
            self.rec.log("monitor/state", rr.StateChange(state=output.state))
            self._monitor_state = output.state
        code = _STATE_CODES.get(output.state)
        if code is not None:
            self._scalar("monitor/state_code", float(code))
        stat = np.asarray(output.statistic, dtype=float)
        dev = np.asarray(output.deviation, dtype=float)
        for i, axis in enumerate(AXES):
            if i < stat.size and math.isfinite(stat[i]):
                self._scalar(f"monitor/statistic/{axis}", float(stat[i]))
            if i < dev.size and math.isfinite(dev[i]):
                self._scalar(f"monitor/deviation/{axis}",
                             math.degrees(dev[i]) if i < 2 else float(dev[i]))
        estimate = getattr(output, "estimate", None)
        if estimate is not None:
            est = np.asarray(estimate, dtype=float)
            for i, axis in enumerate(AXES):
                value = math.degrees(est[i]) if i < 2 else est[i]
                if math.isfinite(value):
                    self._value(f"series/{axis}", "monitor", value, float("nan"))
        event = getattr(output, "event", None)
        if event is not None:
            self._event_markers(output)
            level = MONITOR_LEVELS.get(output.state, "INFO")
            text = f"monitor → {output.state}"
            if output.reason:
                text += f": {output.reason}"
            self.rec.log("log", rr.TextLog(text, level=level))

    def log_nominal(self, frames: NDArray, t: NDArray, nominal: Any) -> None:
        """The nominal calibration (``filters.nominal.NominalCalibration``) as a line with its
        tolerance band in each ``series/{axis}`` over the ``frames`` (at times ``t`` [s])."""
        rr = self._rr
        frames = np.asarray(frames, dtype=np.int64)
        t = np.asarray(t, dtype=float)
        for axis, value, tol in zip(AXES, (nominal.pitch_deg, nominal.roll_deg,
                                           nominal.height_m),
                                    (nominal.pitch_tol_deg, nominal.roll_tol_deg,
                                     nominal.height_tol_m), strict=True):
            path = f"series/{axis}/nominal"
            self._style_series(path, "nominal", axis)
            self.rec.send_columns(path, indexes=self._indexes(frames, t),
                                  columns=rr.Scalars.columns(scalars=np.full(len(frames), value)))
            self._style_band(f"{path}_band", "nominal", "tolerance")
            band = np.tile([value - tol, value + tol], (len(frames), 1))
            self.rec.send_columns(f"{path}_band", indexes=self._indexes(frames, t),
                                  columns=rr.Scalars.columns(scalars=band).partition(
                                      np.full(len(frames), 2)))

    def _event_markers(self, output: Any) -> None:
        """A marker in each ``series/{axis}`` at a monitor event: at its new extrinsics, or
        at the filter's mount where it has none."""
        event = getattr(output, "event", None) or {}
        mount = event.get("estimate") or event.get("filter_mount") or {}
        for axis in AXES:
            value = float_or_nan(mount.get(COLUMNS[axis][0]))
            if math.isfinite(value):
                path = f"series/{axis}/events"
                if path not in self._styled:
                    self._styled.add(path)
                    self.rec.log(path, self._rr.SeriesPoints(
                        colors=[KIND_COLORS["events"]], names=[f"{axis} monitor event"],
                        marker_sizes=[8.0], markers=["diamond"]), static=True)
                self._scalar(path, value)

    # --- generic -----------------------------------------------------------------------------

    def log_text(self, frame: int, t: float, text: str, level: str = "INFO") -> None:
        """A line in the ``log`` entity at ``frame``/``t``."""
        self.set_time(frame, t)
        self.rec.log("log", self._rr.TextLog(text, level=level))

    def log_scalars(self, frame: int, t: float, values: Mapping[str, float]) -> None:
        """Free-form scalars (entity path → value) at ``frame``/``t``; NaN values skipped."""
        self.set_time(frame, t)
        for path, value in values.items():
            if value is not None and math.isfinite(value):
                self._scalar(path, float(value))

    def finish(self) -> None:
        """Flush everything and close the recording's sinks (idempotent)."""
        if self._finished:
            return
        self._finished = True
        # bounded: a viewer that is not listening (--rerun-connect to nobody) would otherwise
        # keep the command from ever exiting; the tables are written already
        try:
            self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except RuntimeError as exc:  # rerun: "Flush timed out - not all log messages were sent"
            print(f"vipm-track: warning: rerun: the recording did not all reach its viewer "
                  f"within {FLUSH_TIMEOUT_S:.0f} s ({exc}); the tables are complete",
                  file=sys.stderr)
        self.rec.disconnect()

    def __enter__(self) -> RerunSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()

    # --- helpers -----------------------------------------------------------------------------

    @property
    def _rr(self) -> Any:
        # rerun is imported when a recording is made: the CLI starts without it
        import rerun as rr

        return rr

    def _indexes(self, frame: NDArray, t: NDArray) -> list:
        rr = self._rr
        indexes = [rr.TimeColumn(FRAME_TIMELINE, sequence=frame)]
        if np.all(np.isfinite(t)):
            indexes.append(rr.TimeColumn(TIME_TIMELINE, duration=t))
        return indexes

    def _scalar(self, path: str, value: float) -> None:
        self.rec.log(path, self._rr.Scalars(value))

    def _value(self, group: str, kind: str, value: float, std: float) -> None:
        path = f"{group}/{kind}"
        name = group.rsplit("/", 1)[-1]
        self._style_series(path, kind, name)
        self.rec.log(path, self._rr.Scalars(value))
        if math.isfinite(std):
            self._style_band(f"{path}_band", kind)
            self.rec.log(f"{path}_band", self._rr.Scalars(
                [value - BAND_SIGMA * std, value + BAND_SIGMA * std]))

    def _style_series(self, path: str, kind: str, name: str) -> None:
        if path in self._styled:
            return
        self._styled.add(path)
        rr = self._rr
        color = KIND_COLORS[kind]
        label = f"{name} {kind.replace('_', '-')}"
        if kind == "per_frame":
            style = rr.SeriesPoints(colors=[color], names=[label], marker_sizes=[2.0])
        else:
            style = rr.SeriesLines(colors=[color], names=[label], widths=[2.0])
        self.rec.log(path, style, static=True)

    def _style_band(self, path: str, kind: str, what: str = "") -> None:
        if path in self._styled:
            return
        self._styled.add(path)
        color = (*KIND_COLORS[kind], 110)
        names = ([f"{kind} −{what}", f"{kind} +{what}"] if what else
                 [f"{kind} −{BAND_SIGMA:g}σ", f"{kind} +{BAND_SIGMA:g}σ"])
        self.rec.log(path, self._rr.SeriesLines(colors=[color, color], widths=[0.5, 0.5],
                                                names=names), static=True)

    def _step_path(self, kind: str, motion: PlanarMotion) -> None:
        """Extend the ``kind`` trajectory by one motion (world frame: G of its first frame)."""
        start = self._paths.get(kind, PlanarMotion(0.0, 0.0, 0.0))
        end = compose_motion(start, motion)
        self._paths[kind] = end
        segment = [[start.tx, -start.tz], [end.tx, -end.tz]]
        self.rec.log(f"trajectory/{kind}", self._rr.LineStrips2D(
            [segment], colors=[KIND_COLORS[kind]], radii=[-1.5]))

    def _image(self, path: str, image: NDArray) -> float:
        """Log an image as JPEG, shrunk by the smallest integer factor that brings its longer
        side to at most ``max_image_side``; returns the scale applied (1 / factor)."""
        img = np.asarray(image)
        factor = max(1, math.ceil(max(img.shape[:2]) / self.max_image_side))
        if factor > 1:  # an integer factor takes OpenCV's fast block-average path
            img = cv2.resize(img, None, fx=1.0 / factor, fy=1.0 / factor,
                             interpolation=cv2.INTER_AREA)
        img = _to_uint8(img)  # after shrinking: float IPM warps are large
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
            return 1.0 / factor
        self.rec.log(path, self._rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg"))
        return 1.0 / factor

    def _patches(self, root: str, stage: Any, scale: float) -> None:
        """Boxes at the patch centres and arrows of their displacements, both × ``scale``."""
        rr = self._rr
        centres = np.asarray(stage.centres, dtype=float)
        disp = np.asarray(stage.displacements, dtype=float)
        measured = np.all(np.isfinite(disp), axis=1)
        inliers = np.asarray(stage.inliers, dtype=bool)
        colors = _flag_colors(inliers, measured)
        sizes = np.asarray(getattr(stage, "sizes", ()), dtype=float)
        if sizes.shape == (len(centres),):
            self.rec.log(f"{root}/patches", rr.Boxes2D(
                centers=centres * scale, sizes=np.repeat(sizes[:, None] * scale, 2, 1),
                colors=colors, radii=0.5))
        else:
            self.rec.log(f"{root}/patches", rr.Points2D(centres * scale, colors=colors, radii=2.0))
        self.rec.log(f"{root}/displacements", rr.Arrows2D(
            origins=centres[measured] * scale,
            vectors=disp[measured] * scale * self.arrow_scale,
            colors=colors[measured], radii=1.0))


_STATE_CODES = {
    "UNCALIBRATED": 0, "CALIBRATED": 1, "DRIFTING": 2, "RECALIBRATE": 3, "INVALID": 4, "HOLD": 5,
}


def _check_kind(kind: str) -> None:
    if kind not in KINDS:
        raise ValueError(f"unknown series kind {kind!r}; expected one of {KINDS}")


def _flag_colors(inliers: NDArray, measured: NDArray) -> NDArray[np.uint8]:
    """(N, 3) colours: inlier green, measured outlier red, unmeasured grey."""
    colors = np.empty((len(inliers), 3), np.uint8)
    colors[:] = UNMEASURED_COLOR
    colors[measured & ~inliers] = OUTLIER_COLOR
    colors[measured & inliers] = INLIER_COLOR
    return colors


def _to_uint8(image: NDArray) -> NDArray[np.uint8]:
    """uint8 view of an image (float IPM warps: NaN → 0, clipped to 0..255)."""
    img = np.asarray(image)
    if img.dtype == np.uint8:
        return img
    return np.clip(np.nan_to_num(img, nan=0.0), 0, 255).astype(np.uint8)


__all__: Sequence[str] = ["RerunSink"]
