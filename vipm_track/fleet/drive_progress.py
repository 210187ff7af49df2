"""A drive's progress within a fleet run: the worker processing it sends where it is (stage,
frames done of the drive's frames) as a Dask event; the client shows the running drives
beside its bar of finished ones, so an hour-long drive is not an hour of silence."""

from __future__ import annotations

import threading
import time
import uuid
from typing import Any

#: the Dask event topic of drive progress (``Worker.log_event`` / ``Client.subscribe_topic``),
#: one per fleet run (:func:`progress_topic`): runs sharing a scheduler see their own drives
PROGRESS_TOPIC = "vipm-track-drive-progress"


def progress_topic() -> str:
    """A topic of its own for one fleet run's progress events."""
    return f"{PROGRESS_TOPIC}-{uuid.uuid4().hex}"

#: seconds between a drive's progress events (its first and a stage's last are always sent)
EVENT_INTERVAL_S = 2.0

#: running drives named in the bar's text; the others are counted
SHOWN_DRIVES = 3


class DriveProgress:
    """Progress of one drive, sent to ``topic`` from the Dask worker running it (nothing
    without a topic or elsewhere: a drive run in a plain process has its own output)."""

    def __init__(self, drive: str, frames: int | None, topic: str | None) -> None:
        from distributed import get_worker

        self._worker: Any = None
        if topic is not None:
            try:
                self._worker = get_worker()
            except ValueError:  # not within a Dask task
                pass
        self.drive, self.frames, self.topic = drive, frames, topic
        self._last = -float("inf")

    def update(self, stage: str, done: int | None, final: bool = False) -> None:
        """``done`` of the drive's frames through ``stage``; sent at most every
        ``EVENT_INTERVAL_S`` seconds unless ``final``."""
        now = time.monotonic()
        if self._worker is None or (not final and now - self._last < EVENT_INTERVAL_S):
            return
        self._last = now
        self._worker.log_event(self.topic, {"drive": self.drive, "stage": stage,
                                             "done": done, "frames": self.frames})


class FleetProgress:
    """The client's view of the running drives, from their events: ``text()`` for the bar."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._running: dict[str, dict[str, Any]] = {}
        self._finished: set[str] = set()

    def on_event(self, event: tuple[float, dict[str, Any]]) -> None:
        """Handler of ``Client.subscribe_topic``: ``event`` is (scheduler time, message)."""
        message = event[1]
        with self._lock:
            if message.get("drive") not in self._finished:
                self._running[str(message["drive"])] = message

    def finished(self, drive: str) -> None:
        with self._lock:
            self._finished.add(drive)
            self._running.pop(drive, None)

    def text(self) -> str:
        """``a: estimate 1200/6000, b: smooth; 2 more running`` (empty with none running)."""
        with self._lock:
            running = [self._running[d] for d in sorted(self._running)]
        parts = []
        for m in running[:SHOWN_DRIVES]:
            counted = m["stage"] == "estimate" and m["done"] is not None
            of = f"/{m['frames']}" if counted and m["frames"] else ""
            parts.append(f"{m['drive']}: {m['stage']}"
                         + (f" {m['done']}{of} frames" if counted else ""))
        more = len(running) - SHOWN_DRIVES
        return ", ".join(parts) + (f"; {more} more running" if more > 0 else "")
