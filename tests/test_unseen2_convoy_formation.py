"""Tier 2 — why a heterogeneous convoy does not form (found running convoys of an ETR 1000 and a
100 km/h EMU on a line nobody tuned for): a follower slower than its leader ran at its own top
speed most of the time, and ``vc_summary.json`` / ``vcsumo run`` put it down to "the controller did
not close it" — the at-the-limit test looked at the line's limit only, never at the train's own."""

import json

import pytest

from vcsumo.cli.main import main
from vcsumo.sim.convoy_formation import REASONS

from .conftest import write

pytestmark = pytest.mark.sumo

LINE = """
name: plain
km_start: 0.0
km_end: 12.0
line_speed_kmh: 200
default_train: etr1000
stations:
  - {id: AA, name: Aa, km: 0.5, platform_length_m: 600}
  - {id: ZZ, name: Zz, km: 11.5, platform_length_m: 600}
signalling: {block_length_m: 1500}
"""
EMU = """
name: emu100
length_m: 60.0
mass_kg: 120000.0
rotating_mass_factor: 1.08
max_speed_kmh: 100.0
max_traction_n: 150000.0
max_power_w: 1500000.0
davis_a_n: 2000.0
davis_b_n_per_mps: 25.0
davis_c_n_per_mps2: 3.0
service_brake_decel_mps2: 0.9
emergency_brake_decel_mps2: 1.3
max_jerk_mps3: 1.0
traction_lag_s: 0.3
"""
TT = """
name: pair
line: plain
services:
  - {id: L, train: etr1000, origin: AA, destination: ZZ, departure: "08:00"}
  - {id: F, train: emu100.yaml, origin: AA, destination: ZZ, departure: "08:00:30"}
convoys:
  - {id: C, services: [L, F]}
"""


def test_a_follower_slower_than_its_leader_is_said_to_run_at_its_permitted_speed(in_tmp, capsys):
    write(in_tmp / "plain.yaml", LINE)
    write(in_tmp / "emu100.yaml", EMU)
    tt = write(in_tmp / "pair.yaml", TT)
    code = main(["run", "--line", "plain.yaml", "--timetable", str(tt), "--regime", "vc", "--controller", "cbc", "--out", "r"])
    out = capsys.readouterr().out
    assert code == 0, out  # healthy: the convoy not forming is not a health problem
    f = next(x for x in json.loads((in_tmp / "r" / "vc_summary.json").read_text())["followers"] if x["train"] == "F")
    # 100 km/h behind a 200 km/h leader on a 200 km/h line: the gap opens while it runs flat out
    assert f["formed_share"] < 0.5 and f["not_formed_reason"] == REASONS[0] == "at its permitted speed", f
    assert f"F: {REASONS[0]}" in out
