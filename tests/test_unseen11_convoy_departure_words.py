"""Eleventh round of unseen inputs — a convoy follower timetabled after its leader but leaving later
still was told it was "timetabled before" it.

Found on a line of our own: a 600 m freight FL leaving its 700 m terminal platform at 06:00:00 and
its convoy follower EF (a 75 m EMU) timetabled at 06:00:30. The two cannot stand in the platform
together (747 m with the 72 m standstill gap), so EF leaves once FL has cleared it, at 06:01:12 —
and the run warned ``convoy follower EF is timetabled at 06:00:30, before FL ahead of it in the
convoy (06:00:00)``, which is false. The warning now gives the real reason.
"""

from __future__ import annotations

import warnings

from vcsumo.line import load_line
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import make_vc_driver
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write

LONG = (__import__("pathlib").Path(__file__).parents[1] / "vcsumo" / "data" / "networks" / "rolling_stock" / "regional_emu160.yaml").read_text() \
    .replace("name: regional_emu160", "name: long_emu").replace("length_m: 75.0", "length_m: 200.0")

TT = """name: long_first
line: regional_graded
services:
  - {id: PL, train: long_emu.yaml, origin: ALD, destination: GLN, departure: "07:00"}
  - {id: PF, train: regional_emu160, origin: ALD, destination: GLN, departure: "07:00:05"}
convoys:
  - {id: P, services: [PL, PF]}
"""


def test_a_follower_that_cannot_stand_behind_its_leader_is_told_why(tmp_path):
    write(tmp_path / "long_emu.yaml", LONG)
    line = load_line("regional_graded")
    net = build_network(line)
    tt, p = load_timetable(write(tmp_path / "tt.yaml", TT), line)
    trains = plan_trains(tt, p, line, net.topology, dt=0.2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        make_vc_driver(tt, p, trains, "cbc", 0.2, 42)
    msgs = [str(w.message) for w in caught if "convoy follower PF" in str(w.message)]
    pf, pl = {t.id: t for t in trains}["PF"], {t.id: t for t in trains}["PL"]
    assert pf.depart_s > 7 * 3600 + 5  # it waits until PL has cleared it
    late = pf.depart_s - (7 * 3600 + 5)
    assert len(msgs) == 1 and "before PL" not in msgs[0], msgs
    assert msgs[0].startswith(f"convoy follower PF is timetabled at 07:00:05, after PL ahead of it in the convoy (07:00:00), but cannot stand behind it "
                              f"on its departure track: it leaves once PL has cleared it by the standstill gap, at "), msgs[0]
    assert f"({late:.0f} s after its timetable; summary.csv's scheduled departure is that time)" in msgs[0], msgs[0]
