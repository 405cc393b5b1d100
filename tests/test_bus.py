"""The Zenoh side of the service: real sessions on loopback, a free port per test."""

from __future__ import annotations

import json
import queue
import time

import numpy as np
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from service.bench.service import free_port
from service.bus import Bus, BusError, CommandRefused, client_config, decode_scan, encode_scan
from service.config import ZenohConfig

DOC = {"schema": "asrmap/map/1", "robot": "r1",
       "asrs": [{"id": i, "created": float(i), "origin": [0.0, 0.0, 0.0], "boundary": [], "edges": [],
                 "centre": [0.0, 0.0], "exits": [], "duplicate_of": None, "scans": 1} for i in (1, 2, 3)],
       "links": [], "cycles": []}


@pytest.fixture
def endpoint():
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def client(endpoint):
    s = zenoh.open(client_config([endpoint]))
    try:
        yield s
    finally:
        s.close()


def make_bus(endpoint, allow=(), on_command=None, document=lambda: DOC) -> Bus:
    return Bus("r1", ZenohConfig(listen=(endpoint,), allow_commands=tuple(allow)), document, on_command)


def get(session, selector: str):
    """(ok payload dict | None, err payload dict | None) of the first reply, retried while the
    client is still connecting (a get with no route returns no replies at once)."""
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        for r in session.get(selector, timeout=2.0):
            if r.ok:
                return json.loads(r.ok.payload.to_bytes()), str(r.ok.encoding)
            return None, json.loads(r.err.payload.to_bytes())
        time.sleep(0.05)
    raise AssertionError(f"no reply to {selector}")


def received(session, key: str, publish, timeout: float = 5.0):
    """Subscribe to ``key`` and call ``publish()`` until a sample arrives (subscriptions propagate)."""
    q: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(key, lambda s: q.put((str(s.key_expr), s.payload.to_bytes(),
                                                            str(s.encoding))))
    try:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            publish()
            try:
                return q.get(timeout=0.1)
            except queue.Empty:
                pass
        raise AssertionError(f"nothing on {key}")
    finally:
        sub.undeclare()


def test_events_carry_their_schema_in_payload_and_encoding(endpoint, client):
    with make_bus(endpoint) as bus:
        key, data, enc = received(client, "asrmap/r1/event",
                                  lambda: bus.publish_event({"event": "asr_created", "t": 1.0, "asr": 1}))
    assert key == "asrmap/r1/event" and enc == "application/json;asrmap/event/1"
    assert json.loads(data) == {"schema": "asrmap/event/1", "event": "asr_created", "t": 1.0, "asr": 1}


def test_an_asr_is_put_on_its_own_key(endpoint, client):
    with make_bus(endpoint) as bus:
        key, data, enc = received(client, "asrmap/r1/asr/*", lambda: bus.publish_asr(DOC["asrs"][1]))
    assert key == "asrmap/r1/asr/2" and enc == "application/json;asrmap/asr/1"
    assert json.loads(data)["schema"] == "asrmap/asr/1" and json.loads(data)["id"] == 2


def test_pose_and_status_have_their_schemas(endpoint, client):
    with make_bus(endpoint) as bus:
        _, pose, enc = received(client, "asrmap/r1/pose", lambda: bus.publish_pose({"t": 0.0, "asr": 1}))
        assert enc == "application/json;asrmap/pose/1" and json.loads(pose)["schema"] == "asrmap/pose/1"
        _, status, enc = received(client, "asrmap/r1/status", lambda: bus.publish_status({"t": 0.0}))
        assert enc == "application/json;asrmap/status/1" and json.loads(status)["schema"] == "asrmap/status/1"


def test_a_scan_is_binary_with_its_schema_in_the_encoding(endpoint, client):
    ranges = np.linspace(0.5, 7.5, 181)
    with make_bus(endpoint) as bus:
        _, data, enc = received(client, "asrmap/r1/scan",
                                lambda: bus.publish_scan(3.5, ranges, -np.pi / 2, np.pi / 180, 8.0))
    assert enc == "application/octet-stream;asrmap/scan/1"
    scan = decode_scan(data)
    assert scan["t"] == 3.5 and np.allclose(scan["ranges"], ranges, atol=1e-6) and scan["max_range"] == 8.0


@settings(max_examples=50, deadline=None)
@given(st.floats(0, 1e6), st.lists(st.floats(0, 80, width=32), max_size=721))
def test_scan_encoding_round_trips(t, ranges):
    scan = decode_scan(encode_scan(t, np.array(ranges), -1.0, 0.01, 80.0))
    assert scan["t"] == t and list(scan["ranges"]) == ranges


def test_a_truncated_scan_is_a_value_error():
    with pytest.raises(ValueError, match="says 3 beams"):
        decode_scan(encode_scan(0.0, np.ones(3), 0, 0, 8)[:-2])


def test_the_map_queryable_returns_the_whole_document(endpoint, client):
    with make_bus(endpoint):
        doc, enc = get(client, "asrmap/r1/map")
    assert enc == "application/json;asrmap/map/1" and doc == DOC


