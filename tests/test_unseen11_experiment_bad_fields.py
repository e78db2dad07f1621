"""Eleventh round of unseen inputs — experiment files with a wrong field that ran anyway.

Found by changing one field at a time of an experiment of our own (41 mutations): most were one
error line, but six ran, exited 0 and wrote a results folder that measured something else than the
file said — a gap window ending before it starts or starting after the run (its gaps silently
absent, ``window_duration_s`` 0), a grade beyond the end of the straight (dropped), a leader
emergency brake beyond the end of the track or after the run (never applied, while the same place
given in km was refused), a supervisor file for a stack that has no supervisor (ignored); and a
variant whose stock or controller did not resolve was reported against the file's own train
(``trains[1].stock``, which is fine in the file) instead of the variant. Each is now one line naming
the file and the field, exit 2, nothing written.
"""

import pytest
import yaml

from vcsumo.cli.main import main

BASE = """
name: bad
step_s: 0.2
duration_s: 100.0
seeds: [1]
track:
  straight: {length_m: 10000.0, speed_limit_mps: 20.0, grades: [{from_m: 3000.0, permille: -30.0}]}
trains:
  - {id: L, stock: regional_emu160, position_m: 3000.0, speed_mps: 16.0}
  - {id: F, stock: regional_emu160, gap_m: 300.0, speed_mps: 16.0, controller: cbc}
leader:
  driver: speed_tracker
  schedule: [[0.0, 16.0]]
  events: [{action: emergency_brake, at_m: 4000.0}]
measurements:
  gap_windows: [{name: w, from_s: 10.0, to_s: 50.0}]
"""

CASES = [
    (["measurements", "gap_windows"], [{"name": "w", "from_s": 50.0, "to_s": 10.0}], "measurements.gap_windows[0].to_s: 10 s must be after from_s (50 s)"),
    (["measurements", "gap_windows"], [{"name": "w", "from_s": 500.0, "to_s": 800.0}], "measurements.gap_windows[0].from_s: 500 s is not within the run (duration_s 100 s)"),
    (["track", "straight", "grades"], [{"from_m": 20000.0, "permille": 5.0}], "track.straight.grades[0].from_m: 20000 m is beyond the end of the track (10000 m)"),
    (["leader", "events"], [{"action": "emergency_brake", "at_m": 50000.0}], "leader.events[0].at_m: 50000 m is beyond the end of the track (10000 m)"),
    (["leader", "events"], [{"action": "emergency_brake", "at_s": 150.0}], "leader.events[0].at_s: 150 s is not within the run (duration_s 100 s)"),
    (["trains", 1, "supervisor_params"], "cbf", "trains[1].supervisor_params: controller 'cbc' has no supervisor to take it (cbf-cbc has the CBF)"),
    (["variants"], [{"name": "v", "set": {"trains.1.stock": "none.yaml"}}], "variants[0] (v): trains[1].stock: train file"),
    (["variants"], [{"name": "v", "set": {"trains.1.controller": "zz"}}], "variants[0] (v): trains[1].controller: unknown controller 'zz'"),
]


@pytest.mark.parametrize("where, value, expected", CASES, ids=[c[2].split(":")[0] + ":" + c[2].split(":")[1][:12] for c in CASES])
def test_a_wrong_field_is_one_line_exit_2_nothing_written(in_tmp, capsys, where, value, expected):
    data = yaml.safe_load(BASE)
    node = data
    for key in where[:-1]:
        node = node[key]
    node[where[-1]] = value
    f = in_tmp / "bad.yaml"
    f.write_text(yaml.safe_dump(data))
    code = main(["experiment", str(f), "--out", "e", "--no-plots"])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert code == 2 and not (in_tmp / "e").exists()
    assert len(err) == 1 and err[0].startswith(f"error: {f}: {expected}"), err


def test_the_file_as_written_runs(in_tmp, capsys):
    f = in_tmp / "good.yaml"
    f.write_text(BASE)
    assert main(["experiment", str(f), "--out", "e", "--no-plots"]) == 0, capsys.readouterr().err
