"""Replay of the shared real logs against ground truth (slow: run with ``pytest -m slow -s``).

Each case prints its figures (ASRs, cycles, precision, revisits, recall, scans/s, frame error before
and after realignment) for the paper's plain method and with the extensions.
"""

import dataclasses

import pytest

from mapper.cycle_params import CycleParams
from service.commands.replay import summary
from service.datasets import log_path
from service.replay import params_for_log, replay

CASES = [
    ("intel-raw-first5505.clf.gz", "intel-corrected.log.gz"),
    ("intel-corrected.log.gz", None),
    ("aces-corrected.log.gz", None),
    ("mit-csail.clf.gz", "csail-robotlaser1.log.gz"),
    ("csail-corrected.log.gz", None),
]


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["paper", "extended"])
@pytest.mark.parametrize(("log", "truth"), CASES, ids=[c[0].split(".")[0] for c in CASES])
def test_replay_of_a_real_log_keeps_cycle_precision(shared_data, log, truth, mode):
    params = params_for_log(log_path(log))
    cycles = CycleParams.paper() if mode == "paper" else CycleParams()
    params = dataclasses.replace(params, cycles=cycles)
    res = replay(log_path(log), params=params, truth=log_path(truth) if truth else None)
    print(f"\n== {log} ({mode})" + (f", truth {truth}" if truth else ""))
    for line in summary(res):
        print(line)
    ev = res.evaluation
    assert ev is not None and ev.evaluated > 0
    if mode == "extended":
        # The paper's plain check is printed, not held to this: with the metres of drift these logs'
        # odometry has, its crosscheck alone accepts neighbouring corridor pieces (see the README).
        assert ev.cycles == 0 or ev.precision >= 0.98, ev.false_pairs
        assert ev.frame_error_after <= ev.frame_error_before + 0.5


@pytest.mark.slow
def test_intel_raw_keeps_its_precision_when_the_viewpoints_move(shared_data):
    # Which scans become viewpoints decides every ASR, so one replay is one sample of the closures:
    # the same log with the viewpoint spacing 2 cm either way prints their spread (README, "Cycle
    # closing"), and none of the samples may close a false pair.
    base = params_for_log(log_path("intel-raw-first5505.clf.gz"))
    spread = []
    for spacing in (0.23, 0.24, 0.25, 0.26, 0.27):
        params = dataclasses.replace(base, view_spacing=spacing)
        res = replay(log_path("intel-raw-first5505.clf.gz"), params=params,
                     truth=log_path("intel-corrected.log.gz"))
        ev = res.evaluation
        spread.append(f"{spacing:.2f} m: {ev.true_positives} true / {ev.false_positives} false, "
                      f"{ev.detected} of {ev.revisits} revisits")
        assert ev.cycles == 0 or ev.precision >= 0.98, (spacing, ev.false_pairs)
    print("\nintel raw, view_spacing " + "; ".join(spread))


@pytest.mark.slow
def test_intel_raw_replays_every_scan_and_prints_its_throughput(shared_data):
    # The throughput goal (500x real time) is a figure for README, not an assertion.
    res = replay(log_path("intel-raw-first5505.clf.gz"))
    print(f"\nintel raw: {res.scans_per_second:,.0f} scans/s, {res.realtime_factor:,.0f}x real time")
    assert res.scans == 5505
