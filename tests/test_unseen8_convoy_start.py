"""Eighth round of unseen inputs — a convoy follower that starts at another station than its leader.

Found 2026-11-28 on a slow line of our own (80 km/h, four stations): a follower F2 departing Charlie
(km 14) at 09:00 while its predecessor L2 left Alpha (km 0.8) at 09:00 ran 12.9 km in front of it
to the terminal, never coupled (``coupled_steps`` 0, "never ran coupled above 5 m/s"), and the run
was reported healthy with exit 0 — the convoy the file declared was never run.  Nothing overtakes on
a track: such a follower now enters the network behind its predecessor once that has passed
(:mod:`vcsumo.sim.convoy_insertion`), a late departure the run warns of before it starts.  A
follower that joins after its leader has passed departs on time, coupled.
"""

from __future__ import annotations

import json

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write

LINE = """
name: joinline
km_start: 0.0
km_end: 12.0
line_speed_kmh: 80
stations:
  - {id: A, name: Alpha, km: 0.8, platform_length_m: 400, dwell_s: 40}
  - {id: B, name: Bravo, km: 6.0, platform_length_m: 400, dwell_s: 40}
  - {id: D, name: Delta, km: 11.2, platform_length_m: 400, dwell_s: 40}
gradients:
  - {from_km: 2.0, to_km: 4.0, permille: 20.0}
signalling: {block_length_m: 800}
"""
EMU = """name: emu
length_m: 75.0
mass_kg: 165000.0
rotating_mass_factor: 1.06
max_speed_kmh: 160.0
max_traction_n: 200000.0
max_power_w: 2600000.0
davis_a_n: 2400.0
davis_b_n_per_mps: 30.0
davis_c_n_per_mps2: 4.0
service_brake_decel_mps2: 0.8
emergency_brake_decel_mps2: 1.2
"""


def _run(tmp_path, monkeypatch, follower_departs: str) -> int:
    write(tmp_path / "emu.yaml", EMU)
    write(tmp_path / "line.yaml", LINE)
    write(tmp_path / "tt.yaml", f"""name: tt
line: joinline
services:
  - {{id: L, train: emu.yaml, origin: A, destination: D, departure: "09:00", stops: [{{station: B}}]}}
  - {{id: F, train: emu.yaml, origin: B, destination: D, departure: "{follower_departs}"}}
convoys:
  - {{id: C, services: [L, F]}}
""")
    monkeypatch.chdir(tmp_path)
    return main(["run", "--line", "line.yaml", "--timetable", "tt.yaml", "--regime", "vc", "--controller", "cbc", "--out", "r"])


@pytest.mark.sumo
def test_a_follower_that_starts_ahead_of_its_leader_enters_behind_it(tmp_path, monkeypatch, capsys):
    assert _run(tmp_path, monkeypatch, "09:00") == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "convoys[0] (C): F departs at 09:00:00" in err and "ahead of its predecessor L, which gets there at" in err
    assert "F enters the network only once L has passed (a late departure" in err
    tr = pd.read_csv(tmp_path / "r" / "trajectories.csv")
    s = tr.pivot_table(index="time_s", columns="train", values="s_m")
    assert s["F"].first_valid_index() > s["L"][s["L"] > s["L"].iloc[0] + 5200.0].index[0]  # F entered once L had passed Bravo (km 6.0)
    ev = pd.read_csv(tmp_path / "r" / "summary.csv").set_index("train")
    assert ev.loc["F", "departure_s"] - ev.loc["F", "scheduled_departure_s"] > 60.0  # its late departure, as it happened
    vc = json.loads((tmp_path / "r" / "vc_summary.json").read_text())["followers"][0]
    assert vc["train"] == "F" and vc["coupled_steps"] > 0
    assert json.loads((tmp_path / "r" / "summary.json").read_text())["healthy"]


@pytest.mark.sumo
def test_a_follower_joining_after_its_leader_has_passed_runs_coupled(tmp_path, monkeypatch, capsys):
    assert _run(tmp_path, monkeypatch, "09:07") == 0, capsys.readouterr().err
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    vc = json.loads((tmp_path / "r" / "vc_summary.json").read_text())["followers"][0]
    assert summary["healthy"] and summary["trains_arrived"] == 2
    assert vc["train"] == "F" and vc["predecessor"] == "L" and vc["coupled_steps"] > 0
