"""Single-track sections: where a train entering the network on one is held, and junctions of
double and single track (vcsumo.sim.single_track_lock).  The lines are our own, made for these
cases (2026-11-28)."""

from __future__ import annotations

import warnings

import pandas as pd
import pytest

from vcsumo.line import load_line
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write

pytestmark = pytest.mark.sumo

MIDLINE = """
name: stl
km_start: 0.0
km_end: 20.0
tracks: single
line_speed_kmh: 160
stations:
  - {id: WST, name: West, km: 0.2, platform_length_m: 300, dwell_s: 30}
  - {id: MID, name: Middle, km: 10.0, platform_length_m: 300, dwell_s: 30}
  - {id: EST, name: East, km: 19.8, platform_length_m: 300, dwell_s: 30}
signalling: {block_length_m: 1000}
"""
FROM_THE_MIDDLE = """
name: tt
line: stl
services:
  - {id: E1, train: regional_emu160, origin: WST, destination: EST, departure: "08:00"}
  - {id: W1, train: regional_emu160, origin: MID, destination: WST, departure: "08:02"}
"""


def _run(tmp_path, line_text: str, tt_text: str, regime: str, **kw):
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.sim.network import build_network

    line = load_line(write(tmp_path / "line" / "line.yaml", line_text))
    built = build_network(line)
    tt, path = load_timetable(write(tmp_path / "tt.yaml", tt_text), line)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (opposing trains timetabled onto the same single track: a wait, said)
        trains = plan_trains(tt, path, line, built.topology)
    res = simulate(Scenario(line, built, trains, regime, step_length_s=0.5, **kw), tmp_path / regime)
    return res.summary, pd.read_csv(tmp_path / regime / "summary.csv").set_index("train"), built.topology, trains


def test_the_insertion_hold_is_at_the_platform_exit_signal(tmp_path):
    """A train leaving a platform on single track stands with its front exactly at the end of the
    platform's edge, at the exit signal.  The lock looked the signal up with the edge *after* the
    front (``index_at(start_s_m)``): W1 (Middle, km 10.0) was held at the km 9.0 signal instead of
    the km 9.85 exit signal, SUMO checks an insertion constraint only at the first signal ahead,
    and inserted W1 at 08:04:11, as soon as E1 had passed Middle, while E1 still held the single
    track until it arrived at 08:08:24 ('entered although held': the lock's one-direction rule
    broken for 253 s; no collision only because SUMO's own check had kept W1 out while E1 was
    approaching).  The convoy insertion looked the same signal up the other way (``start_s_m -
    0.01``); both now ask the topology (Topology.first_signal_ahead)."""
    for regime in ("fbs", "mb"):
        s, per, _, _ = _run(tmp_path, MIDLINE, FROM_THE_MIDDLE, regime)
        assert s["trains_arrived"] == 2 and s["collisions"] == 0 and s["healthy"], (regime, s)
        assert per.loc["W1", "departure_s"] >= per.loc["E1", "arrival_s"], (regime, per)  # one direction at a time

    from vcsumo.sim.network import build_network

    line = load_line(write(tmp_path / "l" / "line.yaml", MIDLINE))

    topo = build_network(line).topology
    tt, path = load_timetable(write(tmp_path / "t.yaml", FROM_THE_MIDDLE), line)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        w1 = next(t for t in plan_trains(tt, path, line, topo) if t.id == "W1")
    sig = topo.first_signal_ahead(w1.edges, w1.profile.starts_m, w1.start_s_m)
    assert topo.nodes[sig].km == pytest.approx(9.85)  # Middle's exit signal towards West


BRANCHED = """
name: sdb
km_start: 0.0
km_end: 5.0
tracks: single
line_speed_kmh: 100
stations:
  - {id: NA, name: Northa, km: 4.5, platform_length_m: 400, dwell_s: 30}
signalling: {block_length_m: 800}
branches:
  - {id: xtra, name: Extra, junction_km: 2.0, leaves_towards: end, length_m: 3000, speed_kmh: 120, diverging_speed_kmh: 50, tracks: double,
     block_length_m: 1000, stations: [{id: XA, name: Extra, km: 0.5, platform_length_m: 400, dwell_s: 30}]}
"""  # test_unseen10_network's north/extra network as one line: a single-track line with a double-track branch
THROUGH_THE_JUNCTION = """
name: tt
line: sdb
services:
  - {id: U1, train: etr1000, origin: start, destination: XA, departure: "08:00"}
  - {id: U2, train: etr1000, origin: XA, destination: start, departure: "08:00"}
  - {id: U3, train: etr1000, origin: NA, destination: start, departure: "08:02"}
"""


