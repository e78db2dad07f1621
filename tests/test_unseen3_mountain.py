"""Unseen-looking cases, third round: a mountain line of our own (25 permille, stations on 20 permille
grades, 200 m platforms) and a heavy slow commuter EMU, written as a user would (files next to each
other, the train named by file). Real SUMO, through the command line."""

from __future__ import annotations

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write
from .test_network_unseen import FREIGHT  # a 450 m, 1,000 t freight train (0.35 / 0.5 m/s²)

pytestmark = pytest.mark.sumo

ALPINE = """
name: alpine
title: Mountain line (unseen test), 30 km, 25 permille, 120 km/h
notes: test line of our own [A]
sources:
  A: assumed by the vcsumo developers
km_start: 0.0
km_end: 30.0
tracks: double
start_elevation_m: 500
line_speed_kmh: 120
directions: {up: Valley -> Summit, down: Summit -> Valley}
default_train: commuter.yaml
stations:
  - {id: VAL, name: Valley, km: 0.6, platform_length_m: 500, dwell_s: 60}
  - {id: MID, name: Midway, km: 10.0, platform_length_m: 200, dwell_s: 45}
  - {id: STP, name: Steep, km: 17.0, platform_length_m: 200, dwell_s: 30}
  - {id: TOP, name: Summit, km: 29.4, platform_length_m: 500, dwell_s: 60}
speed_limits:
  - {from_km: 5.0, to_km: 7.0, speed_kmh: 60}
  - {from_km: 21.0, to_km: 23.5, speed_kmh: 80}
gradients:
  - {from_km: 1.0, to_km: 9.0, permille: 25.0}
  - {from_km: 11.0, to_km: 16.0, permille: 22.0}
  - {from_km: 16.0, to_km: 18.0, permille: 20.0}
  - {from_km: 18.0, to_km: 24.0, permille: -25.0}
  - {from_km: 24.0, to_km: 29.0, permille: 18.0}
signalling:
  block_length_m: 1200
"""
COMMUTER = """
name: commuter
title: heavy slow commuter EMU (unseen test) [A]
length_m: 100.0
mass_kg: 260000.0
rotating_mass_factor: 1.08
max_speed_kmh: 120.0
max_traction_n: 220000.0
max_power_w: 2000000.0
davis_a_n: 3500.0
davis_b_n_per_mps: 40.0
davis_c_n_per_mps2: 5.0
service_brake_decel_mps2: 0.7
emergency_brake_decel_mps2: 1.1
max_jerk_mps3: 0.8
traction_lag_s: 0.6
"""
# a down convoy stopping at Steep (on a 20 permille descent) and Midway: two 100 m trains and their
# 72 m standstill gap do not fit the 200 m platforms, so the follower waits behind its leader with
# its front inside the platform, 170 m short of its own stopping point
PAIR = """
name: pair
line: alpine
services:
  - {id: D1, train: commuter.yaml, origin: TOP, destination: VAL, departure: "07:05", stops: [{station: STP}, {station: MID}]}
  - {id: D2, train: commuter.yaml, origin: TOP, destination: VAL, departure: "07:05:30", stops: [{station: STP}, {station: MID}]}
convoys:
  - {id: CD, services: [D1, D2]}
"""


def test_a_follower_waiting_in_a_platform_too_short_for_its_convoy_serves_its_stop(tmp_path, capsys):
    """The supervision took a follower standing in its platform behind its leader as served although
    SUMO did not hold it there; when the leader left, the follower ran on and SUMO skipped its stop
    at Steep (mpc; before the fix: 5 of 6 stops, exit 1). Now every stop is served, by both trains,
    at its platform, and the run is healthy."""
    line = write(tmp_path / "alpine.yaml", ALPINE)
    write(tmp_path / "commuter.yaml", COMMUTER)
    tt = write(tmp_path / "pair.yaml", PAIR)
    out = tmp_path / "r"
    code = main(["run", "--line", str(line), "--timetable", str(tt), "--regime", "vc", "--controller", "mpc", "--out", str(out)])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "stops served 6/6 (skipped 0, short dwell 0)" in cap.out
    ev = pd.read_csv(out / "stop_events.csv")
    served = set(zip(ev.train, ev.station))
    assert {("D1", "STP"), ("D2", "STP"), ("D1", "MID"), ("D2", "MID")} <= served
    assert (ev.dwell_s >= 1.0).all()

# a heterogeneous convoy down the mountain: a freight train leads, a commuter EMU (which out-brakes
# it on level track) follows; its relative-braking rule is the mid-braking form
HETERO = """
name: hetero
line: alpine
services:
  - {id: B1, train: freight.yaml, origin: TOP, destination: VAL, departure: "07:00"}
  - {id: B2, train: commuter.yaml, origin: TOP, destination: VAL, departure: "07:00:30"}
convoys:
  - {id: CB, services: [B1, B2]}
"""


def test_a_light_follower_behind_a_freight_train_keeps_the_rule_over_the_grade_changes(tmp_path, capsys):
    """Before the fix the rule took each train's deceleration at the two ends of its braking run: as
    the freight train's run reached the 25 permille climb the required gap jumped from 93 to 220 m in
    one step and the health monitor counted a gap violation (margin −60 m). With the run integrated
    on the gradient profile it grows with the trains and the run is healthy."""
    line = write(tmp_path / "alpine.yaml", ALPINE)
    write(tmp_path / "commuter.yaml", COMMUTER)
    write(tmp_path / "freight.yaml", FREIGHT)
    tt = write(tmp_path / "hetero.yaml", HETERO)
    out = tmp_path / "r"
    code = main(["run", "--line", str(line), "--timetable", str(tt), "--regime", "vc", "--controller", "cbc", "--out", str(out)])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "gap violations 0, collisions 0" in cap.out
    s = pd.read_csv(out / "summary.csv").set_index("train")
    assert s.loc["B2", "gap_violations"] == 0 and s.loc["B2", "min_gap_m"] > 70.0
