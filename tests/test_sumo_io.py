"""SUMO's files through :mod:`vcsumo.sim.sumo_io`, on real SUMO output from tiny runs: the additional
file (signal recording), the ``.sumocfg`` (a run replayed from it by the sumo binary), the signal
switches, and the log counters against what libsumo reported step by step."""

from __future__ import annotations

import re
import shutil
import subprocess
import xml.etree.ElementTree as ET

import pytest

from vcsumo.line import load_line
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.sim.network import build_network
from vcsumo.sim.sumo_backend import SPEED_MODE_VC_FOLLOWER, SumoBackend, sumo_args
from vcsumo.sim.sumo_io import SignalRecording, SumoLogCounts, rail_signal_links, read_signal_switches, read_sumo_log, write_additional
from vcsumo.sim.sumo_paths import sumo_binary
from vcsumo.timetable import PlannedTrain, routes_xml

from .conftest import write

# 12 km, 1 km blocks, no branch: trains on the up track
LINE = """
name: iotest
title: A 12 km double-track line with 1 km blocks
km_start: 0.0
km_end: 12.0
tracks: double
start_elevation_m: 50
line_speed_kmh: 160
default_train: etr1000
stations:
  - {id: AAA, name: Alpha, km: 0.3, platform_length_m: 400, dwell_s: 60}
  - {id: ZZZ, name: Zulu, km: 11.7, platform_length_m: 400, dwell_s: 60}
signalling: {block_length_m: 1000}
"""
STEP_S = 0.5
SLOW_START_MPS, SLOW_MPS, FAST_MPS = 5.0, 2.0, 30.0


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    line = load_line(write(tmp_path_factory.mktemp("sumo_io") / "iotest" / "line.yaml", LINE))
    return line, build_network(line)


def _train(topo, tid: str, stock, first_edge: int, depart_s: float, speed_mps: float) -> PlannedTrain:
    edges = topo.track_for("main", "up").edges[first_edge:]
    prof = RouteProfile.from_edges(topo, edges)
    pos = min(stock.length_m + 1.0, float(prof.lengths_m[0]))
    return PlannedTrain(tid, tid, stock, edges, prof, depart_s, pos, speed_mps, "up", end_pos_m=None, start_s_m=pos, stop_at_end=False)


def _signals(net, n: int = 8) -> list[str]:
    cand = [net.topology.edges[e].to_node for e in net.topology.track_for("main", "up").edges[:n]]
    links = rail_signal_links(net.net_file, cand)
    return [c for c in cand if any(k[0] == c for k in links)]


def _commanded_run(net, out, moving_block: bool, n_slow: int, end_s: float = 300.0) -> dict:
    """``n_slow`` slow trains ahead, inserted at 5 m/s and commanded to 2 m/s, and a fast train behind
    commanded to 30 m/s, all under speed mode 26 (the VC follower's: SUMO's safe-speed check off, a
    red signal enforced by stopping the train at it within a step).  Counts what libsumo reports at
    every step: emergency stops, and collisions as episodes (a pair colliding at a step where it did
    not collide at the step before)."""
    slow, fast = load_rolling_stock("hcmc_l1"), load_rolling_stock("etr1000")
    topo = net.topology
    trains = [_train(topo, f"slow{k}", slow, 3 + k, 0.0, SLOW_START_MPS) for k in range(n_slow)] + [_train(topo, "fast", fast, 0, 20.0, 20.0)]
    out.mkdir(parents=True)
    (out / "routes.rou.xml").write_text(routes_xml(trains, topo))
    sigs = _signals(net)
    add = write_additional(out / "network" / "signals.add.xml", [SignalRecording(s, out / f"signal_{s}.xml") for s in sigs])
    args = sumo_args(net.net_file, out / "routes.rou.xml", [net.stations_file, add], out, STEP_S, end_s, moving_block=moving_block)
    speed = {t.id: (FAST_MPS if t.id == "fast" else SLOW_MPS) for t in trains}
    stops = episodes = 0
    before: set = set()
    driven: set = set()
    with SumoBackend(args, error_log=out / "sumo_errors.log") as sim:
        while sim.time < end_s - 1e-9:
            sim.step()
            for vid in sim.train_ids():
                if vid not in driven:
                    sim.set_speed_mode(vid, SPEED_MODE_VC_FOLLOWER)
                    driven.add(vid)
                sim.set_speed(vid, speed[vid])
            stops += len(sim.emergency_stops())
            now = set(sim.collisions())
            episodes += len(now - before)
            before = now
    return {"emergency_stops": stops, "collision_episodes": episodes, "signals": sigs, "slow": slow, "log": (out / "sumo_errors.log").read_text()}


