"""A run cut short by --end-time: the stops trains had not reached are ``stops_not_reached``, not
skipped; the summary stays not healthy (trains have not arrived) and the terminal says why.

On main@4c41627 every scheduled stop not served counted as skipped (``stops_skipped`` = scheduled −
served), so a run cut short reported the destinations of the trains still running as skipped stops.
"""

from __future__ import annotations

import json
import math
import re

import pandas as pd

from vcsumo.cli.main import main
from vcsumo.sim.run_results import STOP_PASSED_M, stop_counts
from vcsumo.timetable import PlannedStop


def test_a_run_cut_short_counts_the_stops_ahead_as_not_reached(in_tmp, capsys):
    """felez_test ``test``: three trains one minute apart to the 3,700 m stop (the first arrives at
    ≈ 186 s).  Cut at 200 s: the first has served its stop, the other two are running towards theirs."""
    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--end-time", "200", "--out", "r"]) == 0
    summary = json.loads((in_tmp / "r" / "summary.json").read_text())
    assert summary["simulated_until_s"] <= 200.0 + 1e-6
    assert (summary["trains"], summary["trains_arrived"]) == (3, 1)
    assert (summary["stops_scheduled"], summary["stops_served"], summary["stops_skipped"], summary["stops_not_reached"]) == (3, 1, 0, 2)
    assert summary["healthy"] is False  # a cut-short run is never clean: two trains have not arrived
    trains = pd.read_csv(in_tmp / "r" / "summary.csv").set_index("train")
    assert trains["stops_not_reached"].to_dict() == {"T.1": 0, "T.2": 1, "T.3": 1}
    assert trains["stops_skipped"].sum() == 0
    out = capsys.readouterr().out
    assert "1 of 3 trains arrived and 2 stops not reached (not skipped)" in out.replace("\n", " ")
    flat = " ".join(out.split())
    assert ("health: cut short at --end-time, nothing wrong until then (NOT healthy as a whole run) — trains arrived 1/3, "
            "stops served 1/3 (skipped 0, short dwell 0)") in flat, flat
    # the same run to the end: every train arrives, every stop served, healthy
    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", "full"]) == 0
    full = json.loads((in_tmp / "full" / "summary.json").read_text())
    assert (full["stops_served"], full["stops_skipped"], full["stops_not_reached"], full["healthy"]) == (3, 0, 0, True)
    line = " ".join(capsys.readouterr().out.split())  # the terminal's health line names every counter the verdict rests on
    assert re.search(r"health: healthy — trains arrived 3/3, stops served 3/3 \(skipped 0, short dwell 0\), min margin to the safe separation [0-9.]+ m, "
                     r"min gap [0-9.]+ m, gap violations 0, collisions 0, overspeed 0, braking beyond service 0, authority overruns 0, "
                     r"SUMO emergency brakings 0", line), line


def _stop(s_m: float, platform: str) -> PlannedStop:
    return PlannedStop(platform, platform, s_m, 30.0, None, None)


def test_an_unserved_stop_is_skipped_once_passed_and_not_reached_ahead():
    stops = [_stop(1000.0, "A"), _stop(2000.0, "B"), _stop(3000.0, "C")]
    served = {"A"}.__contains__
    # running when the run ended, its front 1 m short of B: B and C not reached
    assert stop_counts(stops, served, False, 1999.0) == {"stops_scheduled": 3, "stops_served": 1, "stops_skipped": 0, "stops_not_reached": 2}
    # its front beyond B by more than the tolerance: B was passed without stopping (skipped)
    assert stop_counts(stops, served, False, 2000.0 + STOP_PASSED_M + 1.0)["stops_skipped"] == 1
    assert stop_counts(stops, served, False, 2000.0 + STOP_PASSED_M - 1.0)["stops_skipped"] == 0  # standing at it
    # arrived without serving them: skipped; never departed: not reached
    assert stop_counts(stops, served, True, math.nan)["stops_skipped"] == 2
    assert stop_counts(stops, served, False, math.nan)["stops_not_reached"] == 2
