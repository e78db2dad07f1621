"""Tier 1 — defects found by running a network nobody tuned for (issue 14): three made-up lines
(a 30 km main line with a 22 ‰ climb and a tunnel, a 12 km branch joined mid-line, a coast line
whose end runs into the main line's end), a home-made freight train and timetables written as a user
would, next to the network in a folder of their own."""

import warnings

import pytest

from vcsumo.errors import InputError
from vcsumo.line import load_line
from vcsumo.network_file import load_network
from vcsumo.network_topology import build_network_topology
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write

MAIN = """
name: ridge
km_start: 0.0
km_end: 30.0
line_speed_kmh: 200
default_train: etr1000
stations:
  - {id: PRT, name: Portlow, km: 0.5, platform_length_m: 450}
  - {id: RDG, name: Ridgetop, km: 29.4, platform_length_m: 420}
gradients:
  - {from_km: 17.0, to_km: 24.0, permille: 22.0}
signalling: {block_length_m: 1500}
"""
COAST = """
name: coast
km_start: 100.0
km_end: 118.0
line_speed_kmh: 160
stations:
  - {id: CST, name: Coastby, km: 100.4, platform_length_m: 500}
  - {id: EDG, name: Edge, km: 117.8, platform_length_m: 400}
signalling: {block_length_m: 1500}
"""
NET = """
name: ridge_net
lines:
  - {line: ridge.yaml}
  - {line: coast.yaml}
joins:
  - id: ridgetop_join
    end: {line: coast, at: end}
    meets: {line: ridge, km: 30.0}
"""
FREIGHT = """
name: freight100
length_m: 450.0
mass_kg: 1000000.0
rotating_mass_factor: 1.08
max_speed_kmh: 100.0
max_traction_n: 300000.0
max_power_w: 4200000.0
davis_a_n: 14000.0
davis_b_n_per_mps: 100.0
davis_c_n_per_mps2: 8.0
service_brake_decel_mps2: 0.35
emergency_brake_decel_mps2: 0.5
max_jerk_mps3: 0.5
traction_lag_s: 1.0
"""
TT = """
name: t
line: ridge_net
services:
  - {id: F1, train: freight.yaml, origin: "coast:start", destination: "ridge:start", departure: "08:00"}
"""


def _net(tmp_path):
    write(tmp_path / "ridge.yaml", MAIN)
    write(tmp_path / "coast.yaml", COAST)
    return load_network(write(tmp_path / "network.yaml", NET))


def test_platform_ending_exactly_at_a_line_end(tmp_path):
    """A platform that ends at the end of the line (117.8 km + 200 m = 118.0 km) is accepted: the
    check asked to "end it there", where it already ended (floating-point remainder of 1e-14 km)."""
    ln = load_line(write(tmp_path / "coast.yaml", COAST))
    assert ln.station("EDG")[1].km == pytest.approx(117.8)
    short = COAST.replace("km: 117.8, platform_length_m: 400", "km: 117.795, platform_length_m: 400")
    with pytest.raises(InputError, match="within 10 m of the section end"):
        load_line(write(tmp_path / "c2" / "coast.yaml", short))


def test_rolling_stock_file_next_to_the_timetable(tmp_path, monkeypatch):
    """A timetable names its own train file by a path relative to itself (as a network file names its
    line files), whatever folder vcsumo runs from."""
    net = _net(tmp_path)
    write(tmp_path / "freight.yaml", FREIGHT)
    monkeypatch.chdir(write(tmp_path / "elsewhere" / "x", "").parent)
    tt, path = load_timetable(write(tmp_path / "t.yaml", TT), net)
    trains = plan_trains(tt, path, net, build_network_topology(net))
    assert trains[0].stock.name == "freight100" and trains[0].stock.length_m == 450.0