@pytest.mark.sumo
def test_emergency_stops_at_red_are_counted_as_libsumo_saw_them(net, tmp_path):
    _, n = net
    run = _commanded_run(n, tmp_path / "fbs", moving_block=False, n_slow=1)
    got = read_sumo_log(tmp_path / "fbs" / "sumo_errors.log")
    # the fast train is stopped at the red signal behind the slow one at every step it is commanded on
    assert run["emergency_stops"] > 3 and got.emergency_stops == run["emergency_stops"]
    # SUMO wrote only the first three (--aggregate-warnings 3) and their total at the end
    written = run["log"].count("performs emergency stop")
    assert written < got.emergency_stops and "total messages of type" in run["log"]
    assert 1 <= got.emergency_stops_at_red_signal <= written
    assert got.collisions == 0 and got.teleports == 0 and got.errors == 0
    # every stop SUMO names was at a signal the recording shows red at that moment
    sw = read_signal_switches([tmp_path / "fbs" / f"signal_{s}.xml" for s in run["signals"]])
    assert set(sw.signal) == set(run["signals"]) and set("".join(sw.state)) <= set("rsGg")
    named = re.findall(r"end of lane '(\w+)_0' because of a red traffic light .*time=([0-9.]+)\.", run["log"])
    assert len(named) == got.emergency_stops_at_red_signal
    for edge, t in named:
        sig = n.topology.edges[edge].to_node
        last = sw[(sw.signal == sig) & (sw.time_s <= float(t))].sort_values("time_s").iloc[-1]
        assert last.state[0] in "rs", (edge, t)


@pytest.mark.sumo
def test_collisions_and_emergency_braking_are_counted_as_libsumo_saw_them(net, tmp_path):
    _, n = net
    n_slow = 5
    run = _commanded_run(n, tmp_path / "mb", moving_block=True, n_slow=n_slow)
    got = read_sumo_log(tmp_path / "mb" / "sumo_errors.log")
    # moving block: no signal protects the slow trains, the fast one runs into each of them once
    assert run["collision_episodes"] == n_slow and got.collisions == run["collision_episodes"]
    # each slow train brakes from 5 to 2 m/s in one step, harder than its emergency brake: one warning each
    assert (SLOW_START_MPS - SLOW_MPS) / STEP_S > run["slow"].emergency_brake_decel_mps2
    assert got.emergency_braking == n_slow and run["log"].count("performs emergency braking") < n_slow
    assert got.emergency_stops == 0 and got.teleports == 0 and got.other_warnings == 0 and got.errors == 0


