"""Sequence runner: every consecutive pair of a frame source through the two-frame estimator.

:func:`run_sequence` yields one :class:`SequenceStep` per frame (frame k's motion is from
frame k-1); ``runs.estimate_sequence`` streams their rows into a per-frame table.

Tracking mode (the default) seeds each pair from the previous result: the previous frame's
pose for the virtual IPM and the previous motion (scaled by the ratio of frame intervals) to
predict displacements and offset the patch windows, which is what lets fast motion and
forward-looking cameras work. The first pair, and the pair after any failure, start cold
from the rig's nominal pose; a tracked pair that fails is tried
once more cold before it is given up.

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
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel
from .errors import InputError
from .estimator import PreparedFrame, PreparedPair, TwoFrameEstimator
from .geometry import PlanarMotion
from .pair_result import PairGuess, angular_change
from .rig import Rig
from .sources import Frame, FrameSource
from .workers import threads

if TYPE_CHECKING:
    from .estimator_config import EstimatorConfig
    from .pair_result import PairResult

FIRST_FRAME = "first frame"
NO_PREVIOUS = "no previous frame"
UNREADABLE = "unreadable frame"
WRONG_SIZE = "wrong image size"

#: Bounds on the frame-interval ratio used to scale the previous motion into a prediction.
_DT_RATIO_RANGE = (0.25, 4.0)


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


def predict_guess(previous: PairResult, dt_prev: float, dt: float) -> PairGuess:
    """Seed for the next pair from an ok result: its current pose for both frames and its
    motion scaled by ``dt / dt_prev`` (clipped to [0.25, 4])."""
    ratio = dt / dt_prev if dt_prev > 0 and dt > 0 else 1.0
    ratio = float(np.clip(ratio, *_DT_RATIO_RANGE))
    m = previous.motion
    motion = PlanarMotion(m.tx * ratio, m.tz * ratio, m.yaw * ratio)
    return PairGuess(pose_prev=previous.pose_curr, pose_curr=previous.pose_curr, motion=motion,
                     angular_rate=angular_change(previous, ratio),
                     angular_accel_ms=None if previous.angular_accel_ms is None
                     else tuple(ratio**4 * np.asarray(previous.angular_accel_ms)))


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
    first readable frame's size disagrees with the rig's camera;
    later frames of a wrong size get status ``wrong image size``. ``continuation``: the
    source continues a run (a later chunk), so none of its frames is the run's first: a
    frame of a wrong size gets that status, one without a predecessor ``no previous frame``.
    """
    if estimator is None:
        estimator = TwoFrameEstimator(rig, config)
    camera = rig.camera
    prev_image: NDArray | None = None
    prev_t = prev_dt = float("nan")
    previous_ok: PairResult | None = None
    checked_size = continuation
    frames = _prepared_frames(source, estimator, camera)
    for frame, prepared in (_read_ahead(frames) if threads() > 1 else frames):
        if frame.image is None:
            prev_image, previous_ok = None, None
            yield SequenceStep(frame.index, frame.t, None, frame.error or UNREADABLE)
            continue
        try:
            image = prepare_image(frame, camera)
        except ValueError as exc:
            if not checked_size:
                raise InputError(f"{source.description}: {exc}") from exc
            prev_image, previous_ok = None, None
            h, w = frame.image.shape[:2]
            named = f": {frame.name}" if frame.name else ""  # (as an unreadable frame is)
            yield SequenceStep(frame.index, frame.t, None, f"{WRONG_SIZE} {w}×{h} (camera "
                               f"{camera.width}×{camera.height}){named}")
            continue
        checked_size = True
        if prev_image is None:
            status = FIRST_FRAME if np.isnan(prev_t) and not continuation else NO_PREVIOUS
            prev_image, prev_t, prev_dt, previous_ok = image, frame.t, float("nan"), None
            yield SequenceStep(frame.index, frame.t, None, status)
            continue
        dt = frame.t - prev_t
        guess = None
        if tracking and previous_ok is not None:
            guess = predict_guess(previous_ok, prev_dt, dt)
        start = time.perf_counter()
        result = estimate_pair(estimator, prev_image, image, guess, dt, prepared)
        if guess is not None and result.status != "ok" and retry_cold:
            result = estimate_pair(estimator, prev_image, image, None, dt, prepared)
            guess = None
        seconds = time.perf_counter() - start
        previous_ok = result if result.status == "ok" else None
        prev_image, prev_t, prev_dt = image, frame.t, dt
        yield SequenceStep(frame.index, frame.t, result, result.status, guess is not None, seconds)


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


def estimate_pair(
    estimator: TwoFrameEstimator, prev: NDArray, curr: NDArray, guess: PairGuess | None,
    frame_interval_s: float | None = None, prepared: PreparedPair | None = None,
) -> PairResult:
    """One pair ``frame_interval_s`` seconds apart (``prepared``: its
    :meth:`TwoFrameEstimator.prepare_pair`, where made ahead); an exception inside the
    estimator becomes a failed result, not a dead run."""
    try:
        if prepared is not None:
            return estimator.estimate(prev, curr, guess, frame_interval_s, prepared=prepared)
        return estimator.estimate(prev, curr, guess, frame_interval_s)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return _FailedResult(f"estimator error: {type(exc).__name__}: {exc}"[:200])


@dataclass
class _FailedResult:
    """Stand-in for a ``PairResult`` when the estimator raised (only ``status`` is read)."""

    status: str
    reason: str = ""
    timings: dict[str, float] = field(default_factory=dict)

    def to_measurement(self, frame: int, t: float) -> Any:
        return None


def config_with(config: EstimatorConfig, **changes: Any) -> EstimatorConfig:
    """A copy of ``config`` with the non-``None`` ``changes`` applied."""
    return replace(config, **{k: v for k, v in changes.items() if v is not None})
