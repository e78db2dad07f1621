"""A coupled follower with no packet at t = 0 (``known_at_start: false``) brakes until the first one
arrives, and that emergency brake is counted (unseen round of 2026-11-28: checked, kept).

Its guard takes the predecessor as standing at its front: the safe choice.  The brake is applied (a
regional EMU at 20 m/s: one 0.2 s step, 20.00 → 19.96 m/s), so it is one emergency activation;
with ``known_at_start: true`` (the safety campaign's offline loop; the SUMO loop links a convoy at
its start) there is none."""

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write

EXPERIMENT = """
name: start_cbc
step_s: 0.2
duration_s: 10.0
seeds: [1]
record_every: 1
known_at_start: KNOWN
track:
  straight: {length_m: 20000.0, speed_limit_mps: 40.0}
trains:
  - {id: L, stock: regional_emu160, position_m: 6000.0, speed_mps: 20.0}
  - {id: F, stock: regional_emu160, gap_m: coupled, speed_mps: 20.0, controller: cbc}
leader:
  driver: speed_tracker
  schedule: [[0.0, 20.0]]
channel: {period_s: 0.5, delay_s: 0.1, exp_rate_per_s: 5.0, loss_probability: 0.01}
"""


@pytest.mark.parametrize("known", [False, True])
def test_a_follower_without_leader_data_brakes_and_it_is_counted(in_tmp, capsys, known):
    exp = write(in_tmp / "start.yaml", EXPERIMENT.replace("KNOWN", str(known).lower()))
    assert main(["experiment", str(exp), "--out", "e", "--no-plots"]) == 0
    t = pd.read_csv(in_tmp / "e" / "trajectories.csv")
    f = t[t.train == "F"].reset_index(drop=True)
    m = pd.read_csv(in_tmp / "e" / "measurements.csv")
    count = m[(m.train == "F") & (m.quantity == "emergency_activations")].value.iloc[0]
    first_packet = f[f.packet_received.astype(bool)].time_s.min()
    before = f[f.time_s < first_packet]
    if known:
        assert count == 0 and not f.emergency.astype(bool).any()
    else:
        assert len(before) >= 1 and before.emergency.astype(bool).all() and (before.force_cmd_n < 0).all()
        assert count == 1 and not f[f.time_s >= first_packet].emergency.astype(bool).any()
        assert f.speed_mps.iloc[1] < 20.0
