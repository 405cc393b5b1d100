"""The monitor: robots by liveliness, their maps from the queryable, live events, in and out of process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from service.bench.service import free_port
from service.bus import Bus
from service.config import ZenohConfig
from service.monitor import Monitor, SvgWriter, Update, format_update, status_line
from tests.test_bus import DOC

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _until(mon: Monitor, pred, timeout: float = 5.0) -> list[Update]:
    seen: list[Update] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        seen += mon.poll(0.1)
        if pred(seen):
            return seen
    raise AssertionError(f"not seen; got {[(u.kind, u.data) for u in seen]}")


def _bus(ep: str, robot: str = "r1") -> Bus:
    return Bus(robot, ZenohConfig(listen=(ep,)), lambda: DOC)


def test_a_robot_appears_with_its_map_and_disappears():
    ep = f"tcp/127.0.0.1:{free_port()}"
    with Monitor([ep]) as mon:
        bus = _bus(ep)
        seen = _until(mon, lambda s: any(u.kind == "map" for u in s))
        assert [u.kind for u in seen[:2]] == ["alive", "map"] and seen[1].data["asrs"] == DOC["asrs"]
        bus.close()
        _until(mon, lambda s: any(u.kind == "gone" and u.robot == "r1" for u in s))
        assert not mon.robots["r1"].alive


def test_events_and_asr_updates_reach_the_view():
    ep = f"tcp/127.0.0.1:{free_port()}"
    with _bus(ep) as bus, Monitor([ep], "r1") as mon:
        _until(mon, lambda s: any(u.kind == "map" for u in s))
        bus.publish_asr({**DOC["asrs"][0], "id": 4, "scans": 7})
        bus.publish_event({"event": "asr_created", "t": 1.5, "asr": 4, "origin": [1.0, 2.0, 0.5]})
        # the ASR and the event have their own subscribers: either may be handled first
        seen = _until(mon, lambda s: any(u.kind == "event" for u in s)
                      and any(a["id"] == 4 for a in mon.robots["r1"].doc["asrs"]))
        line = format_update(next(u for u in seen if u.kind == "event"))
        assert line == "r1  asr_created t=1.50 asr=4 origin=(1.00, 2.00, 0.50)"
        assert [a["id"] for a in mon.robots["r1"].doc["asrs"]] == [1, 2, 3, 4]


def test_status_line_shows_timing_motors_the_last_stop_and_alerts():
    st = {"pioneer": {"link": "ok"}, "laser": {"link": "fault", "faults": 2}, "rates": {"scans": 10.0},
          "timing": {"latency": 0.0421, "realtime_factor": 7.5, "cpu_share": 0.134, "skew": 0.051},
          "battery": 10.6, "motors": {"enabled": False, "e_stop": True, "alerts": ["e-stop pressed: x"]},
          "dropped_scans": 0, "last_stop": {"t": 1.0, "reason": "the laser is blind"}}
    assert status_line(st) == (
        "pioneer=ok laser=fault(2 faults) scans=10.00/s latency=42 ms rtf=7.50 cpu=13% skew=51 ms "
        "battery=10.60 V E-STOP dropped_scans=0 last stop: the laser is blind ALERT e-stop pressed: x")


def test_status_line_shows_what_the_explorer_does_and_how_long_ago_the_robot_was_stopped():
    """The last stop's age comes from the service's own clock (both times are its monotonic
    seconds), so a monitor on another computer shows it right."""
    st = {"t": 5040.2, "pioneer": {"link": "ok"}, "laser": {"link": "ok"},
          "explore": {"active": True, "status": "to exit 7/0"},
          "last_stop": {"t": 5002.0, "reason": "the laser is blind"}}
    assert status_line(st) == ("pioneer=ok laser=ok dropped_scans=0 explore: to exit 7/0 "
                               "last stop 38 s ago: the laser is blind")
    idle = {**st, "explore": {"active": False, "status": "idle"}}
    assert "explore" not in status_line(idle)


def test_status_line_names_both_links_rates_battery_and_drops():
    st = {"pioneer": {"link": "ok"}, "laser": {"link": "fault"}, "rates": {"scans": 9.96}, "battery": 12.4,
          "dropped_scans": 3}
    assert status_line(st) == "pioneer=ok laser=fault scans=9.96/s battery=12.40 V dropped_scans=3"


def _cli(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "service.cli", *args], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)


def test_monitor_once_in_another_process_lists_the_robot_and_its_map():
    ep = f"tcp/127.0.0.1:{free_port()}"
    with _bus(ep, "robot7"):
        out, err = _cli("monitor", "--once", "--connect", ep, "--wait", "1").communicate(timeout=20)
    assert out.splitlines() == ["robot7  alive", "robot7  map: 3 ASRs, 0 links, 0 cycles (0 accepted)"], err


def test_monitor_once_without_robots_exits_1_saying_so():
    p = _cli("monitor", "--once", "--connect", f"tcp/127.0.0.1:{free_port()}", "--wait", "0.3")
    out, err = p.communicate(timeout=20)
    assert p.returncode == 1 and out == ""
    assert "no robot '*' alive through tcp/127.0.0.1:" in err


def test_a_bad_endpoint_or_wait_is_one_line_exit_2():
    for args in (["--connect", "garbage"], ["--wait", "-1"]):
        p = _cli("monitor", "--once", *args)
        _, err = p.communicate(timeout=20)
        assert p.returncode == 2 and "Traceback" not in err and err.strip().splitlines()[-1].startswith(
            "asrmap monitor: "), err


def test_live_monitor_prints_events_and_exits_0_on_sigterm():
    ep = f"tcp/127.0.0.1:{free_port()}"
    with _bus(ep) as bus:
        p = _cli("monitor", "--connect", ep)
        try:
            assert p.stdout.readline().startswith("watching asrmap/*/")
            assert p.stdout.readline() == "r1  alive\n"
            assert p.stdout.readline().startswith("r1  map: 3 ASRs")
            deadline = time.monotonic() + 5
            bus.publish_event({"event": "fault", "t": 2.0, "device": "laser", "reason": "no scan for 0.5 s"})
            line = p.stdout.readline()
            assert line == "r1  fault t=2.00 device=laser reason=no scan for 0.5 s\n"
            assert time.monotonic() < deadline
        finally:
            p.send_signal(signal.SIGTERM)
            assert p.wait(timeout=5) == 0


SQUARE_DOC = {"schema": "asrmap/map/1", "robot": "r1", "asrs": [
    {"id": i, "created": float(i), "origin": [2.0 * (i - 1), 0.0, 0.0],
     "boundary": [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]],
     "edges": ["surface", "exit", "surface", "surface"], "centre": [0.0, 0.0],
     "exits": [{"id": f"{i}/0", "a": [1.0, -0.5], "b": [1.0, 0.5], "to": i + 1 if i == 1 else None}],
     "duplicate_of": None, "scans": 3} for i in (1, 2)],
    "links": [{"from": 1, "exit": "1/0", "to": 2, "via": None, "oneway": False}], "cycles": []}


def test_monitor_once_writes_an_svg_of_each_robot(tmp_path):
    import xml.etree.ElementTree as ET

    ep = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "map-{robot}.svg"
    with Bus("r1", ZenohConfig(listen=(ep,)), lambda: SQUARE_DOC):
        p = _cli("monitor", "--once", "--connect", ep, "--wait", "1", "--svg", str(out))
        stdout, err = p.communicate(timeout=20)
    assert stdout.splitlines()[-1] == f"wrote {tmp_path / 'map-r1.svg'}", err
    root = ET.parse(tmp_path / "map-r1.svg").getroot()
    assert root.tag.endswith("svg") and "r1: 2 ASRs, 1 links" in (tmp_path / "map-r1.svg").read_text()


def test_payloads_that_are_not_what_their_key_promises_are_skipped_counted_and_survived(tmp_path, caplog):
    import json

    import zenoh

    ep = f"tcp/127.0.0.1:{free_port()}"
    rogue = zenoh.open(zenoh.Config.from_json5(json.dumps({
        "mode": "peer", "listen": {"endpoints": [ep]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}}})))
    token = rogue.liveliness().declare_token("asrmap/rogue/alive")
    queryable = rogue.declare_queryable("asrmap/rogue/map", lambda q: q.reply(q.key_expr, b"\xff not json"))
    svg = SvgWriter(str(tmp_path / "{robot}.svg"), period=0.0)
    try:
        with Monitor([ep]) as mon:
            seen = _until(mon, lambda s: any(u.kind == "alive" for u in s))
            assert mon.robots["rogue"].doc is None  # its map answer was not a map
            mon.robots["rogue"].doc = {"schema": "asrmap/map/1", "asrs": [], "links": [], "cycles": []}
            for key, payload in [("status", b"garbage"), ("pose", b"[]"), ("event", b'{"event": 5}'),
                                 ("asr/1", b'{"schema": "asrmap/asr/1", "id": "x"}'),
                                 ("asr/2", b'{"schema": "asrmap/asr/1", "id": 2, "boundary": 3}'),
                                 ("status", b'{"schema": "asrmap/status/1", "timing": {"latency": "x"}}'),
                                 ("event", b'{"schema": "asrmap/event/1", "event": "recovered"}')]:
                rogue.put(f"asrmap/rogue/{key}", payload)
            # Each key has its own subscriber: the puts may be handled in any order.
            seen = _until(mon, lambda s: {"event", "status"} <= {u.kind for u in s} and mon.bad_payloads >= 5
                          and any(a.get("id") == 2 for a in mon.robots["rogue"].doc["asrs"]))
            lines = [format_update(u) for u in seen]
            svg.update(mon)  # an ASR it cannot draw: warned, the monitor goes on
    finally:
        queryable.undeclare()
        token.undeclare()
        rogue.close()
    assert "rogue  recovered " in lines and any("status (unreadable" in line for line in lines)
    assert mon.bad_payloads == 5  # the map answer, status, pose, the schema-less event, the id-less ASR
    assert "cannot draw rogue's map" in caplog.text


def test_status_line_says_where_the_robot_is_from_its_latest_pose():
    pose = {"t": 3.0, "asr": 7, "pose": [1.0, 0.5, 0.0], "global": [5.123, -3.2, 1.5708], "odometry": None}
    st = {"pioneer": {"link": "ok"}, "laser": {"link": "ok"}}
    assert status_line(st, pose) == "pioneer=ok laser=ok dropped_scans=0 at ASR 7 (5.12, -3.20 m, 90°)"
    for bad in (None, [], {"asr": 7}, {"asr": 7, "global": [1.0, "x", 0.0]},
                {"asr": 7, "global": [float("nan"), 0.0, 0.0]}):
        assert status_line(st, bad) == "pioneer=ok laser=ok dropped_scans=0"


def test_a_live_status_carries_the_latest_pose_and_the_picture_shows_the_robot(tmp_path):
    import xml.etree.ElementTree as ET

    ep = f"tcp/127.0.0.1:{free_port()}"
    pose = {"t": 3.0, "asr": 2, "pose": [0.2, 0.1, 0.0], "global": [1.5, 0.5, 0.0], "odometry": [0, 0, 0]}
    with _bus(ep) as bus, Monitor([ep], "r1") as mon:
        _until(mon, lambda s: any(u.kind == "map" for u in s))
        bus.publish_pose(pose)
        _until(mon, lambda s: mon.robots["r1"].pose is not None)
        bus.publish_status({"pioneer": {"link": "ok"}, "laser": {"link": "ok"}})
        seen = _until(mon, lambda s: any(u.kind == "status" for u in s))
        line = format_update(next(u for u in seen if u.kind == "status"))
        assert line.endswith("at ASR 2 (1.50, 0.50 m, 0°)"), line
        written = SvgWriter(str(tmp_path / "{robot}.svg"), period=0.0).update(mon)
    root = ET.parse(written[0]).getroot()
    ns = {"svg": "http://www.w3.org/2000/svg"}
    assert root.find("svg:polygon[@id='robot']", ns) is not None
    assert root.find("svg:circle[@id='robot-asr']", ns) is not None
