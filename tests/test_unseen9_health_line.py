"""``vcsumo run``'s health line names the counters the verdict rests on, each under its own name.

Found by unseen9 (2026-11-28) reading the health line beside ``summary.json``: its last counter,
"SUMO emergency brakings", printed ``emergency_brakes`` — the loop's count of SUMO's emergency
*stops* — not ``sumo_emergency_brakings``, the real emergency brakings that make a run unhealthy; and
SUMO's emergency stops, stop warnings and teleports, which the verdict also rests on, were not in the
line.  A follower stopped within one step on a 25 permille climb (the real SUMO emergency braking of
tests/test_sumo_emergency_braking.py) was "NOT healthy — ... SUMO emergency brakings 0".
"""

from __future__ import annotations

import pytest

from tests.test_sumo_emergency_braking import _run
from vcsumo.cli.commands import health_line, unhealthy_reasons


@pytest.mark.sumo
def test_a_real_sumo_emergency_braking_is_counted_in_the_health_line(tmp_path):
    res, _stock, _rows, _log = _run(tmp_path, "cbc", (250.0,))
    s = res.summary
    assert not s["healthy"] and s["sumo_emergency_brakings"] == 1 and s["emergency_brakes"] == 0
    reasons = unhealthy_reasons(s)
    line = health_line(s, reasons)
    assert line.startswith("health: NOT healthy — ") and reasons == ["1 SUMO emergency brakings"]
    assert line.endswith(", SUMO emergency brakings 1, SUMO emergency stops 0, SUMO stop warnings 0, teleports 0"), line
