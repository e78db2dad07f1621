"""Sixth round of unseen inputs — a network of two lines of our own: a 100 km/h valley line and an
80 km/h fell line joined into it, 90 km/h DMUs; a VC convoy forms at the join (the leader comes down
the valley line, the follower off the fell line, both on to the valley line's end).

Defect found: ``vcsumo run`` (and ``batch``) coupled a follower as soon as its predecessor came
virtually ahead of it through the merge — the difference of their distances to the junction — however
far both still were from it: on the two lines of our own (60 and 18 km) the leader, 3 m/s faster,
overtook the follower *virtually* 8.5 km before the junction, the follower was coupled 1.6 m virtually
behind its rear and its guard applied the emergency brake for 18 s (21.7 → 12 m/s) on an open line, in
no conflict with anything.  On the short lines below: the leader inserted standing at its origin 320 m
virtually ahead of the follower at 22 m/s, 6 km from the junction (emergency brake, 38 steps; the
follower arrived 14.8 s later), or overtaking it virtually 520 m before the junction (2.1 m behind, 45
steps).  The junction study's followers have had a rule against this (``JunctionPolicy``); the timetable
driver had not.  Now, before its predecessor has reached the merge, a follower couples only with it
virtually ahead by the spacing its stack keeps and the safe separation (the relative-braking rule at
their speeds); until then SUMO drives it, supervised, and the approach locking orders the junction:
0 emergency brake applications in every case (the 60 km lines: coupled 273.7 m behind)."""

import json

import pandas as pd
import pytest

from vcsumo.network_file import load_network
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import make_vc_driver
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write
from .test_unseen6_junction_fouling import DMU

pytestmark = pytest.mark.sumo

VALLEY = """name: valley
km_start: 0.0
km_end: 16.0
line_speed_kmh: 100
default_train: dmu90.yaml
stations:
  - {id: ASH, name: Ash, km: 0.3, platform_length_m: 200, dwell_s: 40}
  - {id: YEW, name: Yew, km: 15.7, platform_length_m: 200, dwell_s: 40}
signalling: {block_length_m: 1200}
"""
FELL = """name: fell
km_start: 0.0
km_end: 10.0
line_speed_kmh: 80
default_train: dmu90.yaml
stations:
  - {id: FTP, name: Fell Top, km: 9.7, platform_length_m: 200, dwell_s: 40}
signalling: {block_length_m: 1500}
"""
NET = """name: valleyfell
lines:
  - {line: valley.yaml}
  - {line: fell.yaml}
joins:
  - {id: fell_junction, name: Fell Junction, end: {line: fell, at: start}, meets: {line: valley, km: 10.0}, towards: end, diverging_speed_kmh: 50}
"""
TIMETABLE = """name: merge
line: valleyfell
services:
  - {id: L, train: dmu90.yaml, origin: YEW, destination: ASH, departure: "07:03:20"}
  - {id: M, train: dmu90.yaml, origin: FTP, destination: ASH, departure: "07:00", via: [fell_junction]}
convoys:
  - {id: K, services: [L, M]}
"""


@pytest.mark.parametrize("leader_departs", ["07:03:00", "07:03:20"])
def test_a_follower_joining_at_a_merge_is_not_braked_to_open_a_virtual_gap(tmp_path, leader_departs):
    for name, text in (("dmu90.yaml", DMU), ("valley.yaml", VALLEY), ("fell.yaml", FELL)):
        write(tmp_path / name, text)
    net = load_network(write(tmp_path / "network.yaml", NET))
    built = build_network(net)
    tt, path = load_timetable(write(tmp_path / "merge.yaml", TIMETABLE.replace('"07:03:20"', f'"{leader_departs}"')), net)
    trains = plan_trains(tt, path, net, built.topology, dt=0.2)
    drv = make_vc_driver(tt, path, trains, "cbc", 0.2, seed=3)
    res = simulate(Scenario(net, built, trains, "vc", step_length_s=0.2, driver=drv), tmp_path / "out")
    drv.write_report(tmp_path / "out")
    s = res.summary
    assert s["trains_arrived"] == 2 and s["healthy"], s
    summary = json.loads((tmp_path / "out" / "vc_summary.json").read_text())["summary"]
    assert summary["vc_emergency_activations"] == 0, summary  # main: 1 (38 / 45 steps of the guard's emergency brake)
    rec = pd.read_csv(tmp_path / "out" / "vc_followers.csv")
    assert rec.gap_m.iloc[0] > 150.0, rec.iloc[0]  # main: 320.3 m behind a standing leader / 2.1 m
