"""The CARMEN log reader on the shared real logs and on a file with malformed lines."""

from __future__ import annotations

import gzip
import logging
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mapper.types import Odometry, Scan
from service.carmen import (
    CarmenReader,
    LaserRecord,
    LogFormatError,
    OdomRecord,
    ParamRecord,
    flaser_geometry,
    mapper_inputs,
)


@pytest.mark.parametrize(
    ("name", "kind", "count"),
    [
        ("intel-raw-first5505.clf.gz", "FLASER", 5505),
        ("mit-csail.clf.gz", "FLASER", 1988),
        ("csail-robotlaser1.log.gz", "ROBOTLASER1", 686),
        ("intel-corrected.log.gz", "FLASER", 910),
        ("csail-corrected.log.gz", "FLASER", 406),
        ("aces-corrected.log.gz", "FLASER", 440),
    ],
)
def test_laser_counts_match_sources_md(shared_data, name, kind, count):
    reader = CarmenReader(shared_data / name)
    lasers = [r for r in reader if isinstance(r, LaserRecord)]
    assert len(lasers) == count
    assert reader.counters[kind] == count
    assert reader.counters["malformed"] == 0


def test_intel_raw_flaser_geometry_and_pose(shared_data):
    first = next(r for r in CarmenReader(shared_data / "intel-raw-first5505.clf.gz"))
    assert first.kind == "FLASER" and len(first.ranges) == 180 and first.ranges.dtype == np.float32
    assert first.t == pytest.approx(0.000246)
    assert first.angle_min == pytest.approx(-math.pi / 2)
    # n = 180: the last beam still sits at +90 degrees
    assert first.angle_min + 179 * first.angle_increment == pytest.approx(math.pi / 2)
    assert first.pose == first.odom_pose == pytest.approx((0.0, 0.0, -0.002458))


def test_flaser_beam_spacing():
    assert flaser_geometry(181)[1] == pytest.approx(math.radians(1.0))
    assert flaser_geometry(361)[1] == pytest.approx(math.radians(0.5))


def test_csail_robotlaser1_fields(shared_data):
    reader = CarmenReader(shared_data / "csail-robotlaser1.log.gz")
    r = next(iter(reader))
    assert r.kind == "ROBOTLASER1" and len(r.ranges) == 361
    assert r.angle_min == pytest.approx(-1.570796) and r.angle_increment == pytest.approx(0.008727)
    assert r.t == pytest.approx(1134864642.914187)
    assert r.laser_pose is not None and r.odom_pose is None
    # ranges of 81.91 m are no-return: at or beyond max_range
    assert r.ranges.max() >= r.max_range


def test_odom_and_param_records(shared_data):
    recs = list(CarmenReader(shared_data / "intel-corrected.log.gz"))
    assert sum(isinstance(r, ParamRecord) for r in recs) == 2
    assert sum(isinstance(r, OdomRecord) for r in recs) == 14541
    p = next(r for r in recs if isinstance(r, ParamRecord))
    assert p.name == "robot_frontlaser_offset" and p.value == "0.0"


def test_malformed_lines_are_reported_with_file_and_line_then_skipped(tmp_path, caplog):
    good = "FLASER 3 1.0 2.0 81.91 0.1 0.2 0.3 0.1 0.2 0.3 5.5 host 5.6"
    lines = [
        "# a comment",
        good,
        "FLASER 3 1.0 2.0 0.1 0.2 0.3 0.1 0.2 0.3 5.5 host 5.6",  # one reading short
        "ODOM 1 2 x 0 0 0 6.0 host 6.0",  # not a number
        "ODOM 1 2 3 0.5 0.1 0 6.5 host 6.5",
        "NEFF 12",
        "",
        "PARAM",
    ]
    p = tmp_path / "bad.log.gz"
    with gzip.open(p, "wt") as fh:
        fh.write("\n".join(lines) + "\n")
    reader = CarmenReader(p)
    with caplog.at_level(logging.WARNING, logger="service.carmen"):
        recs = list(reader)
    assert [type(r).__name__ for r in recs] == ["LaserRecord", "OdomRecord"]
    assert reader.counters["malformed"] == 3
    assert reader.counters["comment"] == 1 and reader.counters["ignored"] == 1
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 3
    assert f"{p}:3:" in msgs[0] and f"{p}:4:" in msgs[1] and f"{p}:8:" in msgs[2]
    laser = recs[0]
    assert laser.t == 5.5 and laser.line == 2
    assert laser.angle_increment == pytest.approx(math.pi / 2)


