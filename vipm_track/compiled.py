"""The decorator of the compiled kernels (numba): the filters', the rolling-shutter solve's
and the phase correlation's inner loops."""

from __future__ import annotations

import atexit
import os
import sys
import tempfile
import uuid
from collections.abc import Callable
from typing import TypeVar

from numba import njit
from numba.core import event

_F = TypeVar("_F", bound=Callable[..., object])


#: the floating-point licences of :func:`reduction_kernel`: sums may be reordered (into SIMD
#: lanes) and multiply-adds fused; NaN and inf keep their meaning
_REASSOCIATE = frozenset({"reassoc", "contract", "nsz", "arcp"})


def kernel(fn: _F) -> _F:
    """``numba.njit`` without the GIL (so threads run kernels side by side), its machine
    code cached on disk (beside the source, else in the user's cache folder), so only the
    first run compiles (~10 s); where neither can be written (a read-only install without a
    home folder) it compiles once per process."""
    return _compile(fn, fastmath=False)


def reduction_kernel(fn: _F) -> _F:
    """:func:`kernel` whose sums may be reordered into SIMD lanes (a few ulp of difference,
    several times faster over patches of pixels); NaN and inf tests still hold."""
    return _compile(fn, fastmath=set(_REASSOCIATE))


def _compile(fn: _F, fastmath: bool | set[str]) -> _F:
    try:
        return njit(cache=True, nogil=True, fastmath=fastmath)(fn)  # type: ignore[return-value]
    except RuntimeError:  # numba: "cannot cache function …: no locator available"
        return njit(nogil=True, fastmath=fastmath)(fn)  # type: ignore[return-value]


#: names the marker file that makes the notice once per run, not once per process: the
#: run's first process sets it, the worker processes it starts inherit it
_NOTICE_MARKER_ENV = "VIPM_TRACK_COMPILE_NOTICE_MARKER"


def _notice_marker() -> str:
    """The run's marker path; the first process of a run chooses it and removes the file
    at exit."""
    marker = os.environ.get(_NOTICE_MARKER_ENV)
    if marker is None:
        marker = os.path.join(tempfile.gettempdir(),
                              f"vipm-track-compile-{os.getpid()}-{uuid.uuid4().hex}")
        os.environ[_NOTICE_MARKER_ENV] = marker
        atexit.register(_remove, marker)
    return marker


def _remove(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _claim_notice(marker: str) -> bool:
    """True in the one process of a run that creates ``marker`` first (and where it cannot
    be written: better said twice than a silent wait)."""
    try:
        os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
    except FileExistsError:
        return False
    except OSError:
        return True
    return True


class _FirstCompileNotice(event.Listener):
    """Says once per run (this process and the worker processes it starts), on stderr, when
    one of the project's kernels is compiled rather than loaded from the cache: the first
    run on a machine (or after an upgrade) spends 10–20 s compiling before its first
    result, which would otherwise look like a hang."""

    def __init__(self) -> None:
        self.said = False
        self.marker = _notice_marker()

    def on_start(self, ev: event.Event) -> None:
        dispatcher = (ev.data or {}).get("dispatcher")
        module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
        if self.said or not module.startswith("vipm_track"):
            return
        self.said = True
        if _claim_notice(self.marker):
            print("vipm-track: compiling numerical kernels for this machine (10–20 s; cached "
                  "for later runs)", file=sys.stderr, flush=True)

    def on_end(self, ev: event.Event) -> None:
        pass


_NOTICE = _FirstCompileNotice()
event.register("numba:compile", _NOTICE)
