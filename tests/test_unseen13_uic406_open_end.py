"""Tier 1 — UIC 406 under fixed block counts the block a train entering at an open end stands in
(unseen-networks, 2026-12-01).

Found in a batch on a network of our own (alpnet: freight and regional trains entering at the
valley line's start and the mountain line's end): ``uic406.csv`` had the sections from those open
ends to the first station under ``mb`` (valley:start-VLA, 16 virtual blocks; mountain:end-MTZ,
2.39 %) but not under ``fbs`` at all.  A train inserted at an open end has its front its own length
in, past the signal at the end of the track (or with no signal behind it), and the blocks behind
its front were dropped — with them the block it stands in, so a section without a further signal
vanished and every other entry section lost its first block.  Now that block is blocked from the
train's departure until its tail has cleared the next signal by the overlap and the position error,
as the module's rule says."""

import pytest

from vcsumo.line import load_line
from vcsumo.running_time import time_at, unhindered_run
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.signalling.uic406 import capacity_consumption
from vcsumo.timetable import load_timetable, plan_trains
from vcsumo.topology import build_topology

from .conftest import write

LINE = """
name: entry
km_start: 0.0
km_end: 12.0
line_speed_kmh: 160
default_train: regional_emu160
stations:
  - {id: ENT, name: Entry, km: 1.0, platform_length_m: 300, dwell_s: 30}
  - {id: MID, name: Middle, km: 8.0, platform_length_m: 300, dwell_s: 30}
signalling: {block_length_m: 2000}
"""
TT = """
name: t
line: entry
services:
  - {id: T, train: regional_emu160, origin: start, destination: end, departure: "08:00", repeat: {count: 3, every_s: 600}}
"""


def test_fixed_block_counts_the_block_an_entering_train_stands_in(tmp_path):
    line = load_line(write(tmp_path / "entry.yaml", LINE))
    topo = build_topology(line)
    tt, path = load_timetable(write(tmp_path / "t.yaml", TT), line)
    trains = plan_trains(tt, path, line, topo)
    model = SeparationModel(load_assumptions())
    a = model.assumptions
    res = {r: capacity_consumption(line, topo, trains, r, model=model).set_index(["direction", "section"]) for r in ("fbs", "mb")}
    # the entry section (open end to Entry's stopping point, 1.15 km) is there under both regimes
    assert ("up", "start-ENT") in res["mb"].index
    assert ("up", "start-ENT") in res["fbs"].index, res["fbs"].index.tolist()
    row = res["fbs"].loc[("up", "start-ENT")]
    assert row.trains == 3 and row.blocks == 1
    # the oracle: each train blocks it from its departure until its tail has cleared the section's end
    # (the signal at Entry's platform exit) by the overlap and the position error, on its run braking
    # on the supervised curve; three trains compressed: three such times
    t = trains[0]
    s_b = t.profile.s_of("main", row.to_km)
    run = unhindered_run(t.stock.params(), t.profile, dt=0.5, s0=t.start_s_m, end_s=s_b + 2000.0, stop_at_end=False,
                         curve=RouteBraking(model, t.stock, t.profile).curve(0.75))
    block = float(time_at(run, s_b + a.overlap_m + a.position_error_m + t.stock.length_m)[0])
    assert row.cycle_s == pytest.approx(3 * block, abs=3 * 1.0)
    # the next section, whose blocks all lie ahead of the entering trains, is unchanged in kind
    assert res["fbs"].loc[("up", "ENT-MID")].trains == 3
