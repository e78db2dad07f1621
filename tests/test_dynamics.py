"""Tier 1 — the train model against physics and the data sheet (no SUMO)."""

import math

import numpy as np
import pytest

from vcsumo.dynamics import (
    acceleration,
    balance_speed,
    brake_force_limit,
    braking_distance,
    curve_equivalent_gradient,
    curve_force,
    discrete_stop_speed,
    gradient_force,
    jerk_limit,
    lag_step,
    max_acceleration,
    running_resistance,
    traction_limit,
)
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.units import G


@pytest.fixture(scope="module")
def etr():
    return load_rolling_stock("etr1000").params()


@pytest.fixture(scope="module")
def felez():
    return load_rolling_stock("felez2019").params()


def test_davis_resistance_matches_hand_value(etr):
    # R = A + B v + C v^2 at 300 km/h: 8800 + 61.8*83.33 + 8.7*83.33^2
    v = 300 / 3.6
    assert running_resistance(etr, v) == pytest.approx(8800 + 61.8 * v + 8.7 * v * v)
    assert running_resistance(etr, v, tunnel_factor=1.5) - running_resistance(etr, v) == pytest.approx(0.5 * 8.7 * v * v)


def test_traction_is_force_limited_then_power_limited(etr):
    v_corner = etr.max_power_w / etr.max_traction_n  # 26.5 m/s
    assert traction_limit(etr, 0.5 * v_corner) == pytest.approx(etr.max_traction_n)
    assert traction_limit(etr, 2 * v_corner) == pytest.approx(etr.max_power_w / (2 * v_corner))
    # power never exceeded (eq. 4b)
    v = np.linspace(0.2, 100, 500)
    assert np.all(traction_limit(etr, v) * v <= etr.max_power_w * (1 + 1e-12))


def test_braking_power_limit_felez(felez):
    # Felez Table II: a_br = 0.92 -> 147.9 kN, P_br = 2.2 MW -> power-limited above 14.9 m/s
    assert brake_force_limit(felez, 5.0) == pytest.approx(160800 * 0.92)
    assert brake_force_limit(felez, 20.0) == pytest.approx(2.2e6 / 20.0)


def test_gradient_and_curve_forces(etr):
    assert gradient_force(etr, 0.015) == pytest.approx(500000 * G * 0.015)
    # Roeckl/Rochard 600/R N/kN: R = 600 m -> 1 N per kN of train weight (within 2 %: 6 vs 5.886)
    assert curve_force(etr, 600.0) / (etr.mass_kg * G / 1000.0) == pytest.approx(600.0 / 600.0, rel=0.02)
    assert curve_equivalent_gradient(600.0) * etr.mass_kg * G == pytest.approx(curve_force(etr, 600.0))
    assert curve_force(etr, math.inf) == 0.0


def test_balance_speeds_match_datasheet(etr, felez):
    # DATASHEET §2: proxy balance speed 355 km/h in the open, 313 km/h in tunnel (T_f 1.5),
    # about 242 km/h on a long 15 permille climb in tunnel; §3: Felez train ~85 km/h.
    free = etr.with_(max_speed_ms=150.0)
    assert balance_speed(free) * 3.6 == pytest.approx(355, abs=2)
    assert balance_speed(free, 0.0, 1.5) * 3.6 == pytest.approx(313, abs=2)
    assert balance_speed(free, 0.015, 1.5) * 3.6 == pytest.approx(242, abs=2)
    assert balance_speed(felez.with_(max_speed_ms=100.0)) * 3.6 == pytest.approx(85, abs=1.5)


def test_acceleration_is_zero_at_balance(etr):
    free = etr.with_(max_speed_ms=150.0)
    vb = balance_speed(free)
    assert max_acceleration(free, vb) == pytest.approx(0.0, abs=1e-6)
    assert max_acceleration(free, vb - 5) > 0 > max_acceleration(free, vb + 5)


def test_coasting_down_a_slope_gains_speed(etr):
    # OSRD-style sanity: coasting (u = 0) on -10 permille from 30 m/s for 30 s speeds the train up
    v, dt = 30.0, 0.1
    for _ in range(300):
        v += float(acceleration(etr, v, 0.0, gradient=-0.010)) * dt
    a_grav = G * 0.010 / etr.rotating_mass_factor
    assert 30.0 < v < 30.0 + a_grav * 30
    assert v == pytest.approx(30.0 + 30 * float(acceleration(etr, 31.5, 0.0, gradient=-0.010)), rel=0.02)


def test_braking_distance_and_discrete_stop_speed_are_inverse():
    for v in (5.0, 20.0, 83.33):
        d = braking_distance(v, 0.65, reaction_time_s=0.25)
        assert discrete_stop_speed(d, 0.65, dt=0.5) == pytest.approx(v, rel=1e-9)
    assert braking_distance(83.33, 0.65) == pytest.approx(83.33**2 / 1.3)


def test_lag_and_jerk(felez):
    # eq. 1c: tau = 0.25, dt = 0.1 -> F moves 40 % of the way
    assert lag_step(0.0, 1000.0, 0.25, 0.1) == pytest.approx(400.0)
    assert lag_step(0.0, 1000.0, 0.0, 0.1) == 1000.0
    # eq. 4c: j_max M dt = 0.98 * 160800 * 0.1
    step = 0.98 * 160800 * 0.1
    assert jerk_limit(0.0, 1e6, felez, 0.1) == pytest.approx(step)
    assert jerk_limit(0.0, -1e6, felez, 0.1) == pytest.approx(-step)


def test_casadi_flavour_gives_the_same_numbers(etr):
    import casadi as ca

    v = ca.SX.sym("v")
    f = ca.Function("f", [v], [max_acceleration(etr, v, 0.01, 1.5)])
    for vv in (1.0, 30.0, 80.0):
        assert float(f(vv)) == pytest.approx(float(max_acceleration(etr, vv, 0.01, 1.5)), rel=1e-12)
