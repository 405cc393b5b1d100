"""The durable map store: a real SQLite file, round trips, minimal writes, SIGKILL mid-write."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time

import pytest

from service.store import MapStore, StoreError, Synced


def _asr(i: int, scans: int = 1, gen: int = 0) -> dict:
    return {"id": i, "created": float(i), "origin": [float(i), 0.0, 0.0],
            "boundary": [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]], "edges": ["surface", "exit", "unknown"],
            "centre": [0.6, 0.3], "exits": [{"id": f"{i}/0", "a": [1.0, 0.0], "b": [1.0, 1.0], "to": None}],
            "duplicate_of": None, "scans": scans, "gen": gen}


def _doc(n: int, gen: int = 0) -> dict:
    return {"schema": "asrmap/map/1", "robot": "pioneer",
            "asrs": [_asr(i, gen=gen) for i in range(1, n + 1)],
            "links": [{"from": i, "exit": f"{i}/0", "to": i + 1, "via": f"{i + 1}/1", "oneway": False}
                      for i in range(1, n)],
            "cycles": [{"time": float(k), "asr": 1, "matches": 1, "accepted": True, "iou": 0.5,
                        "reason": "centre-crosscheck"} for k in range(gen)]}


def test_an_empty_store_loads_none(tmp_path):
    with MapStore(tmp_path / "map.sqlite") as s:
        assert s.load() is None


def test_the_document_round_trips_through_a_reopened_file(tmp_path):
    doc = _doc(4, gen=2)
    with MapStore(tmp_path / "map.sqlite") as s:
        s.sync(doc)
    with MapStore(tmp_path / "map.sqlite") as s:
        assert s.load() == doc


def test_the_file_is_in_wal_mode(tmp_path):
    with MapStore(tmp_path / "map.sqlite") as s:
        s.sync(_doc(1))
        assert sqlite3.connect(tmp_path / "map.sqlite").execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_only_changed_rows_are_written(tmp_path):
    with MapStore(tmp_path / "map.sqlite") as s:
        doc = _doc(3)
        assert s.sync(doc).rows == 3 + 2 + 1  # asrs, links, the robot name
        assert s.sync(doc).rows == 0
        doc["asrs"][1]["scans"] = 9
        doc["cycles"].append({"time": 1.0, "asr": 3, "matches": 1, "accepted": False, "iou": 0.1,
                              "reason": "x"})
        assert s.sync(doc) == Synced(2, [2])
        assert s.load() == doc


def test_asrs_and_links_absent_from_the_document_are_deleted(tmp_path):
    with MapStore(tmp_path / "map.sqlite") as s:
        s.sync(_doc(3, gen=2))
        s.sync(_doc(2, gen=1))
    with MapStore(tmp_path / "map.sqlite") as s:
        assert s.load() == _doc(2, gen=1)


def test_a_corrupt_file_is_moved_aside_and_a_new_map_started(tmp_path, caplog):
    path = tmp_path / "map.sqlite"
    path.write_bytes(b"SQLite format 3\0" + os.urandom(4096))
    with MapStore(path) as s:
        assert s.load() is None
        s.sync(_doc(1))
    assert list(tmp_path.glob("map.sqlite.corrupt-*")) and "moved to" in caplog.text


def test_archive_moves_the_map_aside_and_starts_empty(tmp_path):
    with MapStore(tmp_path / "map.sqlite") as s:
        s.sync(_doc(2))
        aside = s.archive("not-continued")
        assert s.load() is None
    assert aside.name.startswith("map.sqlite.not-continued-")
    with MapStore(aside) as old:
        assert old.load() == _doc(2)


def test_the_robots_pose_is_kept_apart_from_the_map(tmp_path):
    with MapStore(tmp_path / "map.sqlite") as s:
        assert s.load_pose() is None
        s.sync(_doc(2))
        s.save_pose(2, (0.5, -0.25, 1.0))
        s.save_pose(2, (0.75, -0.25, 1.0))
    with MapStore(tmp_path / "map.sqlite") as s:
        assert s.load_pose() == (2, (0.75, -0.25, 1.0)) and s.load() == _doc(2)


def test_an_unusable_state_directory_is_one_clear_error(tmp_path):
    (tmp_path / "file").write_text("not a directory")
    with pytest.raises(StoreError, match=r"cannot open the map store .*file/map.sqlite: .*file is not a "
                                         r"directory; check \[store\] state_dir"):
        MapStore(tmp_path / "file" / "map.sqlite")
    assert (tmp_path / "file").read_text() == "not a directory"


def test_a_store_path_that_is_a_directory_is_refused_and_never_moved_aside(tmp_path):
    # Once, a directory there failed "SQLite's integrity check" and was renamed *.corrupt-<t>,
    # with everything in it (a [store] path of "" is the state directory itself).
    (tmp_path / "maps").mkdir()
    (tmp_path / "maps" / "keep.txt").write_text("mine")
    with pytest.raises(StoreError, match=r"is a directory or a device, not a file"):
        MapStore(tmp_path / "maps")
    assert (tmp_path / "maps" / "keep.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maps"]


_WRITER = textwrap.dedent("""
    import sys
    sys.path.insert(0, {root!r})
    from tests.test_store import _doc
    from service.store import MapStore
    s = MapStore(sys.argv[1])
    start = (s.load() or {{"cycles": []}})["cycles"]
    gen = len(start)
    while True:
        gen += 1
        s.sync(_doc(2 + gen % 40, gen=gen))
        print(gen, flush=True)
""")


def test_sigkill_mid_write_leaves_the_last_committed_map(tmp_path):
    """Each generation rewrites every ASR in one transaction: after SIGKILL they all agree."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    path = tmp_path / "map.sqlite"
    for delay in (0.05, 0.13, 0.21, 0.08, 0.3):
        p = subprocess.Popen([sys.executable, "-c", _WRITER.format(root=root), str(path)],
                             stdout=subprocess.PIPE, text=True)
        first = int(p.stdout.readline())
        time.sleep(delay)
        p.send_signal(signal.SIGKILL)
        printed = [first, *(int(x) for x in p.stdout.read().split())]
        p.wait()
        assert sqlite3.connect(path).execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        with MapStore(path) as s:
            doc = s.load()
        gen = len(doc["cycles"])
        # Printed after commit, so the store holds at least the last printed generation, and at
        # most one more (committed, killed before the print).
        assert printed[-1] <= gen <= printed[-1] + 1
        assert doc == _doc(2 + gen % 40, gen=gen)
