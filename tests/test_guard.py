"""The separation guard as a force filter, and the plant's emergency brake (no SUMO)."""

from __future__ import annotations

import math

import pytest

from vcsumo.control.base import Command, Message, Observation, TrainStateMsg
from vcsumo.control.guard import GuardConfig, SeparationGuard, predecessor_estimate
from vcsumo.dynamics import acceleration, brake_force_limit
from vcsumo.plant import PlantState, TrainPlant, emergency_brake_limit
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel
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


MODEL = SeparationModel(load_assumptions())
RULE = RelativeBraking(MODEL, STOCK, STOCK, PROFILE)
DEAD = MODEL.dead_time_s + 1.5 * DT


def _msg(gap_m: float, v: float, sent: float) -> Message:
    return Message("L", sent, TrainStateMsg(sent, 1000.0 + gap_m + L, v), L)


def test_a_command_within_the_guard_speed_passes_unchanged():
    g = SeparationGuard(STOCK, STOCK, 50.0)
    cmd = Command(1e4, mode="cbc")
    out = g.limit(_obs(msg=_msg(3000.0, 50.0, 10.0)), cmd)
    assert out is cmd and g.interventions == 0 and g.last_speed_mps > 49.9 and g.last_force_in_n == 1e4


def test_the_guard_speed_is_the_separation_models_relative_braking():
    """Equal speeds, a fresh message: the guard speed is the largest v whose worst-case closing
    (RelativeBraking, dead time + 1.5 steps) fits the gap less margin and position errors."""
    g = SeparationGuard(STOCK, STOCK, 50.0)
    gap = MODEL.vc_gap(STOCK, STOCK, 50.0, message_age_s=0.0) + 1.5 * DT * 50.0 - 2.0  # a little short for 50 m/s (the guard adds 1.5 steps)
    out = g.limit(_obs(msg=_msg(gap, 50.0, 10.0)), Command(2e5))
    v_guard = out.info["guard_speed_mps"]
    assert RULE.closing(1000.0, v_guard, 1000.0 + gap + L, 50.0, DEAD) <= gap - MODEL.margin_m + 1e-6
    assert RULE.closing(1000.0, v_guard + 0.05, 1000.0 + gap + L, 50.0, DEAD) > gap - MODEL.margin_m
    assert 45.0 < v_guard < 50.0
    assert _speed_after(out.force_n, 50.0) == pytest.approx(v_guard, abs=1e-9) and g.interventions == 1


def test_an_older_message_makes_the_guard_stricter():
    """The same predecessor running at 50 m/s, heard of now or 2 s ago (then 100 m further back): it
    may have braked as hard as it can since the older message was sent."""
    fresh, old = SeparationGuard(STOCK, STOCK, 50.0), SeparationGuard(STOCK, STOCK, 50.0)
    fresh.limit(_obs(msg=_msg(400.0, 50.0, 10.0)), Command(2e5))
    old.limit(_obs(msg=_msg(300.0, 50.0, 8.0)), Command(2e5))
    assert old.last_speed_mps < fresh.last_speed_mps - 1.0


def test_the_sensor_is_trusted_only_when_configured():
    """SUMO's exact gap is a perfect sensor: by default the guard works on the channel alone."""
    obs = _obs(sensed_gap=5000.0, sensed_speed=50.0, msg=_msg(300.0, 50.0, 9.0))
    off, on = SeparationGuard(STOCK, STOCK, 50.0), SeparationGuard(STOCK, STOCK, 50.0, GuardConfig(sensor=True))
    off.limit(obs, Command(2e5))
    on.limit(obs, Command(2e5))
    assert off.last_speed_mps < on.last_speed_mps


def test_the_guard_never_asks_more_than_the_emergency_brake_and_flags_it():
    g = SeparationGuard(STOCK, STOCK, 50.0)
    out = g.limit(_obs(msg=_msg(5.0, 0.0, 10.0)), Command(0.0))  # a standing train 5 m ahead
    assert out.info["guard_speed_mps"] == 0.0
    assert out.force_n == pytest.approx(-P.mass_kg * P.emergency_brake_decel_mps2)
    assert out.emergency and out.force_n < -float(brake_force_limit(P, 50.0))


def test_predecessor_knowledge_sensed_then_message_then_nothing():
    msg = Message("L", 8.0, TrainStateMsg(8.0, 1000.0 + 500.0 + L, 40.0), L)
    sensed = predecessor_estimate(_obs(sensed_gap=400.0, sensed_speed=45.0, msg=msg), L)
    assert (sensed.source, sensed.front_m, sensed.speed_mps, sensed.age_s) == ("sensed", 1000.0 + 400.0 + L, 45.0, 0.0)
    told = predecessor_estimate(_obs(sensed_gap=400.0, sensed_speed=45.0, msg=msg), L, sensor=False)
    assert (told.source, told.front_m, told.speed_mps, told.age_s) == ("message", 1000.0 + 500.0 + L, 40.0, 2.0)
    blind = predecessor_estimate(_obs(msg=Message("L", 8.0, TrainStateMsg(8.0, math.nan, 40.0), L)), L)
    assert (blind.source, blind.front_m, blind.speed_mps) == ("none", 1000.0, 0.0)
    # knowing nothing, the follower is held at standstill speed: the predecessor may stand at its front
    g = SeparationGuard(STOCK, STOCK, 50.0)
    out = g.limit(_obs(), Command(1e5))
    assert g.last_speed_mps == 0.0 and out.force_n == pytest.approx(-P.mass_kg * P.emergency_brake_decel_mps2)


def test_near_its_stop_the_guard_keeps_to_the_guaranteed_service_curve():
    g = SeparationGuard(STOCK, STOCK, 50.0)
    g.limit(_obs(msg=_msg(20000.0, 50.0, 10.0)), Command(0.0))
    free = g.last_speed_mps
    g.limit(_obs(msg=_msg(20000.0, 50.0, 10.0), stop=1000.0 + 2000.0), Command(0.0))
    stop = g.last_speed_mps
    service = RouteBraking(MODEL, STOCK, PROFILE, "service")
    assert stop == pytest.approx(service.permitted_speed(1000.0, 3000.0, 0.0, 1.5 * DT, 50.0)) and stop < free


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
