"""Sixth round of unseen inputs — an offline experiment of our own: five heterogeneous trains (a 90 km/h
DMU leading a regional EMU, a DMU, an HCMC metro train and a regional EMU) on a 20 permille descent,
one follower per registered stack (mpc, cbc, cbf-mpc, cbf-cbc), all placed ``gap_m: coupled``.

Defect found: ``coupled`` put a ``cbf-mpc`` follower at the NMPC's own spacing (110.7 m at 20 m/s),
inside its CBF's unsafe set: the true barrier was +43.5 m at t = 0 (+51.0 m for a regional EMU behind
the DMU), so every ``cbf-mpc`` experiment started ``coupled`` was NOT HEALTHY (exit 1) — for the
placement vcsumo chose, not for anything the stack did.  Now a supervised follower starts where its
supervisor lets its controller sit: at least where the barrier on those states (holding its speed) is
−1 m (the regional EMU 166.1 m, the metro train 158.7 m; true barrier at most −4.4 m, healthy).
``cbf-cbc`` was not affected (cbc's spacing, 249.8 m, lies outside the barrier)."""

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write
from .test_unseen6_junction_fouling import DMU

EXPERIMENT = """
name: coupled_cbf
step_s: 0.2
duration_s: 20.0
seeds: [1]
record_every: 5
track:
  straight: {length_m: 20000.0, speed_limit_mps: 25.0, grades: [{from_m: 3000.0, permille: -20.0}]}
trains:
  - {id: L, stock: dmu90.yaml, position_m: 6000.0, speed_mps: 20.0}
  - {id: F, stock: regional_emu160, gap_m: coupled, speed_mps: 20.0, controller: CTRL}
leader:
  driver: speed_tracker
  schedule: [[0.0, 20.0]]
channel: {period_s: 0.5, delay_s: 0.1, exp_rate_per_s: 5.0, loss_probability: 0.01}
"""


@pytest.mark.parametrize("controller", ["cbf-mpc", "cbf-cbc"])
def test_a_coupled_start_lies_outside_the_supervisors_barrier(in_tmp, capsys, controller):
    write(in_tmp / "dmu90.yaml", DMU)
    exp = write(in_tmp / "coupled.yaml", EXPERIMENT.replace("CTRL", controller))
    code = main(["experiment", str(exp), "--out", "e", "--no-plots"])
    out = capsys.readouterr().out
    m = pd.read_csv(in_tmp / "e" / "measurements.csv")
    t = pd.read_csv(in_tmp / "e" / "trajectories.csv")
    first = t[(t.train == "F") & t.true_barrier_m.notna()].iloc[0]
    assert first.true_barrier_m < 0.0, first  # main: +51.0 m at t = 0 under cbf-mpc
    assert m[(m.train == "F") & (m.quantity == "true_barrier_max_m")].value.iloc[0] <= 0.0
    assert code == 0 and "NOT HEALTHY" not in out
