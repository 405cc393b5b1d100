"""The map document asrmap/map/1: exact round trips, field names as interfaces.md shows them."""

import json
import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mapper.cycle_params import CycleParams
from mapper.document import DocumentError, document_of, from_document, load_globalmap, to_document
from mapper.events import CycleDetected
from mapper.globalmap import GlobalMap
from tests.json_damage import damage
from tests.synthetic_asrs import box_asr, drive
from tests.test_cycles import LOOP


def _loop_map():
    gm = GlobalMap(CycleParams())
    drive(gm, LOOP[:5], per_step=(0.15, -0.1, 0.02))
    # Awkward floats: the round trip must keep every bit.
    gm.asrs[1].created = 0.1 + 0.2
    gm.asrs[2].boundary = gm.asrs[2].boundary + np.array([1e-17, math.pi * 1e-9])
    return gm


def test_the_document_has_exactly_the_documented_fields():
    doc = document_of(_loop_map(), robot="pioneer")
    assert set(doc) == {"schema", "robot", "asrs", "links", "cycles"} and doc["schema"] == "asrmap/map/1"
    a = doc["asrs"][0]
    assert set(a) == {
        "id",
        "created",
        "origin",
        "boundary",
        "edges",
        "centre",
        "exits",
        "duplicate_of",
        "scans",
    }
    assert set(a["exits"][0]) == {"id", "a", "b", "to"}
    assert set(doc["links"][0]) == {"from", "exit", "to", "via", "oneway"}
    assert set(doc["cycles"][0]) == {"time", "asr", "matches", "accepted", "iou", "reason"}
    assert [a["id"] for a in doc["asrs"]] == [1, 2, 3, 4, 5]
    assert doc["asrs"][4]["duplicate_of"] == 1
    assert len(a["boundary"]) == len(a["edges"])


def test_records_round_trip_exactly():
    doc = document_of(_loop_map())
    md = from_document(doc)
    assert to_document(md.asrs, md.links, md.cycles, md.robot) == doc


def test_json_round_trip_is_exact():
    doc = document_of(_loop_map())
    text = json.dumps(doc)
    assert json.loads(text) == doc
    assert json.loads(text)["asrs"][0]["created"] == 0.1 + 0.2


def test_a_loaded_map_exports_the_same_document_and_keeps_working():
    gm = _loop_map()
    doc = document_of(gm)
    # ASR 2 is a straight corridor piece, which verify_constrained leaves unclosed (test_cycles).
    gm2 = load_globalmap(json.loads(json.dumps(doc)), CycleParams(verify_constrained=0.0))
    assert document_of(gm2) == doc
    # Continue: the next ASR along the loop (east side again) is recognised as a revisit of ASR 2.
    box, frame, exits = LOOP[5]
    asr = box_asr(6, box, frame, exits)
    crossing = (8.0, 0.0, math.pi / 2)
    events = gm2.add_created(asr, 5, gm2.asrs[5].exits[0].id, asr.exits[0].id, crossing, 6.0)
    assert [(e.asr, e.matches) for e in events if isinstance(e, CycleDetected)] == [(6, 2)]


def test_a_document_of_another_schema_is_refused_with_a_reason():
    with pytest.raises(DocumentError, match="schema"):
        from_document({"schema": "asrmap/event/1"})
    doc = document_of(_loop_map())
    del doc["asrs"][0]["boundary"]
    with pytest.raises(DocumentError, match="boundary"):
        from_document(doc)


@pytest.mark.parametrize(("damage", "message"), [
    (lambda d: d.update(asrs="x"), "asrs: expected a list, found str"),
    (lambda d: d["asrs"].__setitem__(0, 3), "asrs[0]: expected an object, found int"),
    (lambda d: d["asrs"][1].update(boundary=3), "asr 2: boundary: expected [[x, y], ...] in metres"),
    (lambda d: d["asrs"][1].update(origin="x"), "asr 2: origin: expected [x, y, theta] (m, m, rad)"),
    (lambda d: d["asrs"][1].update(origin=[1.0, 2.0]), "asr 2: origin: expected [x, y, theta]"),
    (lambda d: d["asrs"][1].update(origin=["0", 0.0, 0.0]), "asr 2: origin: expected [x, y, theta]"),
    (lambda d: d["asrs"][1].update(centre=[True, 0.0]), "asr 2: centre: expected [x, y] in metres"),
    (lambda d: d["asrs"][0]["boundary"].__setitem__(0, [None, None]), "asr 1: boundary: expected"),
    (lambda d: d["asrs"][0]["boundary"].__setitem__(0, [float("nan"), 0.0]), "finite numbers"),
    (lambda d: d["asrs"][0].update(centre=[1.0, 2.0, 3.0]), "asr 1: centre: expected [x, y] in metres"),
    (lambda d: d["asrs"][0]["exits"][0].pop("b"), "asr 1: exits[0]: missing field 'b'"),
    (lambda d: d["asrs"][0]["exits"].__setitem__(0, None), "asr 1: exits[0]: expected an object"),
    (lambda d: d["links"][0].pop("exit"), "links[0]: missing field 'exit'"),
    (lambda d: d["links"][0].update({"from": None}), "links[0].from: expected an integer, found None"),
    (lambda d: d["links"][0].update(oneway="false"), "links[0].oneway: expected true or false"),
    (lambda d: d["asrs"][1].update(duplicate_of=[]), "asr 2: duplicate_of: expected an integer or null"),
    (lambda d: d["asrs"][1].update(duplicate_of=99), "asr 2: duplicate_of 99 names an ASR"),
    (lambda d: d["asrs"][1].update(id=1), "asrs: two ASRs with one id"),
    (lambda d: d["asrs"][0]["exits"][0].update(to="2"), "asr 1: exits[0].to: expected an integer or null"),
    (lambda d: d["cycles"].append({"time": 1.0, "asr": 2, "matches": 1, "accepted": 1, "iou": 0.5,
                                   "reason": "x"}), ".accepted: expected true or false"),
    (lambda d: d["cycles"].insert(0, 3), "cycles[0]: expected an object, found int"),
])
def test_a_damaged_document_is_one_document_error_naming_the_record(damage, message):
    doc = json.loads(json.dumps(document_of(_loop_map())))
    damage(doc)
    with pytest.raises(DocumentError, match=re.escape(message)):
        from_document(doc)


def test_a_one_way_link_without_a_known_exit_round_trips():
    # A duplicate whose entrance no view showed as an exit keeps a link with "exit": null.
    doc = document_of(_loop_map())
    doc["links"].append({"from": 5, "exit": None, "to": 4, "via": None, "oneway": True})
    md = from_document(json.loads(json.dumps(doc)))
    assert to_document(md.asrs, md.links, md.cycles, md.robot) == doc



_FUZZ_BASE = document_of(_loop_map())


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_any_damage_to_a_document_is_a_document_error_or_a_map_that_draws(data):
    """What ``asrmap render`` and ``asrmap run`` (restoring a store) read from a file: one place
    replaced by any JSON value, or a key dropped. Either :class:`DocumentError` names it, or the
    document loads and its picture draws."""
    from service.render import render_svg

    doc = json.loads(json.dumps(_FUZZ_BASE))
    damage(doc, data)
    try:
        from_document(doc)
    except DocumentError:
        return
    render_svg(doc)
