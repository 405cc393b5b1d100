"""The pipelined mapper (``defer_views=True``) builds the same map and emits the same events, in the
same order, as the mapper that does each viewpoint's work in its own scan."""

from __future__ import annotations

import json

import pytest

import mapper.mapper as mapper_module
from mapper.mapper import Mapper
from mapper.params import MapperParams
from service.carmen import mapper_inputs
from tests.synthetic_runs import LOOP_WAYPOINTS, ROOMS_WAYPOINTS, corridor_loop, drive_mapper, path, two_rooms


def _run(walls, truth, defer: bool):
    m = Mapper(MapperParams(laser_x=0.0, laser_y=0.0), defer_views=defer)
    events, _, _ = drive_mapper(m, walls, truth)
    events += m.flush()
    return [e.to_dict() for e in events], json.dumps(m.document(), sort_keys=True)


@pytest.fixture(params=[0.0, 1e9], ids=["stages-always-wait", "stages-never-wait"])
def spare(request, monkeypatch):
    """When a view's stages run depends on the clock (the last stage, ``_SPARE``; the view's
    surfaces, exits and polygon worked ahead, ``_AHEAD``); what the mapper computes must not."""
    monkeypatch.setattr(mapper_module, "_SPARE", request.param)
    monkeypatch.setattr(mapper_module, "_AHEAD", request.param)
    return request.param


def test_two_rooms_back_and_forth_through_doorways_give_the_same_events_and_map(spare):
    # there and back: new ASRs, re-entries through known exits and the entry hysteresis
    truth = path([*ROOMS_WAYPOINTS, (1.0, 2.0)], laps=1.0, step=0.05)
    now, later = _run(two_rooms(), truth, False), _run(two_rooms(), truth, True)
    assert any(e["event"] == "exit_crossed" for e in now[0])
    assert later == now


def test_a_corridor_loop_with_its_cycle_check_gives_the_same_events_and_map(spare):
    truth = path(LOOP_WAYPOINTS, laps=1.3, step=0.05)
    now, later = _run(corridor_loop(), truth, False), _run(corridor_loop(), truth, True)
    assert any(e["event"] == "asr_created" for e in now[0])
    assert later == now


def test_reading_the_map_between_scans_sees_every_view_taken(shared_data, spare):
    """``asrs`` and ``document()`` union the waiting view first; the events still come once."""
    items = list(mapper_inputs(shared_data / "intel-raw-first5505.clf.gz"))[:1500]
    params = MapperParams(laser_x=0.0, laser_y=0.0)
    now, later = Mapper(params), Mapper(params, defer_views=True)
    ev_now, ev_later = [], []
    for k, item in enumerate(items):
        kind = "add_odometry" if type(item).__name__ == "Odometry" else "add_scan"
        ev_now += getattr(now, kind)(item)
        ev_later += getattr(later, kind)(item)
        if k % 97 == 0:
            assert json.dumps(later.document(), sort_keys=True) == json.dumps(now.document(), sort_keys=True)
            assert {i: a.scans for i, a in later.asrs.items()} == {i: a.scans for i, a in now.asrs.items()}
    ev_later += later.flush()
    assert [e.to_dict() for e in ev_later] == [e.to_dict() for e in ev_now]
