"""Live inputs, each read in its own thread and handed on through a callback: camera frames
(a device index, a stream URL OpenCV/FFmpeg opens, or a video file, optionally played at its
own pace as a camera would deliver it), wheel-speed samples replayed from a recording in
step with the video, and CAN messages from a live python-can bus.

The readers know nothing of what is done with the data: the receiver (``LiveMonitor``) is
called with each item as it arrives, from the reader's thread, and must not block.

Clocks. A camera or a stream is timed by the frame's arrival (Unix time, the clock
python-can stamps bus messages with); a file by its own times. A file played with
``realtime`` maps its time ``t`` to wall time ``start + (t − t_first)`` (``Playback``), and
the speed samples of a recording replayed beside it follow the same map.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .errors import InputError, printable
from .sources import VideoSource, _to_grey

#: seconds between attempts to reopen a stream or camera that stopped delivering
REOPEN_INTERVAL_S = 1.0


@dataclass(frozen=True)
class VideoSpec:
    """What ``--video`` names: a camera ``device`` index, a stream ``url``, or a ``file``."""

    device: int | None = None
    url: str | None = None
    file: Path | None = None

    @property
    def live(self) -> bool:
        """A camera or stream (timed by arrival), not a recording."""
        return self.file is None

    @property
    def description(self) -> str:
        if self.device is not None:
            return f"camera {self.device}"
        return self.url if self.url is not None else str(self.file)


def parse_video(text: str) -> VideoSpec:
    """``--video SOURCE``: a camera index (``0``), a URL (``rtsp://…``, ``http://…``: anything
    with ``://``) or a video file, which must exist (InputError naming it otherwise)."""
    text = text.strip()
    if text.isascii() and text.isdigit():  # '²' is a digit to str.isdigit, not to int()
        return VideoSpec(device=int(text))
    if "://" in text:
        return VideoSpec(url=text)
    path = Path(text)
    if path.is_dir():
        raise InputError(f"--video {printable(text, 200)}: a folder; live reads a camera (its "
                         "index, e.g. 0), a stream (its URL) or a video file, not an image "
                         "folder (replay one with `vipm-track monitor --images`)")
    if not path.is_file():
        raise InputError(f"--video {printable(text, 200)}: no such file (a camera is given "
                         "by its index, e.g. 0; a stream by its URL, e.g. rtsp://host/path)")
    return VideoSpec(file=path)


class Playback:
    """Paces a recording as a camera would deliver it: :meth:`wait_until` sleeps until the
    wall time of recording time ``t`` [s] (the first call fixes the map); without
    ``realtime`` it returns at once. Shared by the frame and speed readers of one run."""

    def __init__(self, realtime: bool, stop: threading.Event) -> None:
        self.realtime = realtime
        self.stop = stop
        self._origin: tuple[float, float] | None = None  # (recording t, monotonic time)
        self._lock = threading.Lock()

    def start(self, t: float) -> None:
        """Fix the map at recording time ``t`` = now (where not fixed yet)."""
        with self._lock:
            if self._origin is None:
                self._origin = (float(t), time.monotonic())

    def wall_offset(self) -> float | None:
        """Unix time minus recording time [s] once started (None before): puts a live bus,
        stamped in Unix time, on the recording's clock."""
        if self._origin is None:
            return None
        t0, m0 = self._origin
        return (time.time() - (time.monotonic() - m0)) - t0

    def wait_until(self, t: float) -> bool:
        """Sleep until recording time ``t`` is due; False if the run was stopped meanwhile."""
        if not self.realtime:
            return not self.stop.is_set()
        self.start(t)
        assert self._origin is not None
        t0, m0 = self._origin
        delay = m0 + (t - t0) - time.monotonic()
        return not self.stop.wait(delay) if delay > 0 else not self.stop.is_set()


@dataclass
class ReaderStats:
    """What a reader thread saw: items delivered, unreadable ones, the first few errors."""

    delivered: int = 0
    unreadable: int = 0
    errors: list[str] = field(default_factory=list)

    def error(self, text: str) -> None:
        self.unreadable += 1
        if len(self.errors) < 5:
            self.errors.append(printable(text, 200))


class FrameReader(threading.Thread):
    """Reads ``spec`` and calls ``on_frame(image, t, index)`` with each grey frame.

    A file ends the thread at its end (``finished`` set); a camera or stream that stops
    delivering is reopened every :data:`REOPEN_INTERVAL_S` until ``stop`` is set (the
    receiver's watchdog says the camera is silent meanwhile). A frame that cannot be decoded
    is counted and skipped. ``fps``: times a file's frames by ``index / fps``. A file read
    without ``realtime`` calls ``wait_taken()`` after each frame, so that it goes as fast as
    the receiver processes and drops nothing. ``max_frames``: read at most that many of a
    file."""

    def __init__(self, spec: VideoSpec, on_frame: Callable[[NDArray[np.uint8], float, int], Any],
                 playback: Playback, stop: threading.Event, fps: float | None = None,
                 on_tick: Callable[[float], Any] | None = None,
                 wait_taken: Callable[[], Any] | None = None,
                 max_frames: int | None = None) -> None:
        super().__init__(name="vipm-live-frames", daemon=True)
        self.wait_taken = wait_taken
        self.spec, self.on_frame, self.playback, self.stop = spec, on_frame, playback, stop
        self.fps = fps
        self.on_tick = on_tick  # told each file frame's time before the frame (speed replay)
        self.stats = ReaderStats()
        self.finished = threading.Event()
        self.failure: BaseException | None = None
        if spec.file is not None:
            # checks the file now (InputError naming it) rather than in the thread
            self._video = VideoSource(spec.file, fps=fps, max_frames=max_frames)

    def run(self) -> None:
        try:
            if self.spec.file is not None:
                self._read_file()
            else:
                self._read_live()
        except BaseException as exc:  # handed to the main thread, which reports it
            self.failure = exc
        finally:
            self.finished.set()

    def _read_file(self) -> None:
        for frame in self._video:
            if not self.playback.wait_until(frame.t):
                return
            if self.on_tick is not None:
                self.on_tick(frame.t)
            if frame.image is None:
                self.stats.error(frame.error or f"unreadable frame {frame.index}")
                continue
            self.stats.delivered += 1
            self.on_frame(frame.image, frame.t, frame.index)
            if not self.playback.realtime and self.wait_taken is not None:
                self.wait_taken()

    def _read_live(self) -> None:
        index = 0
        capture = None
        while not self.stop.is_set():
            if capture is None:
                capture = open_capture(self.spec)
                if capture is None:
                    self.stop.wait(REOPEN_INTERVAL_S)
                    continue
            ok, image = capture.read()
            t = time.time()
            if not ok or image is None:
                capture.release()
                capture = None
                self.stats.error(f"{self.spec.description}: no frame at {t:.3f} (reopening)")
                self.stop.wait(REOPEN_INTERVAL_S)
                continue
            self.stats.delivered += 1
            self.on_frame(_to_grey(image), t, index)
            index += 1
        if capture is not None:
            capture.release()


def open_capture(spec: VideoSpec) -> cv2.VideoCapture | None:
    """An open ``cv2.VideoCapture`` of a camera or stream, or None where it does not open."""
    target: int | str = spec.device if spec.device is not None else str(spec.url)
    capture = cv2.VideoCapture(target)
    if not capture.isOpened():
        capture.release()
        return None
    return capture


def check_opens(spec: VideoSpec) -> None:
    """InputError naming the camera or stream where it cannot be opened at all (checked once
    before the run, so a wrong index fails fast; later outages are waited out)."""
    if spec.file is not None:
        return
    capture = open_capture(spec)
    if capture is None:
        raise InputError(f"--video {spec.description}: OpenCV cannot open it (no such camera, "
                         "or the stream does not answer)")
    capture.release()


class SpeedReplay:
    """Hands the samples of a recorded speed (t [s, the video's clock], m/s) to
    ``on_speed(t, v)`` in step with the video: under ``realtime`` in a thread at their wall
    time (:meth:`start`); otherwise the frame reader calls :meth:`until` with each frame's time
    and the samples up to ``lead_s`` seconds after it are handed on first."""

    def __init__(self, t: NDArray[np.float64], speed_mps: NDArray[np.float64],
                 on_speed: Callable[[float, float], Any], playback: Playback,
                 lead_s: float = 0.5) -> None:
        self.t, self.v = np.asarray(t, dtype=float), np.asarray(speed_mps, dtype=float)
        self.on_speed, self.playback, self.lead_s = on_speed, playback, lead_s
        self._next = 0
        self._lock = threading.Lock()
        self.thread: threading.Thread | None = None

    def until(self, t: float) -> None:
        """Hand on every sample up to ``t + lead_s`` not handed on yet (fast playback)."""
        if self.playback.realtime:
            return
        self._hand_on(t + self.lead_s)

    def _hand_on(self, t: float) -> None:
        with self._lock:
            while self._next < len(self.t) and self.t[self._next] <= t:
                self.on_speed(float(self.t[self._next]), float(self.v[self._next]))
                self._next += 1

    def start(self) -> None:
        """Under ``realtime``: start the thread that hands each sample on at its wall time."""
        if not self.playback.realtime:
            return

        def paced() -> None:
            for i in range(len(self.t)):
                if not self.playback.wait_until(float(self.t[i])):
                    return
                self._hand_on(float(self.t[i]))

        self.thread = threading.Thread(target=paced, name="vipm-live-speed", daemon=True)
        self.thread.start()


class BusReader(threading.Thread):
    """Reads a python-can ``bus`` and calls ``on_message(msg)`` with every message until
    ``stop`` is set; ``time_shift`` [s] is added to each message's timestamp first (a file
    played against a live bus: ``Playback.wall_offset``, negated). A failing bus is reported
    on stderr once and read again after :data:`REOPEN_INTERVAL_S`. Bad input from
    ``on_message`` (a speed message on two channels that disagree) ends the thread, kept as
    ``failure`` for the main thread to report."""

    def __init__(self, bus: Any, on_message: Callable[[Any], Any], stop: threading.Event,
                 time_shift: Callable[[], float] | None = None) -> None:
        super().__init__(name="vipm-live-bus", daemon=True)
        self.bus, self.on_message, self.stop, self.time_shift = bus, on_message, stop, time_shift
        self.stats = ReaderStats()
        self.failure: InputError | None = None

    def run(self) -> None:
        import can

        while not self.stop.is_set():
            try:
                msg = self.bus.recv(timeout=0.1)
            except can.CanError as exc:
                if not self.stats.errors:
                    print(f"vipm-track: warning: CAN bus: {exc}; retrying", file=sys.stderr)
                self.stats.error(str(exc))
                self.stop.wait(REOPEN_INTERVAL_S)
                continue
            if msg is None:
                continue
            if self.time_shift is not None:
                shift = self.time_shift()
                if not math.isfinite(shift):
                    continue  # the playback has not started: no clock to put it on yet
                msg.timestamp = float(msg.timestamp) + shift
            self.stats.delivered += 1
            try:
                self.on_message(msg)
            except InputError as exc:
                self.failure = exc
                return


def open_bus(text: str) -> Any:
    """A python-can bus from ``--bus INTERFACE:CHANNEL`` (e.g. ``socketcan:can0``,
    ``virtual:vcan``); InputError naming it where it cannot be opened."""
    import can

    interface, _, channel = text.partition(":")
    if not interface or not channel:
        raise InputError(f"--bus {printable(text, 100)!r}: expected INTERFACE:CHANNEL, e.g. "
                         "socketcan:can0")
    try:
        return can.Bus(interface=interface, channel=channel)
    except Exception as exc:  # python-can raises assorted types for a missing interface
        raise InputError(f"--bus {printable(text, 100)}: cannot open: {exc}") from exc


__all__ = [
    "BusReader", "FrameReader", "Playback", "ReaderStats", "SpeedReplay", "VideoSpec",
    "check_opens", "open_bus", "open_capture", "parse_video",
]
