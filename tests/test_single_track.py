"""Single track without crossing loops: one direction at a time, same-direction trains follow each
other, opposing trains never pass through each other (vcsumo.sim.single_track_lock)."""

from __future__ import annotations

import pandas as pd
import pytest

from vcsumo.line import load_line
from vcsumo.network_file import load_network
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write
from .test_network_unseen import DBL, DSB  # the same double-track line and single-track branch
from .test_network_unseen import DS_NET as NET, DSB_HEAD_ON as HEAD_ON

LINE = """
name: sgline
km_start: 0.0
km_end: 12.0
tracks: single
line_speed_kmh: 160
stations:
  - {id: WST, name: West, km: 0.2, platform_length_m: 300}
  - {id: EST, name: East, km: 11.8, platform_length_m: 300}
signalling: {block_length_m: 1500}
"""
BOTH_AT_ONCE = """
name: both
line: sgline
services:
  - {id: E1, train: regional_emu160, origin: WST, destination: EST, departure: 0}
  - {id: W1, train: regional_emu160, origin: EST, destination: WST, departure: 0}
"""


def _run(tmp_path, line, text: str, regime: str, **kw):
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.sim.network import build_network

    built = build_network(line)
    tt, path = load_timetable(write(tmp_path / "tt.yaml", text), line)
    with pytest.warns(UserWarning, match="timetabled onto the same single track in opposite directions"):
        trains = plan_trains(tt, path, line, built.topology)
    res = simulate(Scenario(line, built, trains, regime, step_length_s=0.5, **kw), tmp_path / "out")
    return res, pd.read_csv(tmp_path / "out" / "summary.csv").set_index("train"), pd.read_csv(tmp_path / "out" / "trajectories.csv")


def _apart(tr: pd.DataFrame, up: list[str], down: list[str], section: str) -> None:
    """Every train running up the single track is behind (lower km than) every one running down it
    whenever both are on it: they never pass each other."""
    for u in up:
        for d in down:
            a = tr[tr.train == u].set_index("time_s")[["section", "km"]].add_suffix("_u")
            b = tr[tr.train == d].set_index("time_s")[["section", "km"]].add_suffix("_d")
            both = a.join(b, how="inner")
            on = both[(both.section_u == section) & (both.section_d == section)]
            assert (on.km_u < on.km_d).all(), (u, d, on[on.km_u >= on.km_d].head())


@pytest.mark.sumo
@pytest.mark.parametrize("regime", ["fbs", "mb"])
def test_opposing_trains_starting_at_either_end_of_a_single_track_line(tmp_path, regime):
    """A single-track line without crossing loops, one train from each end at the same time: one
    departs, the other waits in its platform until the first has arrived (the whole line is one
    stretch), then runs; both arrive, the run is healthy and they never meet."""
    line = load_line(write(tmp_path / "sgline" / "line.yaml", LINE))
    res, s, tr = _run(tmp_path, line, BOTH_AT_ONCE, regime)
    assert res.summary["trains_arrived"] == 2 and res.summary["collisions"] == 0 and res.summary["healthy"]
    first, second = s.sort_values("departure_s").index
    assert s.loc[first, "departure_delay_s"] < 1.0
    assert s.loc[second, "departure_s"] >= s.loc[first, "arrival_s"]  # waited until the line was clear
    # the same run for both: the wait is all of the second train's delay
    assert s.loc[second, "running_time_s"] == pytest.approx(s.loc[first, "running_time_s"], abs=2.0)
    _apart(tr, ["E1"], ["W1"], "main")


SGL = """
name: sgl
km_start: 0.0
km_end: 16.0
tracks: single
line_speed_kmh: 160
stations:
  - {id: SGE, name: Single End, km: 15.6, platform_length_m: 300}
signalling: {block_length_m: 1500}
"""
THREE = """
name: three
line: ds
services:
  - {id: Y, train: regional_emu160, origin: SGE, destination: DST, departure: 0}
  - {id: X1, train: regional_emu160, origin: DST, destination: SGE, departure: 60}
  - {id: X2, train: regional_emu160, origin: DST, destination: SGE, departure: 180}
"""


def _net(tmp_path):
    write(tmp_path / "dbl.yaml", DBL)
    write(tmp_path / "sgl.yaml", SGL)
    return load_network(write(tmp_path / "network.yaml", NET))


@pytest.mark.sumo
@pytest.mark.parametrize("regime", ["fbs", "mb"])
def test_two_followers_wait_in_front_of_the_single_track_for_an_opposing_train(tmp_path, regime):
    """Y runs down the single track; X1 and X2 follow each other towards it on the double track.
    Both wait in front of it, on the double track, until Y has left it, then run on it one behind
    the other under the regime's own separation (the health monitor's margin to the safe
    separation, from the first step); all arrive, healthy, and no X ever passes Y."""
    net = _net(tmp_path)
    res, s, tr = _run(tmp_path, net, THREE, regime)
    assert res.summary["trains_arrived"] == 3 and res.summary["collisions"] == 0 and res.summary["healthy"]
    y_off = tr[(tr.train == "Y") & (tr.section == "sgl.main")].time_s.max()  # Y's last sample on the single track
    for x in ("X1", "X2"):
        on = tr[(tr.train == x) & (tr.section == "sgl.main")]
        assert on.time_s.min() > y_off, x  # entered only after Y had left it
        stood = tr[(tr.train == x) & (tr.speed_mps < 0.05) & (tr.time_s > s.loc[x, "departure_s"] + 5) & (tr.time_s < on.time_s.min())]
        assert len(stood) > 10 and (stood.section == "dbl.main").all() and stood.km.max() < 6.0, x  # waited on its own track
    assert s.loc["Y", "arrival_s"] == pytest.approx(s.loc["Y", "departure_s"] + s.loc["Y", "running_time_s"])
    # the followers keep their order and their separation on the single track (no margin below the safe separation)
    assert s.loc["X2", "gap_violations"] == 0 and s.loc["X1", "arrival_s"] < s.loc["X2", "arrival_s"]
    _apart(tr, ["X1", "X2"], ["Y"], "sgl.main")




