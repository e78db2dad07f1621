"""The VC driver's junction option (:class:`vcsumo.sim.junction_policy.JunctionPolicy`) without
SUMO: the link handshake follows what the channel delivers, and the braking curves to a lower limit
ahead and to the end of authority at a merge are the separation model's (guaranteed braking on the
route, the assumption set's dead time) — never asking for more than the emergency brake."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcsumo.control.base import Message, TrainStateMsg
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.dynamics import acceleration
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.sim.junction_policy import JunctionPolicy
from vcsumo.sim.loop import Snapshot, TrainState
from vcsumo.timetable import PlannedTrain

DT = 0.2
LINE_MPS, TURNOUT_MPS = 83.33, 27.78
MODEL = SeparationModel(load_assumptions())


def _profile(gradient: float = 0.0) -> RouteProfile:
    """10 km at one gradient: 300 km/h, a 1 km stretch at 100 km/h from 5 km, 300 km/h again."""
    return RouteProfile(edges=["a", "b", "c"], starts_m=np.array([0.0, 5000.0, 6000.0]), lengths_m=np.array([5000.0, 1000.0, 4000.0]),
                        speeds_ms=np.array([LINE_MPS, TURNOUT_MPS, LINE_MPS]), gradients=np.full(3, gradient), tunnel_factors=np.ones(3),
                        sections=["main"] * 3, km_from=np.array([0.0, 5.0, 6.0]), km_to=np.array([5.0, 6.0, 10.0]), point_limits=[])


def _convoy(gradient: float = 0.0):
    stock = load_rolling_stock("etr1000")
    prof = _profile(gradient)
    return [PlannedTrain(tid, tid, stock, ["a", "b", "c"], prof, 0.0, 300.0, 0.0, "up", end_pos_m=None, start_s_m=300.0, stop_at_end=False)
            for tid in ("L", "F")]


@pytest.fixture(scope="module")
def convoy():
    return _convoy()


def _snap(t: float, authority: dict | None = None, **trains: tuple[float, float]) -> Snapshot:
    return Snapshot(t, DT, {k: TrainState(k, t, s, "main", s / 1000.0, v, 0.0, "a", None, math.inf) for k, (s, v) in trains.items()}, authority or {})


def _floor(stock, v: float, gradient: float = 0.0) -> float:
    """Speed after one step of emergency braking, m/s."""
    p = stock.params()
    return max(0.0, v + DT * float(acceleration(p, v, -p.mass_kg * p.emergency_brake_decel_mps2, gradient, 1.0)))


def test_the_follower_joins_once_its_predecessors_first_message_has_arrived(convoy):
    pol = JunctionPolicy([convoy], DT, MODEL)
    channel = Channel(ChannelConfig(model="constant", delay_s=1.0))
    snap = _snap(0.0, {"F": 900.0}, L=(3000.0, 50.0), F=(1000.0, 50.0))
    hidden = pol.visible(snap)
    assert set(hidden.trains) == {"L"} and hidden.junction_authority_m == {"F": 900.0}  # SUMO drives F
    channel.send(Message("L", 0.0, TrainStateMsg(0.0, 3000.0, 50.0), 202.0), ["F"], 0.0)
    for t in (0.0, 0.4, 0.8):  # in flight: not linked
        channel.deliver("F", t)
        pol.limit(_snap(t, L=(3000.0, 50.0), F=(1000.0, 50.0)), {}, channel.latest)
        assert set(pol.visible(snap).trains) == {"L"}
    channel.deliver("F", 1.0)
    pol.limit(_snap(1.0, L=(3050.0, 50.0), F=(1050.0, 50.0)), {}, channel.latest)
    assert pol.linked == {"F"} and pol.visible(snap) is snap
    # without the handshake the driver couples the follower at once
    assert set(JunctionPolicy([convoy], DT, MODEL, link_handshake=False).visible(snap).trains) == {"L", "F"}


@pytest.mark.parametrize("gradient", [0.0, -0.015])
def test_a_lower_limit_ahead_is_approached_on_the_guaranteed_braking_curve(gradient):
    convoy = _convoy(gradient)
    stock, prof = convoy[1].stock, convoy[1].profile
    braking = RouteBraking(MODEL, stock, prof)
    pol = JunctionPolicy([convoy], DT, MODEL)
    # far from the 100 km/h stretch: the command stands
    assert pol.limit(_snap(0.0, L=(3000.0, 40.0), F=(100.0, 40.0)), {"F": 40.0}, lambda r: {}) == {"F": 40.0}
    assert pol.speed_profile_caps == 0 and pol.first_command == {"F": (0.0, 100.0)}
    # 2 km before it, a little above the curve: capped to the curve, which the guaranteed brake
    # (bottom of the box, the descent counted) keeps after 1.5 steps
    d = 2000.0
    v_curve = braking.permitted_speed(5000.0 - d, 5000.0, TURNOUT_MPS, 1.5 * DT, LINE_MPS)
    a = braking.decel_at(5000.0 - d, v_curve)
    assert v_curve ** 2 - TURNOUT_MPS ** 2 == pytest.approx(2 * (a * d - v_curve * 1.5 * DT * a), rel=1e-6)  # v·T + (v² − v_t²)/(2a) = d
    v0 = v_curve + 0.1
    v = pol.limit(_snap(1.0, L=(7000.0, v0), F=(5000.0 - d, v0)), {"F": LINE_MPS}, lambda r: {})["F"]
    assert v == pytest.approx(braking.permitted_speed(5000.0 - d, 5000.0, TURNOUT_MPS, 1.5 * DT, v0)) and pol.speed_profile_caps == 1
    assert _floor(stock, v0, gradient) < v < v0
    # 100 m before it at line speed the curve cannot be kept: the train gets its emergency brake, no more
    v = pol.limit(_snap(2.0, L=(7000.0, LINE_MPS), F=(4900.0, LINE_MPS)), {"F": LINE_MPS}, lambda r: {})["F"]
    assert v == pytest.approx(_floor(stock, LINE_MPS, gradient))
    assert pol.first_command == {"F": (0.0, 100.0)}  # the first command only
    # the option off: nothing is capped
    off = JunctionPolicy([convoy], DT, MODEL, speed_profile=False)
    assert off.limit(_snap(1.0, L=(7000.0, LINE_MPS), F=(3000.0, LINE_MPS)), {"F": LINE_MPS}, lambda r: {}) == {"F": LINE_MPS}


def test_a_descent_lowers_the_curve():
    flat, down = (RouteBraking(MODEL, c[1].stock, c[1].profile) for c in (_convoy(0.0), _convoy(-0.015)))
    assert down.permitted_speed(3000.0, 5000.0, TURNOUT_MPS, 1.5 * DT, 60.0) < flat.permitted_speed(3000.0, 5000.0, TURNOUT_MPS, 1.5 * DT, 60.0) - 1.0


def test_the_follower_keeps_its_braking_curve_to_the_end_of_authority_at_a_merge(convoy):
    """The loop's approach locking ends the follower's authority before the junction: the command is
    capped to the guaranteed braking curve to it after the set's dead time; with no authority given
    (the predecessor's front has passed) nothing is capped; too close to stop even with the emergency
    brake, the step is counted and the emergency brake applied."""
    stock = convoy[1].stock
    braking = RouteBraking(MODEL, stock, convoy[1].profile)
    emergency = RouteBraking(MODEL, stock, convoy[1].profile, "emergency")
    pol = JunctionPolicy([convoy], DT, MODEL, speed_profile=False)
    v0, s_f = 60.0, 1000.0
    dead = MODEL.dead_time_s + 1.5 * DT
    d_ma = braking.stopping_distance(s_f, v0, dead) - 5.0  # 5 m short of what it needs at 60 m/s
    v = pol.limit(_snap(0.0, {"F": d_ma}, L=(900.0, v0), F=(s_f, v0)), {"F": v0}, lambda r: {})["F"]
    assert v == pytest.approx(braking.permitted_speed(s_f, s_f + d_ma, 0.0, dead, v0))
    assert _floor(stock, v0) < v < v0 and braking.stopping_distance(s_f, v, dead) <= d_ma + 0.5 and pol.signal_caps == 1
    assert pol.signal_overruns == 0  # the emergency brake could still stop it
    # no end of authority: no cap
    assert pol.limit(_snap(1.0, L=(2000.0, v0), F=(s_f, v0)), {"F": v0}, lambda r: {}) == {"F": v0}
    # 50 m before its end of authority at 60 m/s no brake can stop it there: counted, emergency brake
    assert emergency.stopping_distance(s_f, v0, MODEL.dead_time_s) > 50.0
    v = pol.limit(_snap(2.0, {"F": 50.0}, L=(900.0, v0), F=(s_f, v0)), {"F": v0}, lambda r: {})["F"]
    assert v == pytest.approx(_floor(stock, v0)) and pol.signal_overruns == 1 and pol.signal_overrun_episodes == 1
    pol.limit(_snap(2.2, {"F": 40.0}, L=(900.0, v0), F=(s_f + 10.0, v0 - 0.2)), {"F": v0}, lambda r: {})
    assert pol.signal_overruns == 2 and pol.signal_overrun_episodes == 1 and pol.counts()["signal_caps"] == 3
    # the option off (SUMO's red signal alone): nothing is capped
    off = JunctionPolicy([convoy], DT, MODEL, speed_profile=False, merge_authority=False)
    assert off.limit(_snap(0.0, {"F": d_ma}, L=(900.0, v0), F=(s_f, v0)), {"F": v0}, lambda r: {}) == {"F": v0}
