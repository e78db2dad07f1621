"""Tier 2 — networks of lines in SUMO: a through service from one line to another, a convoy that
forms on one line and splits onto the other line's branch, and the shipped network."""

import json

import pandas as pd
import pytest

from vcsumo.network_file import load_network
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import make_vc_driver
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write
from .test_network_file import BETA, make_network

BETA_FAST = BETA.replace("line_speed_kmh: 160", "line_speed_kmh: 200")

pytestmark = pytest.mark.sumo

RUN = """
name: r
line: twolines
services:
  - {id: L, train: etr1000, origin: AST, destination: BEND, departure: "07:00"}
  - {id: F, train: etr1000, origin: AST, destination: SPUR, departure: "07:00"}
convoys:
  - {id: C, services: [L, F]}
"""


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    net = load_network(make_network(tmp_path_factory.mktemp("net")))
    return net, build_network(net)


def test_network_in_sumo_matches_the_topology(two, tmp_path):
    from vcsumo.sim.sumo_backend import SumoBackend

    net, built = two
    topo = built.topology
    (tmp_path / "empty.rou.xml").write_text("<routes/>")
    with SumoBackend(["-n", str(built.net_file), "-a", str(built.stations_file), "-r", str(tmp_path / "empty.rou.xml"), "--end", "1", "--no-step-log", "true"]) as sim:
        ls = sim._ls
        assert set(ls.trafficlight.getIDList()) == topo.signal_nodes()
        for nodes in topo.named_nodes.values():  # every join is a signal
            assert set(nodes) <= set(ls.trafficlight.getIDList())
        for e in topo.edges.values():
            assert ls.lane.getLength(e.id + "_0") == pytest.approx(e.length_m, abs=1e-3)
    # the lines keep their gradients where they were moved to: alpha rises 5 ‰ on km 6-8, beta is level
    import xml.etree.ElementTree as ET

    shapes = {ln.get("id")[:-2]: [tuple(map(float, p.split(","))) for p in ln.get("shape").split()]
              for ln in ET.parse(built.net_file).getroot().iter("lane") if not ln.get("id").startswith(":")}
    for e in topo.edges.values():
        if e.track in ("alpha.main_up", "beta.main_up"):
            pts = shapes[e.id]
            rise = (pts[-1][2] if len(pts[-1]) > 2 else 0.0) - (pts[0][2] if len(pts[0]) > 2 else 0.0)
            slope = 5e-3 if e.track == "alpha.main_up" and 6.0 <= e.km_from < 8.0 else 0.0
            assert rise == pytest.approx(slope * e.length_m, abs=0.05), e.id


def test_through_service_and_split_run_in_sumo(two, tmp_path):
    """Under moving block: the train from alpha arrives at beta's station, the one for the spur
    diverges at beta's junction; each runs its whole route over both lines."""
    net, built = two
    tt, path = load_timetable(write(tmp_path / "r.yaml", RUN), net)
    trains = plan_trains(tt, path, net, built.topology)
    res = simulate(Scenario(net, built, trains, "mb", step_length_s=0.5), tmp_path / "out")
    s = res.summary
    assert s["trains_arrived"] == 2 and s["collisions"] == 0 and s["teleports"] == 0
    by = res.trains.set_index("train")
    for t in trains:
        # SUMO adds the internal lanes of the junction nodes passed (about 25 m at each of the two)
        run = by.loc[t.id, "route_length_m"] - (t.final_stop.s_m - t.start_s_m)
        assert 0.0 <= run < 60.0
    st = res.stop_events.set_index("train")
    assert st.loc["L", "station"] == "BEND" and st.loc["F", "station"] == "SPUR"
    traj = res.trajectories
    assert set(traj[traj.train == "L"].section) == {"alpha.main", "beta.main"}
    assert set(traj[traj.train == "F"].section) == {"alpha.main", "beta.main", "beta.spur"}
    # chainage per line: beta's km grows from 100
    b = traj[(traj.train == "L") & (traj.section == "beta.main")]
    assert b.km.min() >= 100.0 - 1e-6 and b.km.is_monotonic_increasing