def test_missing_rolling_stock_file_says_where_it_was_looked_for(tmp_path):
    net = _net(tmp_path)
    tt, path = load_timetable(write(tmp_path / "t.yaml", TT), net)
    with pytest.raises(InputError) as exc:
        plan_trains(tt, path, net, build_network_topology(net))
    msg = str(exc.value)
    assert msg.startswith(f"{path}: services[0].train: train file 'freight.yaml' not found") and str(tmp_path) in msg


CONVOY = """
name: c
line: ridge_net
services:
  - {id: L, train: regional_emu160, origin: CST, destination: PRT, departure: "08:00", stops: [{station: EDG}, {station: RDG}]}
  - {id: F, train: etr1000, origin: CST, destination: PRT, departure: "08:00:20", stops: [{station: EDG}, {station: RDG}]}
convoys:
  - {id: C, services: [L, F]}
"""


def test_convoy_that_cannot_stand_in_a_shared_platform_is_warned(tmp_path):
    """A regional (75 m) leading an ETR 1000 (202 m) 72 m behind needs 349 m of platform where both
    stop: Edge's 400 m holds them, a 240 m one does not — the follower then waits outside the platform
    until its leader has left, and the convoy falls apart at every such stop (seen as 'not formed: at
    the line's permitted speed', with nothing naming the platform).  vc says so before it runs."""
    from vcsumo.sim.vc_driver import make_vc_driver

    net = _net(tmp_path)
    topo = build_network_topology(net)
    tt, path = load_timetable(write(tmp_path / "c.yaml", CONVOY), net)
    trains = plan_trains(tt, path, net, topo)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # 400 m: no warning
        make_vc_driver(tt, path, trains, "cbc", 0.2)
    write(tmp_path / "coast.yaml", COAST.replace("km: 117.8, platform_length_m: 400", "km: 117.88, platform_length_m: 240"))
    net = load_network(tmp_path / "network.yaml")
    trains = plan_trains(tt, path, net, build_network_topology(net))
    with pytest.warns(UserWarning, match=r"convoy L\+F: F \(etr1000, 202 m\) cannot stand behind L \(regional_emu160, 75 m\) in the platform of EDG \(240 m\): 349 m needed"):
        make_vc_driver(tt, path, trains, "cbc", 0.2)


LAKE = """
name: lake
km_start: 0.0
km_end: 12.0
line_speed_kmh: 140
stations:
  - {id: LKS, name: Lakeside, km: 11.6, platform_length_m: 250}
signalling: {block_length_m: 1200}
"""


def test_no_route_says_what_the_train_can_reach(tmp_path):
    """The lake line joins the main line at km 15 running alongside it towards its end: a train from
    Lakeside merges towards Portlow and cannot reach Coastby without reversing.  The error says why
    and what it can reach."""
    write(tmp_path / "ridge.yaml", MAIN)
    write(tmp_path / "coast.yaml", COAST)
    write(tmp_path / "lake.yaml", LAKE)
    net = load_network(write(tmp_path / "network.yaml", NET.replace("  - {line: coast.yaml}\n", "  - {line: coast.yaml}\n  - {line: lake.yaml}\n") + """
  - id: forkham_jn
    end: {line: lake, at: start}
    meets: {line: ridge, km: 15.0}
    towards: end
    diverging_speed_kmh: 80
"""))
    topo = build_network_topology(net)
    tt, path = load_timetable(write(tmp_path / "t.yaml", TT.replace('train: freight.yaml, origin: "coast:start"', "train: etr1000, origin: LKS")
                                    .replace('destination: "ridge:start"', "destination: CST")), net)
    with pytest.raises(InputError, match=r"services\[0\].destination: no route from 'LKS' to 'CST' on ridge_net \(infeasible\): trains do not reverse.*"
                                         r"from there a train reaches PRT, ridge:start, lake:end$"):
        plan_trains(tt, path, net, topo)


