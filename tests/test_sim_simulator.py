"""Simulated runs: the robot in a world through the pioneer kinematics, in-process and on the full stack."""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest

from mapper.cycle_params import CycleParams
from mapper.params import MapperParams
from service.cli import main
from service.explore import ExploreParams
from service.sim.simulator import DirectSim, SimParams, SimRobot, StackSim, WorldDevices, new_mapper
from service.sim.world import load_world, parse_world


def corridor():
    return parse_world({"schema": "asrmap/world/1", "start": [1.0, 1.0, 0.0],
                        "loops": [[[0, 0], [4, 0], [4, 2], [0, 2]]]})


def test_the_pioneer_drive_stalls_at_a_wall_and_keeps_ground_truth():
    t = [0.0]
    robot = SimRobot(corridor(), SimParams(), lambda: t[0])
    drive = robot.drive
    drive.motors_enabled = True
    drive.set_velocity(0.5)
    for _ in range(100):
        t[0] += 0.1
        drive.step(0.1)
    assert drive.left_stall and drive.right_stall
    assert robot.body.pose[0] == pytest.approx(4.0 - 0.210, abs=0.01)  # front against the wall
    assert robot.true_pose_at(t[0])[0] == pytest.approx(robot.body.pose[0])
    # Odometry is the emulator's, with its error model: it starts at (0, 0, 0) and does not see the wall.
    assert drive.odometry_pose[0] == pytest.approx((4.0 - 0.210 - 1.0) * 1.01, abs=0.02)


def test_world_devices_answer_the_drivers_with_the_world():
    from laser import LMS2xx
    from pioneer import Pioneer

    world = load_world("office")  # starts at (1.5, 4.9) facing east along the 15 m corridor
    with WorldDevices(world) as dev, LMS2xx(dev.laser_path, 38400) as lms:
        scan = lms.read(timeout=5.0)
        assert scan is not None
        ranges, angles = np.asarray(scan.ranges), np.asarray(scan.angles)
        # Straight ahead: the corridor's end wall, 13.5 m away, is beyond the simulated 8.191 m
        # reach: no return, not a wall at 8.191 m (the reader's mode 5 reaches 32 m, where 8.191
        # m would be a real reading; the empty beams of every scan once read as one).
        ahead = int(np.argmin(np.abs(angles)))
        assert scan.no_return[ahead] and ranges[ahead] == pytest.approx(scan.max_range)
        assert not np.any(np.isclose(ranges, 8.191, atol=0.005) & ~scan.no_return)
        # To the right (-90 deg): the corridor's south wall 0.9 m away, less the laser's 8 mm offset.
        assert ranges[0] == pytest.approx(0.9 + 0.008, abs=0.05)
        with Pioneer(dev.pioneer_path) as robot:
            robot.set_velocity(0.3, 0.0)
            time.sleep(1.5)
            robot.stop()
        assert dev.robot.body.pose[0] > world.start[0] + 0.2  # moved east in the world


def test_a_short_direct_run_explores_without_touching_anything():
    sim = DirectSim(load_world("office"), SimParams(duration=60.0))
    s = sim.run()
    assert s.sim_time == pytest.approx(60.0, abs=0.2)
    assert s.contacts == 0
    assert s.distance > 3.0 and s.asrs >= 1
    assert "world office" in s.lines()[0]


def test_the_full_stack_maps_a_world_through_ptys_drivers_and_the_service():
    sim = StackSim(load_world("office"), SimParams(duration=25.0), speed=5.0)
    s = sim.run()
    assert s.scans > 20
    assert s.distance > 0.5 and s.contacts == 0
    assert s.asrs >= 1 and sim.document["asrs"]


def test_asrmap_simulate_direct_writes_the_map_and_a_picture(tmp_path, capsys):
    svg, doc = tmp_path / "m.svg", tmp_path / "m.json"
    rc = main(["simulate", "--direct", "--world", "aliasing", "--duration", "20",
               "--svg", str(svg), "--json", str(doc)])
    out = capsys.readouterr().out
    assert rc == 0
    assert json.loads(doc.read_text())["schema"] == "asrmap/map/1"
    assert svg.read_text().lstrip().startswith("<")
    assert "world aliasing" in out and "cycles detected" in out
    assert "loops driven 0 (the world has 4 holes), closed by the map 0" in out  # 20 s: no loop yet


def test_a_bad_world_is_one_line_on_stderr(tmp_path, capsys):
    bad = tmp_path / "w.json"
    bad.write_text('{"schema": "asrmap/world/1", "start": [0, 0]}')
    assert main(["simulate", "--direct", "--world", str(bad)]) == 2
    assert "start: expected 3 numbers" in capsys.readouterr().err


