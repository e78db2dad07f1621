"""The headway study takes ``--directions``, like the capacity and junction studies.

Found by unseen-studies (2026-12-01): on a line of our own with an 8 km −30 ‰ descent, a 1,500 t
train with 300 kN of tractive effort cannot restart on the climb in the down direction, so
``vcsumo study headway --line descent30 --train heavy1500`` stopped with
``error: infeasible: train heavy1500 cannot start on the 30.0 ‰ grade under it ... (down)`` and exit
status 2 — and there was no way to study the up direction alone, where the same train runs (the
capacity study, which has ``--directions``, measured it: FBS 568.4 s, MB 488.2 s).  The headway
study now has ``--directions`` (default both).
"""

from __future__ import annotations

import pandas as pd
import pytest

from tests.conftest import write
from vcsumo.cli.main import main

pytestmark = pytest.mark.sumo

LINE = """name: descent_hd
km_start: 0.0
km_end: 9.0
tracks: double
start_elevation_m: 400
line_speed_kmh: 100
default_train: heavy.yaml
stations:
  - {id: TOP, name: Top, km: 0.5, platform_length_m: 600, dwell_s: 60}
  - {id: BOT, name: Bottom, km: 8.5, platform_length_m: 600, dwell_s: 60}
gradients:
  - {from_km: 3.0, to_km: 6.0, permille: -25.0}
signalling: {block_length_m: 1500}
headway:
  measuring_points_km: [6.5]
  release_km: {up: 1.5, down: 7.5}
"""

HEAVY = """name: heavy_hd
length_m: 500.0
mass_kg: 1500000.0
rotating_mass_factor: 1.06
max_speed_kmh: 80.0
max_traction_n: 300000.0
max_power_w: 4000000.0
davis_a_n: 15000.0
davis_b_n_per_mps: 300.0
davis_c_n_per_mps2: 15.0
service_brake_decel_mps2: 0.35
emergency_brake_decel_mps2: 0.55
max_jerk_mps3: 0.3
traction_lag_s: 1.0
"""


def test_the_direction_a_train_can_run_is_studied_alone(in_tmp, capsys):
    write(in_tmp / "line.yaml", LINE)
    write(in_tmp / "heavy.yaml", HEAVY)
    assert main(["-q", "study", "headway", "--line", "line.yaml", "--regime", "mb", "--out", "both"]) == 2
    err = capsys.readouterr().err
    assert "cannot start on the 25.0 ‰ grade" in err and "(down)" in err and not (in_tmp / "both").exists()
    assert main(["-q", "study", "headway", "--line", "line.yaml", "--regime", "mb", "--directions", "up", "--out", "up"]) == 0
    rows = pd.read_csv(in_tmp / "up" / "headway.csv")
    assert rows.direction.tolist() == ["up"] and rows.healthy.all()
    assert abs(rows.deviation_pct.iloc[0]) < 5.0, rows[["headway_sim_s", "headway_analytic_s"]]
