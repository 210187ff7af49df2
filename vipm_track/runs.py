"""Whole sequences: the pairs of a frame source run in this process
(``pipeline.run_sequence``) or in chunks over several (``parallel.run_chunked``), and
streamed into an estimates table with a summary of what came out."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .measurement import PairMeasurement, measurement_row
from .parallel import DEFAULT_CHUNK_FRAMES, run_chunked
from .pipeline import FIRST_FRAME, SequenceStep, run_sequence
from .progress import progress_bar
from .rig import Rig
from .sources import FrameSource
from .statuses import counts_text
from .table import (
    CONCISE,
    ESTIMATE_COLUMNS,
    ESTIMATE_TABLE,
    ColumnChoice,
    TableWriter,
    choose_columns,
)

if TYPE_CHECKING:
    from .estimator import TwoFrameEstimator
    from .estimator_config import EstimatorConfig


def sequence_steps(
    source: FrameSource,
    rig: Rig,
    config: EstimatorConfig | None = None,
    tracking: bool = True,
    estimator: TwoFrameEstimator | None = None,
    workers: int = 1,
    chunk_frames: int | None = None,
) -> Iterator[SequenceStep]:
    """:func:`run_sequence`, or, with ``workers`` > 1 or ``chunk_frames`` given, its steps
    from chunks of ``chunk_frames`` frames (default 500) run in ``workers`` processes
    (:mod:`vipm_track.parallel`: each chunk's first pair starts cold, and ``estimator`` is
    then each chunk's own)."""
    if workers <= 1 and chunk_frames is None:
        return run_sequence(source, rig, config, tracking, estimator)
    return run_chunked(source, rig, config, tracking, workers,
                       chunk_frames or DEFAULT_CHUNK_FRAMES)


# --- rows ------------------------------------------------------------------------------------

ROW_COLUMNS: tuple[str, ...] = ESTIMATE_COLUMNS


def step_row(step: SequenceStep, height: float) -> dict[str, Any]:
    """The estimates-table row of a step: measurement columns, ``patches`` (patches matched in
    the last stage) and ``residual_px``; numbers empty unless the status is ``ok``."""
    result = step.result
    measurement = result.to_measurement(step.frame, step.t) if result is not None else None
    if measurement is None:
        return {"frame": step.frame, "t": step.t, "height_m": height, "status": step.status}
    row = measurement_row(measurement)
    row["status"] = step.status
    stages = getattr(result, "stages", None) or []
    row["patches"] = len(stages[-1].centres) if stages else None
    residual = getattr(result, "residual_px", None)
    row["residual_px"] = float(residual) if residual is not None and step.ok else None
    return row


def step_measurement(step: SequenceStep, height: float) -> PairMeasurement:
    """The pair measurement of a step (the filters' input); a frame without an estimate
    carries its status (``no estimate`` where the step said ``ok`` without one) and NaNs,
    at the assumed ``height`` [m]."""
    m = step.result.to_measurement(step.frame, step.t) if step.ok else None
    if m is None:
        status = step.status if step.status != "ok" else "no estimate"
        m = PairMeasurement(step.frame, step.t, np.full(7, np.nan), np.full((7, 7), np.nan),
                            height, status)
    return m


# --- whole runs ------------------------------------------------------------------------------


@dataclass
class RunSummary:
    """Counts and timing of a run: frames seen, rows ok, statuses, estimator and wall time."""

    frames: int = 0
    ok: int = 0
    pairs: int = 0
    statuses: Counter = field(default_factory=Counter)
    estimator_seconds: float = 0.0
    wall_seconds: float = 0.0

    def add(self, step: SequenceStep) -> None:
        self.frames += 1
        self.ok += step.ok
        self.pairs += step.result is not None
        self.statuses[step.status] += 1
        self.estimator_seconds += step.seconds

    @property
    def pairs_per_second(self) -> float:
        return self.pairs / self.wall_seconds if self.wall_seconds > 0 else float("nan")

    def line(self) -> str:
        """One-line summary: frames ok / total, pairs per second, other statuses."""
        others = counts_text(self.statuses, leave_out=("ok", FIRST_FRAME))
        text = (
            f"{self.ok}/{self.frames} frames ok ({100.0 * self.ok / max(self.frames, 1):.1f} %), "
            f"{self.pairs_per_second:.2f} pairs/s"
        )
        return text + (f"; {others}" if others else "")


def estimate_sequence(
    source: FrameSource,
    rig: Rig,
    out: str | Path,
    config: EstimatorConfig | None = None,
    tracking: bool = True,
    parquet: bool = False,
    progress: bool | None = None,
    on_step: Callable[[SequenceStep], None] | None = None,
    estimator: TwoFrameEstimator | None = None,
    workers: int = 1,
    chunk_frames: int | None = None,
    columns: ColumnChoice = CONCISE,
) -> RunSummary:
    """Run ``source`` and stream one row per frame into the CSV ``out`` (and Parquet beside it
    with ``parquet``). Rows are flushed as they come, so an interrupted run keeps them.

    ``progress``: show progress on stderr (``progress.progress_bar``: a bar on a terminal, a
    line every few seconds where stderr is a file or a pipe; ``None``: as True).
    ``on_step`` is called with every step (e.g. a live display); ``estimator`` replaces the
    one built from ``rig`` and ``config``; ``workers``, ``chunk_frames``: as
    :func:`sequence_steps`; ``columns``: the table's columns (:func:`table.choose_columns`)."""
    written = choose_columns(ESTIMATE_TABLE, columns)
    out = Path(out)
    parquet_path = out.with_suffix(".parquet") if parquet else None
    if progress is None:
        progress = True
    summary = RunSummary()
    start = time.perf_counter()
    steps = sequence_steps(source, rig, config, tracking, estimator, workers,
                           chunk_frames)
    with (
        TableWriter(out, ROW_COLUMNS, parquet_path, written) as writer,
        progress_bar(total=len(source), disable=not progress, unit="frame") as bar,
    ):
        for step in steps:
            writer.write(step_row(step, rig.height_m))
            summary.add(step)
            summary.wall_seconds = time.perf_counter() - start
            bar.update(1)
            bar.set_postfix(ok=summary.ok, refresh=False)
            if on_step is not None:
                on_step(step)
    summary.wall_seconds = time.perf_counter() - start
    return summary
