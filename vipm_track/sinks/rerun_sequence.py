"""Logging a sequence run as it goes: the runner's steps into a :class:`RerunSink`, each with
the camera image it was estimated from.

The sequence runner keeps its images private; :class:`ImageTap` wraps the frame source and
remembers the last few images it handed out, so that the sink can show the image of the step
the runner yields. :func:`run_logging` sets that up for ``runs.estimate_sequence``
(an ``on_step`` callback), :func:`log_steps` for a loop over the runner's steps.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from numpy.typing import NDArray

from ..estimator_config import EstimatorConfig
from .rerun_sink import RerunSink


class ImageTap:
    """A frame source that remembers the images it hands out, so that a sink can show the
    image of the step the sequence runner yields for it (the runner keeps images private).

    Wraps any iterable of ``sources.Frame`` (``len`` and ``description`` pass through); keeps
    the last ``keep`` images. With ``camera`` the images given back are undistorted like the
    runner's (the patches live on the undistorted image)."""

    def __init__(self, source: Any, camera: Any = None, keep: int = 3) -> None:
        self.source = source
        self.camera = camera
        self.keep = keep
        self._images: dict[int, NDArray] = {}
        self.description = getattr(source, "description", "")

    def __len__(self) -> int:
        return len(self.source)

    def __iter__(self) -> Any:
        for frame in self.source:
            if frame.image is not None:
                self._images[frame.index] = frame.image
                while len(self._images) > self.keep:
                    self._images.pop(next(iter(self._images)))
            yield frame

    def image(self, index: int) -> NDArray | None:
        """The image of frame ``index`` (undistorted with ``camera``), if still kept."""
        image = self._images.get(index)
        if image is None or self.camera is None or not getattr(self.camera, "has_distortion",
                                                               False):
            return image
        return self.camera.undistort_image(image)


@dataclass
class RunLogging:
    """What a command needs to log a sequence run: the source to iterate (an
    :class:`ImageTap` when logging), the estimator config (IPM images kept when logging), the
    ``on_step`` callback for ``runs.estimate_sequence`` and ``finish``. Without a sink
    everything passes through unchanged and ``on_step`` is None."""

    sink: RerunSink | None
    source: Any
    config: Any
    on_step: Callable[[Any], None] | None = None

    def finish(self) -> None:
        if self.sink is not None:
            self.sink.finish()


def run_logging(sink: RerunSink | None, source: Any, camera: Any,
                config: Any = None) -> RunLogging:
    """:class:`RunLogging` of a sequence run into ``sink`` (None: nothing logged); ``config``
    is an ``EstimatorConfig`` or None (defaults)."""
    if sink is None:
        return RunLogging(None, source, config)
    tap = ImageTap(source, camera)
    config = replace(config or EstimatorConfig(), keep_images=True)

    def on_step(step: Any) -> None:
        sink.log_step(step, tap.image(step.frame))

    return RunLogging(sink, tap, config, on_step)


def log_steps(sink: RerunSink | None, steps: Any, tap: ImageTap | None = None) -> Any:
    """Pass the runner's ``SequenceStep`` s through, logging each (with its image from
    ``tap``); the sink is finished when the steps end. ``sink`` None: ``steps`` unchanged."""
    if sink is None:
        return steps

    def logged() -> Any:
        try:
            for step in steps:
                sink.log_step(step, tap.image(step.frame) if tap is not None else None)
                yield step
        finally:
            sink.finish()

    return logged()


__all__: Sequence[str] = ["ImageTap", "RunLogging", "log_steps", "run_logging"]