@pytest.mark.parametrize("regime", ["mb", "fbs"])
def test_a_double_track_branch_of_a_single_track_line_does_not_deadlock(tmp_path, regime):
    """U1 leaves the single track onto the double-track branch while U2, coming off the branch,
    waits for that single track.  Both branch tracks met the single track at the junction node,
    and the line builder connected every track there, reversals included (from the down main
    line onto the branch, off the branch onto the up main line): under mb nobody moved (0/3
    arrived at 08:20), under fbs 3/3 with an authority overrun.  Now the branch's tracks
    converge one signal before the junction (its last edge is single track, as a double-track
    line joined inside a single-track one in a network) and no move reverses (converging alone,
    with the builder's connections, deadlocked fbs too: 0/3)."""
    s, _, topo, _ = _run(tmp_path, BRANCHED, THROUGH_THE_JUNCTION, regime, end_time_s=8 * 3600 + 20 * 60)
    assert (s["trains_arrived"], s["authority_overruns"], s["collisions"], s["healthy"]) == (3, 0, 0, True), s
    assert topo.edges["xtra_up_0"].bidi == "xtra_down_4"  # converged at the branch's km 0.3 signal
    for e, nxt in topo.successors.items():
        for n in nxt:
            a, b = topo.edges[e], topo.edges[n]
            assert not (a.section == b.section and a.direction != b.direction), (e, n)  # no reversal on a section
            if a.section == "main" and b.section == "xtra":
                assert a.direction == "up", (e, n)  # onto the branch only from the side it leaves towards
            if a.section == "xtra" and b.section == "main":
                assert b.direction == "down", (e, n)


def _rear_past_convergence(tmp_path, regime: str) -> tuple[float, float]:
    """U1's rear past the branch's convergence point (its km 0.3 signal, where U2 stands) when U2
    first moves and when U2's front passes that point, m."""
    tr = pd.read_csv(tmp_path / regime / "trajectories.csv")
    u1, u2 = tr[tr.train == "U1"].set_index("time_s"), tr[tr.train == "U2"].set_index("time_s")
    x1, x2 = 2300.0, 400.0  # the convergence point on U1's route (km 2.0 + 0.3 km of branch) and on U2's (its platform's exit)
    starts, passes = u2[u2.speed_mps > 0.05].index.min(), u2[u2.s_m > x2 + 0.05].index.min()
    return u1.loc[starts, "s_m"] - 202.0 - x1, u1.loc[passes, "s_m"] - 202.0 - x1  # (an ETR 1000 is 202 m long)


WITH_A_CONVOY = THROUGH_THE_JUNCTION.replace(
    '  - {id: U3, train: etr1000, origin: NA, destination: start, departure: "08:02"}\n',
    '  - {id: U3, train: regional_emu160, origin: NA, destination: start, departure: "08:02"}\n'
    '  - {id: U4, train: regional_emu160, origin: NA, destination: start, departure: "08:02"}\n'
    "convoys:\n  - {id: C1, services: [U3, U4]}\n")


@pytest.mark.parametrize("regime", ["mb", "fbs", "vc"])
def test_a_train_standing_at_the_entry_of_single_track_waits_for_the_opposing_rear_to_clear(tmp_path, regime):
    """U2 stands with its front exactly where the branch's tracks converge onto the single track
    (its platform's exit signal).  The lock took a train whose front was *at* the entry for one
    already on the stretch and gave it the stretch at once, so nothing but SUMO's signal held U2:
    it started with U1's rear 14 m past the convergence point (9 m under vc) and passed it with
    U1's rear 42 m past, inside the lock's clearance (60 m: overlap or margin 50 m + position
    error 10 m, + the report's age at speed), and the run was healthy.  Now U2 asks for the stretch
    like any train in front of it and starts once U1's rear has cleared the point by the clearance."""
    if regime == "vc":  # (the CLI builds the convoy's driver)
        import json

        from vcsumo.cli.main import main

        args = ["run", "--line", str(write(tmp_path / "l" / "line.yaml", BRANCHED)), "--timetable", str(write(tmp_path / "vc.yaml", WITH_A_CONVOY))]
        assert main(args + ["--regime", "vc", "--end-time", "08:20", "--out", str(tmp_path / "vc")]) == 0
        s = json.loads((tmp_path / "vc" / "summary.json").read_text())
    else:
        s, _, _, _ = _run(tmp_path, BRANCHED, THROUGH_THE_JUNCTION, regime, end_time_s=8 * 3600 + 20 * 60)
    assert (s["trains_arrived"], s["authority_overruns"], s["collisions"], s["healthy"]) == (4 if regime == "vc" else 3, 0, 0, True), s
    starts, passes = _rear_past_convergence(tmp_path, regime)
    assert starts >= 60.0 and passes >= 60.0, (starts, passes)


