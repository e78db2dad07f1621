"""Tier 2 — the train ahead is never lost: a train whose front is crossing a junction (on one of
SUMO's internal lanes) stays the train ahead of the train behind it, for the supervision's
movement authority and for the health monitor's separation check.

Found on firenze_bologna (VC cbc convoys, all-stops): the convoy follower leaving Firenze Rifredi
crossed a junction for two 0.2 s steps; the next convoy's leader, 1.5 km behind and beyond SUMO's
look-ahead, was given the train beyond it (3.6 km away) as its train ahead, its authority jumped
by 2 km, it accelerated, and came 24 m inside its safe separation at 143 km/h.
"""

from __future__ import annotations

import pandas as pd
import pytest

from vcsumo.sim.loop import Scenario, simulate
from vcsumo.timetable import load_timetable, plan_trains


@pytest.mark.sumo
def test_the_train_ahead_does_not_vanish_while_it_crosses_a_junction(tmp_path, line_factory, network_factory):
    line = line_factory("regional_graded")
    net = network_factory("regional_graded")
    tt, p = load_timetable("all_stations", line)
    dt = 0.5
    trains = plan_trains(tt, p, line, net.topology, dt=dt)
    sim = simulate(Scenario(line, net, trains, "mb", step_length_s=dt, record_period_s=dt, full_outputs=True), tmp_path / "run")
    traj = pd.read_csv(tmp_path / "run" / "trajectories.csv")
    lost = []
    crossing = 0
    for tid, g in traj.sort_values("time_s").groupby("train"):
        lead = g.leader.fillna("").tolist()
        gap = g.gap_m.tolist()
        edge = g.edge.tolist()
        for k in range(1, len(lead) - 1):
            a, b, c = lead[k - 1], lead[k], lead[k + 1]
            if a and a == c and b != a and gap[k - 1] < 25000.0:
                lost.append((tid, float(g.time_s.iloc[k]), a, b))
        crossing += sum(1 for e in edge if str(e).startswith(":"))
    assert crossing > 0  # trains do cross junctions here (the case is exercised)
    assert not lost, lost[:10]
    assert sim.summary["healthy"], sim.summary
