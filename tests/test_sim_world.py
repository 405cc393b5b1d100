"""World files: the built-ins load, and every kind of mistake is reported with file and entry."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.sim.world import WorldError, builtin_worlds, load_world, parse_world
from tests.json_damage import damage

BUILTIN_DIR = Path(__file__).resolve().parent.parent / "service" / "sim" / "worlds"


def wall(*doors):
    """A 4 m wall along y = 0 with doors given as (at, width) in metres."""
    return {"walls": [{"from": [0, 0], "to": [4, 0], "doors": [{"at": a, "width": w} for a, w in doors]}]}


def doc(**extra):
    d = {"schema": "asrmap/world/1", "start": [1.0, 1.0, 0.0],
         "walls": [{"from": [0, 0], "to": [4, 0], "doors": [{"at": 2.0, "width": 0.9}]}],
         "loops": [[[0, -1], [4, -1], [4, 3], [0, 3]]]}
    d.update(extra)
    return d


def test_builtin_worlds_are_lab_office_aliasing_and_load():
    assert {"lab", "office", "aliasing"} <= set(builtin_worlds())
    for name in builtin_worlds():
        w = load_world(name)
        assert w.name == name and len(w.segments) > 10 and w.clearance(*w.start[:2]) >= 0.3


def test_lab_has_three_doorways_of_0_9_m_and_every_region_is_reachable_space():
    w = load_world("lab")
    widths = np.hypot(w.doors[:, 2] - w.doors[:, 0], w.doors[:, 3] - w.doors[:, 1])
    assert len(w.doors) == 3 and np.allclose(widths, 0.9)
    assert w.region_of(*w.start[:2]) == "lab"
    assert {"lab", "corridor south", "corridor north"} <= set(w.regions)


def test_a_door_is_a_gap_cut_out_of_its_wall():
    w = parse_world(doc(loops=[]))
    assert np.allclose(w.segments, [[0, 0, 1.55, 0], [2.45, 0, 4, 0]])
    assert np.allclose(w.doors, [[1.55, 0, 2.45, 0]])


def test_polygons_become_segments_and_circles_stay_circles():
    w = parse_world(doc(polygons=[[[2, 1], [3, 1], [3, 2]]], circles=[[2, 2.5, 0.02]]))
    assert len(w.segments) == 2 + 4 + 3
    assert w.circles.shape == (1, 3)
    assert w.clearance(2.9, 1.2) == 0.0  # inside the solid triangle


def test_load_from_a_file_path(tmp_path):
    f = tmp_path / "box.json"
    f.write_text(json.dumps(doc(name="box")))
    assert load_world(str(f)).name == "box"


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"schema": "asrmap/world/2"}, "schema: expected 'asrmap/world/1'"),
        ({"wals": []}, "wals: unknown key"),
        ({"start": [1.0, 1.0]}, "start: expected 3 numbers"),
        ({"start": [0.1, 0.1, 0.0]}, "start: the robot's centre (0.1, 0.1) is 0.10 m from an obstacle"),
        (wall((3.8, 0.9)), "walls[0].doors[0]: door from 3.350 to 4.250 m does not fit the wall"),
        (wall((1, 0.9), (1.5, 0.9)), "walls[0].doors[1]: overlaps walls[0].doors[0]"),
        (wall((1, 90)), "doors[0]: door from"),
        (wall((1, 0.09)), "units are metres"),
        ({"polygons": [[[2, 1], [3, 2], [3, 1], [2, 2]]]}, "polygons[0]: not a simple polygon"),
        ({"circles": [[2, 2, -0.1]]}, "circles[0][2]: expected a positive number"),
        ({"segments": [[1, 1, 1, "x"]]}, "segments[0][3]: expected a finite number, got 'x'"),
        ({"loops": [[[0, 0], [0, 0], [1, 1]]]}, "loops[0][1]: repeats the previous point"),
    ],
)
def test_mistakes_name_the_file_and_the_entry(change, message):
    with pytest.raises(WorldError) as err:
        parse_world(doc(**change), source="bad.json")
    assert str(err.value).startswith("bad.json: ")
    assert message in str(err.value)


def test_unknown_world_name_lists_the_builtins():
    with pytest.raises(WorldError, match="built-in worlds are aliasing, lab, office"):
        load_world("moon")


def test_not_json_names_line_and_column(tmp_path):
    f = tmp_path / "w.json"
    f.write_text('{"schema": "asrmap/world/1",\n "start": [1, 1, 0,]}')
    with pytest.raises(WorldError, match=r"w.json: not JSON: .* line 2"):
        load_world(f)



@settings(max_examples=200, deadline=None)
@given(name=st.sampled_from(["lab", "office", "aliasing"]), data=st.data())
def test_any_damage_to_a_world_file_is_a_world_error_or_a_world_the_laser_sees(name, data):
    """What ``--world FILE`` reads: one place of a built-in world replaced by any JSON value, or a
    key dropped. Either :class:`WorldError` names it, or the world loads and a scan from its start
    pose is ranges of a real LMS (finite, 0 to max range)."""
    from service.sim.raycast import RayCaster

    doc = json.loads((BUILTIN_DIR / f"{name}.json").read_text())
    damage(doc, data)
    try:
        world = parse_world(doc, source=f"{name}.json")
    except WorldError:
        return
    caster = RayCaster(world)
    ranges = caster.scan(world.start, np.radians(np.arange(-90.0, 90.5, 1.0)))
    assert np.isfinite(ranges).all() and (ranges >= 0).all() and (ranges <= caster.max_range).all()
