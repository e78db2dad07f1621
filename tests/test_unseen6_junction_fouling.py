"""Sixth round of unseen inputs — a slow line of our own: 90 km/h two-car DMUs (45 m, 0.7 m/s²
service brake) on a 100 km/h double-track valley line with 200 m platforms and a 40 km/h turnout onto
a spur (the junction study's down merge: the main-line train first, the spur train merging behind it).

Defect found: while the train ahead still fouls the junction (its rear on the other track), the loop
gives the merging train the gap to the junction, a fixed point (``MergeLocking.fouling_gap``), but the
supervision built the end of authority from it as from a rear that moves: it took off how far the
train ahead had run since its last position report (MB: one every 2 s).  With the main-line train
through the junction at 25 m/s, the end of authority ran towards the spur train at 25 + 6 = 31 m/s
(46.5 → −3.1 m in 1.6 s), the spur train braked at its full service brake and the health monitor
counted a movement-authority overrun of 3.1 m: the junction study's VC case (cbc, Δ = 0) was reported
NOT HEALTHY for an end of authority that never existed.  Now a gap to the fouling point is kept where
it is (``Supervisor.permitted(..., fouling=True)``): the end of authority stays at the fouling point
less the margin, as the approach locking's own."""

from pathlib import Path

import pytest

from vcsumo.line import load_line
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.sim.network import build_network
from vcsumo.studies.junction.model import Case, build_setup, simulate_pair, solo_runs

from .conftest import write

pytestmark = pytest.mark.sumo

DMU = """name: dmu90
title: Slow 2-car DMU, 45 m, 90 km/h (unseen6) [A]
length_m: 45.0
mass_kg: 95000.0
rotating_mass_factor: 1.08
max_speed_kmh: 90.0
max_traction_n: 90000.0
max_power_w: 700000.0
davis_a_n: 1500.0
davis_b_n_per_mps: 25.0
davis_c_n_per_mps2: 3.0
service_brake_decel_mps2: 0.7
emergency_brake_decel_mps2: 1.1
max_jerk_mps3: 0.8
traction_lag_s: 0.5
uncertainty:
  mass_kg: {low: 85000.0, high: 105000.0}
  service_brake_decel_mps2: {low: 0.65, high: 0.75}
  davis_a_n: {low: 1350.0, high: 1650.0}
  davis_b_n_per_mps: {low: 22.0, high: 28.0}
  davis_c_n_per_mps2: {low: 2.7, high: 3.3}
  max_accel_mps2: {low: 0.8, high: 1.0}
  max_power_w: {low: 665000.0, high: 735000.0}
"""

SPUR_LINE = """name: dale_spur
title: 14 km of a slow valley line with a 40 km/h spur junction (unseen6) [A]
km_start: 0.0
km_end: 14.0
tracks: double
start_elevation_m: 400
line_speed_kmh: 100
default_train: dmu90.yaml
stations:
  - {id: ASH, name: Ash, km: 0.3, platform_length_m: 200, dwell_s: 40}
  - {id: YEW, name: Yew, km: 13.7, platform_length_m: 200, dwell_s: 40}
signalling: {block_length_m: 1200}
branches:
  - {id: spur, name: Spur, junction_km: 8.0, leaves_towards: end, length_m: 5000, speed_kmh: 80, diverging_speed_kmh: 40}
"""


def test_merging_train_keeps_its_authority_at_the_fouling_point(tmp_path):
    write(tmp_path / "dmu90.yaml", DMU)
    line = load_line(write(tmp_path / "line.yaml", SPUR_LINE))
    stock = load_rolling_stock(str(tmp_path / "dmu90.yaml"))
    setup = build_setup(line, build_network(line, None), stock, "spur", "down", 12000.0, 6000.0)
    setup.window_m = 5000.0
    solo = solo_runs(setup, "mb", 0.2, tmp_path / "solo", 42)
    solo_times = {r: solo[r].passages["M"][r] - solo[r].departures[r] for r in ("main", "branch")}
    case = Case("spur", "down", "main", "vc", "cbc", "braking-curve")
    run = simulate_pair(setup, case, 0.0, solo_times, tmp_path / "run", 0.2, 42)  # both at the merge at once
    s = run.summary
    # main: 1 overrun of 3.13 m (an end of authority running towards the spur train at 31 m/s), not healthy
    assert s["authority_overruns"] == 0
    assert s["healthy"], s
    assert s["trains_arrived"] == 2 and s["collisions"] == 0 and s["gap_violations"] == 0
    assert s["min_margin_m"] >= 0.0
