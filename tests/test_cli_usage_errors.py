"""What click itself rejects (an unknown option or command, a value of the wrong type, a missing
argument) is one line like every other input error, exit status 2, nothing written.

Until 2026-12-01 these were click's three lines — ``Usage: vcsumo run [OPTIONS]``, ``Try 'vcsumo run
--help' for help.``, a blank line and ``Error: No such option '--bogus'.`` — while README promises
one line ``error: --option: <problem>`` for every bad option."""

from __future__ import annotations

import pytest

from vcsumo.cli.main import main

CASES = {
    "unknown option": (["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--bogus", "1"],
                       "error: No such option '--bogus'", "(see 'vcsumo run --help')"),
    "not an integer": (["reproduce", "felez2019", "--horizon", "x"], "error: --horizon: 'x' is not a valid integer", "(see 'vcsumo reproduce felez2019 --help')"),
    "not a choice": (["reproduce", "terlizzi2024", "--scenario", "zz"], "error: --scenario: 'zz' is not one of 'os1'", "--help')"),
    "unknown command": (["nosuchcmd"], "error: No such command 'nosuchcmd'", "(see 'vcsumo --help')"),
    "unknown study": (["study", "nosuch"], "error: No such command 'nosuch'", "(see 'vcsumo study --help')"),
    "missing argument": (["experiment"], "error: Missing argument 'FILE'", "(see 'vcsumo experiment --help')"),
    "option without its value": (["run", "--line"], "error: Option '--line' requires an argument", ""),
    "extra argument": (["lines", "extra"], "error: Got unexpected extra argument (extra)", "(see 'vcsumo lines --help')"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_usage_error_is_one_line_and_exit_2(case, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    args, start, end = CASES[case]
    code = main(args)
    cap = capsys.readouterr()
    lines = [x for x in (cap.out + cap.err).splitlines() if x.strip()]
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith(start) and lines[0].endswith(end), lines[0]
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_study_name_lists_the_shipped_studies(tmp_path, monkeypatch, capsys):
    """``vcsumo study run nosuch`` (a name, as README's ``vcsumo study run capacity_hcmc_line1``): one
    line naming the shipped studies — until 2026-12-01 ``error: nosuch: file not found``."""
    monkeypatch.chdir(tmp_path)
    code = main(["study", "run", "nosuch"])
    lines = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith("error: STUDY_FILE: unknown study 'nosuch' (shipped: ") and "capacity_hcmc_line1" in lines[0]
    assert main(["study", "run", "nosuch.yaml"]) == 2  # a path stays a path
    assert capsys.readouterr().err.strip() == "error: nosuch.yaml: file not found"
    assert list(tmp_path.iterdir()) == []
