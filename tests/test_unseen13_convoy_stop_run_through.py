"""Tier 2 — a convoy follower stopping at a platform its predecessor runs through (unseen-networks,
2026-12-01).

Found on a network of our own (a 400 m freight leading a regional EMU down a 30 ‰ mountain line and
on along a valley line, the EMU ending its run at Valla, the freight running through it): as the
freight's front entered Valla's platform at 80 km/h, the VC driver took its *rear* for where SUMO
would stop the follower ("behind a predecessor standing in the platform") although the freight was
not stopping there, gave the controller a stop 135 m ahead, and the EMU braked at its emergency rate
for 7 s (22.2 → 14.2 m/s) with 0.9 km to its own stopping point, then took traction again.  Only a
predecessor that stops at the platform (or stands in it) is a place to stop behind."""

import pandas as pd
import pytest

from vcsumo.network_file import load_network
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import make_vc_driver
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write
from .test_network_file import make_network

pytestmark = pytest.mark.sumo

TT = """
name: through
line: twolines
services:
  - {id: L, train: etr1000, origin: AST, destination: "beta:end", departure: "07:00"}
  - {id: F, train: regional_emu160, origin: AST, destination: BEND, departure: "07:00"}
convoys:
  - {id: C, services: [L, F]}
"""


def test_follower_does_not_stop_behind_a_predecessor_running_through_its_platform(tmp_path):
    net = load_network(make_network(tmp_path / "net"))
    built = build_network(net)
    tt, path = load_timetable(write(tmp_path / "t.yaml", TT), net)
    trains = plan_trains(tt, path, net, built.topology, dt=0.2)
    drv = make_vc_driver(tt, path, trains, "cbc", 0.2, seed=3)
    res = simulate(Scenario(net, built, trains, "vc", step_length_s=0.2, driver=drv), tmp_path / "out")
    drv.write_report(tmp_path / "out")
    s = res.summary
    assert s["trains_arrived"] == 2 and s["collisions"] == 0 and s["gap_violations"] == 0 and s["healthy"]
    st = res.stop_events.set_index("train")
    assert st.loc["F", "station"] == "BEND"
    rec = pd.read_csv(tmp_path / "out" / "vc_followers.csv")
    assert len(rec[rec.train == "F"]) > 100  # it ran coupled
    # the follower never braked beyond its service brake: its stop was in reach of the service brake
    # all along, and the predecessor never stood in front of it
    assert not rec.emergency.any(), rec[rec.emergency].head().to_string()
    traj = res.trajectories
    f = traj[traj.train == "F"]
    assert (-f.accel_mps2).max() <= trains[1].stock.service_brake_decel_mps2 + 0.15