def test_a_gz_log_cut_short_keeps_what_was_read_and_says_so(tmp_path, caplog):
    good = "FLASER 3 1.0 2.0 0.5 0.1 0.2 0.3 0.1 0.2 0.3 {t} host {t}"
    whole = gzip.compress(("\n".join(good.format(t=5.0 + i) for i in range(2000)) + "\n").encode())
    p = tmp_path / "cut.log.gz"
    p.write_bytes(whole[: len(whole) // 2])  # a copy interrupted half way
    reader = CarmenReader(p)
    with caplog.at_level(logging.WARNING, logger="service.carmen"):
        recs = list(reader)
    assert 100 < len(recs) < 2000 and all(isinstance(r, LaserRecord) for r in recs)
    assert reader.counters["truncated"] == 1
    assert any("ends early" in r.getMessage() and str(p) in r.getMessage() for r in caplog.records)


def test_a_gz_name_on_a_file_that_is_not_gzip_is_one_error_naming_it(tmp_path):
    p = tmp_path / "plain.clf.gz"
    p.write_text("FLASER 3 1.0 2.0 0.5 0.1 0.2 0.3 0.1 0.2 0.3 5.0 host 5.0\n")
    with pytest.raises(ValueError, match=r"plain\.clf\.gz: not a gzip file"):
        list(CarmenReader(p))


def test_mapper_inputs_pairs_odometry_with_each_scan(shared_data):
    items = []
    for i, item in enumerate(mapper_inputs(shared_data / "intel-raw-first5505.clf.gz")):
        items.append(item)
        if i >= 9:
            break
    assert [type(i) for i in items] == [Odometry, Scan] * 5
    assert items[0].t == items[1].t
    assert items[1].max_range == 50.0


FLASER_OK = "FLASER 3 1.0 2.0 3.0 {x} 0 0 {x} 0 0 {t} h {t}"
ROBOTLASER_OK = "ROBOTLASER1 0 -1.57 3.14 {res} 81.9 0.01 0 3 1 2 3 0 0 0 0 0 0 0 0 0 0 0 0 {t} h {t}"


@pytest.mark.parametrize(("line", "why"), [
    (FLASER_OK.format(x="nan", t="1.0"), "pose is 'nan', not a finite number"),
    (FLASER_OK.format(x="0", t="inf"), "timestamp is 'inf'"),
    (FLASER_OK.format(x="1e308", t="1.0"), "Odometry.x is 1e+308: expected a finite number of magnitude"),
    (ROBOTLASER_OK.format(res="1e-320", t="1.0"), "ROBOTLASER1 geometry: 3 beams 1e-320 rad apart"),
    (ROBOTLASER_OK.format(res="3.5", t="1.0"), "ROBOTLASER1 geometry"),
    ("ODOM 1 2 nan 0 0 0 1.0 h 1.0", "pose is 'nan'"),
])
def test_non_finite_or_absurd_readings_are_malformed_lines_named_by_file_and_line(
    tmp_path, caplog, line, why
):
    p = tmp_path / "bad.log"
    p.write_text(FLASER_OK.format(x="0", t="0.5") + "\n" + line + "\n")
    reader = CarmenReader(p)
    with caplog.at_level(logging.WARNING, logger="service.carmen"):
        recs = list(reader)
    assert len(recs) == 1 and reader.counters["malformed"] == 1
    assert f"{p}:2: malformed" in caplog.text and why in caplog.text


_TOKENS = ["nan", "inf", "-inf", "-5", "1e308", "99999999999", "x", "", "0", "-0", "1e-320", "3", "181",
           "1e6"]
_LINES = [FLASER_OK.format(x="0", t="1.0"), "ODOM 1 2 3 0 0 0 1.0 h 1.0",
          "PARAM robot_frontlaser_offset 0.1 h 0", ROBOTLASER_OK.format(res="0.0174", t="1.0")]


@st.composite
def _damaged_logs(draw):
    lines = []
    for _ in range(draw(st.integers(1, 6))):
        f = draw(st.sampled_from(_LINES)).split()
        for _ in range(draw(st.integers(0, 3))):
            i = draw(st.integers(0, len(f) - 1))
            op = draw(st.sampled_from(["replace", "delete", "insert"]))
            if op == "replace":
                f[i] = draw(st.sampled_from(_TOKENS))
            elif op == "delete" and len(f) > 1:
                del f[i]
            else:
                f.insert(i, draw(st.sampled_from(_TOKENS)))
        lines.append(" ".join(f))
    return "\n".join(lines) + "\n"


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=_damaged_logs())
def test_damaged_log_lines_never_escape_the_reader_or_the_mapper(tmp_path, text):
    from service.replay import replay

    p = tmp_path / "damaged.log"
    p.write_text(text)
    logging.disable(logging.WARNING)
    try:
        list(mapper_inputs(p))
        try:
            replay(p)
        except LogFormatError:  # no usable scan at all: one line for the user
            pass
    finally:
        logging.disable(logging.NOTSET)


def test_a_malformed_line_says_what_is_wrong_in_words(tmp_path, caplog):
    p = tmp_path / "bad.clf"
    p.write_text("FLASER\nFLASER 180.5 1 2\nROBOTLASER1 0 1\n"
                 "FLASER 3 1e308 2.0 3.0 0 0 0 0 0 0 1.0 h 1.0\n")
    with caplog.at_level(logging.WARNING):
        recs = list(CarmenReader(p))
    msgs = [r.getMessage() for r in caplog.records]
    assert f"{p}:1: malformed FLASER line skipped: too few fields (0 after FLASER)" in msgs
    assert any(f"{p}:2:" in m and "the number of readings is '180.5', not a whole number" in m for m in msgs)
    assert any(f"{p}:3:" in m and "too few fields (2 after ROBOTLASER1)" in m for m in msgs)
    # a range beyond float32 is no return, read without a numpy overflow warning
    assert len(recs) == 1 and not np.isfinite(recs[0].ranges[0]) and len(msgs) == 3