# The goals of the issue. ``office`` (seed 0) finishes with every room entered and no false
# closure; ``aliasing`` gives no false closure; ``lab`` (seed 0) finishes, enters every region,
# closes no false cycle and drives round a loop. The whole goal is not met (README, "Simulation"):
# over seeds 0-9 of ``lab`` and 0-5 of the others, 124 of 124 regions are entered, no run has a
# false closure, 43 of 474 revisits are missed and 63 of 65 loops driven are closed (2026-12-07's
# faster machine, tenth session; the runs differ between machines). There ``lab`` seed 0 closes 5
# of its 5 loops and misses 1 of 13 revisits, ``office`` seed 0 0 of 10: those XPASS (and show)
# where they get there.
EXPLORATION_GOAL = pytest.mark.xfail(
    reason="revisits are missed in most runs: lab seed 0 misses 1 of 13 (README, known "
           "faults: shallow and one-way revisits, corridor drift the pose graph cannot bound, "
           "aligned candidates with few agreeing surfaces)",
    strict=False)
LOOPS_GOAL = pytest.mark.xfail(
    reason="not every loop driven is closed in every run (stepped lab seeds 0-59: 250 of 264, 44 of "
           "60 runs meeting the whole goal, seed 0 among them; README, \"Status\")",
    strict=False)


@functools.cache
def _explored(name: str):
    """One stepped exploration of the world ``name`` (seed 0, at most an hour), shared by the tests."""
    s = DirectSim(load_world(name), SimParams(max_duration=3600.0)).run()
    print("\n".join(s.lines()))
    return s


@pytest.mark.slow
def test_exploring_the_office_finishes_enters_every_room_and_closes_no_false_cycle():
    s = _explored("office")
    assert s.finished
    assert not s.regions_missed
    assert s.false_cycles == 0 and s.true_cycles >= 1


@pytest.mark.slow
def test_exploring_the_lab_finishes_enters_every_region_and_drives_a_loop_with_no_false_closure():
    s = _explored("lab")
    assert s.finished
    assert not s.regions_missed
    assert s.false_cycles == 0
    assert s.loops_driven >= 1 and s.loops_closed >= 1


@pytest.mark.slow
@LOOPS_GOAL
def test_exploring_the_lab_closes_every_loop_it_drives():
    """The goal of issue 7 as the world's loops count it (service.sim.loops): every loop the robot
    drove round is closed by a true cycle closure."""
    s = _explored("lab")
    assert s.loops_closed == s.loops_driven


@pytest.mark.slow
@EXPLORATION_GOAL
@pytest.mark.parametrize("name", ["lab", "office"])
def test_exploring_a_world_finishes_enters_every_region_and_closes_only_true_cycles(name):
    s = _explored(name)
    assert s.finished
    assert not s.regions_missed
    assert s.false_cycles == 0
    assert s.cycles >= 1 and s.revisits_missed == 0


@pytest.mark.slow
def test_identical_rooms_far_apart_give_no_false_closure():
    s = DirectSim(load_world("aliasing"), SimParams(max_duration=1800.0)).run()
    print("\n".join(s.lines()))
    assert not s.regions_missed
    assert s.false_cycles == 0
    assert s.true_cycles >= 1


@pytest.mark.slow
def test_asrmap_simulate_fast_reports_its_real_time_factor(tmp_path, capsys):
    rc = main(["simulate", "--world", "lab", "--fast", "--duration", "120",
               "--svg", str(tmp_path / "m.svg"), "--json", str(tmp_path / "m.json")])
    out = capsys.readouterr().out
    assert rc == 0
    factor = float(out.split("x real time")[0].rsplit("(", 1)[1])
    # The 10x goal is a figure (README, measured by this command), not a timed assertion.
    print(f"\nasrmap simulate --fast: {factor:.1f}x real time")
    assert factor > 0 and not math.isnan(factor)


def test_a_simulation_is_followed_live_by_asrmap_monitor_in_another_process(tmp_path):
    import os
    import signal
    import subprocess
    import sys

    from service.bench.service import free_port

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    ep = f"tcp/127.0.0.1:{free_port()}"

    def cli(*args: str) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "service.cli", *args], cwd=root, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    mon = cli("monitor", "--connect", ep, "--robot", "simbot")
    sim = cli("simulate", "--world", "office", "--fast", "5", "--duration", "30", "--listen", ep,
              "--robot", "simbot", "--svg", str(tmp_path / "m.svg"), "--json", str(tmp_path / "m.json"))
    try:
        _, sim_err = sim.communicate(timeout=120)
    finally:
        mon.send_signal(signal.SIGINT)
        mon_out, mon_err = mon.communicate(timeout=20)
    assert sim.returncode == 0, sim_err[-2000:]
    lines = mon_out.splitlines()
    assert "simbot  alive" in lines and "simbot  gone" in lines, mon_out[-2000:] + mon_err[-2000:]
    assert any(line.startswith("simbot  asr_created") for line in lines)
    assert any(line.startswith("simbot  status ") for line in lines)


