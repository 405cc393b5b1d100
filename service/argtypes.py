"""argparse value types shared by the subcommands: a bad value is argparse's one-line usage error."""

from __future__ import annotations

import argparse
import math


def _number(text: str, ok, expected: str) -> float:
    try:
        x = float(text)
    except ValueError:
        x = math.nan
    if not (math.isfinite(x) and ok(x)):
        raise argparse.ArgumentTypeError(f"expected {expected}, found {text!r}")
    return x


def positive(text: str) -> float:
    """A finite number > 0 (seconds, a speed factor)."""
    return _number(text, lambda x: x > 0, "a number > 0")


def count(text: str) -> int:
    """A whole number >= 1 (how many runs)."""
    return int(_number(text, lambda x: x >= 1 and x == int(x), "a whole number >= 1"))


def non_negative(text: str) -> float:
    """A finite number >= 0 (a wait in seconds)."""
    return _number(text, lambda x: x >= 0, "a number >= 0")


def speed(text: str) -> float | str:
    """A replay speed factor > 0, or ``max``."""
    return text if text == "max" else _number(text, lambda x: x > 0, "a number > 0 or 'max'")
