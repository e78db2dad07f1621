"""Braking-curve supervision and run health in real SUMO (issue 11): every stop served on graded
lines, no overspeed, no overrun, a moving-block follower stopping behind a train standing on a
descent, merges without a train let in front of one that can no longer stop — and the same health
counters firing when SUMO drives alone."""

from __future__ import annotations

import math
import pytest

from vcsumo.line import load_line
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.sim.network import build_network
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.timetable import END_OF_TRACK_WINDOW_M, load_timetable, plan_trains

from .conftest import write

pytestmark = pytest.mark.sumo

HEALTH = ["stops_skipped", "overspeed_events", "authority_overruns", "sumo_emergency_stops", "sumo_stop_warnings", "collisions",
          "gap_violations", "beyond_service_brakings", "sumo_emergency_brakings", "teleports"]


@pytest.fixture(scope="module")
def regional(network_factory, line_factory):
    line = line_factory("regional_graded")
    net = network_factory("regional_graded")
    tt, path = load_timetable("all_stations", line)
    return line, net, plan_trains(tt, path, line, net.topology, dt=0.5)


@pytest.mark.parametrize("regime", ["fbs", "mb"])
def test_graded_line_every_stop_served_and_healthy(regional, regime, tmp_path):
    """Stations on -10 to +10 ‰, a 100 km/h restriction on a descent, a terminus on a descent and a
    branch train merging in front of main-line trains: all 64 stops served, nothing counted."""
    line, net, trains = regional
    res = simulate(Scenario(line, net, trains, regime, step_length_s=0.5), tmp_path / regime)
    s = res.summary
    assert s["stops_scheduled"] == 64 and s["stops_served"] == 64
    assert s["trains_arrived"] == s["trains"] == 12
    assert {k: s[k] for k in HEALTH} == {k: 0 for k in HEALTH}
    assert s["healthy"] and s["min_margin_m"] >= -0.01
    # every train at or below its permitted speed (+ tolerance) at every recorded second
    tr = res.trajectories
    assert len(tr) > 1000 and (res.trains.overspeed_max_kmh == 0).all()


OPEN_ENDS = """
name: open_ends
line: regional_graded
services:
  - {id: OUT, train: regional_emu160, origin: ALD, destination: end, departure: "06:00"}
  - {id: IN, train: regional_emu160, origin: end, destination: ALD, departure: "06:00"}
  - {id: HILL, train: regional_emu160, origin: ALD, destination: "branch:hill", departure: "06:04"}
"""


@pytest.mark.parametrize("regime", ["fbs", "mb"])
def test_trains_to_an_open_end_arrive_there(line_factory, network_factory, regime, tmp_path):
    """A train whose route ends at an open end of the network ends its trip with a stop SUMO serves
    there: the supervision holds it short of the end by the end-of-track rule and the stop's window
    takes it there (else it would stand for ever and every train behind it too); it leaves the network."""
    line = line_factory("regional_graded")
    net = network_factory("regional_graded")
    tt, path = load_timetable(write(tmp_path / "open.yaml", OPEN_ENDS), line)
    trains = plan_trains(tt, path, line, net.topology, dt=0.5)
    res = simulate(Scenario(line, net, trains, regime, step_length_s=0.5), tmp_path / regime)
    s = res.summary
    assert s["trains_arrived"] == 3 and s["healthy"], {k: s[k] for k in HEALTH}
    by = res.trains.set_index("train")
    for t in trains:
        if t.final_stop is None:  # it ran to the end of its route: the route length SUMO reports
            end = t.profile.starts_m[-1] + t.end_pos_m - t.start_s_m
            assert end - max(t.stock.length_m, END_OF_TRACK_WINDOW_M) - 1.0 <= by.loc[t.id, "route_length_m"] <= end + 1.0


def test_sumo_alone_skips_stops_and_the_counters_fire(regional, tmp_path):
    """Without supervision SUMO plans at the level-track deceleration: it skips stations on
    descents and stops at the end of the track by an emergency stop — and the run says so."""
    line, net, trains = regional
    s = simulate(Scenario(line, net, trains, "fbs", step_length_s=0.5, supervise=False), tmp_path / "alone").summary
    assert s["stops_skipped"] >= 10 and s["sumo_stop_warnings"] >= 10
    assert s["sumo_emergency_stops"] >= 1
    assert not s["healthy"]


