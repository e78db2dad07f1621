"""Gap references (survey eq. 3.1–3.6, 3.10)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vcsumo.control.gap_reference import (
    ExpTransition,
    JerkLimitedTransition,
    JerkProfile,
    SinTransition,
    SteadyGap,
    exp_accel_coefficients,
    exp_transition_accel_mps2,
    exp_transition_gap_m,
    jerk_limited_speed_mps,
    leader_offset_m,
    rbd_gap_m,
    sin_transition_coefficients,
    sin_transition_gap_m,
    steady_gap_m,
)

STEADY = SteadyGap(d_min_m=50.0, headway_s=1.5)


# ---------------------------------------------------------------------------------------------
# eq. 3.1, 3.10


def test_eq31_relative_braking_gap():
    # equal speeds: the constant safety margin
    assert rbd_gap_m(40.0, 40.0, 80.0, 0.65) == pytest.approx(80.0)
    # follower 10 m/s faster than its predecessor at a_b = 0.5: + (50² − 40²)/(2·0.5) = 900 m
    assert rbd_gap_m(50.0, 40.0, 80.0, 0.5) == pytest.approx(980.0)
    # slower follower needs less than D_safe
    assert rbd_gap_m(30.0, 40.0, 80.0, 0.5) < 80.0
    with pytest.raises(ValueError):
        rbd_gap_m(1.0, 1.0, 1.0, 0.0)


def test_steady_spacing_policies():
    assert steady_gap_m(40.0, 50.0) == 50.0  # constant distance
    assert steady_gap_m(40.0, 50.0, headway_s=1.5) == pytest.approx(110.0)  # constant time headway
    assert steady_gap_m(40.0, 50.0, 1.5, predecessor_speed_mps=30.0, brake_decel_mps2=0.5) == pytest.approx(110.0 + 700.0)
    assert STEADY.gap_m(20.0) == pytest.approx(80.0)
    assert STEADY.evaluate(0.0, 0.0, 40.0, 40.0).gap_m == pytest.approx(110.0)


def test_eq310_leader_offset():
    # x_i = x_0 − D_i with D_i = Σ (d_m + L_{m−1})
    assert leader_offset_m([100.0, 120.0], [202.0, 68.0]) == pytest.approx(490.0)
    with pytest.raises(ValueError):
        leader_offset_m([1.0], [])


# ---------------------------------------------------------------------------------------------
# eq. 3.2–3.3


def test_eq32_exponential_transition_continuous_and_reaches_end():
    tr = ExpTransition.between(10.0, 800.0, 0.05, STEADY, 40.0)
    assert tr.k1_m == pytest.approx(690.0)
    # held before the start, continuous at the start
    assert tr.evaluate(0.0, 0.0, 40.0, 40.0).gap_m == pytest.approx(800.0)
    assert tr.evaluate(10.0, 0.0, 40.0, 40.0).gap_m == pytest.approx(800.0)
    assert tr.evaluate(10.0 + 1e-6, 0.0, 40.0, 40.0).gap_m == pytest.approx(800.0, abs=1e-3)
    # monotone decay to d^de: within 0.1 m after ln(6900)/k2 s
    t = np.linspace(10.0, 10.0 + math.log(6900.0) / 0.05, 2000)
    g = np.array([tr.evaluate(x, 0.0, 40.0, 40.0).gap_m for x in t])
    assert np.all(np.diff(g) < 0)
    assert g[-1] == pytest.approx(110.0, abs=0.1)
    # rate and acceleration are the derivatives of the value
    s = tr.evaluate(30.0, 0.0, 40.0, 40.0)
    h = 1e-4
    num_rate = (tr.evaluate(30.0 + h, 0, 40, 40).gap_m - tr.evaluate(30.0 - h, 0, 40, 40).gap_m) / (2 * h)
    assert s.rate_mps == pytest.approx(num_rate, rel=1e-6)
    num_acc = (tr.evaluate(30.0 + h, 0, 40, 40).rate_mps - tr.evaluate(30.0 - h, 0, 40, 40).rate_mps) / (2 * h)
    assert s.accel_mps2 == pytest.approx(num_acc, rel=1e-6)
    assert exp_transition_gap_m(20.0, 690.0, 0.05, 110.0) == pytest.approx(tr.evaluate(30.0, 0, 40, 40).gap_m)


def test_eq33_follower_acceleration_matches_eq32():
    """Behind a constant-speed leader the follower acceleration is −d̈ of eq. 3.2, i.e. eq. 3.3 with k3 = −k1 k2, k4 = k2."""
    k1, k2 = 690.0, 0.05
    k3, k4 = exp_accel_coefficients(k1, k2)
    tr = ExpTransition(0.0, k1, k2, STEADY)
    for t in (0.0, 5.0, 40.0, 200.0):
        assert exp_transition_accel_mps2(t, k3, k4) == pytest.approx(-tr.evaluate(t, 0, 40, 40).accel_mps2)
    # Profile 1 of Fig. 4 starts with a non-zero acceleration
    assert abs(exp_transition_accel_mps2(0.0, k3, k4)) > 0


# ---------------------------------------------------------------------------------------------
# eq. 3.4–3.5


def test_eq35_coefficients_and_endpoints():
    k1, k2, k3, k4 = sin_transition_coefficients(800.0, 110.0, 1000.0, 5000.0)
    assert (k1, k4) == pytest.approx((345.0, 455.0))
    assert k2 == pytest.approx(math.pi / 4000.0)
    assert k3 == pytest.approx((5000.0 - 3000.0) / 2)
    assert sin_transition_gap_m(1000.0, 800.0, 110.0, 1000.0, 5000.0) == pytest.approx(800.0)
    assert sin_transition_gap_m(5000.0, 800.0, 110.0, 1000.0, 5000.0) == pytest.approx(110.0)
    assert sin_transition_gap_m(0.0, 800.0, 110.0, 1000.0, 5000.0) == pytest.approx(800.0)
    assert sin_transition_gap_m(9e9, 800.0, 110.0, 1000.0, 5000.0) == pytest.approx(110.0)


@pytest.mark.parametrize("d0", [800.0, 60.0])  # merge and split
def test_eq34_sinusoidal_transition_continuous_monotone_flat_ends(d0):
    tr = SinTransition(1000.0, 5000.0, d0, STEADY)
    x = np.linspace(0.0, 6000.0, 6001)
    g = np.array([tr.evaluate(0.0, xx, 40.0, 40.0).gap_m for xx in x])
    assert np.max(np.abs(np.diff(g))) < abs(d0 - 110.0) * math.pi / 4000.0 * 1.0 + 1e-9  # Lipschitz: |dd/dx| ≤ |k1|k2
    assert g[0] == pytest.approx(d0) and g[-1] == pytest.approx(110.0)
    inner = np.diff(g[(x >= 1000) & (x <= 5000)])
    assert np.all(inner * np.sign(110.0 - d0) >= -1e-12)  # monotone towards the end value
    # zero slope at both ends (C¹ joins to the constant parts)
    assert tr.evaluate(0.0, 1000.0 + 1e-6, 40.0, 40.0).rate_mps == pytest.approx(0.0, abs=1e-6)
    assert tr.evaluate(0.0, 5000.0 - 1e-6, 40.0, 40.0).rate_mps == pytest.approx(0.0, abs=1e-6)
    # rate = dd/dx · v
    h = 1e-3
    s = tr.evaluate(0.0, 2500.0, 40.0, 40.0)
    dd_dx = (tr.evaluate(0, 2500.0 + h, 40, 40).gap_m - tr.evaluate(0, 2500.0 - h, 40, 40).gap_m) / (2 * h)
    assert s.rate_mps == pytest.approx(dd_dx * 40.0, rel=1e-5)


# ---------------------------------------------------------------------------------------------
# eq. 3.6


def _sampled(profile: JerkProfile, dt: float = 0.01):
    t = np.arange(0.0, profile.duration_s + 5.0, dt)
    sva = np.array([profile.state(x) for x in t])
    return t, sva


def test_eq36_speed_section():
    """In the constant-acceleration section v = v0 + ½ J t1² + a_max (t − t1) (eq. 3.6)."""
    prof = JerkProfile.design(600.0, jerk_mps3=0.1, max_accel_mps2=0.15, idle_s=25.0)
    assert prof.peak_accel_mps2 == pytest.approx(0.15) and prof.hold_s > 0
    t1 = prof.t1_s
    assert t1 == pytest.approx(0.15 / 0.1)
    for t in np.linspace(t1, t1 + prof.hold_s, 7):
        assert jerk_limited_speed_mps(t, 40.0, prof) == pytest.approx(40.0 + 0.5 * 0.1 * t1**2 + 0.15 * (t - t1))
    assert jerk_limited_speed_mps(prof.duration_s, 40.0, prof) == pytest.approx(40.0, abs=1e-9)
    assert jerk_limited_speed_mps(prof.t1_s * 2 + prof.hold_s, 40.0, prof, sign=-1) == pytest.approx(40.0 - prof.peak_speed_mps)


@settings(max_examples=40, deadline=None)
@given(
    distance=st.floats(1.0, 3000.0),
    jerk=st.floats(0.05, 1.0),
    accel=st.floats(0.05, 1.0),
    idle=st.floats(0.0, 40.0),
    cap=st.one_of(st.none(), st.floats(0.5, 20.0)),
)
def test_eq36_profile_limits_continuity_and_end(distance, jerk, accel, idle, cap):
    prof = JerkProfile.design(distance, jerk, accel, idle, cap)
    t, sva = _sampled(prof, dt=max(prof.duration_s / 4000.0, 1e-3))
    s, v, a = sva.T
    dt = t[1] - t[0]
    assert s[-1] == pytest.approx(distance, rel=1e-9, abs=1e-9)  # reaches the end value
    assert v[-1] == pytest.approx(0.0, abs=1e-9) and a[-1] == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.abs(a) <= accel * (1 + 1e-9))
    if cap is not None:
        assert np.all(v <= cap * (1 + 1e-9))
    assert prof.idle_s >= idle - 1e-9
    # continuity: increments bounded by the derivative bounds
    assert np.max(np.abs(np.diff(a))) <= jerk * dt * (1 + 1e-6) + 1e-12
    assert np.max(np.abs(np.diff(v))) <= accel * dt * (1 + 1e-6) + 1e-12
    assert np.all(np.diff(s) >= -1e-12)
    # idle phase: zero acceleration between traction and braking
    t_idle = 2 * prof.t1_s + prof.hold_s + 0.5 * prof.idle_s
    assert prof.state(t_idle)[2] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("d0,steady", [(800.0, STEADY), (110.0, SteadyGap(d_min_m=500.0, headway_s=1.5))])
def test_jerk_limited_transition_merge_and_split(d0, steady):
    tr = JerkLimitedTransition.design(5.0, d0, steady, 40.0, jerk_mps3=0.1, max_accel_mps2=0.15, idle_s=25.0)
    end = steady.gap_m(40.0)
    t = np.arange(0.0, tr.end_time_s + 10.0, 0.05)
    g = np.array([tr.evaluate(x, 0.0, 40.0, 40.0).gap_m for x in t])
    assert g[0] == pytest.approx(d0) and g[-1] == pytest.approx(end)
    assert np.all(np.diff(g) * np.sign(end - d0) >= -1e-9)
    sample = [tr.evaluate(x, 0.0, 40.0, 40.0) for x in t]
    assert max(abs(s.accel_mps2) for s in sample) <= 0.15 + 1e-9
    assert tr.evaluate(tr.end_time_s + 1.0, 0.0, 40.0, 40.0).rate_mps == pytest.approx(0.0, abs=1e-9)
