"""The filters' and the drift monitor's runs logged to a :class:`RerunSink`: a live track
passed through (:func:`log_track_steps`), a finished filter or smoother run batched
(:func:`log_filter_run`), a whole monitor run (:func:`log_monitor_run`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from vipm_track.filters.track import track_row

from ..measurement import measurement_row
from ..progress import progress_bar
from ..table import rows_to_columns
from .rerun_sink import RerunSink


def log_track_steps(sink: RerunSink | None, steps: Any) -> Any:
    """Pass ``filters.track.track`` output ``(state, measurement, speed)`` through, logging
    the measurement (``per_frame``) and the filter's row (``filtered``, ``mount``, speeds);
    the sink is finished when the steps end. ``sink`` None: ``steps`` unchanged."""
    if sink is None:
        return steps

    def logged() -> Any:
        try:
            for state, measurement, speed in steps:
                if measurement is not None:
                    sink.log_measurement(measurement)
                sink.log_track_row(track_row(state, measurement, speed), "filtered")
                yield state, measurement, speed
        finally:
            sink.finish()

    return logged()


def log_filter_run(sink: RerunSink | None, measurements: Sequence[Any],
                   rows: Sequence[Mapping[str, Any]], kind: str = "smoothed") -> None:
    """Log a finished filter/smoother run, batched: the measurements as ``per_frame`` (failed
    ones as log lines) and its track-table rows (``filters.track.track_row``) as ``kind``,
    their mount columns as ``mount``, all with ±2σ bands where the rows have std columns.
    ``sink`` None: nothing. The sink stays open (see :meth:`RerunSink.finish`)."""
    if sink is None:
        return

    ok = [measurement_row(m) for m in measurements if m.ok]
    if ok:
        sink.log_table(rows_to_columns(ok), "per_frame")
    for m in measurements:
        if not m.ok:
            sink.log_text(m.frame, m.t, f"frame {m.frame}: {m.status}", "WARN")
    if rows:
        sink.log_table(rows_to_columns(rows), kind)


def log_monitor_run(sink: RerunSink | None, measurements: Sequence[Any], states: Sequence[Any],
                    outputs: Sequence[Any], progress: bool = False,
                    nominal: Any = None) -> None:
    """Log a whole monitor run (``filters.monitor_inputs.monitor_measurements``): the
    measurements and the EKF's frame pose and mount (:func:`log_filter_run`, ``filtered``),
    the ``nominal`` calibration with its tolerances (where given), and every monitor output
    (state, events as markers, statistics, deviation, new extrinsics). ``sink`` None:
    nothing. The sink is finished afterwards."""
    if sink is None:
        return

    try:
        rows = [track_row(s, m, None) for m, s in zip(measurements, states, strict=True)
                if s is not None]
        log_filter_run(sink, measurements, rows, "filtered")
        if nominal is not None and measurements:
            sink.log_nominal([m.frame for m in measurements], [m.t for m in measurements],
                             nominal)
        it: Any = outputs
        if progress:
            it = progress_bar(outputs, desc="rerun", unit="frame")
        for output in it:
            sink.log_monitor(output)
    finally:
        sink.finish()


__all__: Sequence[str] = ["log_filter_run", "log_monitor_run", "log_track_steps"]
