"""The guard places the predecessor where it can be at the least: braking at its strongest since the
time stamp of the newest message, on the gradients it meets meanwhile — by hand.

The relative-braking rule's leader brakes at the top of its range with its whole resistance and the
steepest up-grade under its body (the shared note *safe-separation*).  A message t old says where it
was; until 2026-12-01 the guard moved it on for the whole age at the deceleration where it was, so a
leader whose front was 2 m before a 30 ‰ climb (the climb counts as soon as its front is on it) was
placed as if on the level for all of a 20 s outage: 59.8 m further on than the rule's own worst case
at 50 m/s, and 5.93 m/s faster (21.23 against 15.30 m/s) — room the rule does not have, handed to the
follower.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcsumo.control.base import Message, Observation, TrainStateMsg
from vcsumo.control.guard import SeparationGuard
from vcsumo.dynamics import running_resistance
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel, brake_range
from vcsumo.units import G

STOCK = load_rolling_stock("etr1000")
P = STOCK.params()
L = P.length_m
MODEL = SeparationModel(load_assumptions())
DT = 0.2
CLIMB_AT = 5000.0
CLIMB = 0.030


def _route(grade: float) -> RouteProfile:
    """Level to CLIMB_AT, then ``grade`` (rise/run) to 20 km; open air, 300 km/h."""
    return RouteProfile(edges=["a", "b"], starts_m=np.array([0.0, CLIMB_AT]), lengths_m=np.array([CLIMB_AT, 15000.0]), speeds_ms=np.array([83.3, 83.3]),
                        gradients=np.array([0.0, grade]), tunnel_factors=np.array([1.0, 1.0]), sections=["a", "b"], km_from=np.array([0.0, 5.0]),
                        km_to=np.array([5.0, 20.0]), point_limits=[])


def _leader_decel(v: float) -> float:
    """The rule's strongest leader without the grade, by hand: top of its emergency range, its whole
    resistance at v with the Davis terms at the top of their box and the tunnel factor 1.5, over M̲."""
    box = STOCK.uncertainty
    top = P.with_(davis_a_n=box.davis_a_n.high, davis_b_n_per_mps=box.davis_b_n_per_mps.high, davis_c_n_per_mps2=box.davis_c_n_per_mps2.high)
    return brake_range(STOCK, MODEL.assumptions, "emergency")[1] + float(running_resistance(top, v, 1.5)) / box.mass_kg.low


def _worst_leader(v0: float, before_m: float, age_s: float, grade: float) -> tuple[float, float]:
    """(distance, speed) of that leader age_s after braking from v0 with its front ``before_m`` short of the climb, by hand."""
    a0 = _leader_decel(v0)
    a1 = a0 + G * grade  # its front on the climb: the climb is under its body
    v1 = math.sqrt(v0 * v0 - 2.0 * a0 * before_m)
    t1 = (v0 - v1) / a0
    if age_s <= t1:
        return v0 * age_s - 0.5 * a0 * age_s * age_s, v0 - a0 * age_s
    t = min(age_s - t1, v1 / a1)
    return before_m + v1 * t - 0.5 * a1 * t * t, v1 - a1 * t


def _sep(grade: float, age_s: float, v0: float = 50.0, before_m: float = 2.0):
    prof = _route(grade)
    guard = SeparationGuard(STOCK, STOCK, 50.0, model=MODEL)
    t = 100.0
    front_l = CLIMB_AT - before_m
    s_f = front_l - L - 3000.0
    msg = Message("L", t - age_s, TrainStateMsg(t - age_s, front_l, v0), L)
    obs = Observation(time_s=t, step_s=DT, ego_id="F", ego=TrainStateMsg(t, s_f, 30.0, 0.0, 0.0), params=P, profile=prof, received={"L": msg}, predecessor="L")
    return guard.separation(obs), front_l


@pytest.mark.parametrize("age_s", [0.0, 5.0, 20.0, 60.0])
def test_the_predecessor_is_placed_where_the_rule_s_strongest_leader_can_be(age_s):
    sep, front_l = _sep(CLIMB, age_s)
    moved, v = _worst_leader(50.0, 2.0, age_s + DT, CLIMB)  # one step from now
    assert sep.s_l - front_l == pytest.approx(moved, abs=1e-6) and sep.v_l == pytest.approx(max(v, 0.0), abs=1e-9)


def test_on_level_track_it_is_the_constant_deceleration_of_before():
    sep, front_l = _sep(0.0, 20.0)
    a0, t = _leader_decel(50.0), 20.0 + DT
    assert sep.s_l - front_l == pytest.approx(50.0 * t - 0.5 * a0 * t * t, abs=1e-6) and sep.v_l == pytest.approx(50.0 - a0 * t, abs=1e-9)


def test_the_climb_ahead_gives_the_follower_less_room_than_the_level():
    """The figures of the module doc: 20 s of outage at 50 m/s, the front 2 m before a 30 ‰ climb."""
    climb, front_l = _sep(CLIMB, 20.0)
    level, _ = _sep(0.0, 20.0)
    assert level.s_l - climb.s_l == pytest.approx(59.8, abs=0.1) and level.v_l - climb.v_l == pytest.approx(5.93, abs=0.01)
    assert climb.room == pytest.approx(level.room - (level.s_l - climb.s_l), abs=1e-6)
