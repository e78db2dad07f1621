"""Tier 2 — a convoy follower timetabled *before* its leader at the same origin (unseen-networks,
2026-12-01).

Found by ``vcsumo batch`` on a network of our own: random primary delays put a convoy leader 7 min
44 s behind its follower at their common origin (outside the 5 min in which a convoy leaves
together), and an open-end origin let a 75 m follower timetabled 90 s before its 202 m leader keep
its own time.  In both the follower is kept out of the network until its predecessor has passed
(:mod:`vcsumo.sim.convoy_insertion`), but SUMO, which inserts one train per edge and step in
departure order, then never tried the predecessor either: **neither train ever departed** (0 of 2
arrived, the run went on for 7.5 simulated hours) and nothing warned.  Now such a follower departs
behind its predecessor (with it where the departure track holds both, else once it has cleared its
position), later than its timetable, warned of with both times."""

import warnings

import pytest

from vcsumo.network_file import load_network
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import make_vc_driver
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write
from .test_network_file import make_network

pytestmark = pytest.mark.sumo

CASES = {
    # the follower 6.5 min before its leader at a station whose platform holds both
    "station_6min": ("AST", "AST", "etr1000", "07:06:00", "06:59:30"),
    # an open end: the follower (75 m) 90 s before its leader (202 m)
    "open_end_90s": ("alpha:start", "alpha:start", "regional_emu160", "07:01:30", "07:00:00"),
}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    net = load_network(make_network(tmp_path_factory.mktemp("net")))
    return net, build_network(net)


@pytest.mark.parametrize("case", CASES)
def test_a_follower_timetabled_before_its_leader_departs_behind_it(built, tmp_path, case):
    net, b = built
    origin_l, origin_f, stock_f, dep_l, dep_f = CASES[case]
    tt_text = f"""
name: first
line: twolines
services:
  - {{id: L, train: etr1000, origin: "{origin_l}", destination: BEND, departure: "{dep_l}"}}
  - {{id: F, train: {stock_f}, origin: "{origin_f}", destination: SPUR, departure: "{dep_f}"}}
convoys:
  - {{id: C, services: [L, F]}}
"""
    tt, path = load_timetable(write(tmp_path / "first.yaml", tt_text), net)
    trains = plan_trains(tt, path, net, b.topology, dt=0.2)
    timetabled = {t.id: t.depart_s for t in trains}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        drv = make_vc_driver(tt, path, trains, "cbc", 0.2, seed=3)
    said = [str(w.message) for w in caught if "convoy follower F" in str(w.message)]
    assert len(said) == 1 and "before L" in said[0], [str(w.message) for w in caught]
    end = timetabled["L"] + 1800.0  # both need about 10 min; before, neither had departed by then
    res = simulate(Scenario(net, b, trains, "vc", step_length_s=0.2, driver=drv, end_time_s=end), tmp_path / "out")
    s = res.summary
    assert s["trains_arrived"] == 2, res.trains[["train", "departure_s", "arrival_s"]].to_string()
    assert s["collisions"] == 0 and s["gap_violations"] == 0 and s["teleports"] == 0 and s["healthy"]
    by = res.trains.set_index("train")
    # the follower entered behind its leader: never before it, and later than its timetable
    assert by.loc["F", "departure_s"] >= by.loc["L", "departure_s"]
    assert by.loc["F", "departure_s"] > timetabled["F"]
    # what the warning promised is what happened: the follower left when the plan said
    assert by.loc["F", "scheduled_departure_s"] == pytest.approx(by.loc["F", "departure_s"], abs=1.0)
    traj = res.trajectories
    f = traj[traj.train == "F"]
    assert set(f.section) >= {"alpha.main", "beta.main", "beta.spur"}
