"""SVG of a map document: well-formed, every ASR drawn in both panels, one-way and cycle links marked."""

import math
import xml.etree.ElementTree as ET

from mapper.cycle_params import CycleParams
from mapper.document import document_of
from mapper.globalmap import GlobalMap
from service.render import NODE_GAP, NODE_RADIUS, _spread, render_svg, write_svg
from tests.synthetic_asrs import drive
from tests.test_cycles import LOOP

NS = {"svg": "http://www.w3.org/2000/svg"}


def _doc():
    gm = GlobalMap(CycleParams())
    drive(gm, LOOP, per_step=(0.15, -0.1, 0.02))
    return document_of(gm)


def test_the_svg_is_well_formed_and_draws_every_asr_in_both_panels():
    doc = _doc()
    root = ET.fromstring(render_svg(doc).encode())
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    polygons = root.findall("svg:polygon", NS)
    assert len(polygons) == len(doc["asrs"])
    node_labels = [t.text for t in root.findall("svg:text", NS)]
    for a in doc["asrs"]:
        assert node_labels.count(str(a["id"])) == 2  # topological node + metric centre


def test_one_way_links_carry_an_arrow_and_cycle_links_are_red():
    root = ET.fromstring(render_svg(_doc()).encode())
    lines = root.findall("svg:line", NS)
    assert any(ln.get("marker-end") == "url(#arrow)" for ln in lines)
    assert any(ln.get("stroke") == "#c0392b" and ln.get("stroke-width") == "2.4" for ln in lines)


def test_an_empty_map_and_a_written_file_are_valid(tmp_path):
    empty = {"schema": "asrmap/map/1", "robot": "r&d <1>", "asrs": [], "links": [], "cycles": []}
    ET.fromstring(render_svg(empty).encode())
    p = write_svg(tmp_path / "map.svg", _doc(), title="loop & <block>")
    ET.parse(p)


def test_asrmap_render_writes_the_picture_of_a_saved_map(tmp_path, capsys):
    import json

    from service.cli import main

    src = tmp_path / "map.json"
    src.write_text(json.dumps(_doc()))
    out = tmp_path / "map.svg"
    assert main(["render", str(src), "--svg", str(out)]) == 0
    ET.parse(out)
    assert "6 ASRs" in capsys.readouterr().out


def test_asrmap_render_refuses_a_file_that_is_not_a_map_in_one_line(tmp_path, capsys):
    from service.cli import main

    src = tmp_path / "events.json"
    src.write_text('{"schema": "asrmap/event/1"}')
    assert main(["render", str(src), "--svg", str(tmp_path / "x.svg")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "asrmap/map/1" in err[0]


def test_asrmap_render_refuses_a_binary_file_naming_it(tmp_path, capsys):
    from service.cli import main

    src = tmp_path / "scan.bin"
    src.write_bytes(b"\x02\x80\xd6\x02\xb0\xff\xfe garbage")
    assert main(["render", str(src), "--svg", str(tmp_path / "x.svg")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(src) in err[0] and "not JSON" in err[0]


def test_topological_nodes_do_not_cover_each_other_and_lone_nodes_keep_their_place():
    """A duplicate's node lies on its original's (same place): it is moved aside so both numbers
    read; nodes far from every other stay at their ASR's centre."""
    doc = _doc()
    assert any(a.get("duplicate_of") is not None for a in doc["asrs"])
    root = ET.fromstring(render_svg(doc).encode())
    nodes = [(float(c.get("cx")), float(c.get("cy"))) for c in root.findall("svg:circle", NS)
             if c.get("r") == f"{NODE_RADIUS:g}"]
    assert len(nodes) == len(doc["asrs"])
    for i, (x, y) in enumerate(nodes):
        for u, v in nodes[:i]:
            assert math.hypot(x - u, y - v) >= 2 * NODE_RADIUS

    spread = _spread({1: (100.0, 100.0), 2: (100.0, 100.0), 3: (105.0, 100.0), 4: (300.0, 50.0)})
    assert spread[1] == (100.0, 100.0) and spread[4] == (300.0, 50.0)
    pts = list(spread.values())
    gaps = [math.hypot(p[0] - q[0], p[1] - q[1]) for i, p in enumerate(pts) for q in pts[:i]]
    assert min(gaps) >= NODE_GAP - 1e-6
    # A dense cluster (an open-plan room of duplicates): 40 nodes within 20 px all come apart.
    cluster = _spread({k: (200.0 + (k * 7) % 20, 200.0 + (k * 13) % 20) for k in range(40)})
    pts = list(cluster.values())
    gaps = [math.hypot(p[0] - q[0], p[1] - q[1]) for i, p in enumerate(pts) for q in pts[:i]]
    assert min(gaps) >= NODE_GAP - 1e-6


def test_the_robot_is_drawn_at_its_global_pose_and_its_asr_ringed_and_a_bad_pose_is_left_out():
    doc = _doc()
    a = doc["asrs"][-1]
    root = ET.fromstring(render_svg(doc, robot={"asr": a["id"], "global": [0.0, 0.0, 0.5]}).encode())
    arrow = root.find("svg:polygon[@id='robot']", NS)
    assert arrow is not None and "(0.00, 0.00) m, 29°" in arrow.find("svg:title", NS).text
    ring = root.find("svg:circle[@id='robot-asr']", NS)
    label = next(t for t in root.findall("svg:text", NS)  # the node's number sits in its ring
                 if t.text == str(a["id"]) and t.get("text-anchor") == "middle")
    assert abs(float(ring.get("cx")) - float(label.get("x"))) < 1e-6
    for bad in ("junk", {"asr": "x", "global": [1, 2]}, {"global": [float("inf"), 0, 0]}):
        root = ET.fromstring(render_svg(doc, robot=bad).encode())
        assert root.find("svg:polygon[@id='robot']", NS) is None
        assert root.find("svg:circle[@id='robot-asr']", NS) is None
