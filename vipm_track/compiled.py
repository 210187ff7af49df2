"""The decorator of the compiled kernels (numba): the filters' and the rolling-shutter solve."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from numba import njit

_F = TypeVar("_F", bound=Callable[..., object])


def kernel(fn: _F) -> _F:
    """``numba.njit`` with its machine code cached on disk (beside the source, else in the
    user's cache folder), so only the first run compiles (~10 s); where neither can be
    written (a read-only install without a home folder) it compiles once per process."""
    try:
        return njit(cache=True)(fn)  # type: ignore[return-value]
    except RuntimeError:  # numba: "cannot cache function …: no locator available"
        return njit(fn)  # type: ignore[return-value]
