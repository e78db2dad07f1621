"""Eighth round of unseen inputs — the separation guard's settings file is the same for ``vcsumo run``,
the capacity study and the safety campaign.

Found 2026-11-28: ``vcsumo run`` (and the junction study) read ``controllers/guard.yaml`` (in
``$VCSUMO_HOME`` when set), while the capacity study's and the SUMO-loop campaign's VC driver and
the offline campaign's stacks took the built-in defaults: a user who switched the guard's on-board
sensor on (``sensor: true``) ran one guard under ``vcsumo run`` and had the campaign — which is to
check what the runs and studies run — check another.
"""

from __future__ import annotations

import shutil

from vcsumo.line import load_line
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import VCDriver
from vcsumo.studies.safety_scenarios import SafetyCampaign, follower_stacks_for, line_route
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import DATA, write
from .test_unseen8_convoy_start import EMU

LINE = """
name: guardline
km_start: 0.0
km_end: 12.0
line_speed_kmh: 140
default_train: {train}
stations:
  - {{id: A, name: Alpha, km: 0.8, platform_length_m: 400, dwell_s: 40}}
  - {{id: Z, name: Zulu, km: 11.2, platform_length_m: 400, dwell_s: 40}}
gradients:
  - {{from_km: 5.0, to_km: 7.0, permille: -12.0}}
signalling: {{block_length_m: 1500}}
"""
TT = """name: pair
line: guardline
services:
  - {id: L, train: emu.yaml, origin: A, destination: Z, departure: "07:00"}
  - {id: F, train: emu.yaml, origin: A, destination: Z, departure: "07:00:30"}
convoys:
  - {id: C, services: [L, F]}
"""


def _home(tmp_path, monkeypatch):
    home = tmp_path / "home"
    shutil.copytree(DATA / "controllers", home / "controllers")
    shutil.copytree(DATA / "assumptions", home / "assumptions")
    shutil.copytree(DATA / "networks" / "rolling_stock", home / "networks" / "rolling_stock")
    write(home / "controllers" / "guard.yaml", "sensor: true\n")
    monkeypatch.setenv("VCSUMO_HOME", str(home))
    emu = write(tmp_path / "emu.yaml", EMU)
    return write(tmp_path / "line.yaml", LINE.format(train=emu))


def test_the_campaign_and_the_studies_use_the_guard_file_vcsumo_run_uses(tmp_path, monkeypatch):
    line_path = _home(tmp_path, monkeypatch)
    line = load_line(line_path)
    net = build_network(line)
    tt, p = load_timetable(write(tmp_path / "pair.yaml", TT), line)
    # the VC driver as the capacity study and the SUMO-loop campaign build it (no guard named)
    driver = VCDriver([plan_trains(tt, p, line, net.topology)], "cbc", 0.2)
    assert driver.followers["F"].stack.guard.cfg.sensor is True
    # the offline campaign's stacks
    cfg = SafetyCampaign(lines=[str(line_path)], controllers=["cbc"])
    stock = load_rolling_stock(str(tmp_path / "emu.yaml"))
    for controller in ("cbc", "cbf-cbc"):
        stacks = follower_stacks_for(controller, line_route(str(line_path), "up"), ["t0", "t1"], cfg, [stock, stock])
        assert stacks[0].guard.cfg.sensor is True, controller
