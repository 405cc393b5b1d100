"""The ``asrmap`` command line: argparse subcommands discovered in :mod:`service.commands`.

Errors a user can cause (a missing port, a bad config key, a malformed log) are printed as one
line on stderr with exit status 2; ``--debug`` shows the traceback as well.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys

import serial

from service import commands
from service.argtypes import log_level

log = logging.getLogger("asrmap")

# The order of `asrmap --help`; commands not listed here follow alphabetically.
ORDER = ["simulate", "run", "emulate", "replay", "monitor", "render", "probe", "bench"]

# Exceptions that mean "the user or the environment is at fault", not a bug. Every typed error of
# the packages (ProtocolError, LinkLost, ConfigError, LogFormatError, ...) derives from one of these.
USER_ERRORS = (OSError, ValueError, ConnectionError, TimeoutError, serial.SerialException)


def _command_modules():
    names = [m.name for m in pkgutil.iter_modules(commands.__path__)]
    names.sort(key=lambda n: (ORDER.index(n) if n in ORDER else len(ORDER), n))
    for name in names:
        yield importlib.import_module(f"service.commands.{name}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="asrmap",
        description="ASR mapping for a Pioneer 2DX with a SICK LMS200 (Jefferies, Cosgrove, Baker & Yeap).",
    )
    parser.add_argument("--log-level", default="INFO", type=log_level,
                        help="logging level: DEBUG, INFO, WARNING, ERROR or CRITICAL")
    parser.add_argument("--debug", action="store_true", help="show tracebacks for errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _command_modules():
        p = sub.add_parser(
            mod.NAME,
            help=mod.HELP,
            description=mod.HELP,
            epilog=f"example:\n  {mod.EXAMPLE}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=getattr(logging, args.log_level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        return 130
    except USER_ERRORS as exc:
        if args.debug:
            raise
        print(f"asrmap {args.command}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
