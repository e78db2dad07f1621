"""A VC follower's emergency brake is judged by the same rule on a climb as on the level.

SUMO warns of 'emergency braking' when a train's speed falls by more than its vType's
``emergencyDecel`` (1.2 × its emergency brake + resistance) in a step, and that fall includes the
grade.  A follower the VC driver brakes at its emergency rate slows by g·i more on a climb: on the
level SUMO says nothing, on a 25 ‰ climb it warns.  Before, the warning was judged against the
*service* brake (the rule for trains SUMO drives, which plan only with it), so the same emergency
application made the run unhealthy on a climb and healthy on the level.  A train vcsumo drives is
judged against its own strongest *emergency* brake there (the vType's threshold: braking no brake
can give); trains SUMO drives keep the service rule.  Real SUMO runs."""

from __future__ import annotations

import pandas as pd
import pytest

from vcsumo.dynamics import running_resistance
from vcsumo.line import load_line
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import make_vc_driver
from vcsumo.timetable import load_timetable, plan_trains
from vcsumo.units import G

from .conftest import write

LINE = """
name: {name}
km_start: 0.0
km_end: 12.0
tracks: double
line_speed_kmh: 100
default_train: etr1000
stations:
  - {{id: LOW, name: Lowfield, km: 1.1, platform_length_m: 1000, dwell_s: 30}}
  - {{id: TOP, name: Topham, km: 11.4, platform_length_m: 1000, dwell_s: 30}}
gradients:
  - {{from_km: 2.0, to_km: 10.0, permille: {permille}}}
signalling: {{block_length_m: 1500}}
"""
# a freight train whose emergency brake (0.9 m/s²) is well above its service brake (0.5 m/s²)
FREIGHT = """
name: freight_e
length_m: 450.0
mass_kg: 1000000.0
rotating_mass_factor: 1.05
max_speed_kmh: 100.0
max_traction_n: 300000.0
max_power_w: 4200000.0
davis_a_n: 14000.0
davis_b_n_per_mps: 100.0
davis_c_n_per_mps2: 8.0
service_brake_decel_mps2: 0.5
emergency_brake_decel_mps2: 0.9
max_jerk_mps3: 0.5
traction_lag_s: 1.0
"""
CONVOY = """
name: t
line: {name}
services:
  - {{id: L, train: freight.yaml, origin: LOW, destination: TOP, departure: 0}}
  - {{id: F, train: freight.yaml, origin: LOW, destination: TOP, departure: 0}}
convoys:
  - {{id: C, services: [L, F]}}
"""
STEP_S = 0.5
BRAKE_AT_S = (400.0, 400.5, 401.0, 401.5)  # the follower on the climb (or the same place on the level line)


def _run(tmp_path, permille: float):
    name = f"grade{int(permille)}"
    line = load_line(write(tmp_path / name / "line.yaml", LINE.format(name=name, permille=permille)))
    write(tmp_path / "freight.yaml", FREIGHT)
    net = build_network(line)
    tt, p = load_timetable(write(tmp_path / f"{name}.yaml", CONVOY.format(name=name)), line)
    trains = plan_trains(tt, p, line, net.topology, dt=STEP_S)
    drv = make_vc_driver(tt, p, trains, "cbc", STEP_S, seed=3)
    stock = trains[1].stock
    params = stock.params()
    inner = drv.make_step
    applied = []

    def make_step(snap):
        # the emergency brake at the top of its range, as the VC driver's plant model gives it: brake + resistance + grade
        cmds = inner(snap)
        if "F" in cmds and any(abs(snap.time_s - t0) < 1e-6 for t0 in BRAKE_AT_S):
            v = snap.trains["F"].speed_mps
            a = 1.1 * stock.emergency_brake_decel_mps2 + (running_resistance(params, v) + G * params.mass_kg * permille / 1000.0) / (params.mass_kg * params.rotating_mass_factor)
            cmds["F"] = max(0.0, v - 0.98 * a * STEP_S)
            applied.append((snap.time_s, v, a))
        return cmds

    drv.make_step = make_step
    out = tmp_path / f"out{int(permille)}"
    res = simulate(Scenario(line, net, trains, "vc", step_length_s=STEP_S, driver=drv), out)
    path = out / "sumo_emergency_brakings.csv"
    rows = pd.read_csv(path) if path.is_file() else pd.DataFrame()
    return res.summary, rows, applied, stock


@pytest.mark.sumo
def test_the_same_emergency_application_is_healthy_on_the_level_and_on_a_climb(tmp_path):
    level, level_rows, level_applied, stock = _run(tmp_path, 0.0)
    climb, climb_rows, climb_applied, _ = _run(tmp_path, 25.0)
    assert len(level_applied) == len(climb_applied) == len(BRAKE_AT_S) and min(v for _, v, _ in climb_applied) > 5.0
    # on the level SUMO does not warn; on the climb the grade takes the fall above the vType's emergencyDecel
    assert level["sumo_emergency_warnings"] == 0 and level["healthy"]
    assert climb["sumo_emergency_warnings"] >= 1 and max(a for _, _, a in climb_applied) * 0.98 > stock.sumo_emergency_decel_mps2
    # judged against the follower's own emergency brake: explained, the run healthy as on the level
    assert climb["sumo_emergency_brakings"] == 0 and climb["sumo_emergency_warnings_explained"] == climb["sumo_emergency_warnings"], climb_rows.to_string()
    assert climb["healthy"]
    f = climb_rows[climb_rows.train == "F"]
    assert len(f) >= 1 and set(f.verdict) == {"explained"} and set(f.driven_by_sumo) == {False}
    assert (f.decel_mps2 > f.service_limit_mps2 + 0.02).all()  # beyond the service brake...
    assert (f.decel_mps2 <= f.emergency_limit_mps2).all() and f.reason.str.startswith("within its emergency brake").all()  # ...within its emergency brake
