"""Fourth round of unseen inputs — a train between a convoy follower and its predecessor (found in
``vcsumo batch`` on a suburban line of our own with pairs every 6 min: a follower delayed 498 s at its
origin left after the next pair, stayed coupled to its own leader 6 min ahead and ran into the next
pair's follower at 56 km/h). The stack knows only its predecessor (messages; the guard's on-board
sensor is off by default), so a follower was coupled whenever its predecessor was ahead on the shared
track, whatever ran in between. Here a 60 km/h railbus leaves between a pair's members (the follower
more than 300 s after its leader, so it does not depart with it): the follower caught the railbus
at 80 km/h (1 collision, gap −634 m). Now a follower with another train between it and its
predecessor is not coupled: SUMO drives it under the absolute rule behind the train it sees."""

import json

import pytest

from vcsumo.cli.main import main

from .conftest import write

pytestmark = pytest.mark.sumo

LINE = """
name: between
km_start: 0.0
km_end: 30.0
line_speed_kmh: 140
default_train: regional_emu160
stations:
  - {id: AA, name: Aa, km: 0.5, platform_length_m: 300}
  - {id: ZZ, name: Zz, km: 29.5, platform_length_m: 300}
signalling: {block_length_m: 1500}
"""
RAILBUS = """
name: railbus
length_m: 25.0
mass_kg: 40000.0
rotating_mass_factor: 1.1
max_speed_kmh: 60.0
max_traction_n: 30000.0
max_power_w: 300000.0
davis_a_n: 800.0
davis_b_n_per_mps: 10.0
davis_c_n_per_mps2: 1.5
service_brake_decel_mps2: 0.7
emergency_brake_decel_mps2: 1.0
"""
TT = """
name: tt
line: between
services:
  - {id: L, train: regional_emu160, origin: AA, destination: ZZ, departure: "07:00"}
  - {id: X, train: railbus.yaml, origin: AA, destination: ZZ, departure: "07:02"}
  - {id: F, train: regional_emu160, origin: AA, destination: ZZ, departure: "07:06"}
convoys:
  - {id: C, services: [L, F]}
"""


def test_a_follower_with_a_train_between_it_and_its_predecessor_is_not_coupled(tmp_path, monkeypatch, capsys):
    write(tmp_path / "railbus.yaml", RAILBUS)
    write(tmp_path / "tt.yaml", TT)
    line = write(tmp_path / "line.yaml", LINE)
    monkeypatch.chdir(tmp_path)
    code = main(["run", "--line", str(line), "--timetable", "tt.yaml", "--regime", "vc", "--controller", "cbc", "--out", "r"])
    cap = capsys.readouterr()
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert s["collisions"] == 0 and s["gap_violations"] == 0 and s["min_gap_m"] > 70.0, cap.out
    assert s["healthy"] and code == 0
