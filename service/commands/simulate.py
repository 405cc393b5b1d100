"""``asrmap simulate``: a simulated Pioneer 2DX and LMS200 explore a world; the full service maps it."""

from __future__ import annotations

import argparse
import json
import os
import signal
import threading
from dataclasses import replace

from service.argtypes import (
    distinct_files,
    non_negative,
    output_file,
    positive,
    robot_name,
    seed,
    speed_factor,
    write_output,
)
from service.render import write_svg
from service.sim.simulator import DirectSim, SimParams, StackSim
from service.sim.world import builtin_worlds, load_world

NAME = "simulate"
HELP = ("simulated Pioneer 2DX + LMS200 on pty pairs (real protocols) explore a world while the service "
        "maps it and publishes on Zenoh; writes the map and a picture, prints a summary")
EXAMPLE = "asrmap simulate --world office --fast --svg office.svg"

FAST = 10.0  # --fast without a factor: the goal of ten times real time


def add_arguments(p) -> None:
    p.add_argument("--world", default="lab", metavar="NAME|FILE",
                   help=f"built-in world ({', '.join(builtin_worlds())}) or a world .json file "
                        "(default: lab)")
    p.add_argument("--explore", action=argparse.BooleanOptionalAction, default=True,
                   help="explore autonomously (default); --no-explore keeps the robot still (for 60 s "
                        "unless --duration)")
    p.add_argument("--duration", type=positive, default=None, metavar="S",
                   help="stop after S simulated seconds (default: when exploration is done)")
    p.add_argument("--fast", nargs="?", type=speed_factor, const=FAST, default=None, metavar="FACTOR",
                   help=f"run FACTOR times faster than real time (default factor {FAST:g}): the emulators' "
                        "SIP cycle and scan rate and the robot's motion all scale together")
    p.add_argument("--direct", action="store_true",
                   help="no ptys, drivers or Zenoh: the mapper in-process on a simulated clock (as fast "
                        "as the computer allows, repeatable for a seed)")
    p.add_argument("--latency", type=non_negative, default=0.0, metavar="S",
                   help="with --direct: simulated seconds from a scan to the robot acting on the command "
                        "planned from it (default 0; the whole stack at --fast has 0.15-0.35 s)")
    p.add_argument("--svg", default="asrmap-map.svg", metavar="OUT", type=output_file,
                   help="picture of the map (default: %(default)s)")
    p.add_argument("--json", default="asrmap-map.json", metavar="OUT", type=output_file,
                   help="the map document, asrmap/map/1 (default: %(default)s)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the range noise (default: 0)")
    p.add_argument("--robot", default="pioneer", type=robot_name,
                   help="robot name: the Zenoh key prefix asrmap/<robot>/")
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint the service listens on, repeatable (default: tcp/127.0.0.1:7447)")
    p.add_argument("--state-dir", default=None, metavar="DIR",
                   help="where the service keeps its map store (default: a temporary directory)")


def _progress(every: float):
    state = {"next": 0.0}

    def show(t: float, status: str, mapper) -> None:
        if t < state["next"]:
            return
        state["next"] = t + every
        n = len(getattr(mapper, "asrs", {}) or {})
        print(f"t={t:7.1f} s  ASRs {n:3d}  ASR {getattr(mapper, 'current', None)}  {status}", flush=True)

    return show


def run(args) -> int:
    if args.latency and not args.direct:
        raise ValueError("--latency: only with --direct (the whole stack has its own latency)")
    world_file = args.world if os.path.isfile(args.world) else None  # else a built-in world's name
    distinct_files({"--world": world_file}, {"--json": args.json, "--svg": args.svg})
    world = load_world(args.world)
    params = SimParams(seed=args.seed, explore=args.explore, duration=args.duration,
                       command_latency=args.latency)
    if not args.explore and args.duration is None:
        params = replace(params, duration=60.0)  # nothing would ever end the run
    show = _progress(10.0)
    print(f"world {world.name}: {world.description}", flush=True)
    if args.direct:
        sim = DirectSim(world, params, progress=show)
        summary = sim.run()
    else:
        speed = args.fast if args.fast is not None else 1.0
        sim = StackSim(world, params, speed=speed, state_dir=args.state_dir, robot_name=args.robot,
                       progress=show, listen=tuple(args.listen) if args.listen else None)
        _stop_on_signals(sim)
        summary = sim.run()
    doc = sim.document
    if args.json:
        write_output(args.json, json.dumps(doc, indent=1) + "\n")
        print(f"map document: {args.json}")
    if args.svg:
        write_svg(args.svg, doc, title=f"asrmap simulate --world {world.name}", robot=sim.final_pose)
        print(f"picture: {args.svg}")
    for line in summary.lines():
        print(line)
    return 0


def _stop_on_signals(sim: StackSim) -> None:
    """Ctrl-C / SIGTERM end the run cleanly (the summary still prints)."""
    if threading.current_thread() is not threading.main_thread():
        return

    def on_signal(signum, frame) -> None:
        sim.request_stop()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
