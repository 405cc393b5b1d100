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
                         (["bench", "mapper", "--runs", "2.5"], "--runs")):
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
