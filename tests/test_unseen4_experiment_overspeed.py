"""Fourth round of unseen inputs — an experiment whose leader runs above the track's permitted speed
(found with an experiment of our own on a line with an 80 km/h restriction: a freight leader on a
97 km/h schedule ran through it at 97 km/h while its guarded followers kept 80 and fell 600 m behind;
the run was printed without a word and exited 0). The experiment's health knew collisions and the
CBF's true barrier only. Now every train's largest excess over the permitted speed (the lowest limit
under the whole train) is measured (``overspeed_max_kmh``, ``overspeed_steps``) and a run with a
train more than 2 km/h above it is NOT HEALTHY, naming the train (exit 1)."""

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write

EXPERIMENT = """
name: too_fast
step_s: 0.1
duration_s: 40.0
seeds: [1]
record_every: 10
track:
  straight: {length_m: 5000.0, speed_limit_mps: 20.0}
trains:
  - {id: L, stock: regional_emu160, position_m: 2000.0, speed_mps: 19.0}
  - {id: F, stock: regional_emu160, gap_m: coupled, speed_mps: 19.0, controller: cbc}
leader:
  driver: speed_tracker
  schedule: [[0.0, SPEED]]
"""


@pytest.mark.parametrize("speed, healthy", [(25.0, False), (19.5, True)])
def test_a_leader_above_the_permitted_speed_is_not_healthy(in_tmp, capsys, speed, healthy):
    exp = write(in_tmp / "too_fast.yaml", EXPERIMENT.replace("SPEED", str(speed)))
    code = main(["experiment", str(exp), "--out", "e", "--no-plots"])
    out = capsys.readouterr().out
    m = pd.read_csv(in_tmp / "e" / "measurements.csv")
    over = {r.train: r.value for r in m[m.quantity == "overspeed_max_kmh"].itertuples()}
    assert over["F"] == 0.0
    if healthy:
        assert over["L"] == 0.0 and code == 0 and "NOT HEALTHY" not in out
    else:
        assert over["L"] == pytest.approx(18.0, abs=0.5)  # 25 m/s on a 20 m/s track
        assert code == 1 and "NOT HEALTHY (above the permitted speed: L +18.0 km/h" in out