DBL = """
name: dbl
km_start: 0.0
km_end: 6.0
line_speed_kmh: 160
stations:
  - {id: DST, name: Doubleton, km: 0.5, platform_length_m: 300}
signalling: {block_length_m: 1500}
"""
SGL = """
name: sgl
km_start: 0.0
km_end: 16.0
tracks: single
line_speed_kmh: 160
stations:
  - {id: SGE, name: Single End, km: 15.6, platform_length_m: 300}
  - {id: SGJ, name: Single Junction, km: 0.2, platform_length_m: 300}
signalling: {block_length_m: 1500}
"""
DS_NET = """
name: ds
lines:
  - {line: dbl.yaml}
  - {line: sgl.yaml}
joins:
  - id: change
    end: {line: sgl, at: start}
    meets: {line: dbl, km: 6.0}
"""
HEAD_ON = """
name: head_on
line: ds
services:
  - {id: A, train: regional_emu160, origin: SGE, destination: DST, departure: 0}
  - {id: B, train: regional_emu160, origin: DST, destination: SGE, departure: 60, stops: [{station: SGJ}]}
"""


SINGLE_TRACK_FOUND = ("found here: opposing trains in motion on a single track used both ways stood facing each other to the end of the "
                      "run (reported: not arrived). vcsumo's approach locking (sim/interlocking.merge_nodes) took every node of a single "
                      "track for a merging junction and locked the opposing trains against each other there, while SUMO held the other "
                      "back; counting only true merges ended the deadlock but let them pass through each other unreported where a "
                      "single-track branch leaves its junction as two one-way edges. Now merge_nodes counts only nodes whose incoming "
                      "tracks run on over a common edge, sim/single_track_lock gives each stretch to one direction at a time (the other "
                      "train's authority ends in front of it, and SUMO is constrained the same way), and the loop counts opposing trains "
                      "meeting on single track as a collision")


def _ds(tmp_path):
    write(tmp_path / "dbl.yaml", DBL)
    write(tmp_path / "sgl.yaml", SGL)
    return load_network(write(tmp_path / "network.yaml", DS_NET))


def test_single_track_end_joined_to_double_track_stays_single(tmp_path):
    """Where a single-track line's end runs into a double-track line, its last edge pair (here the
    platform of SGJ) is still one track used both ways: the two edges join the same two nodes (SUMO
    makes them a bidirectional pair, so its signals keep opposing trains apart), and the double
    track's two tracks converge on that node."""
    net = _ds(tmp_path)
    topo = build_network_topology(net)
    for e in topo.edges.values():
        if e.track.startswith("sgl."):
            twin = topo.edges[e.bidi]
            assert (twin.from_node, twin.to_node) == (e.to_node, e.from_node), e.id
    node = topo.named_nodes["change"]
    assert len(node) == 1
    dbl_ends = [e for e in topo.edges.values() if e.track.startswith("dbl.") and node[0] in (e.from_node, e.to_node)]
    assert sorted(e.direction for e in dbl_ends) == ["down", "up"]


@pytest.mark.sumo
def test_no_head_on_deadlock_entering_a_single_track_line(tmp_path):
    """B leaves the double-track line for the single track while A runs towards it on the single
    track: B must wait at the join until A has left the single track; both arrive, and they never
    pass each other on it (0 of 2 arrived: they stood facing each other until the end of the run;
    SINGLE_TRACK_FOUND)."""
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.sim.network import build_network

    net = _ds(tmp_path)
    built = build_network(net)
    tt, path = load_timetable(write(tmp_path / "h.yaml", HEAD_ON), net)
    trains = plan_trains(tt, path, net, built.topology)
    res = simulate(Scenario(net, built, trains, "fbs", step_length_s=0.5), tmp_path / "out")
    s = res.summary
    assert s["trains_arrived"] == 2 and s["stops_served"] == s["stops_scheduled"] and s["collisions"] == 0
    assert s["healthy"]
    _never_pass(tmp_path / "out", "sgl.main")


