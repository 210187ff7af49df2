"""The row statuses of an estimates table: every one the estimator, the sequence runner and the
table readers write (docs/formats.md), and :func:`is_known` for a table read back."""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection, Mapping

STATUS_OK = "ok"
STATUS_NO_TEXTURE = "no texture"
STATUS_NO_MOTION = "no motion"
STATUS_FEW_INLIERS = "too few inliers"
STATUS_NOT_CONVERGED = "did not converge"
STATUS_DEGENERATE = "degenerate"
STATUS_NO_NOMINAL = "no nominal pose"
#: an ``ok`` pair whose motion the vehicle could not have reached from the pairs before it
#: (``pair_chain.PairChain``)
STATUS_IMPLAUSIBLE_MOTION = "implausible motion"
FIRST_FRAME = "first frame"
NO_PREVIOUS = "no previous frame"
UNREADABLE = "unreadable frame"
WRONG_SIZE = "wrong image size"
#: an exception inside the estimator (its type and message follow)
ESTIMATOR_ERROR = "estimator error"
#: a live pair with no estimate
NO_ESTIMATE = "no estimate"
#: a row whose status says ``ok`` but whose numbers are not all there
MISSING_NUMBERS = "no estimate (numbers missing in the table)"

KNOWN: frozenset[str] = frozenset({
    STATUS_OK, STATUS_NO_TEXTURE, STATUS_NO_MOTION, STATUS_FEW_INLIERS, STATUS_NOT_CONVERGED,
    STATUS_DEGENERATE, STATUS_NO_NOMINAL, STATUS_IMPLAUSIBLE_MOTION, FIRST_FRAME, NO_PREVIOUS,
    NO_ESTIMATE, MISSING_NUMBERS,
})
#: statuses that carry a detail after them (a file, a size, an exception)
PREFIXES: tuple[str, ...] = (UNREADABLE, WRONG_SIZE, ESTIMATOR_ERROR)


def is_known(status: str) -> bool:
    """Whether ``status`` is one vipm-track writes."""
    return status in KNOWN or status.startswith(PREFIXES)


def counts_text(counts: Mapping[str, int], leave_out: Collection[str] = ()) -> str:
    """``12× ok, 3× no texture``: status counts, most common first, without ``leave_out``."""
    return ", ".join(f"{n}× {status}" for status, n in Counter(counts).most_common()
                     if status not in leave_out)
