"""The VC driver's junction options (:class:`vcsumo.sim.junction_policy.JunctionPolicy`) without
SUMO: the link handshake follows what the channel delivers, and the braking curves to a lower limit
ahead and to a red merge signal keep the follower able to brake for them — never asking for more
than its emergency brake."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcsumo.control.base import Message, TrainStateMsg
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.dynamics import acceleration
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.sim.junction_policy import SIGNAL_MARGIN_M, JunctionPolicy, MergeSignal
from vcsumo.sim.loop import Snapshot, TrainState
from vcsumo.control.guard import guaranteed_decel
from vcsumo.timetable import PlannedTrain

DT = 0.2
LINE_MPS, TURNOUT_MPS = 83.33, 27.78


def _profile() -> RouteProfile:
    """10 km, flat: 300 km/h, a 1 km stretch at 100 km/h from 5 km, 300 km/h again."""
    return RouteProfile(edges=["a", "b", "c"], starts_m=np.array([0.0, 5000.0, 6000.0]), lengths_m=np.array([5000.0, 1000.0, 4000.0]),
                        speeds_ms=np.array([LINE_MPS, TURNOUT_MPS, LINE_MPS]), gradients=np.zeros(3), tunnel_factors=np.ones(3),
                        sections=["main"] * 3, km_from=np.array([0.0, 5.0, 6.0]), km_to=np.array([5.0, 6.0, 10.0]), point_limits=[])


@pytest.fixture(scope="module")
def convoy():
    stock = load_rolling_stock("etr1000")
    prof = _profile()
    return [PlannedTrain(tid, tid, stock, ["a", "b", "c"], prof, 0.0, 300.0, 0.0, "up", end_pos_m=None, start_s_m=300.0, stop_at_end=False)
            for tid in ("L", "F")]


def _snap(t: float, **trains: tuple[float, float]) -> Snapshot:
    return Snapshot(t, DT, {k: TrainState(k, t, s, "main", s / 1000.0, v, 0.0, "a", None, math.inf) for k, (s, v) in trains.items()})


def _floor(stock, v: float) -> float:
    """Speed after one step of emergency braking on the flat, m/s."""
    p = stock.params()
    return max(0.0, v + DT * float(acceleration(p, v, -p.mass_kg * p.emergency_brake_decel_mps2, 0.0, 1.0)))


def test_the_follower_joins_once_its_predecessors_first_message_has_arrived(convoy):
    pol = JunctionPolicy([convoy], DT)
    channel = Channel(ChannelConfig(model="constant", delay_s=1.0))
    snap = _snap(0.0, L=(3000.0, 50.0), F=(1000.0, 50.0))
    assert set(pol.visible(snap).trains) == {"L"}  # SUMO drives F
    channel.send(Message("L", 0.0, TrainStateMsg(0.0, 3000.0, 50.0), 202.0), ["F"], 0.0)
    for t in (0.0, 0.4, 0.8):  # in flight: not linked
        channel.deliver("F", t)
        pol.limit(_snap(t, L=(3000.0, 50.0), F=(1000.0, 50.0)), {}, channel.latest)
        assert set(pol.visible(snap).trains) == {"L"}
    channel.deliver("F", 1.0)
    pol.limit(_snap(1.0, L=(3050.0, 50.0), F=(1050.0, 50.0)), {}, channel.latest)
    assert pol.linked == {"F"} and set(pol.visible(snap).trains) == {"L", "F"}
    # without the handshake the driver couples the follower at once
    assert set(JunctionPolicy([convoy], DT, link_handshake=False).visible(snap).trains) == {"L", "F"}


def test_a_lower_limit_ahead_is_approached_on_the_service_braking_curve(convoy):
    stock = convoy[1].stock
    b = stock.service_brake_decel_mps2
    pol = JunctionPolicy([convoy], DT, merge_signals={})
    # far from the 100 km/h stretch: the command stands
    assert pol.limit(_snap(0.0, L=(3000.0, 40.0), F=(100.0, 40.0)), {"F": 40.0}, lambda r: {}) == {"F": 40.0}
    assert pol.speed_profile_caps == 0 and pol.first_command == {"F": (0.0, 100.0)}
    # 2 km before it, a little above its service braking curve: capped to a speed from which service
    # braking reaches 100 km/h there
    d = 2000.0
    v0 = math.sqrt(TURNOUT_MPS ** 2 + 2 * b * d) + 0.1
    v = pol.limit(_snap(1.0, L=(7000.0, v0), F=(5000.0 - d, v0)), {"F": LINE_MPS}, lambda r: {})["F"]
    assert _floor(stock, v0) < v < v0 and v * v <= TURNOUT_MPS ** 2 + 2 * b * d + 1e-6 and pol.speed_profile_caps == 1
    # 100 m before it at line speed the curve cannot be kept: the train gets its emergency brake, no more
    v = pol.limit(_snap(2.0, L=(7000.0, LINE_MPS), F=(4900.0, LINE_MPS)), {"F": LINE_MPS}, lambda r: {})["F"]
    assert v == pytest.approx(_floor(stock, LINE_MPS))
    assert pol.first_command == {"F": (0.0, 100.0)}  # the first command only
    # the option off: nothing is capped
    off = JunctionPolicy([convoy], DT, speed_profile=False)
    assert off.limit(_snap(1.0, L=(7000.0, LINE_MPS), F=(3000.0, LINE_MPS)), {"F": LINE_MPS}, lambda r: {}) == {"F": LINE_MPS}


@pytest.mark.parametrize("signal_decel", ["emergency", "service"])
def test_the_follower_can_stop_at_the_merge_signal_until_its_predecessor_has_passed(convoy, signal_decel):
    stock = convoy[1].stock
    p = stock.params()
    sig = MergeSignal(stop_s_m=6000.0, predecessor_passed_s_m=6000.0)
    pol = JunctionPolicy([convoy], DT, speed_profile=False, merge_signals={"F": sig}, signal_decel=signal_decel)
    v0 = 60.0
    dec = p.emergency_brake_decel_mps2 if signal_decel == "emergency" else p.service_brake_decel_mps2
    b = guaranteed_decel(p, v0, dec, 0.0)
    # 5 m short of the distance it needs at 60 m/s: one step at v, then braking at the deceleration
    # the guard relies on, must stop it before the signal
    s_f = 6000.0 - SIGNAL_MARGIN_M - (1.5 * v0 * DT + v0 * v0 / (2 * b)) + 5.0
    v = pol.limit(_snap(0.0, L=(5500.0, v0), F=(s_f, v0)), {"F": v0}, lambda r: {})["F"]
    assert _floor(stock, v0) < v < v0 and 1.5 * v * DT + v * v / (2 * b) <= 6000.0 - SIGNAL_MARGIN_M - s_f + 1e-6 and pol.signal_caps == 1
    # the predecessor's front has passed the junction: the signal may be green, no cap
    assert pol.limit(_snap(1.0, L=(6100.0, v0), F=(4100.0, v0)), {"F": v0}, lambda r: {}) == {"F": v0}
    # 50 m before the signal at 60 m/s no brake can stop it: an overrun is counted, the emergency brake applied
    v = pol.limit(_snap(2.0, L=(5900.0, v0), F=(5950.0, v0)), {"F": v0}, lambda r: {})["F"]
    assert pol.signal_overruns == 1 and v == pytest.approx(_floor(stock, v0))
    assert pol.counts()["signal_caps"] == 2


def test_bad_signal_deceleration_is_refused(convoy):
    with pytest.raises(ValueError, match="signal_decel"):
        JunctionPolicy([convoy], DT, signal_decel="strong")
