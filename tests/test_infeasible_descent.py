"""A train whose guaranteed brake cannot hold it on a descent of the line (a 0.3 m/s² service brake,
−10 %, on 40 ‰): every study says so in words — 'no guaranteed service braking on a −40.0 ‰
descent' — not as an internal ValueError, and nothing concludes from figures it does not have.
Before: `study headway` stopped with 'internal error ValueError', capacity rows said 'ValueError: …',
and `study tradeoff` printed an empty table and 'VC n=2: beats MB at every T2T delay bound up to
30 s' with exit 0."""

from __future__ import annotations

import pandas as pd

from vcsumo.cli.main import main

from .conftest import write
from .test_uic406_separation import STEEP_LINE, WEAK

DESCENT = "weak: no guaranteed service braking on a -40.0 ‰ descent"


def _line(tmp_path):
    write(tmp_path / "steep" / "weak.yaml", WEAK)
    return str(write(tmp_path / "steep" / "line.yaml", STEEP_LINE))


def test_tradeoff_of_an_infeasible_route_is_one_error_line_and_writes_nothing(tmp_path, capsys):
    line = _line(tmp_path)
    out = tmp_path / "t"
    assert main(["-q", "study", "tradeoff", "--line", line, "--out", str(out)]) == 2
    err = capsys.readouterr()
    assert f"error: infeasible: {DESCENT} on steep (up) under the assumption set 'etcs_typical'" in err.err
    assert "beats MB" not in err.out and not out.exists()
    # the other direction climbs it: studied
    assert main(["-q", "study", "tradeoff", "--line", line, "--direction", "down", "--out", str(tmp_path / "d")]) == 0


def test_headway_and_capacity_name_the_descent(tmp_path, capsys):
    line = _line(tmp_path)
    assert main(["-q", "study", "headway", "--line", line, "--out", str(tmp_path / "h")]) == 2
    err = capsys.readouterr().err
    assert f"error: {DESCENT}" in err and "internal error" not in err
    code = main(["-q", "study", "capacity", "--line", line, "--convoy-sizes", "2", "--directions", "up", "--workers", "1", "--out", str(tmp_path / "c")])
    assert code == 1
    errors = pd.read_csv(tmp_path / "c" / "capacity.csv")["error"].tolist()
    assert len(errors) == 4 and all(e == DESCENT for e in errors), errors
