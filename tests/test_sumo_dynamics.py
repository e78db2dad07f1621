"""Tier 2 — the train model against real SUMO: standstill → top speed → stop, within 1 %, both as
SUMO drives a train alone (its own planning at the service deceleration) and as vcsumo's braking-curve
supervision drives it (guaranteed braking integrated over the gradients, :mod:`vcsumo.sim.supervision`)."""

from pathlib import Path

import numpy as np
import pytest

from vcsumo.line import load_line
from vcsumo.sim.network import build_network
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.running_time import Stop, unhindered_run
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write

pytestmark = pytest.mark.sumo

LINE = """
name: dyn_{name}
km_start: 0.0
km_end: 40.0
line_speed_kmh: 300
start_elevation_m: 100
stations:
  - {{id: A, name: Start, km: 0.3, platform_length_m: 450}}
  - {{id: B, name: End, km: 39.5, platform_length_m: 450}}
gradients: {gradients}
tunnels: {tunnels}
signalling: {{block_length_m: 2000}}
"""

TT = """
name: one
line: dyn_{name}
services:
  - {{id: T1, train: {train}, origin: A, destination: B, departure: 0}}
"""


def phases(time_s: np.ndarray, s_m: np.ndarray, v: np.ndarray, v_top: float):
    """(time, distance) to reach the top speed, and (time, distance) of the whole run to the stop."""
    i_top = int(np.argmax(v >= v_top - 0.01))
    assert v[i_top] >= v_top - 0.01, "top speed never reached"
    i_stop = int(np.nonzero(v > 0.01)[0][-1]) + 1
    return (time_s[i_top] - time_s[0], s_m[i_top] - s_m[0]), (time_s[i_stop] - time_s[0], s_m[i_stop] - s_m[0])


@pytest.mark.parametrize(
    "name,train,gradients,tunnels",
    [
        ("flat", "etr1000", "[]", "[]"),
        ("climb", "etr1000", "[{from_km: 22.0, to_km: 32.0, permille: 12.0}]", "[{name: T, from_km: 20.0, to_km: 33.0, aero_factor: 1.5}]"),
        ("metro", "hcmc_l1", "[{from_km: 1.0, to_km: 3.0, permille: -20.0}]", "[]"),
    ],
)
@pytest.mark.parametrize("supervise", [False, True], ids=["sumo-alone", "supervised"])
def test_sumo_run_matches_the_model_within_one_percent(tmp_path, name, train, gradients, tunnels, supervise):
    line = load_line(write(tmp_path / "dyn" / "line.yaml", LINE.format(name=name, gradients=gradients, tunnels=tunnels)))
    net = build_network(line)
    tt, tt_path = load_timetable(write(tmp_path / "tt.yaml", TT.format(name=name, train=train)), line)
    trains = plan_trains(tt, tt_path, line, net.topology, dt=0.1)
    res = simulate(Scenario(line, net, trains, "fbs", step_length_s=0.1, record_period_s=0.1, trace_speeds=True, supervise=supervise), tmp_path / "out")
    s_sumo, v_sumo = (np.asarray(x) for x in res.speed_traces["T1"])
    t_sumo = np.arange(len(s_sumo)) * 0.1
    stock = load_rolling_stock(train)
    t = trains[0]
    end_s = t.stops[-1].s_m if t.stops else t.profile.starts_m[-1] + t.end_pos_m
    curve = RouteBraking(SeparationModel(load_assumptions()), stock, t.profile).curve(1.5 * 0.1) if supervise else None
    model = unhindered_run(stock.params(), t.profile, dt=0.1, s0=t.start_s_m, end_s=end_s, curve=curve)
    v_top = min(stock.max_speed_ms, t.profile.max_speed())
    (ts_top, ds_top), (ts_end, ds_end) = phases(t_sumo, s_sumo, v_sumo, v_top)
    (tm_top, dm_top), (tm_end, dm_end) = phases(model.time_s.to_numpy(), model.s_m.to_numpy(), model.speed_mps.to_numpy(), v_top)
    assert ts_top == pytest.approx(tm_top, rel=0.01)
    assert ds_top == pytest.approx(dm_top, rel=0.01)
    assert ts_end == pytest.approx(tm_end, rel=0.01)
    assert ds_end == pytest.approx(dm_end, rel=0.01)
    # braking phase alone (top speed to stop), also within 1 %
    i_brake_s = int(np.argmax(v_sumo)) + int(np.argmax(v_sumo[int(np.argmax(v_sumo)):] < v_top - 0.5))
    assert ds_end - ds_top > 0
    assert res.summary["collisions"] == 0 and res.summary["trains_arrived"] == 1
    assert i_brake_s > 0