@pytest.mark.sumo
def test_opposing_trains_meeting_on_single_track_is_a_collision(tmp_path):
    """The check that the rule held can fire: without vcsumo's supervision (SUMO alone) the two
    trains pass through each other where the single-track branch leaves its junction as two
    one-way edges (SUMO sees no collision there); the loop counts the meeting as a collision with
    the closing speed as impact speed, and the run is not healthy."""
    line = load_line(write(tmp_path / "dsb" / "line.yaml", DSB))
    res, s, tr = _run(tmp_path, line, HEAD_ON, "fbs", supervise=False)
    assert res.summary["collisions"] >= 1 and not res.summary["healthy"]
    hits = pd.read_csv(tmp_path / "out" / "collisions.csv")
    assert set(hits.iloc[0][["collider", "victim"]]) == {"A", "B"} and hits.impact_speed_kmh.iloc[0] > 100.0
    a = tr[tr.train == "A"].set_index("time_s")
    b = tr[tr.train == "B"].set_index("time_s")
    t_hit = hits.time_s.iloc[0]
    assert a.loc[t_hit - 1.0:t_hit + 1.0].section.eq("sg").any() and b.loc[t_hit - 1.0:t_hit + 1.0].section.eq("sg").any()


CONVOY = """
name: vc3
line: ds
services:
  - {id: Y, train: regional_emu160, origin: SGE, destination: DST, departure: 0}
  - {id: X1, train: regional_emu160, origin: DST, destination: SGE, departure: 60}
  - {id: X2, train: regional_emu160, origin: DST, destination: SGE, departure: 60}
convoys:
  - {id: C, services: [X1, X2]}
"""


@pytest.mark.sumo
def test_convoy_waits_in_front_of_the_single_track_and_runs_on_it_coupled(tmp_path):
    """VC: a convoy X1+X2 meets Y, which holds the single track.  The convoy's leader waits in front
    of it on the double track, the follower, virtually coupled, behind it; once Y has left they run
    onto the single track still coupled (the end of authority reaches the driver of the follower
    through the approach locking) and never pass Y."""
    import json

    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.sim.network import build_network
    from vcsumo.sim.vc_driver import make_vc_driver

    net = _net(tmp_path)
    built = build_network(net)
    tt, path = load_timetable(write(tmp_path / "tt.yaml", CONVOY), net)
    with pytest.warns(UserWarning, match="timetabled onto the same single track in opposite directions"):
        trains = plan_trains(tt, path, net, built.topology, dt=0.2)
    drv = make_vc_driver(tt, path, trains, "cbc", 0.2, seed=3)
    res = simulate(Scenario(net, built, trains, "vc", step_length_s=0.2, driver=drv), tmp_path / "out")
    drv.write_report(tmp_path / "out")
    assert res.summary["trains_arrived"] == 3 and res.summary["collisions"] == 0 and res.summary["healthy"]
    tr = pd.read_csv(tmp_path / "out" / "trajectories.csv")
    y_off = tr[(tr.train == "Y") & (tr.section == "sgl.main")].time_s.max()
    x1_on = tr[(tr.train == "X1") & (tr.section == "sgl.main")].time_s.min()
    assert x1_on > y_off
    waited = tr[(tr.train == "X1") & (tr.speed_mps < 0.05) & (tr.time_s > 70) & (tr.time_s < x1_on)]
    assert len(waited) > 10 and (waited.section == "dbl.main").all()
    rec = pd.read_csv(tmp_path / "out" / "vc_followers.csv")
    assert (rec.time_s > x1_on).sum() > 100  # coupled on the single track too
    follower = json.loads((tmp_path / "out" / "vc_summary.json").read_text())["followers"][0]
    assert follower["train"] == "X2" and follower["coupled_steps"] > 1000
    _apart(tr, ["X1", "X2"], ["Y"], "sgl.main")


def test_single_track_nodes_are_no_merging_junctions(tmp_path):
    """The approach locking orders trains only where two tracks run on over a common edge: at the
    branch's junction on the down track (the branch's trains merge into it), not at the nodes of the
    single track, where the two directions' edges end (taking those for merges locked opposing
    trains against each other: they stood facing each other to the end of the run)."""
    from vcsumo.sim.interlocking import merge_nodes
    from vcsumo.sim.single_track_lock import stretches
    from vcsumo.topology import build_topology

    topo = build_topology(load_line(write(tmp_path / "dsb" / "line.yaml", DSB)))
    merges = merge_nodes(topo)
    junction_down = topo.edges[topo.tracks["sg_down"].edges[-1]].to_node
    assert merges == {junction_down}
    # the branch is one stretch, from the junction on each main track to its end
    st = stretches(topo)
    assert set(st) == set(topo.tracks["sg_up"].edges) | set(topo.tracks["sg_down"].edges) and set(st.values()) == {0}