def test_since_keeps_asrs_from_that_id(endpoint, client):
    with make_bus(endpoint):
        doc, _ = get(client, "asrmap/r1/map?since=2")
    assert [a["id"] for a in doc["asrs"]] == [2, 3]


def test_a_wildcard_get_is_answered_on_the_concrete_key(endpoint, client):
    with make_bus(endpoint):
        replies = []
        deadline = time.monotonic() + 5
        while not replies and time.monotonic() < deadline:
            replies = [str(r.ok.key_expr) for r in client.get("asrmap/**/map", timeout=2.0) if r.ok]
    assert replies == ["asrmap/r1/map"]


@pytest.mark.parametrize(("selector", "message"), [
    ("asrmap/r1/map?since=abc", "since: expected an ASR id (integer >= 0); found 'abc'"),
    ("asrmap/r1/map?since=-1", "since: expected an ASR id"),
    ("asrmap/r1/map?until=3", "unknown parameter until; expected since"),
])
def test_bad_map_parameters_get_an_error_reply(endpoint, client, selector, message):
    with make_bus(endpoint):
        ok, err = get(client, selector)
    assert ok is None and err["schema"] == "asrmap/error/1" and message in err["error"]


def test_the_liveliness_token_appears_and_disappears(endpoint, client):
    events: queue.Queue = queue.Queue()
    sub = client.liveliness().declare_subscriber(
        "asrmap/*/alive", lambda s: events.put((str(s.key_expr), s.kind)), history=True)
    try:
        bus = make_bus(endpoint)
        assert events.get(timeout=5) == ("asrmap/r1/alive", zenoh.SampleKind.PUT)
        bus.close()
        assert events.get(timeout=5) == ("asrmap/r1/alive", zenoh.SampleKind.DELETE)
    finally:
        sub.undeclare()


def test_a_command_not_allowed_is_refused_without_effect(endpoint, client):
    called = []
    with make_bus(endpoint, allow=(), on_command=lambda n, p: called.append(n) or {}) as bus:
        ok, err = get(client, "asrmap/r1/cmd/stop")
        assert ok is None and "command stop is disabled" in err["error"] and "allow_commands" in err["error"]
        assert bus.counters["commands_refused"] == 1
    assert called == []


def test_an_allowed_command_runs_and_replies(endpoint, client):
    called = []
    def obey(name, params):
        called.append((name, params))
        return {"stopped": True}

    with make_bus(endpoint, allow=("stop",), on_command=obey):
        ok, _ = get(client, "asrmap/r1/cmd/stop")
        refused, err = get(client, "asrmap/r1/cmd/explore")
    assert ok == {"schema": "asrmap/command/1", "command": "stop", "stopped": True}
    assert refused is None and "explore is disabled" in err["error"]
    assert called == [("stop", {})]


def test_a_command_the_service_cannot_run_gets_its_reason(endpoint, client):
    def refuse(name, params):
        raise CommandRefused("no explorer in this build")

    with make_bus(endpoint, allow=("explore",), on_command=refuse):
        ok, err = get(client, "asrmap/r1/cmd/explore")
    assert ok is None and err["error"] == "no explorer in this build"


def test_a_busy_port_is_a_bus_error_naming_the_endpoint(endpoint):
    with make_bus(endpoint), pytest.raises(BusError, match=f"listen {endpoint}.*(in use|Address)"):
        make_bus(endpoint)


def test_a_zenoh_file_replaces_the_default_session(tmp_path, client, endpoint):
    cfg = tmp_path / "z.json5"
    cfg.write_text(f'{{ mode: "peer", listen: {{ endpoints: ["{endpoint}"] }},'
                   ' scouting: { multicast: { enabled: false } } }')
    with Bus("r1", ZenohConfig(listen=(), config=str(cfg)), lambda: DOC):
        doc, _ = get(client, "asrmap/r1/map")
    assert doc == DOC


ACL = """{
  mode: "peer",
  listen: { endpoints: ["%s"] },
  scouting: { multicast: { enabled: false }, gossip: { enabled: false } },
  access_control: {
    enabled: true,
    default_permission: "allow",
    rules: [ { id: "no-commands", permission: "deny", flows: ["ingress"],
               messages: ["query"], key_exprs: ["asrmap/*/cmd/**"] } ],
    subjects: [ { id: "network", interfaces: ["lo"] } ],
    policies: [ { rules: ["no-commands"], subjects: ["network"] } ],
  },
}"""


def test_zenoh_access_control_in_the_config_file_keeps_commands_from_a_network(tmp_path, endpoint, client):
    """The README's example (with the loopback interface standing for the robot's wifi): a command
    query arriving there never reaches the service, even with the command allowed; the map does."""
    (tmp_path / "z.json5").write_text(ACL % endpoint)
    called = []
    zcfg = ZenohConfig(listen=(), config=str(tmp_path / "z.json5"), allow_commands=("stop",))
    with Bus("r1", zcfg, lambda: DOC, lambda n, p: called.append(n) or {}):
        doc, _ = get(client, "asrmap/r1/map")
        assert doc == DOC
        assert list(client.get("asrmap/r1/cmd/stop", timeout=1.0)) == []
    assert called == []