@pytest.mark.sumo
def test_a_run_replays_from_its_sumocfg(net, tmp_path):
    """The .sumocfg (paths relative to the run folder) replays the run with the sumo binary from a
    copy of the folder: same trips, same signal switches (the recording is an additional file).
    SUMO alone: vcsumo's supervision and drivers are commands in the loop, which a replay does not have."""
    line, n = net
    fast = load_rolling_stock("etr1000")
    trains = [_train(n.topology, "a", fast, 1, 0.0, 0.0), _train(n.topology, "b", fast, 1, 30.0, 0.0)]
    out = tmp_path / "run"
    sigs = _signals(n)
    add = write_additional(out / "network" / "signals.add.xml", [SignalRecording(s, out / f"signal_{s}.xml") for s in sigs])
    simulate(Scenario(line, n, trains, "fbs", additional_files=[add], supervise=False), out)
    copy = tmp_path / "elsewhere" / "copy"
    shutil.copytree(out, copy)
    for f in ["tripinfo.xml", *(f"signal_{s}.xml" for s in sigs)]:
        (copy / f).unlink()
    r = subprocess.run([sumo_binary("sumo"), "-c", "scenario.sumocfg"], cwd=copy, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr

    def trips(folder, prefix=""):
        return sorted((e.get("id"), e.get("depart"), e.get("arrival")) for e in ET.parse(folder / f"{prefix}tripinfo.xml").getroot().iter("tripinfo"))

    # the replay writes its own replay-* files (the recorded outputs of a results folder stay as they are)
    assert len(trips(out)) == 2 and trips(copy, "replay-") == trips(out)
    a = read_signal_switches([out / f"signal_{s}.xml" for s in sigs])
    b = read_signal_switches([copy / f"replay-signal_{s}.xml" for s in sigs])
    assert (a.state.str.contains("r")).any() and a.equals(b)
    # paths in the file are relative to the run folder
    paths = {el.tag: el.get("value") for el in ET.parse(out / "scenario.sumocfg").getroot()}
    assert paths["additional-files"] == "network/stations.add.xml,network/signals.add.xml" and paths["tripinfo-output"] == "tripinfo.xml"


def test_log_kinds_and_totals():
    """Lines as SUMO 1.28 writes them (copied from runs), kinds the tiny runs do not produce, and the
    repeat of initial errors that ``--verbose`` adds at the end."""
    import tempfile
    from pathlib import Path

    text = "\n".join([
        "Loading net-file from 'line.net.xml' ... done (2ms).",
        "Warning: Vehicle 'a'; collision with vehicle 'b', lane='e_0', gap=-9.60, time=56.50, stage=move.",
        "Warning: Vehicle 'a'; junction collision with vehicle 'c', lane=':J_0_0', gap=-1.00, time=60.00, stage=move.",
        "Warning: Teleporting vehicle 'c'; waited too long (jam), lane='e_0', time=70.00.",
        "Warning: Vehicle 'c' ends teleporting on edge 'f', time=75.00.",
        "Warning: Vehicle 'd' skips stop on lane 'e_0' time=80.00.",
        "Warning: Vehicle 'd' performs emergency stop at the end of lane 'e_0' because of a red traffic light (decel=-30.00, offset=3.70), time=52.50.",
        "Warning: Vehicle 'd' performs emergency stop at the end of lane 'e_0' because there is no connection to the next edge (decel=-3.00, offset=0.70), time=53.00.",
        "Warning: Vehicle 'd' performs emergency stop at the end of lane 'e_0' because of a red traffic light (decel=0.35, offset=0.17), time=53.50.",
        "Warning: Vehicle 'stop' is inserted in an emergency situation, time=1.00.",
        "Error: Answered with error to command 0xc4: No lane with index '1' on road 'x'.",
        "Warning: 7 total messages of type: Vehicle '%' performs emergency stop at the end of lane '%'% (decel=%, offset=%), time=%.",
        "Warning: 4 total messages of type: Vehicle '%'; % with vehicle '%', lane='%', gap=%, time=%, stage=%.",
        "Repeating initial error messages:",
        "Error: Answered with error to command 0xc4: No lane with index '1' on road 'x'.",
    ])
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "sumo_errors.log"
        f.write_text(text + "\n")
        got = read_sumo_log(f)
        assert read_sumo_log(Path(d) / "missing.log") == SumoLogCounts()
    assert got == SumoLogCounts(emergency_braking=0, emergency_stops=7, emergency_stops_at_red_signal=2, teleports=1, collisions=4, stop_warnings=1,
                                other_warnings=1, errors=1)
