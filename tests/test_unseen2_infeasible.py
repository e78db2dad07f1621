"""Tier 2 — trains a line cannot carry, said before running (found running a mountain line nobody
tuned for: 30–35 ‰ both ways, a 2,000 t freight train).

* A train whose tractive effort cannot start it on a grade of its route stalled there: ``vcsumo run``
  simulated 4.5 hours with the freight train standing at the foot of the climb (and the trains behind
  it), then exited 1 with "1 of 5 trains arrived" and nothing saying why; with a scheduled arrival
  the schedule check said it "needs 36000 s" (the running-time cap).  Now: one line naming the
  service's train, the grade, where, and the force it needs, exit 2, no results folder.
* A train whose guaranteed service brake cannot hold it on a descent of its route stopped with
  ``error: internal error ValueError ... (a bug in vcsumo)``: the health monitor builds the
  trains' braking before the supervisor, whose clear message was never reached.
"""

import pytest

from vcsumo.cli.main import main

from .conftest import write

pytestmark = pytest.mark.sumo

LINE = """
name: steep
km_start: 0.0
km_end: 6.0
line_speed_kmh: 120
default_train: regional_emu160
stations:
  - {id: LOW, name: Lowford, km: 0.5, platform_length_m: 200}
  - {id: TOP, name: Topham, km: 5.5, platform_length_m: 200}
gradients:
  - {from_km: 1.5, to_km: 3.5, permille: 35.0}
  - {from_km: 3.5, to_km: 5.0, permille: -30.0}
signalling: {block_length_m: 1500}
"""
FREIGHT = """
name: {name}
length_m: 700.0
mass_kg: 2000000.0
rotating_mass_factor: 1.06
max_speed_kmh: 80.0
max_traction_n: {traction}
max_power_w: 11000000.0
davis_a_n: 20000.0
davis_b_n_per_mps: 150.0
davis_c_n_per_mps2: 10.0
service_brake_decel_mps2: {brake}
emergency_brake_decel_mps2: 0.7
max_jerk_mps3: 0.3
traction_lag_s: 1.5
"""
TT = """
name: tt
line: steep
services:
  - {{id: FR, train: {name}.yaml, origin: start, destination: end, departure: "08:00"{arrival}}}
"""


def _case(tmp, name, traction, brake, arrival=""):
    write(tmp / "steep.yaml", LINE)
    write(tmp / f"{name}.yaml", FREIGHT.format(name=name, traction=traction, brake=brake))
    return write(tmp / "tt.yaml", TT.format(name=name, arrival=arrival))


def _one_error_line(capsys):
    cap = capsys.readouterr()
    lines = [x for x in cap.err.strip().splitlines() if x.startswith("error")]  # (after a progress bar, if the run had started)
    assert len(lines) == 1 and cap.err.strip().splitlines()[-1] == lines[0], cap.err
    assert "internal error" not in cap.err and "Traceback" not in cap.err
    return lines[0]


@pytest.mark.parametrize("arrival", ["", ', arrival: "09:00"'])
def test_a_train_that_cannot_start_on_a_grade_of_its_route_is_infeasible(in_tmp, capsys, arrival):
    # 35 ‰ under 2,000 t: 2e6·9.81·0.035 = 687 kN + Davis A 20 kN = 707 kN > 400 kN
    tt = _case(in_tmp, "weak", 400000.0, 0.5, arrival)
    assert main(["run", "--line", "steep.yaml", "--timetable", str(tt), "--regime", "fbs", "--out", "r"]) == 2
    err = _one_error_line(capsys)
    assert err.startswith(f"error: {tt}: services[0].train: infeasible") and "35.0 ‰" in err and "707 kN" in err and "400 kN" in err, err
    assert not (in_tmp / "r").exists() and not list(in_tmp.glob("r.partial*"))


def test_the_same_train_with_enough_traction_runs_healthy(in_tmp, capsys):
    """The check is the physics, not a bar: 800 kN > 707 kN, the train climbs, arrives, healthy."""
    tt = _case(in_tmp, "strong", 800000.0, 0.5)
    assert main(["run", "--line", "steep.yaml", "--timetable", str(tt), "--regime", "fbs", "--out", "r"]) == 0, capsys.readouterr().err
    assert "trains arrived 1/1" in capsys.readouterr().out


def test_a_train_whose_brake_cannot_hold_it_on_a_descent_is_infeasible(in_tmp, capsys):
    # guaranteed service brake 0.9·0.3 + A/M = 0.28 m/s² < g·0.030 = 0.294 m/s² on the 30 ‰ descent
    tt = _case(in_tmp, "unbraked", 800000.0, 0.3)
    assert main(["run", "--line", "steep.yaml", "--timetable", str(tt), "--regime", "mb", "--out", "r"]) == 2
    err = _one_error_line(capsys)
    assert "infeasible" in err and "train FR" in err and "-30.0 ‰" in err and "etcs_typical" in err, err
    assert not (in_tmp / "r").exists() and not list(in_tmp.glob("r.partial*"))
