"""A train's route position inside a junction: SUMO's internal lane is a point of the route.

Found by unseen9 (2026-11-28): ``vcsumo study capacity --line kestrel --convoy-sizes 2 --directions
up`` on a line of our own (25 km, 120 m EMUs, a station 1.2 km before a branch that merges into the
up track at km 16) failed every all-stops case but MB — FBS and VC cbc / cbf-cbc n=2: "no
sustainable headway found ... (trains hindered at every interval tried)" — even at a release
interval of 800 s.  Inside a junction (SUMO's internal lane, 23.7 m long at that merge) the loop
extrapolated the route position with the odometer; the route knows the junction as a point, so the
position ran up to 23.7 m past the next edge's start and jumped back when the train reached it
(16,012.0 -> 16,005.1 m).  The hindrance check interpolates the leader's speed at the follower's
positions; on that non-monotonic trace a train accelerating out of the station was found 0.23 m/s
slower than its identical leader at the same place (tolerance 0.1 m/s) at every interval.  Now the
position inside a junction stays at the next edge's start, and the hindrance check compares speeds
where a train first reaches each position (:func:`vcsumo.studies.min_headway.first_passes`): at a
0.2 s step a VC leader spends 3-4 steps at the junction point, and interpolating across them
compared its speed there with whichever sample came last (0.20 m/s apart; VC all-stops still
failed at 1,170 s).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tests.conftest import write
from vcsumo.cli.main import main

LINE = """name: merge_u9
km_start: 0.0
km_end: 9.0
tracks: double
start_elevation_m: 100
line_speed_kmh: 140
default_train: regional_emu160
stations:
  - {id: AAA, name: Ashby, km: 0.4, platform_length_m: 250, dwell_s: 40}
  - {id: BBB, name: Denby, km: 3.8, platform_length_m: 250, dwell_s: 40}
  - {id: ZZZ, name: Wexham, km: 8.6, platform_length_m: 250, dwell_s: 40}
gradients:
  - {from_km: 4.2, to_km: 6.5, permille: 15.0}
signalling: {block_length_m: 1500}
headway:
  measuring_points_km: [6.0]
  release_km: {up: 1.5, down: 7.5}
branches:
  - {id: mill, name: Mill branch, junction_km: 5.0, leaves_towards: start, length_m: 3000, speed_kmh: 100, diverging_speed_kmh: 60}
"""


def test_route_position_never_runs_back_through_a_junction(tmp_path):
    from vcsumo.line import load_line
    from vcsumo.rolling_stock import load_rolling_stock
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.sim.network import build_network
    from vcsumo.studies.capacity_route import Case, route_setup, unit_trains

    line = load_line(write(tmp_path / "line.yaml", LINE))
    net = build_network(line)
    stock = load_rolling_stock("regional_emu160")
    setup = route_setup(line, net, stock, "up", 0.5)
    units = unit_trains(net.topology, setup, stock, Case("up", "fbs", None, 1, "all-stops"), 1, 0.0, [])
    sim = simulate(Scenario(line, net, [units[0][0]], "fbs", step_length_s=0.5, full_outputs=False, trace_speeds=True), tmp_path / "run")
    s, _v = sim.speed_traces[units[0][0].id]
    steps = np.diff(np.asarray(s))
    assert steps.min() >= -1e-9, f"route position ran back by {-steps.min():.2f} m"
    assert s[-1] > 6000.0  # through the merge at km 5.0


def test_all_stops_capacity_found_with_a_station_before_a_merge(in_tmp):
    write(in_tmp / "line.yaml", LINE)
    rc = main(["study", "capacity", "--line", "line.yaml", "--directions", "up", "--patterns", "all-stops", "--controllers", "cbc",
               "--convoy-sizes", "2", "--workers", "1", "-q", "--out", "o"])
    rows = pd.read_csv(in_tmp / "o" / "capacity.csv").set_index("regime")
    assert rows["error"].isna().all(), rows["error"].to_dict()
    assert rows["healthy"].all() and rc == 0
    sumo = rows.loc[["fbs", "mb"]]
    dev = (sumo["headway_sim_s"] - sumo["headway_analytic_s"]).abs() / sumo["headway_analytic_s"]
    assert (dev < 0.03).all(), sumo[["headway_sim_s", "headway_analytic_s"]]


def test_no_sustainable_headway_says_why_in_words():
    """The failed case's error named the case as a Python repr ("for Case(direction='up', regime='fbs',
    controller=None, ...)") and not why the probes were hindered; it now says what hindered the last one."""
    import math

    from vcsumo.studies.min_headway import Probe

    pr = Probe(620.0, pd.DataFrame(columns=["measuring_point", "train", "time_s"]), {}, {"collisions": 0, "gap_violations": 0})
    pr.speed_deficit["end"] = 0.13
    pr.delays["end"] = 0.0
    assert pr.hindrance("end", 2.0) == "a later train ran slower than the first at the same place, 0.13 m/s beyond the tolerance"
    pr.speed_deficit["end"] = -0.1
    pr.delays["end"] = math.inf
    assert pr.hindrance("end", 2.0) == "a later train never reached the point"
    pr.delays["end"] = 0.5
    assert pr.hindrance("end", 2.0) == "" and pr.ok("end", 2.0)