DESCENT = """
name: descent
km_start: 0.0
km_end: 20.0
line_speed_kmh: 200
start_elevation_m: 300
stations:
  - {id: A, name: Top, km: 0.3, platform_length_m: 400, dwell_s: 30}
  - {id: M, name: Slope, km: 12.0, platform_length_m: 400, dwell_s: 180}
  - {id: B, name: Bottom, km: 19.6, platform_length_m: 400, dwell_s: 30}
gradients:
  - {from_km: 4.0, to_km: 16.0, permille: -11.5}
signalling: {block_length_m: 1500}
"""
TT = """
name: t
line: descent
services:
  - {id: L, train: etr1000, origin: A, destination: B, departure: 0, stops: [{station: M}]}
  - {id: F, train: etr1000, origin: A, destination: B, departure: 100}
"""


def test_moving_block_follower_stops_behind_a_train_standing_on_a_descent(tmp_path):
    """A leader dwells 3 min at a station on -11.5 ‰; the follower, 100 s behind at 200 km/h, brakes on
    its guaranteed curve and stands exactly margin + 2 position errors (70 m) behind its rear."""
    line = load_line(write(tmp_path / "d" / "line.yaml", DESCENT))
    net = build_network(line)
    tt, p = load_timetable(write(tmp_path / "tt.yaml", TT), line)
    trains = plan_trains(tt, p, line, net.topology, dt=0.5)
    res = simulate(Scenario(line, net, trains, "mb"), tmp_path / "sup")
    s = res.summary
    a = load_assumptions()
    assert s["healthy"] and s["collisions"] == 0 and s["gap_violations"] == 0 and s["stops_skipped"] == 0
    assert s["min_gap_m"] == pytest.approx(a.safety_margin_m + 2 * a.position_error_m, abs=1.0)
    # SUMO alone on the same case: the leader overshoots the station, the follower gets inside the
    # safe separation, and both are counted
    alone = simulate(Scenario(line, net, trains, "mb", supervise=False), tmp_path / "alone").summary
    assert alone["stops_skipped"] >= 1 and alone["gap_violations"] >= 1 and alone["min_margin_m"] < -100


def test_a_train_standing_in_its_platform_has_served_its_stop_only_where_sumo_holds_it(line_factory, network_factory):
    """A convoy follower stands in the platform behind its leader. Where SUMO serves the stop there
    (it holds the train), the supervision no longer brakes it to the platform's end after the convoy
    leaves (regional_graded all-stops VC capacity: the follower crept 146 m at 0.08 m/s and fell 2 km
    behind its leader). Where SUMO does not (a follower waiting 170 m short of its stopping point
    behind a leader in a platform too short for both), the stop stays its target: an unseen mountain
    line's follower, supervised as if served, ran through its stop on a 20 permille descent."""
    from vcsumo.signalling.assumptions import load_assumptions
    from vcsumo.signalling.separation import SeparationModel
    from vcsumo.sim.supervision import BrakingCurveSupervisor
    from vcsumo.timetable import load_timetable, plan_trains

    line = line_factory("regional_graded")
    tt, p = load_timetable("all_stations", line)
    t = next(x for x in plan_trains(tt, p, line, network_factory("regional_graded").topology) if len(x.stops) >= 2)
    stop = t.stops[0]
    assert stop.platform_length_m > 0
    held = {t.id: False}
    sup = BrakingCurveSupervisor(SeparationModel(load_assumptions()), "mb", [t], 0.5, held_at_stop=held.get)
    before = stop.s_m - stop.platform_length_m - 5.0
    sup.permitted(t.id, 0.0, before, 0.0)  # standing short of the platform (held at a signal): still its stop
    assert sup.curves[t.id].next_stop == 0 and sup.permitted(t.id, 0.5, before, 20.0).reason == "stop"
    inside = stop.s_m - 0.5 * stop.platform_length_m
    assert sup.permitted(t.id, 1.0, inside, 15.0).reason == "stop"  # running in the platform: still braking for it
    sup.permitted(t.id, 1.5, inside, 0.0)  # standing in it, SUMO not holding it: not served
    assert sup.curves[t.id].next_stop == 0 and sup.permitted(t.id, 2.0, inside, 15.0).reason == "stop"
    held[t.id] = True
    sup.permitted(t.id, 2.5, inside, 0.0)  # standing in it, held by SUMO: served there
    assert sup.curves[t.id].next_stop == 1
    assert sup.permitted(t.id, 3.0, inside + 0.5, 1.0).reason != "stop" or t.stops[1].s_m - inside < 500.0
    alone = BrakingCurveSupervisor(SeparationModel(load_assumptions()), "mb", [t], 0.5)  # nobody to ask: never assumed served
    alone.permitted(t.id, 0.0, inside, 0.0)
    assert alone.curves[t.id].next_stop == 0


