"""A convoy follower timetabled before the train ahead of it from the same platform leaves behind it
— later than its timetable — and the run says so before it starts, naming both times (unseen9: PF at
07:00 behind PL at 07:01 was re-timed to 07:01 without a word, summary.csv showing the new time)."""

from __future__ import annotations

import warnings

from vcsumo.line import load_line
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import make_vc_driver
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write

TT = """name: early
line: regional_graded
services:
  - {id: PL, train: regional_emu160, origin: ALD, destination: GLN, departure: "07:01"}
  - {id: PF, train: regional_emu160, origin: ALD, destination: GLN, departure: "07:00"}
convoys:
  - {id: P, services: [PL, PF]}
"""


def _driver(tmp_path, text):
    line = load_line("regional_graded")
    net = build_network(line)
    tt, p = load_timetable(write(tmp_path / "tt.yaml", text), line)
    trains = plan_trains(tt, p, line, net.topology, dt=0.2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        make_vc_driver(tt, p, trains, "cbc", 0.2, 42)
    return {t.id: t for t in trains}, [str(w.message) for w in caught if "is timetabled at" in str(w.message)]


def test_the_follower_leaves_behind_its_leader_and_the_run_says_so(tmp_path):
    trains, msgs = _driver(tmp_path, TT)
    assert trains["PF"].depart_s == trains["PL"].depart_s == 7 * 3600 + 60  # behind it in the platform, with it
    assert msgs == ["convoy follower PF is timetabled at 07:00:00, before PL ahead of it in the convoy (07:01:00): it leaves behind it at "
                    "07:01:00 (60 s after its timetable; summary.csv's scheduled departure is that time)"]
    # timetabled after its leader (the usual way to write a convoy): brought forward to leave with it, as documented, no warning
    trains, msgs = _driver(tmp_path, TT.replace('departure: "07:00"', 'departure: "07:01:30"'))
    assert trains["PF"].depart_s == trains["PL"].depart_s and msgs == []
