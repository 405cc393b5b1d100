"""``asrmap bench``: throughput and latency figures of the hot paths on this computer."""

from __future__ import annotations

import importlib
import pkgutil

from service import bench
from service.argtypes import count

NAME = "bench"
HELP = "print throughput/latency figures (median, p99, rate) of each hot path on this computer"
EXAMPLE = "asrmap bench sip telegram"


def _benchmarks():
    mods = (importlib.import_module(f"service.bench.{i.name}") for i in pkgutil.iter_modules(bench.__path__))
    return {m.NAME: m for m in mods}


def add_arguments(p) -> None:
    p.add_argument("names", nargs="*", help="benchmarks to run (default: all); --list shows them")
    p.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    p.add_argument("--quick", action="store_true", help="fewer repetitions (a smoke run)")
    p.add_argument("--runs", type=count, default=1, metavar="N",
                   help="mapper: replay N times and print each run's median and p99 and their median "
                        "(this machine's timings vary by tens of per cent between runs)")


def run(args) -> int:
    found = _benchmarks()
    if args.list:
        for name, mod in sorted(found.items()):
            print(f"{name:12s} {mod.HELP}")
        return 0
    unknown = [n for n in args.names if n not in found]
    if unknown:
        raise ValueError(f"unknown benchmark {', '.join(unknown)}; choose from {', '.join(sorted(found))}")
    for name in args.names or sorted(found):
        print(f"== {name}: {found[name].HELP}")
        found[name].run(args)
    return 0
