"""An assumption set with ``speed_tolerance_kmh: 0``: a train at its lane's speed is not overspeeding.

Found by unseen7 (2026-11-28): with the tolerance set to 0 (allowed: 0-20 km/h) a steep line of our
own was not healthy under fbs, mb and vc (16, 19, 18 overspeed events, ``overspeed_max_kmh`` 0.0),
and regional_graded ``all_stations`` under fbs too — each event a train cruising at its lane's limit
as SUMO's network stores it (16.6667 m/s for 60 km/h, 27.7778 m/s for 100 km/h: 3.3e-5 and 2.2e-6 m/s
above the limit the monitor took from the line file).  The monitor now allows 1 mm/s on top of the set's tolerance for that rounding.
"""

from __future__ import annotations

import json
from pathlib import Path

from tests.conftest import write
from vcsumo.cli.main import main

ROOT = Path(__file__).resolve().parent.parent


def test_zero_speed_tolerance_counts_no_rounding_as_overspeed(in_tmp):
    base = (ROOT / "vcsumo" / "data" / "assumptions" / "etcs_typical.yaml").read_text()
    assert "speed_tolerance_kmh: 2.0" in base
    write(in_tmp / "tol0.yaml", base.replace("name: etcs_typical", "name: tol0").replace("speed_tolerance_kmh: 2.0", "speed_tolerance_kmh: 0.0"))
    rc = main(["run", "--line", "regional_graded", "--timetable", "all_stations", "--regime", "fbs", "--assumptions", "tol0.yaml", "--out", "r"])
    summary = json.loads((in_tmp / "r" / "summary.json").read_text())
    assert summary["overspeed_events"] == 0, summary["overspeed_max_kmh"]
    assert summary["healthy"] is True and rc == 0
