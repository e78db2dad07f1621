"""DP speed profile (Felez et al. 2019, eq. 10) and the NMPC terminal set built from it."""

from __future__ import annotations

import numpy as np
import pytest

from vcsumo.control.dp_profile import DPSettings, dp_speed_profile
from vcsumo.control.mpc_terminal import discrete_braking_curves, terminal_set
from vcsumo.control.route_lookup import RouteLookup, route_profile_from_arrays, straight_route_profile
from vcsumo.control.predictors import model_step
from vcsumo.dynamics import balance_speed, brake_force_limit, gradient_force, running_resistance, traction_limit
from vcsumo.rolling_stock import load_rolling_stock


@pytest.fixture(scope="module")
def params():
    return load_rolling_stock("felez2019").params()


@pytest.fixture(scope="module")
def hilly_route():
    """27.78 m/s line with a 15 m/s restriction, a 10 ‰ climb and a 5 ‰ descent, 4 km."""
    return route_profile_from_arrays(
        starts_m=[0.0, 1200.0, 1800.0, 2600.0],
        speeds_mps=[27.78, 15.0, 27.78, 27.78],
        gradients=[0.0, 0.010, 0.0, -0.005],
        length_m=4000.0,
    )


def _implied_force(params, S, V, lookup):
    """Force each DP step needs (inverse of eq. 10c with eq. 1b)."""
    va, vb, ds = V[:-1], V[1:], np.diff(S)
    g, tf = lookup.gradient(S[:-1]), lookup.tunnel_factor(S[:-1])
    return params.mass_kg * (vb**2 - va**2) / (2 * ds) + running_resistance(params, va, tf) + gradient_force(params, g)


def test_dp_never_exceeds_limit_and_is_reachable(params, hilly_route):
    dp = dp_speed_profile(params, hilly_route, 0.0, 4000.0, 0.0, 0.0)
    lookup = RouteLookup(hilly_route, params.length_m)
    S, V = dp.positions_m, dp.v_dp_mps
    vlim = lookup.speed_limit(S)
    assert np.all(V <= vlim + 1e-9)  # (10f)
    assert np.all(dp.v_max_mps <= vlim + 1e-9)
    assert np.all(V <= dp.v_max_mps + 1e-9)
    assert V[0] == 0.0 and V[-1] == 0.0  # starts at rest, (10g) v_f = 0
    u = _implied_force(params, S, V, lookup)
    va = V[:-1]
    # every step is feasible for force and power (10d, 10e); stopping within a step may brake less than maximum
    assert np.all(u <= traction_limit(params, va) + 1.0)
    stopping = V[1:] == 0.0
    assert np.all((u >= -brake_force_limit(params, va) - 1.0) | stopping)
    # the grid is fine where the train is slow and coarse where it is fast (§III-C)
    ds = np.diff(S)
    assert ds.min() >= 0.01 - 1e-9 and ds.max() <= 5.0 + 1e-9
    assert np.median(ds[V[:-1] > 15]) > 3.0


def test_dp_restriction_is_respected_by_whole_train(params, hilly_route):
    dp = dp_speed_profile(params, hilly_route, 0.0, 4000.0)
    # the 15 m/s limit holds from its start until the train's tail has left it (1800 + L)
    inside = (dp.positions_m >= 1200.0) & (dp.positions_m <= 1800.0 + params.length_m)
    assert np.all(dp.v_dp_mps[inside] <= 15.0 + 1e-9)
    after = (dp.positions_m > 1800.0 + params.length_m + 1.0) & (dp.positions_m < 1900.0)
    assert np.all(dp.v_dp_mps[after] > 15.0)  # accelerates again only once the tail is out


def test_dp_is_the_fastest_profile(params):
    """On a long level line the DP profile reaches the balance speed (Fig. 8: about 23 m/s)
    and brakes as late as the brakes allow."""
    route = straight_route_profile(6000.0, 27.78)
    dp = dp_speed_profile(params, route, 0.0, 6000.0)
    vb = balance_speed(params)
    assert 22.5 < dp.v_dp_mps.max() <= vb + 0.05
    # braking envelope: v² ≈ 2·b·distance-to-go near the end (b: brake + resistance at low speed)
    s_end = 6000.0
    near = (dp.positions_m > s_end - 30) & (dp.positions_m < s_end - 1)
    b_lo = (brake_force_limit(params, 7.0) + running_resistance(params, 0.0)) / params.mass_kg
    b_hi = (brake_force_limit(params, 0.1) + running_resistance(params, 7.0)) / params.mass_kg
    v2 = dp.v_dp_mps[near] ** 2
    dist = s_end - dp.positions_m[near]
    assert np.all(v2 <= 2 * b_hi * dist + 0.5) and np.all(v2 >= 2 * b_lo * dist * 0.9 - 0.5)


