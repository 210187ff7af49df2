"""Sequence runner: every consecutive pair of a frame source through the two-frame estimator.

:func:`run_sequence` yields one :class:`SequenceStep` per frame (frame k's motion is from
frame k-1); ``runs.estimate_sequence`` streams their rows into a per-frame table.

Tracking mode (the default) seeds each pair from the previous result: the previous frame's
pose for the virtual IPM and the previous motion (scaled by the ratio of frame intervals) to
predict displacements and offset the patch windows, which is what lets fast motion and
forward-looking cameras work. The first pair, and the pair after any failure, start cold
from the rig's nominal pose; a tracked pair that fails is tried once more cold before it is
given up, and an ``ok`` pair whose motion no vehicle could reach from the last one's is marked
``implausible motion`` (``pair_chain.PairChain``).

With more than one thread (``workers.threads``), the next frame is read and its pair
prepared (``TwoFrameEstimator.prepare_pair``: the grey image, its noise, the
content fixed to the camera) on a second thread while the current pair is estimated: the
estimator's least-squares and warps keep one core, which the preparation then uses.

A frame that cannot be read gets a row with status ``unreadable frame`` and the next frame,
having no predecessor, a row with status ``no previous frame``; the run goes on.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel
from .errors import InputError
from .estimator import PreparedFrame, PreparedPair, TwoFrameEstimator
from .estimator_config import EstimatorConfig
from .pair_chain import PairChain
from .rig import Rig
from .sources import FIRST_SIZE_FRAMES, Frame, FrameSource
from .statuses import FIRST_FRAME, NO_PREVIOUS, UNREADABLE, WRONG_SIZE
from .workers import threads

if TYPE_CHECKING:
    from .pair_result import PairResult

__all__ = ["FIRST_FRAME", "NO_PREVIOUS", "UNREADABLE", "WRONG_SIZE", "SequenceStep",
           "config_with", "prepare_image", "run_sequence"]


@dataclass(frozen=True)
class SequenceStep:
    """Outcome for frame ``frame`` at time ``t`` [s]: the pair result (``None`` when no pair
    was estimated), the row ``status``, whether the pair was seeded by tracking, and the
    estimator's wall time [s] for it."""

    frame: int
    t: float
    result: PairResult | None
    status: str
    tracked: bool = False
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def prepare_image(frame: Frame, camera: CameraModel) -> NDArray[np.uint8]:
    """The grey image of a readable frame, as read (the estimator undistorts it);
    ``ValueError`` if its size is not the camera's."""
    assert frame.image is not None
    camera.check_image(frame.image.shape, frame.name or f"frame {frame.index}")
    return frame.image


def run_sequence(
    source: FrameSource,
    rig: Rig,
    config: EstimatorConfig | None = None,
    tracking: bool = True,
    estimator: TwoFrameEstimator | None = None,
    retry_cold: bool = True,
    continuation: bool = False,
) -> Iterator[SequenceStep]:
    """Yield one :class:`SequenceStep` per frame of ``source`` (see module doc).

    The ``rig``'s height [m] makes the motion metric. Raises :class:`InputError` when the
    first ``FIRST_SIZE_FRAMES`` readable frames (or all, where fewer) disagree with the
    rig's camera; other frames of a wrong size get status ``wrong image size``.
    ``continuation``: the source continues a run (a later chunk), so none of its frames is
    the run's first: a frame of a wrong size gets that status, one without a predecessor
    ``no previous frame``.
    """
    if estimator is None:
        estimator = TwoFrameEstimator(rig, config)
    camera = rig.camera
    prev_image: NDArray | None = None
    prev_t = float("nan")
    settings = (estimator.config if isinstance(estimator, TwoFrameEstimator)
                else config or EstimatorConfig())
    chain = PairChain(estimator, tracking, retry_cold,
                      max_acceleration_mps2=settings.max_acceleration_mps2)
    checked_size = continuation
    # the first frames until one has the camera's size: held back, and an InputError where
    # FIRST_SIZE_FRAMES of them do not (the camera is another's), so that one odd first
    # frame is a frame of the wrong size, not a wrong camera
    held: list[SequenceStep] = []
    mismatch: ValueError | None = None
    frames = _prepared_frames(source, estimator, camera)
    for frame, prepared in (_read_ahead(frames) if threads() > 1 else frames):
        if frame.image is None:
            prev_image = None
            step = SequenceStep(frame.index, frame.t, None, frame.error or UNREADABLE)
            if held:
                held.append(step)
            else:
                yield step
            continue
        try:
            image = prepare_image(frame, camera)
        except ValueError as exc:
            prev_image = None
            h, w = frame.image.shape[:2]
            named = f": {frame.name}" if frame.name else ""  # (as an unreadable frame is)
            step = SequenceStep(frame.index, frame.t, None, f"{WRONG_SIZE} {w}×{h} (camera "
                                f"{camera.width}×{camera.height}){named}")
            if checked_size:
                yield step
                continue
            mismatch = mismatch or exc
            held.append(step)
            if sum(s.status.startswith(WRONG_SIZE) for s in held) >= FIRST_SIZE_FRAMES:
                raise InputError(f"{source.description}: {mismatch}") from exc
            continue
        checked_size = True
        yield from held
        held.clear()
        if prev_image is None:
            status = FIRST_FRAME if np.isnan(prev_t) and not continuation else NO_PREVIOUS
            prev_image, prev_t = image, frame.t
            chain.break_tracking()
            yield SequenceStep(frame.index, frame.t, None, status)
            continue
        dt = frame.t - prev_t
        start = time.perf_counter()
        result, tracked = chain.estimate(prev_image, image, frame.t, dt, prepared)
        seconds = time.perf_counter() - start
        prev_image, prev_t = image, frame.t
        yield SequenceStep(frame.index, frame.t, result, result.status, tracked, seconds)
    if held:  # no frame of the camera's size at all
        raise InputError(f"{source.description}: {mismatch}")


def _prepared_frames(source: FrameSource, estimator: TwoFrameEstimator, camera: CameraModel,
                     ) -> Iterator[tuple[Frame, PreparedPair | None]]:
    """The frames of ``source``, each with the :class:`PreparedPair` of it and the frame
    before where both were read and are of the camera's size (None otherwise, or when the
    estimator is not a :class:`TwoFrameEstimator`)."""
    before: PreparedFrame | None = None
    for frame in source:
        prepared = None
        if frame.image is not None and isinstance(estimator, TwoFrameEstimator):
            try:
                curr = estimator.prepare_frame(prepare_image(frame, camera), "frame")
                if before is not None:
                    prepared = estimator.prepare_pair(before, curr)
            except Exception:  # the runner's own path meets it again and reports it
                curr, prepared = None, None
            before = curr
        else:
            before = None
        yield frame, prepared


_END = object()


def _read_ahead(items: Iterator) -> Iterator:
    """``items``, the next one made on a worker thread while the caller works on this one
    (at the same priority: a lowered one starved it on a busy machine, and OpenCV's own
    threads, when first started from it, kept the lowered priority). Closed early (a
    consumer that stops, Ctrl-C), it waits for the item in the making (one frame's read and
    preparation) so that the source is never read from two threads."""
    with ThreadPoolExecutor(1, thread_name_prefix="vipm-read-ahead") as pool:
        pending = pool.submit(next, items, _END)
        while (item := pending.result()) is not _END:
            pending = pool.submit(next, items, _END)
            yield item


def config_with(config: EstimatorConfig, **changes: Any) -> EstimatorConfig:
    """A copy of ``config`` with the non-``None`` ``changes`` applied."""
    return replace(config, **{k: v for k, v in changes.items() if v is not None})
