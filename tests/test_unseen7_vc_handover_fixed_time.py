"""A VC follower is handed to SUMO for its station stop only within the movement authority the
supervision will give it — with the assumption set's ETCS fixed times and report period.

Found by unseen7 (2026-11-28): felez_test ``convoy`` under vc/cbc with etcs_typical + fixed_time_s =
15 s.  The driver handed a follower over once the absolute rule held behind its predecessor's rear
*now*; the supervision then built its MB authority from where the predecessor was 15 s ago, behind
the follower: 12 authority overruns (UF.* 135.8 m, DF.* 48.3 m past the end of authority at 15-19
m/s), the run not healthy — while under relative braking nothing was ever unsafe.  Now the loop hands
the driver each follower's supervised authority (``Snapshot.handover_authority_m``) and the follower
stays coupled until it can stop within it.
"""

from __future__ import annotations

import json
from pathlib import Path

from tests.conftest import write
from vcsumo.cli.main import main

ROOT = Path(__file__).resolve().parent.parent


def test_vc_followers_handed_over_under_fixed_times_stay_within_their_authority(in_tmp):
    base = (ROOT / "vcsumo" / "data" / "assumptions" / "etcs_typical.yaml").read_text()
    write(in_tmp / "ft15.yaml", base.replace("name: etcs_typical", "name: ft15").replace("fixed_time_s: 0.0", "fixed_time_s: 15.0"))
    rc = main(["run", "--line", "felez_test", "--timetable", "convoy", "--regime", "vc", "--controller", "cbc", "--assumptions", "ft15.yaml",
               "--out", "r"])
    summary = json.loads((in_tmp / "r" / "summary.json").read_text())
    assert summary["authority_overruns"] == 0
    assert summary["trains_arrived"] == 12 and summary["stops_served"] == summary["stops_scheduled"] == 12
    assert summary["collisions"] == 0 and summary["gap_violations"] == 0
    assert summary["healthy"] is True and rc == 0