def test_an_overrun_is_passing_the_end_of_authority_not_standing_where_placed(line_factory, network_factory):
    """A train placed at a platform whose exit signal stands at its front (a departure 30 s behind
    the train ahead) is 10 m past its authority (its position error) without having moved: not an
    overrun (an unseen test line counted two). Moving past it is one, counted once per episode,
    standing in it or not; the counter fires at every speed."""
    from vcsumo.signalling.assumptions import load_assumptions
    from vcsumo.signalling.separation import SeparationModel
    from vcsumo.sim.health import HealthMonitor
    from vcsumo.timetable import load_timetable, plan_trains

    line = line_factory("regional_graded")
    tt, p = load_timetable("all_stations", line)
    t = plan_trains(tt, p, line, network_factory("regional_graded").topology)[0]
    h = HealthMonitor(SeparationModel(load_assumptions()), [t])
    for _ in range(20):  # standing 10 m past it from the start
        h.step(t.id, 0.5, 260.0, 0.0, 0.0, math.inf, -10.0)
    assert h.trains[t.id].overruns == 0
    h.step(t.id, 0.5, 260.0, 0.3, 0.6, math.inf, -10.15)  # it moves on while still past: an overrun
    h.step(t.id, 0.5, 260.2, 0.0, -0.6, math.inf, -10.2)  # stands in it: the same episode
    h.step(t.id, 0.5, 260.2, 0.2, 0.4, math.inf, -10.3)
    assert h.trains[t.id].overruns == 1 and h.trains[t.id].max_overrun_m == 10.3
    h.step(t.id, 0.5, 300.0, 5.0, 0.0, math.inf, 400.0)  # a new authority ahead
    h.step(t.id, 0.5, 700.0, 2.0, -0.5, math.inf, -0.6)  # passes it slowly: a second overrun
    assert h.trains[t.id].overruns == 2


SHARED = """
name: shared_platform
km_start: 0.0
km_end: 12.0
line_speed_kmh: 160
stations:
  - {id: A, name: Start, km: 0.3, platform_length_m: 400, dwell_s: 30}
  - {id: M, name: Middle, km: 6.0, platform_length_m: 600, dwell_s: 30}
  - {id: B, name: End, km: 11.6, platform_length_m: 400, dwell_s: 30}
signalling: {block_length_m: 1500}
"""
SHARED_TT = """
name: t
line: shared_platform
services:
  - {id: L, train: etr1000, origin: A, destination: B, departure: 0, stops: [{station: M, dwell_s: 240}]}
  - {id: F, train: etr1000, origin: A, destination: B, departure: 90, stops: [{station: M, dwell_s: 10}]}
"""


def test_a_train_whose_stop_ends_behind_a_standing_train_is_not_started_at_full_traction(tmp_path):
    """F berths in the platform behind L (which dwells 4 min) and SUMO serves its 10 s stop there, with
    its end of authority (MB: 70 m behind L's rear) a few cm ahead. Left to SUMO at the end of the
    stop, it took one step of full traction (0.35 m/s with 5 cm of authority: below the safe
    separation; seen on the italy_av_north full day at Bologna C.le AV, 17 violations). A train
    standing at its stop is left to SUMO only where one step of its strongest start stays within its
    curve."""
    line = load_line(write(tmp_path / "s" / "line.yaml", SHARED))
    net = build_network(line)
    tt, p = load_timetable(write(tmp_path / "tt.yaml", SHARED_TT), line)
    trains = plan_trains(tt, p, line, net.topology, dt=0.5)
    res = simulate(Scenario(line, net, trains, "mb"), tmp_path / "run")
    s = res.summary
    ev = res.stop_events
    f_mid = ev[(ev.train == "F") & (ev.station == "M")]
    assert len(f_mid) == 1 and f_mid.iloc[0].arrival_s < ev[(ev.train == "L") & (ev.station == "M")].iloc[0].departure_s  # F stood behind L
    assert s["gap_violations"] == 0 and s["min_margin_m"] >= -0.01
    assert s["healthy"] and s["stops_skipped"] == 0
