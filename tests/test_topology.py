"""The topological map: transitions both ways, re-entry lookup, duplicates with one-way links."""

import math

import pytest

from mapper.se2 import compose, inverse
from mapper.topology import Topology, child_origin


def test_a_creation_is_a_transition_both_ways_with_inverse_relative_poses():
    topo = Topology()
    topo.add_node(1)
    topo.add_creation(1, "1/0", 2, "2/1", (3.0, 0.5, 0.2))
    fwd, back = topo.lookup(1, "1/0"), topo.lookup(2, "2/1")
    assert (fwd.dst, fwd.via) == (2, "2/1") and (back.dst, back.via) == (1, "1/0")
    assert back.rel == pytest.approx(inverse((3.0, 0.5, 0.2)))
    assert topo.entered_from(2) == 1 and topo.entered_from(1) is None
    assert topo.lookup(1, "1/1") is None
    assert [ln.to_dict() for ln in topo.links] == [
        {"from": 1, "exit": "1/0", "to": 2, "via": "2/1", "oneway": False}
    ]


def test_an_exit_keeps_its_first_destination():
    topo = Topology()
    topo.add_creation(1, "1/0", 2, "2/0", (1.0, 0.0, 0.0))
    topo.add_link(3, "3/0", 2, "2/0", (1.0, 0.0, 0.0))
    assert topo.lookup(2, "2/0").dst == 1
    assert topo.lookup(3, "3/0").dst == 2


def test_closing_onto_a_match_makes_the_duplicate_link_one_way():
    topo = Topology()
    for k in range(1, 5):
        topo.add_creation(k, f"{k}/1", k + 1, f"{k + 1}/0", (2.0, 0.0, math.pi / 2))
    # ASR 5 (entered from 4 through 4/1) duplicates ASR 1; 4/1 now leads into 1 through 1/0.
    link = topo.close_onto(5, 1, "1/0", (2.0, 0.0, math.pi / 2))
    assert link.to_dict() == {"from": 4, "exit": "4/1", "to": 1, "via": "1/0", "oneway": False}
    assert topo.lookup(4, "4/1").dst == 1
    assert topo.lookup(1, "1/0").dst == 4
    assert topo.lookup(5, "5/0").dst == 4  # the duplicate serves the direction it was entered from
    oneway = [ln for ln in topo.links if ln.oneway]
    assert [ln.to_dict() for ln in oneway] == [
        {"from": 5, "exit": "5/0", "to": 4, "via": "4/1", "oneway": True}
    ]
    assert topo.canonical(5) == 1
    assert {1, 4, 5} <= topo.within(5, 1)


def test_within_counts_hops():
    topo = Topology()
    for k in range(1, 6):
        topo.add_creation(k, f"{k}/1", k + 1, f"{k + 1}/0", (1.0, 0.0, 0.0))
    assert topo.within(3, 0) == {3}
    assert topo.within(3, 1) == {2, 3, 4}
    assert topo.within(3, 2) == {1, 2, 3, 4, 5}
    assert topo.neighbours(1) == {2}


def test_global_poses_compose_along_transitions():
    origin = (0.0, 0.0, 0.0)
    for rel in [(2.0, 0.0, math.pi / 2)] * 4:
        origin = child_origin(origin, rel)
    assert origin == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert child_origin((1.0, 1.0, math.pi), (1.0, 0.0, 0.0)) == pytest.approx(
        compose((1, 1, math.pi), (1, 0, 0))
    )


def test_rekey_moves_a_transition_its_reverse_and_its_link_onto_the_exit_that_replaced_it():
    topo = Topology()
    topo.add_creation(1, "1/0", 2, "2/1", (3.0, 0.5, 0.2))
    moved = topo.rekey(1, "1/0", "1/4")
    assert (moved.exit, moved.dst, moved.via) == ("1/4", 2, "2/1")
    assert topo.lookup(1, "1/0") is None and topo.lookup(1, "1/4") == moved
    assert topo.lookup(2, "2/1").via == "1/4"  # crossing back names the new exit
    assert topo.entered[2] == moved
    assert [ln.to_dict() for ln in topo.links] == [
        {"from": 1, "exit": "1/4", "to": 2, "via": "2/1", "oneway": False}
    ]


def test_rekeying_the_way_back_keeps_the_creation_for_closing_a_cycle():
    """ASR 2, created through 1/0, renames its entrance 2/1 to 2/5 (the way back re-keyed); closing
    2 onto another ASR later needs its creation transition, which must name the new entrance (a
    simulated lab run crashed with a KeyError here)."""
    topo = Topology()
    topo.add_creation(1, "1/0", 2, "2/1", (3.0, 0.5, 0.2))
    topo.rekey(2, "2/1", "2/5")
    assert topo.entered[2] == topo.lookup(1, "1/0") and topo.entered[2].via == "2/5"
    topo.add_node(7)
    link = topo.close_onto(2, 7, "7/0", (0.0, 0.0, 0.0))
    assert link.to_dict() == {"from": 1, "exit": "1/0", "to": 7, "via": "7/0", "oneway": False}
    assert [ln.to_dict() for ln in topo.links if ln.oneway] == [
        {"from": 2, "exit": "2/5", "to": 1, "via": "1/0", "oneway": True}
    ]
