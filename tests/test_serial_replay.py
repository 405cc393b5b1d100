"""Serial replay: recorded logs through the emulated Pioneer and LMS200 (real ptys) and the service."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from laser.playback import PlaybackLMS2xx
from mapper.types import Odometry, Scan
from pioneer.emulator import PioneerEmulator
from pioneer.playback import PlaybackBody, PoseTrack
from service.cli import main
from service.replay import replay
from service.serial_replay import (
    SIP_UNIT_M,
    THETA_UNIT_RAD,
    PlaybackClock,
    Recording,
    compare,
    quantisation_tolerance,
    serial_replay,
)
from tests.synthetic_runs import ROOMS_WAYPOINTS, drifting, path, two_rooms, write_carmen


@pytest.fixture(scope="module")
def rooms_log(tmp_path_factory):
    """A synthetic raw log: 26 s straight through two rooms joined by a corridor (3 ASRs)."""
    truth = path(ROOMS_WAYPOINTS, laps=1.0, step=0.05)
    p = tmp_path_factory.mktemp("serial") / "rooms-raw.clf"
    write_carmen(p, two_rooms(), truth, drifting(truth))
    return p


def test_odometry_playback_round_trips_across_the_15_bit_wrap(pty_pair):
    import pioneer

    # 40 m along x in 20 s: past the 27.5 m (32768 x 0.84 mm) where a SIP's XPOS wraps.
    t = np.array([0.0, 20.0])
    track = PoseTrack(t, [1.0, 41.0], [0.5, 0.5], [0.0, 0.0])
    clock = PlaybackClock(0.0, speed=10.0)
    emu = PioneerEmulator(pty_pair.master, body=PlaybackBody(track, clock.now), sip_cycle=0.1 / 10.0)
    got = []
    with emu, pioneer.Pioneer(pty_pair.path, 9600, pioneer.P2DX, reconnect=False) as dev:
        dev.on_odometry(lambda o: got.append((o.x, o.y, o.theta)))
        clock.start()
        time.sleep(2.4)
    xs = np.array([g[0] for g in got])
    assert xs.max() > 39.9  # the driver's frame starts at the first SIP: x = 1 m there
    assert np.all(np.diff(xs) > -SIP_UNIT_M)  # no 27.5 m jump back at the wrap
    assert abs(xs[-1] - 40.0) <= SIP_UNIT_M
    assert max(abs(g[1]) for g in got) <= SIP_UNIT_M
    assert max(abs(g[2]) for g in got) <= THETA_UNIT_RAD


def test_a_scan_with_max_range_readings_arrives_as_no_return(pty_pair):
    import laser

    ranges = np.full(181, 2.0)
    ranges[[0, 90, 180]] = [81.91, np.inf, 60.0]  # CARMEN's no-return, a non-finite, beyond 50 m
    ranges[45] = 7.3216
    clock = PlaybackClock(0.0, speed=1.0)
    las = PlaybackLMS2xx(pty_pair.master, [0.0, 0.05], [ranges, ranges], clock.to_wall, boot_time=0.05)
    with las, laser.LMS2xx(pty_pair.path, 500000, units="mm", recover=False) as dev:
        clock.start()
        scan = dev.read(timeout=2.0)
    assert scan is not None and scan.count == 181
    assert list(np.flatnonzero(scan.no_return)) == [0, 90, 180]
    assert abs(scan.ranges[45] - 7.3216) <= 0.5e-3
    assert np.all(np.abs(scan.ranges[1:45] - 2.0) <= 0.5e-3)


def _quantised(rec: Recording, unit: float):
    """The log's readings rounded exactly as the protocols round them (and no other change)."""
    for r in rec.inputs():
        if isinstance(r, Odometry):
            q, a = SIP_UNIT_M, THETA_UNIT_RAD
            yield Odometry(r.t, round(r.x / q) * q, round(r.y / q) * q, round(r.theta / a) * a)
        else:
            yield Scan(r.t, (np.rint(np.asarray(r.ranges) / unit) * unit).astype(np.float32), r.angle_min,
                       r.angle_increment, r.max_range)


def test_synthetic_log_direct_and_serial_give_the_same_asrs_links_and_cycles(rooms_log):
    rec = Recording.from_log(rooms_log)
    direct = replay(rooms_log, inputs=rec.inputs())
    quant = replay(rooms_log, inputs=_quantised(rec, 1e-3))
    ser = serial_replay(rooms_log, recording=rec, speed=2.0)
    assert ser.dropped == 0 and ser.motors_stopped
    ag = compare(direct.document, ser.document)
    assert ag.same_structure, ag.problems
    assert ag.asrs[0] >= 3
    # Geometry: the serial map is the direct map of the quantised readings, to within what the
    # service's timing adds (one scan of 0.05 m earlier or later creation at most).
    aq = compare(quant.document, ser.document)
    assert aq.same_structure, aq.problems
    tol = quantisation_tolerance(30.0)
    assert aq.origin_heading <= 10 * tol["heading"]
    assert aq.origin_position <= 0.05 + tol["point"]


def test_real_log_readings_reach_the_mapper_within_the_protocols_quantisation(shared_data):
    log = shared_data / "mit-csail.clf.gz"
    rec = Recording.from_log(log).window(0.0, 40.0)
    ser = serial_replay(log, recording=rec, speed=4.0)
    assert ser.dropped == 0 and ser.motors_stopped
    assert len(ser.scan_inputs) == len(rec.scans)
    unit = 1e-2 if rec.units() == "cm" else 1e-3
    worst = max(float(np.max(np.abs(np.where(a.ranges < a.max_range, a.ranges - b, 0.0))))
                for a, b in zip(ser.scan_inputs, rec.scans, strict=True))
    assert worst <= unit / 2 + 1e-6
    late = np.array([a.t for a in ser.scan_inputs]) - rec.scan_t
    assert np.median(np.abs(late)) < 0.02  # log seconds: thread latency x 4
    assert len(ser.document["asrs"]) >= 2


def test_asrmap_replay_through_serial_exits_0_and_writes_the_outputs(rooms_log, tmp_path, capsys):
    out, svg = tmp_path / "map.json", tmp_path / "map.svg"
    rc = main(["replay", str(rooms_log), "--through-serial", "--speed", "8", "--no-progress",
               "--json", str(out), "--svg", str(svg), "--truth", str(rooms_log)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "motors stopped" in text and "dropped by the pipeline 0" in text
    assert json.loads(out.read_text())["asrs"] and svg.read_text().startswith("<")
