"""The frame rates a vehicle camera's timestamps may come from, and what lies outside them."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

FPS_RANGE_HZ = (0.1, 1000.0)
"""Frame rates a vehicle camera's timestamps may be made from: slower than 0.1 Hz no two
frames share the ground at driving speeds, faster than 1 kHz no camera this serves runs."""


def fps_problem(fps: float) -> str | None:
    """Why ``fps`` [Hz] cannot time frames (completes "--fps must be ..."), or ``None``."""
    low, high = FPS_RANGE_HZ
    if math.isfinite(fps) and low <= fps <= high:
        return None
    return f"a number of frames per second in [{low:g}, {high:g}], got {fps:g}"


def interval_problem(intervals: ArrayLike) -> str | None:
    """Why the ``intervals`` between consecutive frames are not in seconds, or ``None``: their
    median outside what :data:`FPS_RANGE_HZ` allows (milliseconds taken for seconds slow a
    track's speed a thousandfold)."""
    step = np.asarray(intervals, dtype=float)
    step = step[np.isfinite(step) & (step > 0)]
    if step.size == 0:
        return None
    interval = float(np.median(step))
    low, high = FPS_RANGE_HZ
    if 1.0 / high <= interval <= 1.0 / low:
        return None
    return (f"consecutive frames are {interval:.4g} s apart (median), a frame rate outside "
            f"{low:g}–{high:g} Hz: the times must be in seconds")
