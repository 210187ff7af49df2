"""Smoothing a drive: the batch smoother (``smoother``) or the fixed-lag one (``fixed_lag``)
over its pair measurements and wheel speed, frame by frame as each becomes final."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from .ekf import SpeedSource, speed_at
from .fixed_lag import FixedLagSmoother
from .heave import HeaveWidening
from .lever_arm import LeverArm, corrected_drive
from .row_correlation import PairErrorCorrelation, widened_drive
from .smoother import smooth_batch
from .smoother_config import SmoothedFrame, SmootherConfig
from .track import track_row

FloatArray = NDArray[np.float64]


def speeds_at_frames(
    measurements: Sequence[PairMeasurement],
    speed_series: SpeedSource | None,
    clock_offset_s: float = 0.0,
) -> FloatArray:
    """Wheel speed (m/s) at each measurement's time (NaN where none), as the EKF reads it."""
    times = np.array([m.t for m in measurements], dtype=float)
    if speed_series is None:
        return np.full(len(times), np.nan)
    return speed_at(speed_series, times, clock_offset_s)


def smooth(
    measurements: Sequence[PairMeasurement],
    speed_series: SpeedSource | None = None,
    config: SmootherConfig | None = None,
    clock_offset_s: float = 0.0,
    progress: bool = False,
) -> list[SmoothedFrame]:
    """Smoothed estimate of every frame: batch if ``config.lag_s`` is 0, else fixed-lag."""
    return list(smoothed_frames(measurements, speed_series, config, clock_offset_s, progress))


def smoothed_frames(
    measurements: Sequence[PairMeasurement],
    speed_series: SpeedSource | None = None,
    config: SmootherConfig | None = None,
    clock_offset_s: float = 0.0,
    progress: bool = False,
) -> Iterator[SmoothedFrame]:
    """``smooth``'s frames, each as soon as it is final: the fixed-lag smoother's as they
    leave the window (so a caller can write them while the drive goes on), the batch's once
    the whole drive is solved."""
    cfg = config or SmootherConfig()
    speeds = speeds_at_frames(measurements, speed_series, clock_offset_s)
    by_frame = {m.frame: m for m in measurements}
    heave = HeaveWidening(cfg, speed_series, clock_offset_s)
    # the lever arms' slide added to the lateral motion (lever_arm), the pose and motion σ
    # widened by the pairs' error correlation (row_correlation) and the height σ by the
    # body's heave (heave): the batch's by the whole drive's arms and correlation and the
    # heave about each frame, the fixed lag's by the pairs up to each frame
    lever_std = cfg.noise.lever_arm_std_m
    if cfg.lag_s == 0:
        frames, info = smooth_batch(measurements, speeds, cfg, progress)
        frames = widened_drive(corrected_drive(frames, by_frame, lever_std), by_frame)
        yield from heave.widened_drive(frames, by_frame)
        if info.marginals_interrupted:
            raise MarginalsInterrupted
        return
    correlation, lever = PairErrorCorrelation(), LeverArm(lever_std)
    for f in _fixed_lag_frames(measurements, cfg, speeds, progress):
        m = by_frame.get(f.frame)
        yield heave.widened(correlation.widened(lever.corrected(f, m), m), m)


def _fixed_lag_frames(measurements: Sequence[PairMeasurement], cfg: SmootherConfig,
                      speeds: NDArray, progress: bool) -> Iterator[SmoothedFrame]:
    """The fixed-lag smoother's frames as they leave its window."""
    sm = FixedLagSmoother(cfg)
    it = zip(measurements, speeds, strict=True)
    if progress:
        from vipm_track.progress import progress_bar

        it = progress_bar(it, total=len(measurements), desc="fixed-lag smoother", unit="frame")
    for m, v in it:
        yield from sm.step(m, float(v))
    yield from sm.finish()


class MarginalsInterrupted(KeyboardInterrupt):
    """An interrupt while the batch computed its marginals, after every frame was yielded:
    the converged estimate, its standard deviations empty."""

    def __str__(self) -> str:
        return "interrupted while computing the standard deviations: their columns are empty"


def smoothed_rows(
    measurements: Sequence[PairMeasurement],
    speed_series: SpeedSource | None = None,
    config: SmootherConfig | None = None,
    progress: bool = False,
) -> Iterator[tuple[SmoothedFrame, dict]]:
    """(smoothed frame, its track-table row) of every frame, each as soon as it is final
    (:func:`smoothed_frames`); a frame the smoother did not start on has its reason as
    ``status``. The rows of ``vipm-track smooth`` and of a fleet's ``smoothed.parquet``."""
    speeds = speeds_at_frames(measurements, speed_series)
    by_frame = {m.frame: (m, v) for m, v in zip(measurements, speeds, strict=True)}
    for f in smoothed_frames(measurements, speed_series, config, progress=progress):
        m, v = by_frame.get(f.frame, (None, float("nan")))
        row = track_row(f, m, float(v) if np.isfinite(v) else None)
        if not f.initialised:
            row["status"] = f.reason or "skipped"
        yield f, row
