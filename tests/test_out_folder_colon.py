"""A results folder whose path holds a ':' (SUMO reads such an output file as host:port of a socket):
one line naming --out, exit 2, nothing written — until 2026-11-28 ``run`` started SUMO and failed
with "SUMO failed to start: Given port number 'y.partial-…/sumo_messages.log' is not numeric",
blaming the line file (the single-track round's finding)."""

from __future__ import annotations

import pytest

from vcsumo.cli.main import main

COMMANDS = {
    "run": ["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs"],
    "batch": ["batch", "--line", "felez_test", "--timetables", "test", "--regimes", "fbs", "--seeds", "1", "--workers", "1"],
    "capacity": ["study", "capacity", "--line", "felez_test", "--directions", "up", "--patterns", "non-stop", "--convoy-sizes", "1", "--workers", "1"],
    "junction": ["study", "junction", "--line", "regional_graded"],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_colon_in_the_results_folder_is_one_clear_error(command, tmp_path, capsys):
    out = tmp_path / "x:y" / "z"
    code = main([*COMMANDS[command], "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: --out: ") and "':'" in err[0]
    assert not (tmp_path / "x:y").exists()
