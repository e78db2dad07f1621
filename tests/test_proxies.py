"""Robust proxies (Terlizzi et al. 2024, eq. 7, 12, 13) and the route bounds they use."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vcsumo.control.proxies import BoxBounds, GradeWindow, RobustProxies, StopIntegral, robust_plan, sample_params
from vcsumo.line import load_line
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.topology import build_topology
from vcsumo.units import G


@pytest.fixture(scope="module")
def profile() -> RouteProfile:
    topo = build_topology(load_line("firenze_bologna"))
    return RouteProfile.from_edges(topo, topo.track_for("main", "up").edges)


@pytest.fixture(scope="module")
def follower():
    return load_rolling_stock("terlizzi2024_follower")


def test_box_bounds_are_table_iii(follower):
    b = BoxBounds.from_stock(follower)
    assert (b.mass_low_kg, b.mass_high_kg) == (4.5e5, 5.5e5)
    assert (b.davis_a_low_n, b.davis_a_high_n) == (25.11, 28.24)
    assert (b.brake_decel_low_mps2, b.brake_decel_high_mps2) == (0.59, 0.70)
    assert (b.accel_low_mps2, b.accel_high_mps2) == (0.92, 1.08)
    # braking power is not limited for the Table III trains (see their rolling-stock notes)
    assert math.isinf(b.brake_power_low_w) and math.isinf(b.brake_power_high_w)
    assert b.contains(follower.params())


def test_sampled_params_lie_in_the_box(follower):
    b = BoxBounds.from_stock(follower)
    rng = np.random.default_rng(3)
    for corner in (False, True):
        for _ in range(50):
            assert b.contains(sample_params(follower, rng, corner=corner))


def test_robust_input_sets_eq16(follower):
    b = BoxBounds.from_stock(follower)
    # low speed: force limits M·a; high speed: power limits P/v of the weakest/strongest train
    assert b.robust_traction_max_n(1.0) == pytest.approx(4.5e5 * 0.92)
    assert b.robust_traction_max_n(60.0) == pytest.approx(9539260.0 / 60.0)
    assert b.robust_brake_max_n(1.0) == pytest.approx(4.5e5 * 0.59)
    assert b.strongest_brake_n(1.0) == pytest.approx(5.5e5 * 0.70)
    # α̲ of §V: weakest full-brake deceleration (no braking-power limit: a̲_br at every speed)
    assert b.brake_decel_low(10.0) == pytest.approx(0.59)
    assert b.brake_decel_low(80.0) == pytest.approx(0.59)
    # with a braking-power box the weakest deceleration becomes power-limited at high speed
    from vcsumo.rolling_stock import Interval

    boxed = follower.model_copy(update={"max_brake_power_w": 1.0e7, "uncertainty": follower.uncertainty.model_copy(update={"max_brake_power_w": Interval(low=9.5e6, high=1.06e7)})})
    bb = BoxBounds.from_stock(boxed)
    assert bb.brake_decel_low(80.0) == pytest.approx(9.5e6 / (5.5e5 * 80.0))


def test_point_box_proxies_equal_the_model_on_level_track():
    """With no uncertainty and an admissible traction input, eq. 12 and 13 reduce to eq. 5."""
    stock = load_rolling_stock("terlizzi2024_follower").model_copy(update={"uncertainty": None})  # exactly known
    p = stock.params()
    prox = RobustProxies(BoxBounds.from_stock(stock), None)
    f = np.full(300, 0.5 * p.max_traction_n * 0.3)
    plant = TrainPlant(p, PlantState(0.0, 20.0), None, apply_lag=False, apply_jerk=False)
    s_true, v_true = [0.0], [20.0]
    for u in f:
        x = plant.step(u, 0.1)
        s_true.append(x.s_m)
        v_true.append(x.v_mps)
    s_lo, v_lo = prox.rollout("lower", 0.0, 20.0, f, 0.1)
    s_hi, v_hi = prox.rollout("upper", 0.0, 20.0, f, 0.1)
    np.testing.assert_allclose(s_lo, s_true, rtol=0, atol=1e-6)
    np.testing.assert_allclose(s_hi, s_true, rtol=0, atol=1e-6)
    np.testing.assert_allclose(v_lo, v_true, rtol=0, atol=1e-9)


unit = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    fracs=st.lists(unit, min_size=8, max_size=8),
    corner=st.booleans(),
    v0=st.floats(min_value=0.0, max_value=83.0),
    s0=st.floats(min_value=0.0, max_value=88000.0),
    forces=st.lists(st.floats(min_value=-8e5, max_value=8e5), min_size=1, max_size=6),
)
def test_rlp_below_and_rup_above_every_true_trajectory(profile, follower, fracs, corner, v0, s0, forces):
    """Definitions 8 and 9 / Lemma IV.1: RLP ≤ true ≤ RUP component-wise, for p anywhere in the box."""
    box = follower.uncertainty_box()
    if corner:
        fracs = [round(f) for f in fracs]

    def pick(iv, f):
        return iv.low + f * (iv.high - iv.low)

    m = pick(box.mass_kg, fracs[0])
    p = follower.params().with_(
        mass_kg=m,
        davis_a_n=pick(box.davis_a_n, fracs[1]),
        davis_b_n_per_mps=pick(box.davis_b_n_per_mps, fracs[2]),
        davis_c_n_per_mps2=pick(box.davis_c_n_per_mps2, fracs[3]),
        max_traction_n=m * pick(box.max_accel_mps2, fracs[4]),
        service_brake_decel_mps2=pick(box.service_brake_decel_mps2, fracs[5]),
        max_power_w=pick(box.max_power_w, fracs[6]),
        max_brake_power_w=math.inf if box.max_brake_power_w is None else pick(box.max_brake_power_w, fracs[7]),
    )
    dt, n_per = 0.1, 40
    f = np.repeat(np.asarray(forces, dtype=float), n_per)  # piecewise-constant commands, 4 s each
    plant = TrainPlant(p, PlantState(s0, v0), profile)
    s_true, v_true = [s0], [v0]
    for u in f:
        x = plant.step(u, dt)
        s_true.append(x.s_m)
        v_true.append(x.v_mps)
    prox = RobustProxies(BoxBounds.from_stock(follower), profile)
    s_lo, v_lo = prox.rollout("lower", s0, v0, f, dt)
    s_hi, v_hi = prox.rollout("upper", s0, v0, f, dt)
    tol = 1e-7
    assert np.all(s_lo <= np.array(s_true) + tol)
    assert np.all(v_lo <= np.array(v_true) + tol)
    assert np.all(np.array(s_true) <= s_hi + tol)
    assert np.all(np.array(v_true) <= v_hi + tol)


def test_leader_and_follower_decelerations_bound_the_true_full_brake(profile, follower):
    """e̲^L ≥ true full-brake deceleration ≥ ē^F for every p in the box (§V)."""
    prox = RobustProxies(BoxBounds.from_stock(follower), profile)
    rng = np.random.default_rng(11)
    for _ in range(300):
        p = sample_params(follower, rng, corner=bool(rng.random() < 0.5))
        s = float(rng.uniform(0, 90000))
        v = float(rng.uniform(0.5, 83))
        rb = prox.route.bounds(s - p.length_m, s + 10.0)
        plant = TrainPlant(p, PlantState(s, v), profile)
        x = plant.step(-1e9, 0.01)  # full brake: the plant saturates at its own envelope
        true_decel = (v - x.v_mps) / 0.01
        assert prox.leader_decel(v, rb) >= true_decel - 1e-9
        assert prox.follower_decel(v, rb, 0.98) <= true_decel + 1e-9


def test_grade_window_extrema(profile):
    gw = GradeWindow(profile)
    rb = gw.bounds(9000.0, 20000.0)  # 0.6 % then 1.5 % then 0.95 % up
    assert rb.grade_min == pytest.approx(0.006)
    assert rb.grade_max == pytest.approx(0.015)
    assert rb.tunnel_max == pytest.approx(1.5)
    assert GradeWindow(None).bounds(0, 1e6).grade_max == 0.0


def test_stop_integral_matches_constant_grade_formula_and_brute_force(profile):
    level = StopIntegral(None, 200.0)
    assert level.stop_point(100.0, 30.0, 0.5) == pytest.approx(100.0 + 30.0**2 / 1.0)
    si = StopIntegral(profile, 202.0)
    # inside the long 1.5 % up-grade the train-averaged grade is constant
    assert si.stop_point(12000.0, 40.0, 0.4) == pytest.approx(12000.0 + 1600.0 / (2 * (0.4 + G * 0.015)))
    # across grade changes: compare with a fine integration of d(v²/2)/dx = −(a + g·G(x))
    for x0, v, a in [(47000.0, 60.0, 0.2), (36000.0, 70.0, 0.3), (86000.0, 40.0, 0.5)]:
        x, e, h = x0, 0.5 * v * v, 0.05
        while e > 0:
            e -= (a + G * profile.mean_gradient(x, 202.0)) * h
            x += h
        assert si.stop_point(x0, v, a) == pytest.approx(x, abs=0.2)
        assert si.grade_at(x0 + 123.0) == pytest.approx(profile.mean_gradient(x0 + 123.0, 202.0), abs=1e-12)


def test_stop_integral_is_monotone_in_position_and_speed(profile):
    si = StopIntegral(profile, 202.0)
    xs = np.linspace(30000, 70000, 400)
    stops = [si.stop_point(x, 50.0, 0.35) for x in xs]
    assert np.all(np.diff(stops) > 0)
    assert si.stop_point(50000.0, 51.0, 0.35) > si.stop_point(50000.0, 50.0, 0.35)


def test_robust_plan_is_the_rlp_of_the_planned_forces(profile):
    leader = load_rolling_stock("terlizzi2024_leader")
    prox = RobustProxies.from_stock(leader, profile)
    f = np.full(120, 1.0e5)
    t, s, v = robust_plan(prox, 20000.0, 50.0, f, 0.1, 100.0, every=5)
    s_full, v_full = prox.rollout("lower", 20000.0, 50.0, f, 0.1)
    assert t[0] == 100.0 and t[-1] == pytest.approx(112.0)
    assert s[-1] == s_full[-1] and v[-1] == v_full[-1]
    assert math.isclose(s[1], s_full[5])


def test_route_profile_lookups_do_not_depend_on_the_order_of_queries(profile):
    """RouteProfile remembers the last edge found and the last train-length look-ups (per-step
    speed-ups): any sequence of queries gives what a fresh profile answers to each one alone."""
    from bisect import bisect_right

    rng = np.random.default_rng(7)
    walk = profile
    s = 0.0
    for _ in range(3000):
        r = rng.random()
        s = s + rng.uniform(-5.0, 90.0) if r < 0.6 else (float(rng.uniform(-1000.0, profile.length_m + 1000.0)) if r < 0.9 else float(profile.starts_m[rng.integers(len(profile.starts_m))]))
        L = float(rng.choice([0.0, 202.0, 404.0]))
        fresh = RouteProfile(**{f: getattr(profile, f) for f in ("edges", "starts_m", "lengths_m", "speeds_ms", "gradients", "tunnel_factors", "sections", "km_from", "km_to", "point_limits")})
        i = min(max(bisect_right(list(profile.starts_m), s) - 1, 0), len(profile.edges) - 1)
        assert walk.index_at(s) == fresh.index_at(s) == i
        for name, args in (("mean_gradient", (s, L)), ("speed_limit_train", (s, L)), ("tunnel_factor_at", (s,)), ("km_at", (s,)), ("gradient_range", (s, s + L))):
            assert getattr(walk, name)(*args) == getattr(fresh, name)(*args), (name, args)
        sec, km = walk.km_at(s)
        sign = 1.0 if profile.km_to[i] >= profile.km_from[i] else -1.0
        assert (sec, km) == (profile.sections[i], float(profile.km_from[i] + sign * (s - profile.starts_m[i]) / 1000.0))