def test_entering_single_track_close_behind_an_opposing_train_is_a_gap_violation(tmp_path):
    """The check that the lock's clearance held can fire: SUMO alone (no supervision, no lock) lets
    U2 off the branch onto the single track as soon as U1's rear has passed the convergence point
    (by 9 m when it starts, 46 m when its front passes the point, against the lock's 60 m:
    overlap or margin 50 m + position error 10 m).  The run was healthy; now the entry is a gap
    violation (violations.csv: U2 behind U1, the gap U1's rear past the point) and it is not."""
    s, per, _, _ = _run(tmp_path, BRANCHED, THROUGH_THE_JUNCTION, "fbs", end_time_s=8 * 3600 + 20 * 60, supervise=False)
    starts, passes = _rear_past_convergence(tmp_path, "fbs")
    assert starts < 60.0 and passes < 60.0, (starts, passes)  # (the case: SUMO's own signal let it in too close)
    assert per.loc["U2", "gap_violations"] == 1 and not s["healthy"], (per, s)
    v = pd.read_csv(tmp_path / "fbs" / "violations.csv")
    assert list(v[["train", "leader"]].iloc[0]) == ["U2", "U1"] and starts <= v.gap_m.iloc[0] <= passes and v.safe_separation_m.iloc[0] == 60.0, (v, starts, passes)


BEFORE_THE_JUNCTION = """
name: dsj
km_start: 0.0
km_end: 10.0
tracks: double
line_speed_kmh: 160
stations:
  - {id: AAA, name: Alpha, km: 4.6, platform_length_m: 400, dwell_s: 30}
signalling: {block_length_m: 1000}
branches:
  - {id: spur, name: Spur, junction_km: 5.0, leaves_towards: end, length_m: 4000, speed_kmh: 120, diverging_speed_kmh: 60, tracks: single,
     stations: [{id: BRS, name: Branchside, km: 3.5, platform_length_m: 300, dwell_s: 30}]}
"""
ONTO_THE_BRANCH = """
name: tt
line: dsj
services:
  - {id: B1, train: regional_emu160, origin: BRS, destination: start, departure: "08:00"}
  - {id: A1, train: regional_emu160, origin: AAA, destination: BRS, departure: "08:01"}
"""


def test_a_train_departing_at_the_signal_before_single_track_held_by_an_opposing_train_stays_there(tmp_path):
    """A1 departs from Alpha, whose exit signal (km 4.8) is the last before the single-track branch
    (junction km 5.0), while B1 comes off the branch: under FBS its end of authority is that signal,
    at its front.  The lock made A1's request at its first step, after that step's supervision had
    left it to SUMO, whose own signal was clear; SUMO started it and the run reported an authority
    overrun of 10.26 m (not healthy) for a train that stood at its platform.  Now a train departing
    within reach of where it would wait asks before SUMO inserts it, and is held from its first step."""
    s, per, _, _ = _run(tmp_path, BEFORE_THE_JUNCTION, ONTO_THE_BRANCH, "fbs")
    assert (s["trains_arrived"], s["authority_overruns"], s["collisions"], s["healthy"]) == (2, 0, 0, True), (s, per)
    tr = pd.read_csv(tmp_path / "fbs" / "trajectories.csv")
    b1_off = tr[(tr.train == "B1") & (tr.section == "spur")].time_s.max()
    assert tr[(tr.train == "A1") & (tr.section == "spur")].time_s.min() > b1_off  # A1 entered the branch once B1 had left it
