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
