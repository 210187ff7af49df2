"""POC of many patches of several sizes between two planes, batched by size, on threads."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from . import poc

FloatArray = NDArray[np.float64]

#: A size's batch is split across threads only from this many patches on: below it the
#: per-call overhead (Python, small FFTs) outweighs the second core.
MIN_SPLIT_PATCHES = 16

#: environment variable that sets the default thread count (a Dask worker's, which runs one
#: drive per core); else 2, or the machine's cores if fewer
THREADS_ENV = "VIPM_TRACK_THREADS"


def _default_threads() -> int:
    value = os.environ.get(THREADS_ENV, "")
    return int(value) if value.isdigit() and int(value) >= 1 else min(2, os.cpu_count() or 1)


_threads = _default_threads()
_pool: ThreadPoolExecutor | None = None
#: guards ``_threads`` and ``_pool``: a live monitor, a fleet of threads or an embedding
#: application may correlate on several threads while another changes the count
_lock = threading.Lock()


def _forget_pool() -> None:
    """In a forked child: the parent's pool object came along, its threads did not."""
    global _pool, _lock
    _pool, _lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_pool)


def set_threads(threads: int) -> None:
    """Threads that correlate one pair's patches (the FFTs and numpy work release the GIL),
    for the whole process. Each patch's result does not depend on how the batch is split, so
    the estimates are the same for any count; 1 where processes already share the cores
    (parallel chunks). Safe while other threads correlate: their running batches finish on
    the old pool."""
    global _threads, _pool
    if threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    with _lock:
        if threads == _threads:
            return
        old, _pool, _threads = _pool, None, int(threads)
    if old is not None:
        old.shutdown(wait=False)


def threads() -> int:
    """The thread count :func:`match_grouped` uses."""
    return _threads


def _map(fn, items: list) -> list:
    """``fn`` over ``items`` on the pool (made on first use), in order."""
    global _pool
    with _lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(_threads, thread_name_prefix="vipm-poc")
        futures = [_pool.submit(fn, item) for item in items]
    return [f.result() for f in futures]


def _batches(sizes: NDArray[np.int64]) -> list[tuple[int, NDArray[np.intp]]]:
    """(size, patch indices) of each batch: one per size, the large ones split in
    ``_threads`` parts; largest work first, so the threads finish together."""
    out = []
    for s in np.unique(sizes):
        if s <= 0:
            continue
        sel = np.flatnonzero(sizes == s)
        parts = _threads if len(sel) >= MIN_SPLIT_PATCHES else 1
        out += [(int(s), part) for part in np.array_split(sel, parts)]
    return sorted(out, key=lambda b: -b[0] ** 2 * len(b[1]))


def match_grouped(
    ref: NDArray, moving: NDArray, centres: FloatArray, sizes: NDArray[np.int64],
    offsets: FloatArray, recentre: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """POC displacements (N, 2) and peaks (N,) of patches batched by size (one call per
    size, or per part of a size on :func:`threads` threads); NaN displacement and zero
    peak where ``sizes`` is 0."""
    disp = np.full((len(centres), 2), np.nan)
    peaks = np.zeros(len(centres))

    def run(batch: tuple[int, NDArray[np.intp]]) -> tuple[NDArray[np.intp], FloatArray,
                                                          FloatArray]:
        s, sel = batch
        d, p = poc.match_patches(ref, moving, centres[sel], s, offsets=np.round(offsets[sel]),
                                 recentre=recentre)
        return sel, d, p

    batches = _batches(sizes)
    if _threads > 1 and len(batches) > 1:
        results = _map(run, batches)
    else:
        results = [run(b) for b in batches]
    for sel, d, p in results:
        disp[sel] = d
        peaks[sel] = p
    return disp, peaks
