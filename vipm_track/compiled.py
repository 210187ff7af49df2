"""The decorator of the compiled kernels (numba): the filters', the rolling-shutter solve's
and the phase correlation's inner loops."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from numba import njit

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
