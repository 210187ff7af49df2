"""How this process's C allocator hands back freed memory: kept for reuse, not returned to
the operating system after every pair.

A pair's correlation makes and frees tens of megabytes of patch batches and spectra (about
12 million patch pixels per KITTI pair). glibc gives blocks of that size their own memory
map, or trims them off the heap top, as soon as they are freed, so the next batch faults in
fresh pages that the kernel zero-fills first: on the thread that started the process this
was 40 % of a pair's CPU time (167 against 103 ms of CPU per KITTI 07 pair with one
correlation thread, ``docs/speed.md``). Threads other than the first allocate from arenas
that glibc trims more lazily, so the default two-thread run loses little.

``keep_freed_memory`` is called by the command line and by the worker processes it starts,
not on import: the allocator is process-wide, and an application embedding the package
decides its own.
"""

from __future__ import annotations

import ctypes

#: glibc's ``mallopt`` parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: blocks up to this size come from the heap (glibc's largest allowed value on 64-bit)
MMAP_THRESHOLD_BYTES = 32 << 20
#: free memory at the heap top is returned to the system only beyond this
TRIM_THRESHOLD_BYTES = 256 << 20


def keep_freed_memory() -> bool:
    """Keep freed blocks of up to 32 MiB, and up to 256 MiB free at the heap top, for reuse
    (glibc only); whether the allocator took both settings (False elsewhere: a no-op)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # no C library to ask, or one without mallopt
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
