"""Checked argparse types: numbers in a range, vectors."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any

__all__ = [
    "bounded_float",
    "bounded_int",
    "nonnegative_float",
    "nonnegative_int",
    "positive_float",
    "positive_int",
    "unit_float",
    "vector3",
]


def _number(cast: type, ok: Callable[[Any], bool], expected: str) -> Callable[[str], Any]:
    """Make an argparse ``type``: ``cast(text)``, which must satisfy ``ok`` ("expected ...")."""

    def parse(text: str) -> Any:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {value}")
        return value

    return parse


positive_int = _number(int, lambda v: v >= 1, "a positive integer")
nonnegative_int = _number(int, lambda v: v >= 0, "an integer >= 0")
unit_float = _number(float, lambda v: 0.0 < v < 1.0, "a number in (0, 1)")
positive_float = _number(float, lambda v: math.isfinite(v) and v > 0.0, "a finite number > 0")
nonnegative_float = _number(float, lambda v: math.isfinite(v) and v >= 0.0, "a number >= 0")


def bounded_int(lo: int, hi: int) -> Callable[[str], int]:
    """Make an argparse type: an integer in ``[lo, hi]``."""
    return _number(int, lambda v: lo <= v <= hi, f"an integer in [{lo}, {hi}]")


def bounded_float(lo: float, hi: float) -> Callable[[str], float]:
    """Make an argparse type: a float in ``[lo, hi]``."""
    return _number(float, lambda v: lo <= v <= hi, f"a number in [{lo:g}, {hi:g}]")


def vector3(text: str) -> tuple[float, float, float]:
    """Parse three comma-separated numbers, not all zero."""
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not any(values) or not all(map(math.isfinite, values)):
        raise argparse.ArgumentTypeError(
            f"expected three comma-separated numbers, not all 0; got {text!r}"
        )
    return values  # type: ignore[return-value]
