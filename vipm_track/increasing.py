"""The rows of a series that should be increasing and are: its longest strictly increasing
subsequence. One corrupt row (a time of 100 s in a 4-s table, a frame number of 100000) is
then the only row left out, where keeping each row after the last kept one dropped every
row after the corrupt one."""

from __future__ import annotations

import math
from bisect import bisect_left

import numpy as np
from numpy.typing import ArrayLike, NDArray


def longest_increasing(values: ArrayLike) -> NDArray[np.int64]:
    """Indices (ascending) of a longest strictly increasing subsequence of ``values`` (finite
    floats); of several, the one of the earliest rows (in a tie, the row that goes back is
    the one left out, as when reading row by row)."""
    v = np.asarray(values, dtype=float)
    ending = _run_lengths(v)  # longest increasing run ending at each row
    starting = _run_lengths(-v[::-1])[::-1]  # ... and starting at each row
    total = int(ending.max()) if v.size else 0
    out: list[int] = []
    for i in np.flatnonzero(ending + starting - 1 == total).tolist():
        if ending[i] == len(out) + 1 and (not out or v[i] > v[out[-1]]):
            out.append(i)
    return np.array(out, dtype=np.int64)


def _run_lengths(v: NDArray[np.float64]) -> NDArray[np.int64]:
    """Length of the longest strictly increasing subsequence ending at each element
    (patience sorting)."""
    tails: list[float] = []  # smallest last value of an increasing run of each length
    lengths = np.empty(v.size, dtype=np.int64)
    for i, x in enumerate(v.tolist()):
        k = bisect_left(tails, x)
        if k == len(tails):
            tails.append(x)
        else:
            tails[k] = x
        lengths[i] = k + 1
    return lengths


def left_out_between(values: ArrayLike) -> tuple[NDArray[np.int64],
                                                 list[tuple[int, float, float]]]:
    """:func:`longest_increasing`'s indices and, for each index it leaves out, (index, the
    kept value before it, the kept value after it; NaN where there is none): what a message
    about the left-out row names it by."""
    v = np.asarray(values, dtype=float)
    kept = longest_increasing(v)
    kept_list = kept.tolist()
    out = []
    for i in sorted(set(range(v.size)) - set(kept_list)):
        at = bisect_left(kept_list, i)
        out.append((i, float(v[kept_list[at - 1]]) if at > 0 else float("nan"),
                    float(v[kept_list[at]]) if at < len(kept_list) else float("nan")))
    return kept, out


def kept_around(before: float, after: float) -> str:
    """Where a left-out row sits among the kept ones, as its message says it: "between kept
    A and B", "after kept A" or "before kept B" (NaN: no kept row on that side; "" where
    there is none on either)."""
    if math.isfinite(before) and math.isfinite(after):
        return f"between kept {before!r} and {after!r}"
    if math.isfinite(before):
        return f"after kept {before!r}"
    return f"before kept {after!r}" if math.isfinite(after) else ""
