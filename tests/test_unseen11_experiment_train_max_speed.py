"""Eleventh round of unseen inputs — an experiment train above its own maximum speed was healthy.

Found with an experiment of our own: a 60 km/h freight leader on a 25 m/s (90 km/h) schedule on a
108 km/h track ran at 90.3 km/h, 30 km/h above what the train can run (SUMO caps every train at its
vType's maxSpeed; the offline plant does not), and the run was printed healthy, exit 0, with
``overspeed_max_kmh`` 0: the excess was measured against the track's limit only. The permitted speed
of a train is now the lower of the track's (under the whole train) and its own maximum speed, as in
SUMO: the run is NOT HEALTHY, naming the train and the excess (exit 1).
"""

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write

EXPERIMENT = """
name: own_max
step_s: 0.2
duration_s: 120.0
seeds: [1]
record_every: 10
track:
  straight: {length_m: 8000.0, speed_limit_mps: 30.0}
trains:
  - {id: L, stock: {base: regional_emu160, max_speed_kmh: 60.0}, position_m: 3000.0, speed_mps: 15.0}
  - {id: F, stock: regional_emu160, gap_m: 1500.0, speed_mps: 15.0, controller: cbc}
leader:
  driver: speed_tracker
  schedule: [[0.0, SPEED]]
"""


@pytest.mark.parametrize("speed, healthy", [(25.0, False), (16.0, True)])
def test_a_leader_above_its_own_maximum_speed_is_not_healthy(in_tmp, capsys, speed, healthy):
    exp = write(in_tmp / "own_max.yaml", EXPERIMENT.replace("SPEED", str(speed)))
    code = main(["experiment", str(exp), "--out", "e", "--no-plots"])
    out = capsys.readouterr().out
    m = pd.read_csv(in_tmp / "e" / "measurements.csv")
    over = {r.train: r.value for r in m[m.quantity == "overspeed_max_kmh"].itertuples()}
    vmax = {r.train: r.value for r in m[m.quantity == "max_speed_mps"].itertuples()}
    assert over["F"] == 0.0
    if healthy:
        assert over["L"] == 0.0 and code == 0 and "NOT HEALTHY" not in out
    else:
        assert vmax["L"] * 3.6 == pytest.approx(90.0, abs=1.0)  # the plant follows the schedule
        assert over["L"] == pytest.approx(vmax["L"] * 3.6 - 60.0, abs=0.01)
        assert code == 1 and f"NOT HEALTHY (above the permitted speed: L +{over['L']:.1f} km/h" in out
