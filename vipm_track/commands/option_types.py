"""argparse ``type=`` functions for numeric options: each turns an option's text into a value
within the option's range or raises ``ArgumentTypeError``, so that a bad value is argparse's
one-line error naming the option and the value (exit 2) before any work is done."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def whole_number(low: int = 0, high: int | None = None) -> Callable[[str], int]:
    """Type of an integer option in ``[low, high]`` (``high`` None: no upper bound)."""
    wanted = f"a whole number >= {low}" if high is None else \
        f"a whole number in [{low}, {high}]"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}")
        return value

    parse.__name__ = "whole_number"
    return parse


def number(low: float, high: float = math.inf, *, above: bool = False, below: bool = False,
           what: str = "number") -> Callable[[str], float]:
    """Type of a finite float option from ``low`` to ``high``, ``low`` itself excluded where
    ``above`` and ``high`` where ``below`` (``high`` inf: no upper bound). ``what`` names the
    value in the message ("number of seconds")."""
    if math.isinf(high):
        wanted = f"a finite {what} {'>' if above else '>='} {low:g}"
    else:
        wanted = f"a {what} in {'(' if above else '['}{low:g}, {high:g}{')' if below else ']'}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
        inside = (math.isfinite(value) and (value > low if above else value >= low)
                  and (value < high if below else value <= high))
        if not inside:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}")
        return value

    parse.__name__ = "number"
    return parse
