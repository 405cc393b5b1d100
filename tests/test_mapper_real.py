"""The mapper core on the real Intel Research Lab raw log (intel-raw-first5505.clf.gz)."""

from __future__ import annotations

import re

import numpy as np
import shapely

from mapper.mapper import Mapper
from mapper.params import MapperParams
from mapper.types import Scan
from service.carmen import mapper_inputs

# the log's ranges are relative to the robot centre (PARAM robot_frontlaser_offset 0.0)
LOG_PARAMS = MapperParams(laser_x=0.0, laser_y=0.0)


def _run(path, max_scans: int) -> tuple[Mapper, int, list]:
    m = Mapper(LOG_PARAMS)
    n, events = 0, []
    for item in mapper_inputs(path):
        if isinstance(item, Scan):
            if n == max_scans:
                break
            events += m.add_scan(item)
            n += 1
        else:
            m.add_odometry(item)
    return m, n, events


def _check_asrs(m: Mapper) -> None:
    for aid, asr in m.asrs.items():
        poly = asr.polygon
        assert poly.is_valid, f"ASR {aid} polygon invalid"
        assert shapely.LinearRing(asr.boundary).is_ccw
        assert len(asr.edges) == len(asr.boundary)
        assert set(asr.edges) <= {"surface", "exit", "unknown"}
        for vp in m.viewpoints(aid):
            assert poly.buffer(1e-6).contains(shapely.Point(vp[:2])), f"ASR {aid} misses viewpoint {vp}"
        for e in asr.exits:
            assert re.fullmatch(rf"{aid}/\d+", e.id)
            assert e.width >= LOG_PARAMS.passage_width - 1e-9
        assert shapely.Point(asr.centre).within(poly.buffer(1e-6))
        assert asr.centre_rule in ("centroid", "point_on_surface")


def _check_events(m: Mapper, events: list) -> None:
    created = [e for e in events if e.kind == "asr_created"]
    crossed = [e for e in events if e.kind == "exit_crossed"]
    assert len(created) == len(m.asrs)
    # every ASR after the first was created by crossing an exit (re-entries are crossings too)
    into_new = [e for e in crossed if e.new]
    assert sorted(e.to_asr for e in into_new) == sorted(m.asrs)[1:]
    for e in crossed:
        assert e.exit.startswith(f"{e.from_asr}/")


def test_all_5505_intel_scans_build_valid_asrs(shared_data):
    m, n, events = _run(shared_data / "intel-raw-first5505.clf.gz", 10**9)
    assert n == 5505
    assert len(m.asrs) > 3
    _check_asrs(m)
    _check_events(m, events)
    areas = np.array([a.area for a in m.asrs.values()])
    # No ASR is a sliver the robot stays in: a first view taken on a doorway is a sliver whose only
    # exit is its front edge, and the robot once spent the last 2700 scans of this log in one of
    # 0.1 m² (that exit taken for the entrance, its gate stopping every later view).
    held = {aid: sum(1 for _ in m.viewpoints(aid)) for aid in m.asrs}
    stuck = [(aid, round(a.area, 2), held[aid]) for aid, a in m.asrs.items()
             if a.area < LOG_PARAMS.sliver_area and held[aid] > 10]
    assert not stuck, f"slivers holding the robot (ASR, m², viewpoints): {stuck}"
    assert max(a.scans for a in m.asrs.values()) < n / 4, "one ASR took a quarter of the log's views"
    # all 5505 scans take ~20 s on one core: in the default suite (no fast variant needed)
    print(f"{len(m.asrs)} ASRs, area median {np.median(areas):.1f} m², max {areas.max():.1f} m²")
