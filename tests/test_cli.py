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
