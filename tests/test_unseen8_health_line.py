"""Eighth round of unseen inputs — the health line of ``vcsumo run`` names the counters its verdict
rests on, with their own values.

Found 2026-11-28: the line's "SUMO emergency brakings" printed ``emergency_brakes`` (SUMO's emergency
*stops* as TraCI lists them), not ``sumo_emergency_brakings`` (the real emergency brakings the verdict
counts), and the verdict's ``sumo_emergency_stops``, ``sumo_stop_warnings`` and ``teleports`` were not
in it.  A VC follower of the freight convoy stopped within one step on a 25 ‰ climb (one real SUMO
emergency braking, the run not healthy) printed "NOT healthy — ... SUMO emergency brakings 0".
"""

from __future__ import annotations

import pytest

from vcsumo.cli.commands import health_line, unhealthy_reasons

from .test_sumo_emergency_braking import _run


@pytest.mark.sumo
def test_the_health_line_shows_the_real_sumo_emergency_brakings_that_make_the_run_unhealthy(tmp_path):
    res, _stock, _rows, _log = _run(tmp_path, "cbc", (250.0,))
    s = res.summary
    assert s["sumo_emergency_brakings"] == 1 and not s["healthy"]
    reasons = unhealthy_reasons(s)
    line = health_line(s, reasons)
    assert reasons == ["1 SUMO emergency brakings"]
    assert line.startswith("health: NOT healthy — ")
    assert "SUMO emergency brakings 1," in line
    for counter, words in (("sumo_emergency_stops", "SUMO emergency stops"), ("sumo_stop_warnings", "SUMO stop warnings"), ("teleports", "teleports")):
        assert f"{words} {s[counter]}" in line