def test_a_run_that_ends_with_the_robot_wedged_says_so():
    from service.evaluate import Track
    from service.sim.physics import Contact
    from service.sim.simulator import _wedged

    # moving for 100 s, then 70 s jammed within 5 cm against something
    t = list(np.arange(0.0, 170.0, 1.0))
    poses = [(0.05 * min(s, 100.0) + 0.001 * (s % 2), 1.0, 0.0) for s in t]
    touching = [Contact(150.0, poses[150], poses[150])]
    assert _wedged(Track(t, poses), touching, 169.0) == pytest.approx((5.001, 1.0), abs=1e-9)
    assert _wedged(Track(t, poses), [], 169.0) is None  # standing still, touching nothing: not wedged
    assert _wedged(Track(t, poses), touching, 110.0) is None  # still moving within the window
    assert _wedged(Track(t[:10], poses[:10]), touching, 9.0) is None  # shorter than the window


def test_an_exploration_that_gave_exits_up_says_how_many():
    from service.sim.simulator import Summary

    s = Summary(world="lab", sim_time=100.0, wall_time=10.0, finished=True, asrs=3, exits=9,
                exits_unexplored=4, cycles=0, true_cycles=0, false_cycles=0, revisits=0,
                revisits_missed=0, distance=10.0, contacts=0, stuck=2, regions_visited=["lab"],
                regions_missed=[], exits_given_up=2)
    assert s.lines()[0].startswith("world lab: exploration complete (2 exits given up) after 100 s")
    assert "(10.0x real time)" in s.lines()[0]
    s.exits_given_up = 0
    assert s.lines()[0].startswith("world lab: exploration complete after 100 s")


# a room; a corridor east of it turns west round the room's corner into a dead end
CORNER = Path(__file__).parent / "data" / "corner_world.json"


@pytest.mark.parametrize("seed", [2, 4])
def test_a_corridor_round_a_corner_into_a_dead_end_is_entered_before_exploration_ends(seed):
    """The corner's unknown edge, looked at from down the corridor, was retired from afar and the
    dead-end arm never entered (4 of 10 seeds complete); the round that visits regions looked at
    only from afar (``ExploreParams.visit_round``) goes round the corner (10 of 10)."""
    world = load_world(CORNER)
    off = DirectSim(world, SimParams(seed=seed, explore_params=ExploreParams(visit_round=False))).run()
    assert off.finished and off.regions_missed == ["corridor north"]
    on = DirectSim(world, SimParams(seed=seed)).run()
    assert on.finished and on.regions_missed == [] and on.false_cycles == 0


def test_a_pocket_behind_a_chair_is_not_the_whole_world():
    """`aliasing` with range noise 0.0101 m: the first ASR is a pocket of room A bounded by a chair
    (its one exit 0.69 m wide, too narrow to take) and exploration ended 6 s after the start with
    two of three regions unentered; visiting what was only looked at from afar finds the way on."""
    r = DirectSim(load_world("aliasing"), SimParams(seed=0, sigma=0.0101)).run()
    assert r.finished and r.regions_missed == [] and r.false_cycles == 0


def test_a_doorway_merged_into_the_way_back_is_still_gone_through():
    """`aliasing` seed 8: room A's second ASR has the doorway's exit edges run on round the corner
    into the gap the robot came in by, one exit chord linked back to the first ASR. Exploration
    ended after 250 s in room A (the corridor and room B unentered) until the explorer took the
    straight pieces of a linked exit's run as openings of their own (``side_openings``).

    The runs are chaotic: later changes (paths round what the scans show, the cycle check on
    leaving an ASR) took seed 8 past that ASR another way, so both runs switch them off to replay
    the run the fault was traced in."""
    world = load_world("aliasing")

    def run(**explore) -> object:
        mapper = new_mapper(dataclasses.replace(MapperParams(), cycles=CycleParams(leave_check=False)))
        params = SimParams(seed=8, explore_params=ExploreParams(path_obstacle_reach=0.0, **explore))
        return DirectSim(world, params, mapper=mapper).run()

    off = run(side_openings=False)
    assert off.finished and off.regions_missed == ["corridor", "room B"]
    on = run()
    assert on.finished and on.regions_missed == [] and on.false_cycles == 0


def test_command_latency_delays_the_robot_acting_on_each_command():
    # The same run with and without latency decides identically until the robot first moves (the
    # scans are the same): with latency it starts moving that much later in simulated time.
    def first_motion(latency: float) -> float:
        sim = DirectSim(load_world("office"), SimParams(duration=6.0, command_latency=latency))
        sim.run()
        start = sim.robot.body.trajectory[0][1]
        return next(t for t, p in sim.robot.body.trajectory
                    if math.hypot(p[0] - start[0], p[1] - start[1]) > 0 or p[2] != start[2])

    t0, t1 = first_motion(0.0), first_motion(0.5)
    assert t1 - t0 == pytest.approx(0.5, abs=0.1 + 1e-9)  # acted on at the next 0.1 s physics step


def test_latency_is_refused_without_direct(capsys):
    assert main(["simulate", "--latency", "0.2", "--duration", "1"]) == 2
    assert "--latency: only with --direct" in capsys.readouterr().err
