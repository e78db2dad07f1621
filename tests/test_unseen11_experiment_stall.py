"""Eleventh round of unseen inputs — an experiment whose train cannot start on a grade of its track.

Found with an experiment of our own: a 1,600 t freight leader (300 kN) at 16 m/s onto a 30 ‰ climb
(it needs 487 kN to start there) with four followers. The freight slowed to a stand on the climb
under full traction at 6,0xx m (its emergency-brake event at 14,000 m never came), the followers
stopped behind it, and the run was printed healthy, exit 0, with a "brake onset" at t = 0 and
"gaps at brake onset" equal to the starting gaps (400 / 400 / 600 / 300 m). A timetable, the headway
and the capacity study refuse such a train before anything runs (``running_time.stall_problem``);
the experiment now does too, for every train from its start to the farthest it can reach in the run
(on the plant it runs with), and a leader's emergency-brake event that never came is said.
"""

import pytest

from vcsumo.cli.main import main

from .conftest import write

EXPERIMENT = """
name: stall
step_s: 0.2
duration_s: DURATION
seeds: [1]
record_every: 10
track:
  straight: {length_m: 12000.0, speed_limit_mps: 16.7, grades: [{from_m: 3000.0, permille: GRADE}, {from_m: 6000.0, permille: 0.0}]}
trains:
  - {id: freight, stock: {base: regional_emu160, mass_kg: 800000.0, uncertainty_pct: 5.0}, position_m: 1500.0, speed_mps: 16.0}
  - {id: emu, stock: regional_emu160, gap_m: 300.0, speed_mps: 16.0, controller: cbc}
leader:
  driver: speed_tracker
  schedule: [[0.0, 16.0]]
  events: [{action: emergency_brake, at_m: EVENT}]
measurements:
  stop: {}
"""


def run(in_tmp, capsys, grade: float, duration: float = 400.0, event: float = 9000.0):
    exp = write(in_tmp / "stall.yaml", EXPERIMENT.replace("GRADE", str(grade)).replace("DURATION", str(duration)).replace("EVENT", str(event)))
    code = main(["experiment", str(exp), "--out", "e", "--no-plots"])
    out = capsys.readouterr()
    return exp, code, out


def test_a_leader_that_cannot_start_on_a_climb_of_its_track_is_refused(in_tmp, capsys):
    # 800 t, 200 kN: on 30 ‰ gravity alone is 235 kN
    exp, code, out = run(in_tmp, capsys, 30.0)
    lines = [x for x in out.err.splitlines() if x.strip()]
    assert code == 2 and not (in_tmp / "e").exists()
    assert len(lines) == 1, out.err
    assert lines[0].startswith(f"error: {exp}: trains[0].stock: ") and "freight" in lines[0] and "30.0 ‰" in lines[0], lines[0]


def test_a_climb_beyond_the_reach_of_the_run_is_not_refused(in_tmp, capsys):
    # the climb starts 1,500 m ahead; in 30 s even at its own 44.4 m/s the trains cannot get there
    _, code, out = run(in_tmp, capsys, 30.0, duration=30.0)
    assert code == 0, out.err


def test_a_climb_the_train_can_start_on_runs_and_an_event_never_reached_is_said(in_tmp, capsys):
    # 10 ‰: 78 kN of gravity, the train climbs; its emergency brake at 11 km is beyond the reach of a 100 s run
    _, code, out = run(in_tmp, capsys, 10.0, duration=100.0, event=11000.0)
    assert code == 0, out.err
    assert "the leader's emergency brake (at 11000 m) did not come within the run" in out.out, out.out


BRAKE = """
name: weak_brake
step_s: 0.2
duration_s: 300.0
seeds: [1]
record_every: 10
track:
  straight: {length_m: 12000.0, speed_limit_mps: 20.0, grades: [{from_m: 3000.0, permille: -30.0}]}
trains:
  - {id: L, stock: regional_emu160, position_m: 3000.0, speed_mps: 16.0}
  - {id: F, stock: {base: regional_emu160, mass_kg: 800000.0, service_brake_decel_mps2: BRAKE, uncertainty_pct: 5.0}, gap_m: 300.0, speed_mps: 16.0, controller: cbc}
leader:
  driver: speed_tracker
  schedule: [[0.0, 16.0]]
  events: [{action: emergency_brake, at_m: 4000.0}]
"""


@pytest.mark.parametrize("brake, refused", [(0.28, True), (0.45, False)])
def test_a_follower_whose_guaranteed_brake_cannot_hold_it_on_a_descent_is_refused(in_tmp, capsys, brake, refused):
    # on 30 ‰ gravity pulls 0.294 m/s²; 0.28 m/s² − 5 % (the box) − 10 % (etcs_typical) is 0.25: no
    # guaranteed braking. Before, the run went on and was NOT HEALTHY: the follower 8.7 m inside the
    # safe separation (the timetable refuses such a train: 'infeasible: … no guaranteed braking').
    exp = write(in_tmp / "weak.yaml", BRAKE.replace("BRAKE", str(brake)))
    code = main(["experiment", str(exp), "--out", "e", "--no-plots"])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    if refused:
        assert code == 2 and not (in_tmp / "e").exists()
        assert len(err) == 1 and err[0].startswith(f"error: {exp}: trains[1].stock: infeasible: train F") and "-30.0 ‰ descent" in err[0], err
    else:
        assert code == 0, err
