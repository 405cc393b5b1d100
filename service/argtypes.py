"""argparse value types shared by the subcommands (a bad value is argparse's one-line usage error),
and the checks and writing of the files the subcommands write (:func:`distinct_files`,
:func:`write_output`): an error a user could cause is one line naming the option or file."""

from __future__ import annotations

import argparse
import math
import os

#: s. The longest time an option takes (about three years): beyond it the OS's timers overflow.
MAX_SECONDS = 1e8

#: The slowest an emulated device may run against real time: the drivers' timeouts (the P2OS SIP's
#: 1 s) are real time, and at a tenth of real time the emulated Pioneer's 100 ms SIP cycle exceeds them.
MIN_SPEED = 0.2


def _number(text: str, ok, expected: str) -> float:
    try:
        x = float(text)
    except ValueError:
        x = math.nan
    if not (math.isfinite(x) and ok(x)):
        raise argparse.ArgumentTypeError(f"expected {expected}, found {text!r}")
    return x


def positive(text: str) -> float:
    """A number > 0 and at most :data:`MAX_SECONDS` (seconds)."""
    return _number(text, lambda x: 0 < x <= MAX_SECONDS, f"a number > 0 and at most {MAX_SECONDS:g}")


def count(text: str) -> int:
    """A whole number >= 1 (how many runs)."""
    return int(_number(text, lambda x: x >= 1 and x == int(x), "a whole number >= 1"))


def seed(text: str) -> int:
    """A random seed: a whole number >= 0."""
    return int(_number(text, lambda x: 0 <= x < 2**32 and x == int(x), "a whole number from 0 to 2**32 - 1"))


def non_negative(text: str) -> float:
    """A number >= 0 and at most :data:`MAX_SECONDS` (a wait in seconds)."""
    return _number(text, lambda x: 0 <= x <= MAX_SECONDS, f"a number >= 0 and at most {MAX_SECONDS:g}")


_SPEED_RANGE = f"a number from {MIN_SPEED:g} to 1000 (times real time)"


def _in_speed_range(x: float) -> bool:
    return MIN_SPEED <= x <= 1000


def speed_factor(text: str) -> float:
    """How many times faster than real time emulated devices run: :data:`MIN_SPEED` to 1000."""
    return _number(text, _in_speed_range, _SPEED_RANGE)


def speed(text: str) -> float | str:
    """A replay speed factor (:func:`speed_factor`), or ``max``."""
    if text == "max":
        return text
    return _number(text, _in_speed_range, _SPEED_RANGE + " or 'max'")


LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")


def log_level(text: str) -> str:
    """A logging level name, any case (returned upper case)."""
    if text.upper() not in LOG_LEVELS:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(LOG_LEVELS)}, found {text!r}")
    return text.upper()


def robot_name(text: str) -> str:
    """A robot name (one Zenoh key chunk: the key prefix asrmap/<robot>/)."""
    from service.config import ROBOT_NAME_EXPECTED, is_robot_name

    if not is_robot_name(text):
        raise argparse.ArgumentTypeError(f"expected {ROBOT_NAME_EXPECTED}, found {text!r}")
    return text


def robot_or_every(text: str) -> str:
    """A robot name, or ``*`` for every robot."""
    return text if text == "*" else robot_name(text)


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


def _same(a: str, b: str) -> bool:
    if os.path.exists(a) and os.path.exists(b):
        return os.path.samefile(a, b)
    return os.path.realpath(a) == os.path.realpath(b)


def distinct_files(inputs: dict[str, str | None], outputs: dict[str, str | None]) -> None:
    """Refuse (ValueError, naming both options) an output file that is one of the inputs or another
    output: written at the end of the run, it would replace the log or map it was made from, or
    the other output. Options given as None are not checked."""
    given_in = [(k, v) for k, v in inputs.items() if v]
    given_out = [(k, v) for k, v in outputs.items() if v]
    for n, (name, path) in enumerate(given_out):
        for other, src in given_in:
            if _same(path, src):
                raise ValueError(f"{name} {path!r} is the {other} file: writing it would destroy the input")
        for other, out in given_out[n + 1:]:
            if _same(path, out):
                raise ValueError(f"{name} and {other} name the same file {path!r}: "
                                 "one would overwrite the other")


def write_output(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path``; an OS error (a full disk, an I/O error) names the file."""
    try:
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(text)
    except OSError as e:
        raise OSError(f"cannot write {os.fspath(path)!r}: {e.strerror or e}") from e
