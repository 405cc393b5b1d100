"""The command line: discovery of subcommands and one-line errors."""

import subprocess
import sys

from service.cli import build_parser, main


def test_every_subcommand_has_help_with_an_example():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert "bench" in sub.choices
    for name, p in sub.choices.items():
        assert "example:" in p.format_help(), name


def test_unknown_benchmark_is_one_line_exit_2(capsys):
    assert main(["bench", "no-such-benchmark"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown benchmark" in err[0]


def test_console_script_runs_help():
    out = subprocess.run([sys.executable, "-m", "service.cli", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "bench" in out.stdout


def test_bad_numbers_are_refused_naming_the_option(capsys):
    import pytest

    for argv, option in ((["simulate", "--duration", "-5"], "--duration"),
                         (["simulate", "--fast", "0"], "--fast"),
                         (["replay", "x.log", "--speed", "abc"], "--speed"),
                         (["emulate", "pioneer", "--seconds", "nan"], "--seconds"),
                         (["bench", "mapper", "--runs", "0"], "--runs"),
                         (["bench", "mapper", "--runs", "2.5"], "--runs"),
                         # beyond the OS's timers (an OverflowError once), or too slow for the
                         # drivers' timeouts (the service never connected, or hung reconnecting)
                         (["probe", "pioneer", "--emulated", "--seconds", "inf"], "--seconds"),
                         (["emulate", "laser", "--seconds", "1e12"], "--seconds"),
                         (["monitor", "--once", "--wait", "1e308"], "--wait"),
                         (["simulate", "--fast", "0.001"], "--fast"),
                         (["replay", "x.log", "--through-serial", "--speed", "0.05"], "--speed"),
                         (["simulate", "--seed", "-1"], "--seed")):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert f"argument {option}: expected a " in err and ("number" in err), err


def test_an_output_path_that_cannot_be_written_is_refused_before_the_run(capsys, tmp_path):
    """A typo in --json/--svg must not cost a long replay or exploration: argparse refuses it first."""
    import pytest

    log = tmp_path / "run.clf"  # never read: the refusal comes before
    missing = tmp_path / "no-such-dir" / "map.json"
    for argv, option, says in ((["replay", str(log), "--json", str(missing)], "--json", "no directory"),
                               (["replay", str(log), "--svg", str(tmp_path)], "--svg", "the directory"),
                               (["simulate", "--svg", str(missing)], "--svg", "no directory"),
                               (["render", "map.json", "--svg", str(missing)], "--svg", "no directory"),
                               (["monitor", "--svg", str(missing.with_name("{robot}.svg"))], "--svg",
                                "no directory")):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert f"argument {option}: " in err and says in err, err
        assert "Traceback" not in err


def test_a_robot_name_that_is_not_one_zenoh_key_chunk_is_refused(capsys):
    import pytest

    for argv in (["simulate", "--robot", "bad/name*"], ["simulate", "--robot", ""],
                 ["monitor", "--robot", "a*b"], ["monitor", "--once", "--robot", ""]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "argument --robot: expected a name of letters" in err and "Traceback" not in err, err


def test_an_output_that_is_an_input_or_the_other_output_is_refused_and_nothing_is_lost(capsys, tmp_path):
    log = tmp_path / "run.clf"
    log.write_text("FLASER 3 1.0 2.0 0.5 0.1 0.2 0.3 0.1 0.2 0.3 5.0 host 5.0\n")
    doc = tmp_path / "map.json"
    doc.write_text('{"schema": "asrmap/map/1", "asrs": [], "links": [], "cycles": []}')
    before = {p: p.read_bytes() for p in (log, doc)}
    out = tmp_path / "out.json"
    for argv, says in ((["replay", str(log), "--svg", str(log), "--no-progress"], "is the LOG file"),
                       (["replay", str(log), "--truth", str(doc), "--json", str(doc), "--no-progress"],
                        "is the --truth file"),
                       (["render", str(doc), "--svg", str(doc)], "is the MAP file"),
                       (["replay", str(log), "--json", str(out), "--svg", str(out), "--no-progress"],
                        "name the same file"),
                       (["simulate", "--direct", "--json", str(out), "--svg", str(out)],
                        "name the same file")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err
    assert {p: p.read_bytes() for p in (log, doc)} == before and not out.exists()


def test_a_full_disk_at_the_end_names_the_file(capsys, tmp_path):
    import os

    import pytest

    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    log = tmp_path / "run.clf"
    log.write_text("FLASER 3 1.0 2.0 0.5 0.1 0.2 0.3 0.1 0.2 0.3 5.0 host 5.0\n")
    assert main(["replay", str(log), "--json", "/dev/full", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "asrmap replay: cannot write '/dev/full': No space left on device"


def test_json_nested_too_deeply_is_one_line_not_a_recursion_error(capsys, tmp_path):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    for argv, says in ((["render", str(deep), "--svg", str(tmp_path / "r.svg")], "nested too deeply"),
                       (["simulate", "--direct", "--world", str(deep), "--svg", str(tmp_path / "s.svg"),
                         "--json", str(tmp_path / "s.json")], "nested too deeply")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0] and str(deep) in err[0], err
