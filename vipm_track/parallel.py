"""Chunked runs of the sequence runner in several processes, for long recordings.

A pair's estimate depends only on its two frames, the tracking guess from the pair before
and the bound on the motion (``pair_chain``: the pairs of the second before), so a recording
splits into chunks of consecutive frames that run independently: each
chunk also reads the frame before its first (the pair across the boundary is estimated in
the chunk, cold-started like a pair after a failure) and its steps are yielded in frame
order as the chunks finish. The chunks, hence the results, depend on ``chunk_frames`` only,
not on the number of processes; they differ from one sequential run only in the pairs from
each chunk's first on, until tracking has forgotten its start (on a steep camera within a
few pairs; a level camera's run is chaotic in its last bits, see ``docs/kitti.md``); a
chunk's first pairs have no earlier motion to be held to.
"""

from __future__ import annotations

import multiprocessing
import signal
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor, wait
from typing import TYPE_CHECKING

from .allocator import keep_freed_memory
from .errors import InputError
from .pipeline import SequenceStep, run_sequence
from .workers import set_threads

if TYPE_CHECKING:
    from multiprocessing.synchronize import Event

    from .estimator_config import EstimatorConfig
    from .rig import Rig
    from .sources import FrameSource

#: Frames per chunk by default: a cold start per 500 frames costs ~0.1 % of a run's time.
DEFAULT_CHUNK_FRAMES = 500
#: The fewest frames a chunk may hold.
MIN_CHUNK_FRAMES = 2
#: Interrupted, the longest wait (s) for the running chunks to hand back the pairs they have
#: estimated (each stops after its current pair); a second Ctrl-C ends the wait at once.
STOP_WAIT_S = 5.0

#: Set in a worker process (``_start_worker``): the run was interrupted, a running chunk
#: returns the steps it has.
_stop_requested: Event | None = None


def chunk_bounds(n_frames: int, chunk_frames: int) -> list[tuple[int, int]]:
    """(first position, frames) of each chunk of a source of ``n_frames`` frames."""
    return [(p, min(chunk_frames, n_frames - p)) for p in range(0, n_frames, chunk_frames)]


def run_chunked(
    source: FrameSource,
    rig: Rig,
    config: EstimatorConfig | None,
    tracking: bool,
    workers: int,
    chunk_frames: int,
) -> Iterator[SequenceStep]:
    """The steps of :func:`run_sequence` over ``source``, from chunks of ``chunk_frames``
    frames run in ``workers`` processes (1: in this one), in frame order. A source of unknown
    length (a video whose container does not say) or of one chunk runs as one sequence.
    Interrupted (KeyboardInterrupt: Ctrl-C, SIGTERM) while waiting on a chunk, it asks the
    running chunks to stop after their current pair, waits up to :data:`STOP_WAIT_S` for
    them, yields in frame order the steps of every chunk that finished or stopped (a gap
    after each stopped one), then raises."""
    if chunk_frames < MIN_CHUNK_FRAMES:
        raise InputError(f"--chunk-frames must be >= {MIN_CHUNK_FRAMES}, got {chunk_frames}")
    bounds = chunk_bounds(len(source), chunk_frames)
    if len(bounds) <= 1:
        yield from run_sequence(source, rig, config, tracking)
        return
    if workers <= 1:  # the same chunks, one after another in this process
        for p, n in bounds:
            yield from run_chunk(source, rig, config, tracking, p, n)
        return
    context = multiprocessing.get_context("spawn")  # no forked OpenCV / numba thread pools
    # one correlation thread per process: the processes already share the cores
    stop_requested = context.Event()
    pool = ProcessPoolExecutor(min(workers, len(bounds)), mp_context=context,
                               initializer=_start_worker, initargs=(1, stop_requested))
    finished = False
    futures: list[Future[list[SequenceStep]]] = []
    waiting, sent = 0, 0  # the chunk whose steps come next, and how many of them went out
    try:
        futures = [pool.submit(run_chunk, source, rig, config, tracking, p, n)
                   for p, n in bounds]
        for future in futures:
            steps = future.result()
            while sent < len(steps):
                sent += 1
                yield steps[sent - 1]
            waiting, sent = waiting + 1, 0
        finished = True
    except KeyboardInterrupt:
        # Ctrl-C or SIGTERM while waiting on a chunk: nothing computed is lost. The chunks not
        # started are dropped, the running ones hand back the pairs they have estimated, and
        # the steps not yet out follow in frame order (a gap after each stopped chunk); then
        # the interruption goes on. A second interrupt during the wait ends it (``finally``).
        stop_requested.set()
        for future in futures[waiting:]:
            future.cancel()
        wait(futures[waiting:], timeout=STOP_WAIT_S)
        for j, future in enumerate(futures[waiting:]):
            if future.done() and not future.cancelled() and future.exception() is None:
                yield from future.result()[sent if j == 0 else 0:]
        raise
    finally:
        if finished:
            pool.shutdown()
        else:  # interrupted (Ctrl-C, SIGTERM) or failed: end now, not after the running chunks
            _stop(pool)


def _start_worker(threads: int, stop_requested: Event) -> None:
    """A worker process: ``threads`` correlation threads, freed memory kept for reuse
    (``allocator``: its chunks run on its first thread), and Ctrl-C left to the main process
    (it sets ``stop_requested``, then ends the workers), also SIGTERM sent to the whole
    process group (a service stopped): a worker that died or raised at once would lose the
    pairs its chunk has estimated."""
    global _stop_requested
    _stop_requested = stop_requested
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    keep_freed_memory()
    set_threads(threads)


def _stop(pool: ProcessPoolExecutor) -> None:
    """Cancel ``pool``'s pending chunks and end its workers without waiting for the running
    ones (``shutdown`` alone waits for them: minutes for chunks of 500 frames)."""
    workers = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in workers:
        if process.is_alive():
            process.kill()  # they ignore SIGTERM
    for process in workers:
        process.join(timeout=5)


def run_chunk(
    source: FrameSource,
    rig: Rig,
    config: EstimatorConfig | None,
    tracking: bool,
    position: int,
    count: int,
) -> list[SequenceStep]:
    """The steps of the ``count`` frames from ``position`` on (run in a worker process); the
    first of them only, up to the pair it was estimating, where the run was interrupted."""
    steps: list[SequenceStep] = []
    if _stop_requested is not None and _stop_requested.is_set():
        return steps
    overlap = 1 if position > 0 else 0
    chunk = source.frames(position - overlap, count + overlap)
    for step in run_sequence(chunk, rig, config, tracking, continuation=position > 0):
        steps.append(step)
        if _stop_requested is not None and _stop_requested.is_set():
            break
    return steps[overlap:]
