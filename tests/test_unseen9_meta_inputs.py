"""A results folder's ``meta.json`` names every input file the command read, with its SHA-256.

Found by unseen9 (2026-11-28): the meta.json of ``vcsumo run`` on a line of our own listed only
``line`` and ``timetable``; of ``study capacity``, ``study headway``, ``study junction`` and
``study tradeoff`` only ``line``: the train file (a 120 m EMU of our own, named by the line's
``default_train``), the assumption set and the controller, channel and guard parameter files the
runs used were not recorded, so a changed train file could not be told from the results.
"""

from __future__ import annotations

import hashlib
import json

from tests.conftest import write
from vcsumo.cli.main import main

LINE = """name: meta_u9
km_start: 0.0
km_end: 6.0
line_speed_kmh: 120
default_train: emu.yaml
stations:
  - {id: AAA, name: Ashby, km: 0.4, platform_length_m: 200, dwell_s: 30}
  - {id: ZZZ, name: Zeal, km: 5.6, platform_length_m: 200, dwell_s: 30}
signalling: {block_length_m: 1500}
"""

EMU = """name: emu_u9
length_m: 120.0
mass_kg: 240000.0
rotating_mass_factor: 1.07
max_speed_kmh: 140.0
max_traction_n: 250000.0
max_power_w: 3200000.0
davis_a_n: 3200.0
davis_b_n_per_mps: 40.0
davis_c_n_per_mps2: 5.5
service_brake_decel_mps2: 0.75
emergency_brake_decel_mps2: 1.15
"""

TIMETABLE = """name: pair
line: meta_u9
services:
  - {id: A, train: emu.yaml, origin: AAA, destination: ZZZ, departure: "07:00"}
  - {id: B, train: emu.yaml, origin: AAA, destination: ZZZ, departure: "07:05"}
convoys: [{id: C, services: [A, B]}]
"""


def test_run_meta_names_the_train_assumption_and_controller_files(in_tmp):
    write(in_tmp / "line.yaml", LINE)
    emu = write(in_tmp / "emu.yaml", EMU)
    write(in_tmp / "pair.yaml", TIMETABLE.replace("departure: \"07:05\"", "departure: \"07:00:40\""))
    assert main(["-q", "run", "--line", "line.yaml", "--timetable", "pair.yaml", "--regime", "vc", "--controller", "cbc", "--out", "r"]) == 0
    inputs = json.loads((in_tmp / "r" / "meta.json").read_text())["inputs"]
    assert inputs["train:emu"] == {"path": str(emu.resolve()), "sha256": hashlib.sha256(emu.read_bytes()).hexdigest()}
    assert {"line", "timetable", "assumptions:etcs_typical", "controller:cbc", "channel:channel", "guard:guard"} <= set(inputs), sorted(inputs)
    assert not any(k.startswith(("line:", "timetable:")) for k in inputs)  # the line and timetable once, under their own names
