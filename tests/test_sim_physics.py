"""The robot body: collisions block motion and report a stall; ground truth is kept."""

from __future__ import annotations

import math

import pytest

from service.sim.physics import Body
from service.sim.world import parse_world


def room():
    return parse_world({"schema": "asrmap/world/1", "start": [2.0, 2.0, 0.0],
                        "loops": [[[0, 0], [4, 0], [4, 4], [0, 4]]], "circles": [[2.0, 3.3, 0.05]]})


def test_free_motion_goes_where_it_is_told_and_counts_distance():
    b = Body(room())
    pose, stalled = b.move((2.5, 2.0, 0.0), t=1.0)
    assert pose == (2.5, 2.0, 0.0) and not stalled
    assert b.distance == pytest.approx(0.5)


def test_a_wall_blocks_motion_at_contact_and_stalls():
    b = Body(room())
    pose, stalled = b.move((5.0, 2.0, 0.0), t=2.0)
    assert stalled
    # The rectangle's front is 0.210 m ahead of the centre: contact at x = 4 - 0.210.
    assert pose[0] == pytest.approx(4.0 - 0.210, abs=2e-3)
    assert b.contacts and b.contacts[-1].t == 2.0


def test_a_leg_blocks_a_circular_robot():
    b = Body(room(), footprint="circle")
    pose, stalled = b.move((2.0, 3.2, 0.0))
    assert stalled and pose[1] == pytest.approx(3.3 - 0.05 - 0.25, abs=2e-3)


def test_turning_in_place_next_to_a_wall_is_blocked_by_the_corners():
    b = Body(room(), pose=(3.75, 2.0, 0.0))  # front 0.04 m from the wall; front corners at 0.299 m
    _, stalled = b.move((3.75, 2.0, math.pi / 2))
    assert stalled


def test_big_steps_cannot_jump_through_a_thin_wall():
    w = parse_world({"schema": "asrmap/world/1", "start": [1.0, 1.0, 0.0], "segments": [[2, -5, 2, 5]]})
    b = Body(w)
    pose, stalled = b.move((3.0, 1.0, 0.0))
    assert stalled and pose[0] < 2.0


def test_ground_truth_trajectory_and_frames():
    b = Body(room())
    for i in range(1, 11):
        b.move((2.0 + 0.05 * i, 2.0, 0.0), t=float(i))
    assert b.pose_at(5.0)[0] == pytest.approx(2.25, abs=0.03)
    assert b.world_pose((0.1, 0.0, 0.0)) == pytest.approx((2.1, 2.0, 0.0))
    assert b.emulator_pose((2.1, 2.0, 0.0)) == pytest.approx((0.1, 0.0, 0.0))


def test_a_start_inside_an_obstacle_is_refused():
    with pytest.raises(ValueError, match="overlaps an obstacle"):
        Body(room(), pose=(2.0, 3.2, 0.0))


def test_contacts_of_one_push_count_as_one_push():
    # Pressing against the east wall for half a second (a contact every 0.1 s physics step), then
    # again 5 s later: seven contacts, two pushes.
    from service.sim.simulator import pushes

    b = Body(room())
    for t in (0.0, 0.1, 0.2, 0.3, 0.4, 5.0, 5.1):
        assert b.move((5.0, 2.0, 0.0), t=t)[1]
    assert len(b.contacts) == 7 and pushes(b.contacts) == 2
    assert pushes([]) == 0
