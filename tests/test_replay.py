"""asrmap replay on small synthetic CARMEN logs: the library function and the command."""

import gzip
import json
import xml.etree.ElementTree as ET

import pytest

from service.cli import main
from service.replay import replay
from tests.synthetic_runs import LOOP_WAYPOINTS, corridor_loop, drifting, path, write_carmen


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A raw log (drifting odometry) and a "corrected" log (true poses) of one run around the block."""
    tmp_path = tmp_path_factory.mktemp("logs")
    truth = path(LOOP_WAYPOINTS, laps=1.75, step=0.1)
    raw, corrected = tmp_path / "loop-raw.clf", tmp_path / "loop-corrected.log"
    write_carmen(raw, corridor_loop(), truth, drifting(truth))
    write_carmen(corrected, corridor_loop(), truth)
    return raw, corrected


def test_replay_maps_a_raw_log_and_scores_it_against_a_truth_log(logs):
    raw, corrected = logs
    res = replay(raw, truth=corrected)
    assert res.scans == sum(1 for line in raw.read_text().splitlines() if line.startswith("FLASER"))
    assert len(res.document["asrs"]) >= 2
    ev = res.evaluation
    assert ev is not None and ev.cycles >= 1 and ev.false_positives == 0
    assert res.scans_per_second > 0


def test_asrmap_replay_prints_the_figures_and_writes_map_and_picture(logs, tmp_path, capsys):
    raw, corrected = logs
    out_json, out_svg = tmp_path / "map.json", tmp_path / "map.svg"
    code = main(
        ["replay", str(raw), "--truth", str(corrected), "--json", str(out_json), "--svg", str(out_svg)]
    )
    assert code == 0
    captured = capsys.readouterr()
    for word in ("ASRs:", "cycles:", "precision:", "revisits:", "recall:", "scans/s", "transition error"):
        assert word in captured.out
    assert "%" in captured.err  # the progress bar
    doc = json.loads(out_json.read_text())
    assert doc["schema"] == "asrmap/map/1"
    ET.parse(out_svg)


def test_a_log_without_a_readable_scan_is_one_line_exit_2_and_each_bad_line_is_named_once(
    tmp_path, capsys, caplog
):
    bad = tmp_path / "bad.log"
    bad.write_text("FLASER 3 1 2\nODOM 1 2 3 0 0 0 1.0 h 1.0\nFLASER x\n")
    assert main(["replay", str(bad), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.log: no laser scan could be read" in err[0]
    warned = [r.getMessage() for r in caplog.records if "malformed" in r.getMessage()]
    assert sorted(w.split(":")[1] for w in warned) == ["1", "3"]  # lines 1 and 3, each once


def test_a_gz_log_cut_short_replays_what_it_holds_with_the_progress_bar_on(logs, tmp_path, capsys, caplog):
    # The progress bar counts the scans first (a text pass of its own): a cut .gz once ended that
    # pass with an EOFError traceback before the replay began.
    raw, _ = logs
    whole = gzip.compress(raw.read_bytes())
    cut = tmp_path / "cut.clf.gz"
    cut.write_bytes(whole[: len(whole) // 2])
    assert main(["replay", str(cut)]) == 0
    captured = capsys.readouterr()
    assert "ASRs:" in captured.out and "%" in captured.err
    warned = [r.getMessage() for r in caplog.records if "ends early" in r.getMessage()]
    assert len(warned) == 1 and str(cut) in warned[0]


def test_a_truth_log_without_a_pose_is_refused_before_the_replay(logs, tmp_path, capsys):
    raw, _ = logs
    bad = tmp_path / "truth.log"
    bad.write_text("ODOM 1 2 3 0 0 0 1.0 h 1.0\nFLASER x\n")
    for through in ([], ["--through-serial"]):  # directly, and through the emulators and the service
        assert main(["replay", str(raw), "--truth", str(bad), "--no-progress", *through]) == 2
        captured = capsys.readouterr()
        err = captured.err.strip().splitlines()
        assert len(err) == 1 and "truth.log: no robot pose could be read to use as the truth" in err[0]
        assert "ASRs:" not in captured.out  # nothing was replayed and thrown away