def test_convoy_forms_on_one_line_and_splits_onto_the_others_branch(two, tmp_path):
    """VC: the pair leaves alpha's station together, is coupled across the join into beta and
    split at beta's junction; the follower is then handed back to SUMO and reaches the spur."""
    net, built = two
    tt, path = load_timetable(write(tmp_path / "r.yaml", RUN), net)
    trains = plan_trains(tt, path, net, built.topology, dt=0.2)
    drv = make_vc_driver(tt, path, trains, "cbc", 0.2, seed=3)
    res = simulate(Scenario(net, built, trains, "vc", step_length_s=0.2, driver=drv), tmp_path / "out")
    drv.write_report(tmp_path / "out")
    s = res.summary
    assert s["trains_arrived"] == 2 and s["collisions"] == 0 and s["gap_violations"] == 0 and s["teleports"] == 0
    rec = pd.read_csv(tmp_path / "out" / "vc_followers.csv")
    per = {f["train"]: f for f in json.loads((tmp_path / "out" / "vc_summary.json").read_text())["followers"]}
    assert per["F"]["coupled_steps"] > 100
    released = per["F"]["released_at_s"]
    assert released == released  # released (split) during the run
    traj = res.trajectories
    f = traj[traj.train == "F"]
    on_beta = f[f.section == "beta.main"].time_s.min()
    on_spur = f[f.section == "beta.spur"].time_s.min()
    # coupled on alpha and on beta before the split, never after the follower is on the spur
    assert (rec.time_s < on_beta).any() and ((rec.time_s > on_beta) & (rec.time_s < on_spur)).any()
    assert rec.time_s.max() < on_spur
    assert released <= on_spur + 1.0
    # while coupled at speed the follower runs closer than moving block would let it
    fast = rec[(rec.speed_mps > 30) & (rec.predecessor_speed_mps > 30)]
    assert len(fast) and (fast.gap_m < fast.speed_mps ** 2 / (2 * 0.7)).any()


def test_shipped_network_builds_in_sumo(tmp_path):
    from vcsumo.sim.sumo_backend import SumoBackend

    net = load_network("italy_av_north")
    built = build_network(net)
    topo = built.topology
    (tmp_path / "empty.rou.xml").write_text("<routes/>")
    with SumoBackend(["-n", str(built.net_file), "-a", str(built.stations_file), "-r", str(tmp_path / "empty.rou.xml"), "--end", "1", "--no-step-log", "true"]) as sim:
        ls = sim._ls
        assert set(ls.trafficlight.getIDList()) == topo.signal_nodes()
        assert len(ls.busstop.getIDList()) == len(topo.platforms)


def test_the_readme_example_network_runs(in_tmp, root):
    """A network written from the README alone (its example line joined to a second line) runs a
    through service from one line to the other."""
    import re
    from pathlib import Path

    from vcsumo.cli.main import main

    readme = (root / "README.md").read_text()
    blocks = dict(re.findall(r"<!-- example: (\S+) -->\s*```yaml\n(.*?)```", readme, re.S))
    write(in_tmp / "my_line" / "line.yaml", blocks["line"])
    write(in_tmp / "link_line.yaml", blocks["network-line"])
    net = write(in_tmp / "network.yaml", blocks["network"])
    tt = write(in_tmp / "through.yaml", blocks["network-timetable"])
    assert main(["run", "--line", str(net), "--timetable", str(tt), "--regime", "fbs", "--out", "run"]) == 0
    s = json.loads(Path("run/summary.json").read_text())
    assert s["trains"] == 3 and s["trains_arrived"] == 3 and s["collisions"] == 0
    st = pd.read_csv("run/stop_events.csv")
    assert set(st.station) == {"MID", "LNK"} and len(st) == 6
    traj = pd.read_csv("run/trajectories.csv")
    assert set(traj.section) == {"my_line.main", "link_line.main"}
    # the results folder records the network file and every line file it joins
    assert {"line", "line_my_line", "line_link_line", "timetable"} <= set(json.loads(Path("run/meta.json").read_text())["inputs"])
    assert main(["run", "--line", str(net), "--timetable", str(tt), "--regime", "mb", "--end-time", "09:20", "--out", "run2"]) == 0
    s2 = json.loads(Path("run2/summary.json").read_text())
    assert s2["simulated_until_s"] <= 9 * 3600 + 20 * 60 + 1 and s2["trains_arrived"] == 1


def test_batch_takes_a_network(tmp_path):
    """vcsumo batch on a network: runs, and UIC 406 reports every line's sections in its own km."""
    from vcsumo.studies.batch import run_batch

    net_path = make_network(tmp_path / "net")
    tt = write(tmp_path / "r.yaml", RUN)
    df = run_batch(str(net_path), [str(tt)], ["fbs"], [1], out=tmp_path / "b", workers=1)
    assert (df.status == "ok").all() and df.line.iloc[0] == "twolines"
    uic = pd.read_csv(tmp_path / "b" / "uic406.csv")
    ups = uic[(uic.direction == "up")]
    assert {"alpha:AST-J:gj", "alpha:J:gj-J:ab", "beta:J:ab-J:spur"} <= set(ups.section)
    assert ups.set_index("section").loc["beta:J:ab-J:spur", "from_km"] == pytest.approx(100.0)
    # an edit of a member line file is a different batch (its resume key covers every file)
    again = run_batch(str(net_path), [str(tt)], ["fbs"], [1], out=tmp_path / "b", workers=1)
    assert again.attrs["resumed_runs"] == 1
    write(tmp_path / "net" / "beta.yaml", BETA_FAST)
    changed = run_batch(str(net_path), [str(tt)], ["fbs"], [1], out=tmp_path / "b", workers=1)
    assert changed.attrs["new_runs"] == 1 and changed.run_key.iloc[-1] != df.run_key.iloc[0]
