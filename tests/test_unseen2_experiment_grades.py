"""Tier 2 — an offline experiment on a user's own graded line (found trying vcsumo on a mountain
line nobody tuned for): a follower placed ``gap_m: coupled`` on a 30 ‰ descent sat at its
*level-track* spacing (199 m), 75 m short of the spacing its own reference keeps there (274 m, the
certified spacing follows the gradients under the follower), so a cbf-cbc follower started 52 m
inside its barrier and the run was reported NOT HEALTHY for the placement, not for the control."""

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write

LINE = """
name: descent
km_start: 0.0
km_end: 8.0
line_speed_kmh: 160
default_train: regional_emu160
stations:
  - {id: TOP, name: Top, km: 0.3, platform_length_m: 250}
  - {id: FOOT, name: Foot, km: 7.7, platform_length_m: 250}
gradients:
  - {from_km: 1.0, to_km: 7.0, permille: -30.0}
signalling: {block_length_m: 1500}
"""
EXPERIMENT = """
name: descent_start
step_s: 0.1
duration_s: 10.0
seeds: [1]
record_every: 1
track:
  line: {line: descent.yaml, direction: up}
trains:
  - {id: L, stock: etr1000, position_m: 4000.0, speed_mps: 20.0}
  - {id: F, stock: regional_emu160, gap_m: coupled, speed_mps: 20.0, controller: CONTROLLER}
leader:
  driver: speed_tracker
  schedule: [[0.0, 20.0]]
"""


@pytest.mark.parametrize("controller", ["cbc", "cbf-cbc"])
def test_a_coupled_follower_starts_on_its_reference_on_a_descent(in_tmp, capsys, controller):
    write(in_tmp / "descent.yaml", LINE)
    exp = write(in_tmp / "descent_start.yaml", EXPERIMENT.replace("CONTROLLER", controller))
    code = main(["experiment", str(exp), "--out", "e"])
    out = capsys.readouterr().out
    traj = pd.read_csv(in_tmp / "e" / "trajectories.csv")
    f0 = traj[(traj.train == "F") & (traj.time_s == 0.0)].iloc[0]
    # on the descent the spacing is longer than on the level: placed where its own reference is
    assert f0.gap_front_to_rear_m == pytest.approx(f0.gap_ref_m, abs=1.0)
    if controller == "cbf-cbc":
        assert f0.true_barrier_m <= 0.0  # inside the safe set from the start
        assert (traj[traj.train == "F"].true_barrier_m.dropna() <= 0.0).all()
    assert "NOT HEALTHY" not in out and code == 0, out
