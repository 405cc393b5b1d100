"""Scans to cycles: the whole mapper on ray-cast worlds with drifting odometry, scored against truth."""

import dataclasses
import math

import pytest

from mapper.cycle_params import CycleParams
from mapper.events import CycleDetected
from mapper.mapper import Mapper
from mapper.params import MapperParams
from service.evaluate import evaluate
from tests.synthetic_runs import LOOP_WAYPOINTS, ROOMS_WAYPOINTS, corridor_loop, drive_mapper, path, two_rooms

MODES = {"paper": CycleParams.paper(), "extended": CycleParams()}


def _mapper(cycles: CycleParams) -> Mapper:
    return Mapper(dataclasses.replace(MapperParams(laser_x=0.0, laser_y=0.0), cycles=cycles))


def _score(m: Mapper, truth, odo):
    gm = m.globalmap
    entered = {k: gm.topology.entered_from(k) for k in gm.asrs}
    return evaluate(m.document(), truth, odo, entered, gm.odometry_origin)


@pytest.mark.parametrize("mode", MODES)
def test_driving_twice_around_a_block_closes_the_loop_with_no_false_cycle(mode):
    m = _mapper(MODES[mode])
    events, truth, odo = drive_mapper(m, corridor_loop(), path(LOOP_WAYPOINTS, laps=1.75, step=0.1))
    ev = _score(m, truth, odo)
    assert ev.cycles >= 1 and ev.false_positives == 0, ev
    assert ev.detected >= 1
    assert any(isinstance(e, CycleDetected) for e in events)
    assert any(a.duplicate_of is not None for a in m.asrs.values())


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("heading_per_m", [0.0, math.radians(0.5), -math.radians(0.5)])
def test_two_identical_rooms_are_not_taken_for_one(mode, heading_per_m):
    m = _mapper(MODES[mode])
    events, _, _ = drive_mapper(
        m, two_rooms(), path(ROOMS_WAYPOINTS), scale_error=0.05, heading_per_m=heading_per_m
    )
    assert [e for e in events if isinstance(e, CycleDetected)] == []
    assert len(m.asrs) >= 2


def test_a_saved_map_continues_where_it_stopped():
    m = _mapper(CycleParams())
    drive_mapper(m, corridor_loop(), path(LOOP_WAYPOINTS, laps=1.0, step=0.1))
    doc = m.document()
    m2 = Mapper.from_document(doc, m.params)
    assert m2.document() == doc