def test_dp_cache_returns_same_object(params):
    route = straight_route_profile(1500.0, 20.0)
    a = dp_speed_profile(params, route, 0.0, 1500.0)
    b = dp_speed_profile(params, route, 0.0, 1500.0)
    c = dp_speed_profile(params, route, 0.0, 1500.0, settings=DPSettings(dv_mps=0.2))
    assert a is b and c is not a


def test_route_lookup_matches_route_profile(params, hilly_route):
    lk = RouteLookup(hilly_route, params.length_m)
    rng = np.random.default_rng(1)
    s = np.concatenate([rng.uniform(0, 4000, 200), [0.0, 1200.0, 1800.0, 1868.0, 1868.5, 3999.9]])
    for x in s:
        assert lk.speed_limit(np.array([x]))[0] == pytest.approx(hilly_route.speed_limit_train(x, params.length_m))
        assert lk.gradient(np.array([x]))[0] == pytest.approx(hilly_route.mean_gradient(x, params.length_m), abs=1e-12)
        assert lk.tunnel_factor(np.array([x]))[0] == pytest.approx(hilly_route.tunnel_factor_at(x))
    assert not lk.uniform and RouteLookup(straight_route_profile(100.0, 10.0), 50.0).uniform


def test_terminal_set_is_invariant_for_the_nmpc_model(params, hilly_route):
    """From any point on the terminal-set boundary with the brake applied, braking with the
    time-discrete NMPC model (eq. 6b with the lag 1c) never leaves the set and stops before the end."""
    dp = dp_speed_profile(params, hilly_route, 0.0, 4000.0)
    ts = terminal_set(params, hilly_route, dp, 0.1)
    lk = RouteLookup(hilly_route, params.length_m)
    assert np.all(ts.v_max_mps <= dp.v_max_mps.max() + 1e-9)
    assert np.all(ts.terminal_bound(ts.positions_m) <= dp.terminal_bound(ts.positions_m) + 1e-9)
    for s0 in (900.0, 1150.0, 3500.0, 3900.0, 3990.0):
        v = float(ts.terminal_bound(s0))
        s, F = s0, -float(brake_force_limit(params, v))
        for _ in range(600):
            u = -float(brake_force_limit(params, v))
            s, v, F = model_step(params, s, v, F, u, 0.1, float(lk.gradient(np.array([s]))[0]), 1.0, 0.0)
            assert v <= float(ts.terminal_bound(s)) + 1e-6
            assert v <= float(lk.speed_limit(np.array([s]))[0]) + 1e-6
            if v == 0.0:
                break
        assert s <= 4000.0 + 1e-6


def test_terminal_set_beta_extends_past_the_end(params):
    route = straight_route_profile(2000.0, 25.0)
    dp = dp_speed_profile(params, route, 0.0, 2000.0)
    ts = terminal_set(params, route, dp, 0.1)
    b_end, slope_end = ts.beta(2000.0 + 1.0)
    assert b_end < 0 and slope_end < 0
    b, slope = ts.beta(1990.0)
    assert b == pytest.approx(float(ts.terminal_bound(1990.0)) ** 2, rel=1e-3)  # v² vs v interpolation
    assert slope < 0
    # scalar and vector paths agree
    bv, sv = ts.beta(np.array([1990.0, 2001.0]))
    assert bv[0] == pytest.approx(b) and bv[1] == pytest.approx(b_end) and sv[1] == pytest.approx(slope_end)


def test_discrete_braking_curve_is_followed_by_the_model(params):
    route = straight_route_profile(3000.0, 30.0)
    lk = RouteLookup(route, params.length_m)
    (cs, cv), = discrete_braking_curves(params, lk, [(3000.0, 0.0)], 0.1, 25.0, 0.0, brake_fraction=1.0)
    assert cs[-1] == 3000.0 and cv[-1] == 0.0 and cv[0] >= 25.0
    assert np.all(np.diff(cs) > 0) and np.all(np.diff(cv) < 0)
    # forward Euler with the brake force of the curve reproduces it point by point (no lag)
    p0 = params.with_(traction_lag_s=0.0)
    s, v = cs[0], cv[0]
    for k in range(len(cs) - 1):
        s, v, _ = model_step(p0, s, v, 0.0, -float(brake_force_limit(p0, v)), 0.1, 0.0, 1.0, 0.0)
        assert s == pytest.approx(cs[k + 1], abs=1e-6) and v == pytest.approx(cv[k + 1], abs=1e-6)