def _never_pass(out, section):
    """A runs down the single track (decreasing km), B up it: B is never beyond A there."""
    import pandas as pd

    tr = pd.read_csv(out / "trajectories.csv")
    a = tr[tr.train == "A"].set_index("time_s")
    b = tr[tr.train == "B"].set_index("time_s")
    both = a[["section", "km"]].join(b[["section", "km"]], lsuffix="_a", rsuffix="_b", how="inner")
    on = both[(both.section_a == section) & (both.section_b == section)]
    assert (on.km_b < on.km_a).all(), on[on.km_b >= on.km_a].head()


DSB = """
name: dsb
km_start: 0.0
km_end: 8.0
line_speed_kmh: 160
stations:
  - {id: DST, name: Doubleton, km: 0.5, platform_length_m: 300}
signalling: {block_length_m: 1500}
branches:
  - id: sg
    name: Single branch
    junction_km: 6.0
    leaves_towards: end
    length_m: 16000
    speed_kmh: 160
    diverging_speed_kmh: 160
    tracks: single
    stations:
      - {id: SGE, name: Single End, km: 15.6, platform_length_m: 300}
    block_length_m: 3000
"""
DSB_HEAD_ON = """
name: h
line: dsb
services:
  - {id: A, train: regional_emu160, origin: SGE, destination: DST, departure: 0}
  - {id: B, train: regional_emu160, origin: DST, destination: SGE, departure: 60}
"""


@pytest.mark.sumo
def test_opposing_trains_never_pass_each_other_on_a_single_track_branch(tmp_path):
    """A single-track branch leaving a double-track line: B waits on the main line until A has
    left the branch (they passed through each other on the branch's first edge pair, two one-way
    edges; SINGLE_TRACK_FOUND)."""
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.sim.network import build_network

    line = load_line(write(tmp_path / "dsb" / "line.yaml", DSB))
    built = build_network(line)
    tt, path = load_timetable(write(tmp_path / "h.yaml", DSB_HEAD_ON), line)
    res = simulate(Scenario(line, built, plan_trains(tt, path, line, built.topology), "fbs", step_length_s=0.5), tmp_path / "out")
    assert res.summary["trains_arrived"] == 2
    _never_pass(tmp_path / "out", "sg")


def test_planned_meeting_on_single_track_is_warned(tmp_path):
    """No crossing loops are modelled: two trains timetabled onto the same single track in opposite
    directions at once cannot pass.  The plan says so, naming both trains, the track and the times
    (A enters the single track at once, B reaches it 3.5 min later while A is still on it); B leaving
    after A has cleared it, or a second train following A, is no meeting."""
    net = _ds(tmp_path)
    topo = build_network_topology(net)
    tt, path = load_timetable(write(tmp_path / "h.yaml", HEAD_ON), net)
    with pytest.warns(UserWarning, match=r"trains A and B are timetabled onto the same single track in opposite directions at the same time "
                                         r"\(A on sgl.main km 0–15.75 00:00:00–00:0\d:\d\d, B on sgl.main km 0–15.75 00:03:\d\d–"):
        plan_trains(tt, path, net, topo)
    later = HEAD_ON.replace("departure: 60", "departure: 600") + "  - {id: C, train: regional_emu160, origin: SGE, destination: DST, departure: 180}\n"
    tt, path = load_timetable(write(tmp_path / "later.yaml", later), net)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plan_trains(tt, path, net, topo)


@pytest.mark.parametrize("station, end", [("CST", "origin"), ("PRT", "destination")])
def test_origin_or_destination_listed_as_a_stop(tmp_path, station, end):
    """The destination listed among the stops gave two stops at the same platform (60 s, then the
    1 s arrival), the origin a message about running order; both are named for what they are."""
    net = _net(tmp_path)
    tt, path = load_timetable(write(tmp_path / "s.yaml", f"""
name: s
line: ridge_net
services:
  - {{id: S1, train: etr1000, origin: CST, destination: PRT, departure: "08:00", stops: [{{station: {station}}}]}}
"""), net)
    with pytest.raises(InputError, match=rf"services\[0\]\.stops\[0\]\.station: '{station}' is the service's {end}: stops lists the stops in between"):
        plan_trains(tt, path, net, build_network_topology(net))
