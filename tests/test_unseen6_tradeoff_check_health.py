"""Sixth round of unseen inputs — the trade-off study's simulated check on a slow line of our own.

Defect found: a simulated check that is not healthy printed "NOT healthy (...)" naming only six of the
counters its health rests on: a check unhealthy for a short dwell (a VC follower leaving its stop
before its minimum dwell), a SUMO emergency stop, a gap violation or a collision printed "NOT healthy
()" with nothing in the brackets, and ``tradeoff_check.csv`` had no column for short dwells or SUMO's
emergency stops — a check could fail without the study saying why.  Now every counter of the capacity
row's health is in the table and named in the line.  (The short dwell here is injected into the real
capacity run's row: on this line the follower serves its dwells.)"""

import pandas as pd
import pytest

import vcsumo.studies.capacity as capacity
from vcsumo.cli.main import main

from .conftest import write
from .test_unseen6_junction_fouling import DMU
from .test_unseen6_tradeoff_platforms import LINE

pytestmark = pytest.mark.sumo


def test_an_unhealthy_check_says_why(in_tmp, capsys, monkeypatch):
    real = capacity.run_case

    def with_a_short_dwell(*args, **kwargs):
        res = real(*args, **kwargs)
        res.row.update(short_dwells=1, healthy=False)
        return res

    monkeypatch.setattr(capacity, "run_case", with_a_short_dwell)
    write(in_tmp / "dmu90.yaml", DMU)
    line = write(in_tmp / "line.yaml", LINE)
    code = main(["study", "tradeoff", "--line", str(line), "--convoy-sizes", "2", "--delays", "0.5", "--uncertainties", "",
                 "--position-errors", "", "--simulate-check", "1", "--out", "t"])
    out = capsys.readouterr().out
    assert code == 1
    assert "NOT healthy (short dwells 1)" in out, out  # main: "NOT healthy ()"
    chk = pd.read_csv(in_tmp / "t" / "tradeoff_check.csv")
    assert chk.short_dwells.iloc[0] == 1 and "sumo_emergency_stops" in chk.columns
