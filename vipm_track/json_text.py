"""JSON as other programs read it: a number that is not finite (NaN, ±inf) is ``null``.
Python's ``json`` writes bare ``NaN`` and ``Infinity``, which JSON does not have (a
browser's ``JSON.parse`` and ``jq`` refuse the file)."""

from __future__ import annotations

import json
import math
from typing import Any

from .table import format_float


def finite(value: Any) -> Any:
    """``value`` with every non-finite float inside it (dicts, lists, tuples) None."""
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(v) for v in value]
    if isinstance(value, float):
        # as the tables' numbers (docs/formats.md): 1.9, not 1.9000000000000001
        return float(format_float(value)) if math.isfinite(value) else None
    return value


def dumps(value: Any, **options: Any) -> str:
    """``json.dumps`` of :func:`finite` ``value``, refusing any non-finite number left."""
    return json.dumps(finite(value), allow_nan=False, **options)
