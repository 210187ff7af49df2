"""The process's threads for one pair's parallel work: the patches' correlation
(``patch_match``) and the random subsets' Levenberg–Marquardt (``bundle``). Their kernels
release the GIL, so the threads run on separate cores; each item's result does not depend on
the thread it ran on, so the estimates are the same for any count."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

_T = TypeVar("_T")
_R = TypeVar("_R")

#: environment variable that sets the default thread count (a Dask worker's, which runs one
#: drive per core); else 2, or the machine's cores if fewer
THREADS_ENV = "VIPM_TRACK_THREADS"


def _default_threads() -> int:
    value = os.environ.get(THREADS_ENV, "")
    return int(value) if value.isdigit() and int(value) >= 1 else min(2, os.cpu_count() or 1)


_threads = _default_threads()
_pool: ThreadPoolExecutor | None = None
#: guards ``_threads`` and ``_pool``: a live monitor, a fleet of threads or an embedding
#: application may estimate on several threads while another changes the count
_lock = threading.Lock()


def _forget_pool() -> None:
    """In a forked child: the parent's pool object came along, its threads did not."""
    global _pool, _lock
    _pool, _lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_pool)


def set_threads(threads: int) -> None:
    """Threads of one pair's parallel work (module doc), for the whole process: 1 where
    processes already share the cores (parallel chunks). Safe while other threads use the
    pool: their running items finish on the old one."""
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
    """The thread count of :func:`map_on_threads`."""
    return _threads


def map_on_threads(fn: Callable[[_T], _R], items: list[_T]) -> list[_R]:
    """``fn`` over ``items`` on the pool (made on first use), results in order."""
    global _pool
    with _lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(_threads, thread_name_prefix="vipm-poc")
        futures = [_pool.submit(fn, item) for item in items]
    return [f.result() for f in futures]
