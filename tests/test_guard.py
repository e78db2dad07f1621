"""The separation guard as a force filter, and the plant's emergency brake (no SUMO)."""

from __future__ import annotations

import math

import pytest

from vcsumo.control.base import Command, Message, Observation, TrainStateMsg
from vcsumo.control.guard import GuardConfig, SeparationGuard, guard_speed, predecessor_estimate
from vcsumo.dynamics import acceleration, brake_force_limit
from vcsumo.plant import PlantState, TrainPlant, emergency_brake_limit
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.sim.offline import flat_profile, steady_force

STOCK = load_rolling_stock("etr1000")
P = STOCK.params()
L = P.length_m
DT = 0.2
PROFILE = flat_profile(50000.0, speed_limit_mps=90.0)


def _obs(v=50.0, sensed_gap=None, sensed_speed=None, msg=None, t=10.0, stop=None):
    received = {} if msg is None else {"L": msg}
    return Observation(time_s=t, step_s=DT, ego_id="F", ego=TrainStateMsg(t, 1000.0, v), params=P, profile=PROFILE, received=received,
                       predecessor="L", sensed_gap_m=sensed_gap, sensed_speed_mps=sensed_speed, next_stop_m=stop)


def _speed_after(force: float, v: float) -> float:
    return v + DT * float(acceleration(P, v, force, 0.0, 1.0))


def test_a_command_within_the_guard_speed_passes_unchanged():
    g = SeparationGuard(STOCK, STOCK, 50.0)
    cmd = Command(1e4, mode="cbc")
    out = g.limit(_obs(sensed_gap=3000.0, sensed_speed=50.0), cmd)
    assert out is cmd and g.interventions == 0 and g.last_speed_mps > 50.0 and g.last_force_in_n == 1e4


def test_a_command_too_fast_is_limited_to_the_guard_speed_and_counted():
    g = SeparationGuard(STOCK, STOCK, 50.0)
    obs = _obs(sensed_gap=160.0, sensed_speed=50.0)  # both at 50 m/s, 160 m apart: the guard speed is just below 50 m/s
    out = g.limit(obs, Command(2e5))
    v_guard = out.info["guard_speed_mps"]
    v_floor = _speed_after(-P.mass_kg * P.emergency_brake_decel_mps2, 50.0)
    assert v_floor < v_guard < _speed_after(2e5, 50.0)  # the command would exceed it; the emergency brake can keep it
    assert _speed_after(out.force_n, 50.0) == pytest.approx(v_guard, abs=1e-9)
    assert out.force_n < 2e5 and g.interventions == 1 and g.last_speed_mps == v_guard


def test_the_guard_never_asks_more_than_the_emergency_brake_and_flags_it():
    g = SeparationGuard(STOCK, STOCK, 50.0)
    out = g.limit(_obs(sensed_gap=5.0, sensed_speed=0.0), Command(0.0))  # a standing train 5 m ahead
    assert out.info["guard_speed_mps"] == 0.0
    assert out.force_n == pytest.approx(-P.mass_kg * P.emergency_brake_decel_mps2)
    assert out.emergency and out.force_n < -float(brake_force_limit(P, 50.0))


def test_predecessor_knowledge_sensed_then_message_then_nothing():
    msg = Message("L", 8.0, TrainStateMsg(8.0, 1000.0 + 500.0 + L, 40.0), L)
    sensed = predecessor_estimate(_obs(sensed_gap=400.0, sensed_speed=45.0, msg=msg), L)
    assert (sensed.source, sensed.front_m, sensed.speed_mps, sensed.age_s) == ("sensed", 1000.0 + 400.0 + L, 45.0, 0.0)
    told = predecessor_estimate(_obs(msg=msg), L)
    assert (told.source, told.front_m, told.speed_mps, told.age_s) == ("message", 1000.0 + 500.0 + L, 40.0, 2.0)
    blind = predecessor_estimate(_obs(msg=Message("L", 8.0, TrainStateMsg(8.0, math.nan, 40.0), L)), L)
    assert (blind.source, blind.front_m, blind.speed_mps) == ("none", 1000.0, 0.0)
    # knowing nothing, the follower is held at standstill speed: the predecessor may stand at its front
    g = SeparationGuard(STOCK, STOCK, 50.0)
    out = g.limit(_obs(), Command(1e5))
    assert g.last_speed_mps == 0.0 and out.force_n == pytest.approx(-P.mass_kg * P.emergency_brake_decel_mps2)


def test_near_its_stop_the_guard_keeps_to_the_service_brake():
    g = SeparationGuard(STOCK, STOCK, 50.0)
    g.limit(_obs(sensed_gap=20000.0, sensed_speed=50.0), Command(0.0))
    free = g.last_speed_mps
    g.limit(_obs(sensed_gap=20000.0, sensed_speed=50.0, stop=1000.0 + 2000.0), Command(0.0))
    stop = g.last_speed_mps
    # 2,000 m to the stop at the service brake (0.65 m/s² + A/M): about 50 m/s, far below the free guard speed
    b = (P.mass_kg * 0.65 + P.davis_a_n) / (P.mass_kg * P.rotating_mass_factor)
    assert stop == pytest.approx(guard_speed(1000.0, b, DT, 3000.0, 0.0, 0.0, 1.0, 1.0)) and stop < free


def test_guard_config_choices_are_the_braking_assumptions():
    v = {}
    for dec in ("emergency", "service"):
        g = SeparationGuard(STOCK, STOCK, 50.0, GuardConfig(follower_decel=dec))
        g.limit(_obs(sensed_gap=1500.0, sensed_speed=50.0), Command(0.0))
        v[dec] = g.last_speed_mps
    assert v["service"] < v["emergency"]


def test_the_plant_brakes_at_its_emergency_rate_after_its_build_up():
    """Service: clipped to min(M·a_br, P_br/v); emergency: the full M·a_eb whatever the command, built
    up through the force lag (0.5 s) and the jerk limit (0.7 m/s³) of the ETR1000."""
    v0 = 60.0
    service = TrainPlant(P, PlantState(0.0, v0, steady_force(P, v0, PROFILE, 0.0)), PROFILE)
    emergency = TrainPlant(P, PlantState(0.0, v0, steady_force(P, v0, PROFILE, 0.0)), PROFILE)
    ramp = None
    for k in range(50):  # 10 s
        service.step(-1e12, DT)
        emergency.step(0.0, DT, emergency=True)
        if ramp is None and emergency.x.force_n <= -0.99 * emergency_brake_limit(P, emergency.x.v_mps):
            ramp = (k + 1) * DT
    assert service.x.force_n == pytest.approx(-float(brake_force_limit(P, service.x.v_mps)))
    assert emergency.x.force_n == pytest.approx(-P.mass_kg * P.emergency_brake_decel_mps2)
    # the build-up: ≈ (F_cruise + M·a_eb)/(j_max·M) of jerk-limited ramp plus the lag's tail
    assert 1.8 <= ramp <= 3.0
    a_em = -emergency.x.accel_mps2
    assert a_em > P.emergency_brake_decel_mps2 / P.rotating_mass_factor > -service.x.accel_mps2
