"""A convoy follower's stop target behind a predecessor braking into the platform both stop at.

The follower plans its stop behind where its predecessor will stand (its stopping point less its
length and the separation model's margin), not behind where the predecessor's rear is now: that
target moved back step by step as the predecessor braked in, and the follower, planning towards a
point that kept receding, ran 1.3–2.1 m/s above its service curve and fell back on emergency
braking (27 of the 48 follower emergency activations of regional_graded ``convoy`` under cbc).
The hand-over to SUMO keeps to the predecessor's rear where it is (planning the hand-over towards
the farther point too made followers arrive late and miss their convoy's joint departure:
regional_graded all-stops VC capacity 47.0 -> 31.4 trains/h)."""

from __future__ import annotations

import math

from vcsumo.line import load_line
from vcsumo.sim.convoy_plan import follower_stops
from vcsumo.sim.network import build_network
from vcsumo.sim.snapshot import Snapshot, TrainState
from vcsumo.sim.vc_driver import make_vc_driver
from vcsumo.timetable import load_timetable, plan_trains


def test_follower_stops_name_where_the_predecessor_stands():
    line = load_line("regional_graded")
    net = build_network(line)
    tt, p = load_timetable("convoy", line)
    trains = {t.id: t for t in plan_trains(tt, p, line, net.topology, dt=0.1)}
    ego, pred = trains["UF.1"], trains["UL.1"]
    stops, plats, stands = follower_stops(ego, pred, 0.0)
    shared = {x.platform for x in pred.stops} | ({pred.final_stop.platform} if pred.final_stop else set())
    own = list(ego.stops) + ([ego.final_stop] if ego.final_stop else [])
    assert len(stops) == len(plats) == len(stands) == len(own)
    for x, stand in zip(own, stands):
        if x.platform in shared:  # same route, same platform: the predecessor's front stands at the same stopping point
            assert stand == x.s_m
        else:
            assert stand is None
    assert any(s is not None for s in stands)
    # another frame: the predecessor's positions shifted into the follower's
    assert [s + 100.0 if s is not None else None for s in stands] == follower_stops(ego, pred, 100.0)[2]


def test_the_stop_target_stays_behind_where_the_predecessor_will_stand():
    line = load_line("regional_graded")
    net = build_network(line)
    tt, p = load_timetable("convoy", line)
    trains = plan_trains(tt, p, line, net.topology, dt=0.1)
    drv = make_vc_driver(tt, p, trains, "cbc", 0.1, seed=3)
    f = drv.followers["UF.1"]
    k = next(i for i, s in enumerate(f.pred_stands_m) if s is not None and f.stops_m[i] > 3000.0)
    stand = f.pred_stands_m[k]
    length = f.pred.stock.length_m
    margin = drv.model.margin_m
    seen: list[float | None] = []
    make_step = f.stack.make_step

    def capture(obs):
        seen.append(obs.next_stop_m)
        return make_step(obs)

    f.stack.make_step = capture
    f.next_stop = k
    dt = 0.1
    s_l, v_l, s_f, v_f = stand - 100.0, 8.0, stand - 100.0 - length - 120.0, 8.0
    for step in range(10):  # the predecessor brakes into the platform, the follower 120 m behind its rear
        t = 100.0 + step * dt
        snap = {"UL.1": TrainState("UL.1", t, s_l, "main", s_l / 1000.0, v_l, -0.5, "e", None, math.inf),
                "UF.1": TrainState("UF.1", t, s_f, "main", s_f / 1000.0, v_f, -0.5, "e", "UL.1", s_l - length - s_f)}
        drv.make_step(Snapshot(t, dt, snap, {}))
        s_l += v_l * dt
        s_f += v_f * dt
        v_l -= 0.05
        v_f -= 0.05
    assert len(seen) == 10
    assert all(x == min(f.stops_m[k], stand - length - margin) for x in seen), seen
