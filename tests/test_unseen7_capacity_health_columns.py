"""A capacity row that is not healthy says why: every counter the run's verdict rests on is a column.

Found by unseen7 (2026-11-28): ``vcsumo study capacity`` on a steep line of our own (22 ‰ climb from
the release point, a 600 m, 1,200 t freight train, convoys of 2, cbf-cbc): the VC row was
``healthy`` False with every health column 0 (gap violations, collisions, stops skipped, short
dwells, overspeed, braking beyond service, overruns, SUMO emergency stops) and the terminal said only
"not healthy: up non-stop vc cbf-cbc n=2".  The run was unhealthy for 3 real SUMO emergency brakings
(the CBF's emergency brake on the climb, 0.722 m/s² against a service limit of 0.671 m/s²), a counter
the row did not carry.  The rows now carry ``sumo_emergency_brakings``, ``sumo_stop_warnings`` and
``teleports``, and the terminal's note names the counters that are not 0.
"""

from __future__ import annotations

import pandas as pd

from tests.conftest import write
from vcsumo.cli.commands import UNHEALTHY
from vcsumo.cli.main import main
from vcsumo.studies.capacity import CAPACITY_COLUMNS

LINE = """name: steep_u7
km_start: 0.0
km_end: 22.0
tracks: double
start_elevation_m: 300
line_speed_kmh: 120
default_train: freight.yaml
stations:
  - {id: ASH, name: Ashby, km: 0.8, platform_length_m: 750, dwell_s: 60}
  - {id: BRN, name: Barnhill, km: 6.0, platform_length_m: 750, dwell_s: 40}
  - {id: CRG, name: Craig, km: 12.5, platform_length_m: 750, dwell_s: 40}
  - {id: DAL, name: Dale, km: 21.0, platform_length_m: 750, dwell_s: 60}
speed_limits:
  - {from_km: 0.0, to_km: 1.5, speed_kmh: 60}
  - {from_km: 10.0, to_km: 15.0, speed_kmh: 80}
  - {from_km: 20.0, to_km: 22.0, speed_kmh: 60}
gradients:
  - {from_km: 2.0, to_km: 8.5, permille: 22.0}
  - {from_km: 9.0, to_km: 15.5, permille: -25.0}
  - {from_km: 16.0, to_km: 19.0, permille: 20.0}
signalling: {block_length_m: 600}
headway:
  measuring_points_km: [5.0, 14.0]
  release_km: {up: 3.5, down: 19.8}
"""

FREIGHT = """name: freight_u7
length_m: 600.0
mass_kg: 1200000.0
rotating_mass_factor: 1.08
max_speed_kmh: 100.0
max_traction_n: 420000.0
max_power_w: 4000000.0
davis_a_n: 12000.0
davis_b_n_per_mps: 150.0
davis_c_n_per_mps2: 8.0
service_brake_decel_mps2: 0.40
emergency_brake_decel_mps2: 0.55
max_jerk_mps3: 0.5
traction_lag_s: 1.0
"""


def test_every_counter_of_the_run_verdict_is_a_capacity_column():
    assert {k for k, _ in UNHEALTHY} <= set(CAPACITY_COLUMNS)


def test_an_unhealthy_capacity_row_names_its_counter(in_tmp, capsys):
    write(in_tmp / "line.yaml", LINE)
    write(in_tmp / "freight.yaml", FREIGHT)
    rc = main(["study", "capacity", "--line", "line.yaml", "--convoy-sizes", "2", "--directions", "up", "--patterns", "non-stop",
               "--controllers", "cbf-cbc", "--workers", "1", "--out", "o"])
    rows = pd.read_csv(in_tmp / "o" / "capacity.csv")
    out = " ".join(capsys.readouterr().out.split())
    counters = [k for k, _ in UNHEALTHY]
    for _, r in rows.iterrows():
        nonzero = [k for k in counters if r[k] != 0]
        assert bool(r["healthy"]) == (not nonzero), (r["regime"], nonzero)  # not healthy exactly when a counter says so
    vc = rows[rows["regime"] == "vc"].iloc[0]
    if not vc["healthy"]:  # (measured: 3 real SUMO emergency brakings of the CBF's emergency brake on the climb)
        assert rc == 1 and vc["sumo_emergency_brakings"] > 0
        assert "not healthy: up non-stop vc cbf-cbc n=2 (sumo_emergency_brakings" in out, out
