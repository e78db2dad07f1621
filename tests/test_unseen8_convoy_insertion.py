"""Eighth round of unseen inputs — a convoy follower enters the network behind its predecessor.

Found 2026-11-28 (a 4-train convoy of our own trains under ``cbf-cruise``): a follower that does not
fit behind its predecessor in the departure platform departs once that train has cleared it, planned
with the predecessor's unhindered start; the predecessor — a 200 m, 520 t train behind a light EMU —
stood 62 s at the platform (the cruise controller's reference spacing not yet open), and SUMO
inserted the last member at its planned time 219 m in front of it.  The convoy's order was broken,
neither coupled again (``coupled_steps`` 0, "never ran coupled above 5 m/s") and the run was
reported healthy.  The follower is now kept out of the network until its predecessor has passed.
"""

from __future__ import annotations

import json

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write
from .test_unseen8_convoy_inputs import HEAVY
from .test_unseen8_convoy_start import EMU

pytestmark = pytest.mark.sumo

LINE = """
name: platline
km_start: 0.0
km_end: 9.0
line_speed_kmh: 120
stations:
  - {id: A, name: Alpha, km: 0.5, platform_length_m: 420, dwell_s: 30}
  - {id: Z, name: Zulu, km: 8.4, platform_length_m: 600, dwell_s: 30}
signalling: {block_length_m: 800}
"""
TT = """name: tt
line: platline
services:
  - {id: L, train: emu.yaml, origin: A, destination: Z, departure: "07:00"}
  - {id: H, train: heavy.yaml, origin: A, destination: Z, departure: "07:00"}
  - {id: E, train: emu.yaml, origin: A, destination: Z, departure: "07:00"}
convoys:
  - {id: C, services: [L, H, E]}
"""


def test_a_follower_is_not_inserted_in_front_of_its_predecessor(tmp_path, monkeypatch, capsys):
    write(tmp_path / "emu.yaml", EMU)
    write(tmp_path / "heavy.yaml", HEAVY)
    write(tmp_path / "line.yaml", LINE)
    write(tmp_path / "tt.yaml", TT)
    monkeypatch.chdir(tmp_path)
    rc = main(["run", "--line", "line.yaml", "--timetable", "tt.yaml", "--regime", "vc", "--controller", "cbf-cruise", "--out", "r"])
    assert rc == 0, capsys.readouterr().err
    tr = pd.read_csv(tmp_path / "r" / "trajectories.csv")
    s = tr.pivot_table(index="time_s", columns="train", values="s_m").dropna()
    assert len(s) > 100
    assert (s["E"] < s["H"]).all() and (s["H"] < s["L"]).all()  # the convoy's order, at every second all three run
    vc = {f["train"]: f for f in json.loads((tmp_path / "r" / "vc_summary.json").read_text())["followers"]}
    assert vc["E"]["predecessor"] == "H" and vc["E"]["coupled_steps"] > 0
    assert (tr[tr.train == "E"].leader.dropna() == "H").all()  # nothing between it and its predecessor
