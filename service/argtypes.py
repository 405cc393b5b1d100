"""argparse value types shared by the subcommands: a bad value is argparse's one-line usage error."""

from __future__ import annotations

import argparse
import math
import os


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


def output_file(text: str) -> str:
    """A file to write at the end of a run: checked before the run, so a long run is not lost to a typo.

    Its directory must exist and be writable, and the path itself must not be a directory.
    '{robot}' in the path (``monitor --svg``) is kept as given.
    """
    if not text:
        raise argparse.ArgumentTypeError("expected a file path, found ''")
    if os.path.isdir(text):
        raise argparse.ArgumentTypeError(f"expected a file path, found the directory {text!r}")
    parent = os.path.dirname(os.path.abspath(text))
    if not os.path.isdir(parent):
        raise argparse.ArgumentTypeError(f"{text!r}: no directory {parent!r} to write it in")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"{text!r}: the directory {parent!r} is not writable")
    if os.path.exists(text) and not os.access(text, os.W_OK):
        raise argparse.ArgumentTypeError(f"{text!r} exists and is not writable")
    return text
