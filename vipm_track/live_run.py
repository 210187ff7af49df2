"""A whole live run (``vipm-track live``): a camera, stream or video file and a wheel speed
(a live CAN bus, or a recorded speed replayed in step with the video) fed to a
``LiveMonitor``; one CSV row per processed pair, flushed; each state change as a JSON line
(``events``) and a readable line on ``stdout``; optionally a rerun recording or viewer; a
summary on stderr at the end, also after Ctrl-C / SIGTERM.

``run_live`` takes plain arguments; the command only parses them.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import IO, Any

import numpy as np

from vipm_track.filters.nominal import NominalCalibration
from vipm_track.filters.speed_decoder import SpeedDecoder
from vipm_track.filters.track import track_row
from vipm_track.filters.wheel_speed import SpeedSeries

from . import json_text
from .errors import InputError, interrupts_held
from .estimator_config import EstimatorConfig
from .live_monitor import LIVE_COLUMNS, LIVE_TABLE, LiveMonitor, LiveRow, LiveStats
from .live_sources import (
    BusReader,
    FrameReader,
    Playback,
    SpeedReplay,
    check_opens,
    open_bus,
    parse_video,
)
from .rig import Rig
from .sources import VideoSource
from .table import CONCISE, ColumnChoice, TableWriter, choose_columns


def _check_replay_overlap(speed: SpeedSeries, video: Path, fps: float | None) -> None:
    """InputError where a recorded ``speed`` (the video's clock) covers none of the video
    file's frames, as ``track``/``smooth`` refuse it: the run would hold on every frame (20 s
    of "no wheel speed", exit 0)."""
    source = VideoSource(video, fps=fps)
    rate = fps or source.container_fps
    if not source.frame_count or not rate > 0:
        return
    covered, spans = speed.overlap(np.arange(source.frame_count) / rate)
    if covered == 0:
        raise InputError(speed.none_covered(
            spans, f"set --clock-offset to the time of {video} minus the speed's"))


def run_live(
    video: str,
    rig: Rig,
    nominal: NominalCalibration,
    out: str | Path,
    *,
    config: EstimatorConfig | None = None,
    realtime: bool = False,
    fps: float | None = None,
    speed: SpeedSeries | None = None,
    bus: str | Any = None,
    dbc: str | None = None,
    signals: str | None = None,
    combine: str = "mean",
    can_channel: str | None = None,
    speed_scale: float = 1.0,
    events: str | Path | None = None,
    parquet: bool = False,
    columns: ColumnChoice = CONCISE,
    camera_timeout_s: float = 1.0,
    speed_timeout_s: float = 1.0,
    duration_s: float | None = None,
    max_frames: int | None = None,
    monitor_options: dict[str, Any] | None = None,
    sink: Any = None,
    stdout: IO[str] | None = None,
    quiet: bool = False,
) -> LiveStats:
    """Monitor ``video`` live (module doc); returns the run's statistics.

    ``video``: a camera index (``"0"``), a stream URL or a video file (``realtime``: played
    at its frame rate; ``fps`` times its frames) seen by ``rig``'s camera (the estimator's
    nominal pose, height and readout: ``NominalCalibration.rig`` for the nominal's). Wheel
    speed: ``speed`` (a recording on the video's clock, replayed beside it) or ``bus``
    (``"INTERFACE:CHANNEL"`` or a python-can bus) decoded with
    ``dbc``/``signals``/``combine``/``can_channel``/``speed_scale``. A camera or stream runs
    until ``duration_s`` or an interrupt; a file until its end or ``max_frames``.
    ``columns``: the table's columns (``vipm_track.table.choose_columns``). ``sink``: a
    ``sinks.rerun_sink.RerunSink`` (camera with its patches, mount series with bands,
    monitor state). The summary goes to stderr unless ``quiet``; a KeyboardInterrupt is
    raised again after it.
    """
    spec = parse_video(video)
    written = choose_columns(LIVE_TABLE, columns)
    if speed is not None and bus is not None:
        raise InputError("give either a recorded wheel speed (--speed-csv/--can) or --bus, "
                         "not both")
    if speed is not None and spec.live:
        raise InputError(f"--video {spec.description} is live: a recorded wheel speed has no "
                         "clock in common with it; use --bus for a live one")
    if bus is not None and spec.file is not None and not realtime:
        raise InputError("a live --bus with a video file needs --realtime (the file is "
                         "played at its pace and the bus put on its clock)")
    if bus is not None and not dbc:
        raise InputError("--bus needs --dbc DBC to decode the wheel speed")
    check_opens(spec)
    if speed is not None and spec.file is not None:
        _check_replay_overlap(speed, spec.file, fps)
    stdout = stdout or sys.stdout
    stop = threading.Event()
    playback = Playback(realtime, stop)
    decoder = None
    if bus is not None:
        decoder = SpeedDecoder(dbc, signals, combine=combine, channel=can_channel,
                               scale=speed_scale, source=f"bus {bus}")
    if sink is not None:
        config = replace(config or EstimatorConfig(), keep_images=True)
    events_file = open(events, "w", newline="\n") if events else None
    writer = TableWriter(Path(out), LIVE_COLUMNS,
                         Path(out).with_suffix(".parquet") if parquet else None, written)

    def on_row(live: LiveRow) -> None:
        writer.write(live.row)
        if sink is not None:
            m = live.measurement
            if live.result is not None:
                sink.log_pair_views(m.frame, m.t, live.result, live.image)
            sink.log_measurement(m)
            sink.log_track_row(track_row(live.state, m, None), "filtered")
            sink.log_monitor(live.output)

    def on_event(event: dict[str, Any]) -> None:
        if events_file is not None:
            events_file.write(json_text.dumps(event) + "\n")
            events_file.flush()
        t = event.get("t")
        when = f"t={t:.2f} s" if isinstance(t, float | int) else "t=?"
        frame = event.get("frame")
        print(f"{when} frame {frame if frame is not None else '-'}: {event['state']}: "
              f"{event.get('reason', '')}", file=stdout, flush=True)

    monitor = LiveMonitor(rig, nominal, config, can_decoder=decoder,
                          expect_speed=speed is not None or bus is not None,
                          camera_timeout_s=camera_timeout_s, speed_timeout_s=speed_timeout_s,
                          monitor_options=monitor_options, on_row=on_row, on_event=on_event,
                          # a file read as fast as it is processed has no wall-clock pace: a
                          # slow first pair is no silent camera, nor a fast read a silent speed
                          watchdog=spec.live or realtime)
    replay = None
    if speed is not None:
        replay = SpeedReplay(speed.t, speed.speed_mps, monitor.push_speed, playback)
    reader = FrameReader(spec, monitor.push_frame, playback, stop, fps=fps,
                         on_tick=None if replay is None else replay.until,
                         wait_taken=monitor.wait_taken, max_frames=max_frames)
    bus_reader = None
    if bus is not None:
        can_bus = open_bus(bus) if isinstance(bus, str) else bus

        def shift() -> float:  # a file's clock: Unix time less the playback's offset
            offset = playback.wall_offset()
            return float("nan") if offset is None else -offset

        bus_reader = BusReader(can_bus, monitor.push_can, stop,
                               None if spec.live else shift)
    interrupted = False
    start = time.monotonic()
    try:
        monitor.start()
        if spec.file is not None:
            # a file's time starts at 0 (``sources.VideoSource``): the map is fixed before
            # any reader runs, so a speed sample before the first frame cannot shift it
            playback.start(0.0)
        if replay is not None:
            replay.start()
        if bus_reader is not None:
            bus_reader.start()
        reader.start()
        while not reader.finished.wait(0.1):
            if duration_s is not None and time.monotonic() - start >= duration_s:
                break
            if monitor.failure is not None:  # raised by monitor.stop() below
                break
            if bus_reader is not None and bus_reader.failure is not None:
                break
        for failed in (reader, bus_reader):
            if failed is not None and failed.failure is not None:
                raise failed.failure
    except KeyboardInterrupt:
        interrupted = True
    finally:
        # held: a second Ctrl-C (``timeout`` signals the process and then its group) cut
        # the closing writes short and lost the Parquet file and the summary; the drain
        # is one pair at most
        with interrupts_held():
            stop.set()
            # the readers first: a thread of OpenCV's still reading at exit aborts the process
            for thread in (reader, replay and replay.thread, bus_reader):
                if thread is not None and thread.is_alive():
                    thread.join(5.0)
            try:
                stats = monitor.stop(drain=not interrupted)
            finally:
                writer.close()
                if events_file is not None:
                    events_file.close()
                if sink is not None:
                    sink.finish()
                if isinstance(bus, str):  # opened here (one passed in is its owner's)
                    with contextlib.suppress(Exception):  # a failing driver costs no rows
                        can_bus.shutdown()
    if not quiet:
        with interrupts_held():
            _print_summary(out, stats, reader, decoder)
    if interrupted:
        raise KeyboardInterrupt
    return stats


def _print_summary(out: str | Path, stats: LiveStats, reader: FrameReader,
                   decoder: SpeedDecoder | None) -> None:
    """The run's summary on stderr: its counts, the frames that could not be read, the wheel
    speed's decoding and the first RECALIBRATE."""
    print(f"vipm-track live: {out}: {stats.line()}", file=sys.stderr)
    for line in reader.stats.errors:
        print(f"  {line}", file=sys.stderr)
    if decoder is not None:
        for line in decoder.summary.lines():
            print(f"  {line}", file=sys.stderr)
    if stats.first_recalibrate is not None:
        f = stats.first_recalibrate
        print(f"first RECALIBRATE at t={f['t']:.2f} s (frame {f['frame']}): {f['reason']}",
              file=sys.stderr)


__all__ = ["run_live"]
