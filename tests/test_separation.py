"""The separation model against hand-checked figures (shared note *safe-separation*) and against a
brute-force simulation of the worst case."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.separation import (
    SeparationModel,
    absolute_braking_gap,
    authority_speed,
    guaranteed_decel,
    leader_worst_state,
    relative_braking_gap,
    relative_braking_speed,
    strongest_decel,
)
from vcsumo.units import G


def simulate_min_gap(gap0, v_f, v_l, a_f, a_l, dead, dt=1e-3):
    """Brute force: both trains integrated exactly per step (leader braking from t = 0, follower after
    the dead time); the smallest front-to-rear gap over the episode."""
    t, x_f, x_l, vf, vl, worst = 0.0, 0.0, gap0, v_f, v_l, gap0
    while vf > 0.0 or vl > 0.0:
        al = a_l if vl > 0 else 0.0
        af = a_f if (t >= dead and vf > 0) else 0.0
        dl = min(vl * dt - 0.5 * al * dt * dt, vl * vl / (2 * al)) if al else vl * dt
        df = min(vf * dt - 0.5 * af * dt * dt, vf * vf / (2 * af)) if af else vf * dt
        x_l += dl
        x_f += df
        vl = max(0.0, vl - al * dt)
        vf = max(0.0, vf - af * dt)
        t += dt
        worst = min(worst, x_l - x_f)
    return worst


def test_note_oracle_300_kmh_level_track():
    """83.3 m/s, emergency 1.2 m/s² ±10 %: v²/2·(1/1.08 − 1/1.32) ≈ 583 m; with T = 1.5 s (+125 m),
    d_min 50 m and e_pos 2 × 10 m: ≈ 780 m (safe-separation note)."""
    v = 300 / 3.6
    assert relative_braking_gap(v, v, 1.08, 1.32, 0.0) == pytest.approx(584.5, abs=2.0)
    assert relative_braking_gap(v, v, 1.08, 1.32, 1.5) + 50 + 20 == pytest.approx(780, abs=5.0)
    # the stopping-distance difference equals the exact maximum when the follower brakes weaker
    assert relative_braking_gap(v, v, 1.08, 1.32, 1.5) == pytest.approx(v * 1.5 + v * v / 2 * (1 / 1.08 - 1 / 1.32), rel=1e-12)


def test_heavy_leader_light_follower_is_not_a_negative_term():
    """Follower brakes harder than the leader can: the stopping-point difference is negative, the
    true worst closing happens mid-braking and is positive."""
    v = 50.0
    naive = v * 2.0 + v * v / 2 * (1 / 1.3 - 1 / 0.9)
    exact = relative_braking_gap(v, v, 1.3, 0.9, 2.0)
    assert naive < 0.5 * exact
    # closed form: D'(t) = a_f·T + (a_l − a_f)·t = 0 at t* = a_f·T/(a_f − a_l)
    t_star = 1.3 * 2.0 / (1.3 - 0.9)
    d_star = (v * 2.0 + v * (t_star - 2.0) - 0.5 * 1.3 * (t_star - 2.0) ** 2) - (v * t_star - 0.5 * 0.9 * t_star ** 2)
    assert exact == pytest.approx(d_star, rel=1e-9)
    assert simulate_min_gap(exact + 1.0, v, v, 1.3, 0.9, 2.0) == pytest.approx(1.0, abs=0.05)


@settings(max_examples=60, deadline=None)
@given(v_f=st.floats(0.0, 90.0), v_l=st.floats(0.0, 90.0), a_f=st.floats(0.3, 2.0), a_l=st.floats(0.3, 2.0), dead=st.floats(0.0, 4.0))
def test_relative_gap_is_the_exact_worst_closing(v_f, v_l, a_f, a_l, dead):
    gap = relative_braking_gap(v_f, v_l, a_f, a_l, dead)
    assert gap >= 0.0
    # starting exactly that far apart the trains just touch (within the integration error) ...
    assert simulate_min_gap(gap + 1.0, v_f, v_l, a_f, a_l, dead, dt=2e-3) >= 1.0 - 0.2
    # ... and any closer they would not keep that distance
    if gap > 1.0:
        assert simulate_min_gap(gap - 1.0 + 1.0, v_f, v_l, a_f, a_l, dead, dt=2e-3) < 1.0 + 0.2


def test_absolute_braking_and_authority_speed_are_inverse():
    for d, a, T, vt in [(1000.0, 0.5, 2.0, 0.0), (6000.0, 0.58, 2.0, 0.0), (300.0, 1.0, 0.0, 10.0), (5.0, 0.5, 1.0, 0.0)]:
        v = authority_speed(d, a, T, vt)
        assert v * T + (v * v - vt * vt) / (2 * a) == pytest.approx(d, rel=1e-9)
    assert authority_speed(-1.0, 0.5, 2.0, 12.0) == 12.0
    assert absolute_braking_gap(30.0, 0.6, 2.0) == pytest.approx(60 + 750)


def test_relative_braking_speed_inverts_the_rule():
    v_l, a_f, a_l, T = 60.0, 1.0, 1.4, 2.5
    for room in (0.0, 50.0, 400.0, 900.0):
        v = relative_braking_speed(room, v_l, a_f, a_l, T, 100.0)
        assert relative_braking_gap(v, v_l, a_f, a_l, T) <= room + 1e-6
        if v < 100.0:
            assert relative_braking_gap(v + 0.01, v_l, a_f, a_l, T) > room
    assert relative_braking_speed(-1.0, v_l, a_f, a_l, T, 100.0) == 0.0
    assert relative_braking_speed(1e6, v_l, a_f, a_l, T, 100.0) == 100.0


def test_leader_worst_state():
    assert leader_worst_state(40.0, 1.0, 0.0) == (0.0, 40.0)
    d, v = leader_worst_state(40.0, 1.0, 2.0)
    assert d == pytest.approx(78.0) and v == pytest.approx(38.0)
    d, v = leader_worst_state(10.0, 1.0, 30.0)  # stopped after 10 s
    assert d == pytest.approx(50.0) and v == 0.0


@pytest.fixture(scope="module")
def etr():
    return load_rolling_stock("etr1000")


@pytest.fixture(scope="module")
def typical():
    return load_assumptions()


def test_shipped_assumption_set(typical):
    assert typical.name == "etcs_typical"
    assert typical.dead_time_s == pytest.approx(typical.reaction_time_s + 0.5 * typical.brake_build_up_s)
    assert typical.position_uncertainty_m == 2 * typical.position_error_m


def test_guaranteed_decel_on_a_descent(etr, typical):
    """ETR1000 service brake on −11.5 ‰: bottom of the box (0.585 m/s², below the file's 0.60), Davis A
    low over the heaviest mass, minus g·0.0115, over ρ = 1.04 — below the ≈ 0.57 m/s² SUMO delivers
    there with nominal parameters (safe-separation note)."""
    a = guaranteed_decel(etr, typical, "service", 50.0, -0.0115)
    hand = (0.65 * 0.9 + 8096 / 540000 - G * 0.0115) / 1.04
    assert a == pytest.approx(hand, rel=1e-9)
    assert a < 0.57
    # an up-grade is not counted as help; a steeper descent takes more
    assert guaranteed_decel(etr, typical, "service", 50.0, 0.02) == pytest.approx(guaranteed_decel(etr, typical, "service", 50.0, 0.0))
    assert guaranteed_decel(etr, typical, "emergency", 50.0, -0.02) < guaranteed_decel(etr, typical, "emergency", 50.0, -0.01)


def test_no_guaranteed_braking_is_an_error(etr, typical):
    with pytest.raises(ValueError, match="no guaranteed braking"):
        guaranteed_decel(etr, typical, "service", 30.0, -0.07)


def test_strongest_decel_includes_resistance_and_grade(etr, typical):
    v = 300 / 3.6
    a = strongest_decel(etr, typical, "emergency", v, 0.0, tunnel_factor=1.0)
    box = etr.uncertainty
    r = box.davis_a_n.high + box.davis_b_n_per_mps.high * v + box.davis_c_n_per_mps2.high * v * v
    assert a == pytest.approx(1.2 * 1.1 + r / box.mass_kg.low, rel=1e-9)
    assert strongest_decel(etr, typical, "emergency", v, 0.01, 1.0) == pytest.approx(a + G * 0.01)


def test_vc_gap_etr1000_300_kmh(etr, typical):
    """By hand: a_f = (1.08 + 8096/540000)/1.04, a_l = 1.32 + R_high(83.3 m/s, tunnel 1.5)/461 t,
    T = 0.5 + 3/2 + 0.5 (message age) s, margin 50 + 2·10 m: ≈ 1.36 km (the note: 1.1–1.6 km once
    resistance and grade are counted)."""
    m = SeparationModel(typical)
    v = 300 / 3.6
    a_f = (1.2 * 0.9 + 8096 / 540000) / 1.04
    r = 9504 + 66.7 * v + 1.5 * 9.4 * v * v
    a_l = 1.2 * 1.1 + r / 461000
    hand = 70 + v * 2.5 + v * v / 2 * (1 / a_f - 1 / a_l)
    assert m.vc_gap(etr, etr, v) == pytest.approx(hand, rel=1e-9)
    assert 1100 < m.vc_gap(etr, etr, v) < 1600
    # a descent where the follower brakes widens it; no delay narrows it
    assert m.vc_gap(etr, etr, v, grade_f=-0.0115) > m.vc_gap(etr, etr, v) + 100
    assert m.vc_gap(etr, etr, v, message_age_s=0.0) == pytest.approx(m.vc_gap(etr, etr, v) - 0.5 * v)


def test_mb_gap_and_absolute_gap(etr, typical):
    m = SeparationModel(typical)
    v = 200 / 3.6
    a = guaranteed_decel(etr, typical, "service", v, 0.0)
    assert m.absolute_gap(etr, v) == pytest.approx(70 + v * 2.0 + v * v / (2 * a))
    assert m.mb_gap(etr, v) == pytest.approx(m.absolute_gap(etr, v) + 2.0 * v)
    # arrays work (analytic headway profiles)
    vs = np.array([10.0, 40.0, 80.0])
    assert np.allclose(m.absolute_gap(etr, vs), [m.absolute_gap(etr, float(x)) for x in vs])
    # standing still the margin and the position errors remain
    assert m.absolute_gap(etr, 0.0) == pytest.approx(70.0)


def test_vc_beats_mb_per_train_at_300_kmh(etr, typical):
    """Under the same assumptions a 2-train convoy needs less track per train than MB (the premise of
    VC, now with the worst case on both sides)."""
    m = SeparationModel(typical)
    v = 300 / 3.6
    mb_per_train = m.mb_gap(etr, v) + etr.length_m
    vc_pair = m.mb_gap(etr, v) + 2 * etr.length_m + m.vc_gap(etr, etr, v)
    assert vc_pair / 2 < mb_per_train


def test_assumption_file_is_strict(tmp_path):
    from vcsumo.errors import InputError

    f = tmp_path / "a.yaml"
    f.write_text("name: a\nbraking_uncertainty: 0.1\nreaction_time_s: 1\nbrake_build_up_s: 2\nt2t_delay_bound_s: 0.5\n"
                 "position_report_period_s: 2\nposition_error_m: 10\nsafety_margin_m: 50\noverlap_m: 50\nbrakes: 3\n")
    with pytest.raises(InputError, match="brakes"):
        load_assumptions(f)
    with pytest.raises(InputError, match="unknown assumption set 'nope'"):
        load_assumptions("nope")
    f.write_text(f.read_text().replace("brakes: 3\n", ""))
    a = load_assumptions(f)
    assert isinstance(a, AssumptionSet) and a.dead_time_s == pytest.approx(2.0) and a.absolute_braking == "service"


def test_route_braking_on_level_track_is_the_constant_rule(etr, typical):
    """On a level route the integrated braking equals v·T + v²/(2a) with the guaranteed a."""
    from vcsumo.route_profile import RouteProfile
    from vcsumo.signalling.separation import RouteBraking

    prof = _level_profile(40000.0)
    br = RouteBraking(SeparationModel(typical), etr, prof, "service")
    a = guaranteed_decel(etr, typical, "service", 60.0, 0.0)
    assert br.stopping_distance(1000.0, 60.0, 2.0) == pytest.approx(120.0 + 3600.0 / (2 * a), rel=1e-9)
    v = br.permitted_speed(1000.0, 1000.0 + 120.0 + 3600.0 / (2 * a), 0.0, 2.0, 60.0)
    assert v == pytest.approx(60.0, rel=1e-9)
    assert isinstance(prof, RouteProfile)


def test_route_braking_integrates_a_descent_that_starts_part_way(etr, typical):
    """Braking from 50 m/s with a -15 ‰ descent starting 1 km ahead: the energy budget is spent at the
    level rate for 1 km and at the descent rate after — between the all-level and all-descent figures,
    and exactly the piecewise sum."""
    from vcsumo.signalling.separation import RouteBraking

    prof = _profile([(0.0, 5000.0, 0.0), (5000.0, 20000.0, -0.015)])
    br = RouteBraking(SeparationModel(typical), etr, prof, "service")
    a0 = guaranteed_decel(etr, typical, "service", 50.0, 0.0)
    a1 = guaranteed_decel(etr, typical, "service", 50.0, -0.015)
    d = br.stopping_distance(4000.0, 50.0, 0.0)
    # the train body (202 m) reaches the descent with its front: the -15 ‰ counts from 4798 m on the front's edge
    assert 1250.0 / a0 < d < 1250.0 / a1
    e = a0 * 1000.0 + a1 * (d - 1000.0)
    assert e == pytest.approx(1250.0, rel=0.02)


def test_relative_braking_light_follower_behind_heavy_leader(typical):
    """A follower that brakes harder than the leader can: the rule is positive, mid-braking, and a
    brute-force simulation of the worst case from that gap never closes below the margin."""
    from vcsumo.rolling_stock import RollingStock
    from vcsumo.signalling.separation import RelativeBraking

    heavy = load_rolling_stock("etr1000").model_copy(update={"name": "heavy", "emergency_brake_decel_mps2": 0.8, "service_brake_decel_mps2": 0.5,
                                                             "uncertainty": None})
    light = load_rolling_stock("regional_emu160").model_copy(update={"emergency_brake_decel_mps2": 1.5, "uncertainty": None})
    assert isinstance(heavy, RollingStock)
    model = SeparationModel(typical)
    rule = RelativeBraking(model, light, heavy, _level_profile(40000.0))
    assert not rule.never_outbrakes
    v = 40.0
    closing = rule.closing(1000.0, v, 3000.0, v, typical.dead_time_s)
    a_f = rule.follower.decel_at(1000.0, v)
    a_l = rule.leader.decel_at(3000.0, v)
    assert a_f > a_l and closing > 0.0
    assert closing == pytest.approx(relative_braking_gap(v, v, a_f, a_l, typical.dead_time_s), rel=1e-9)
    assert simulate_min_gap(closing + 1.0, v, v, a_f, a_l, typical.dead_time_s) >= 1.0 - 0.05


def _profile(pieces):
    """A RouteProfile of level/graded pieces (start m, end m, gradient) on a made-up topology-free route."""
    from vcsumo.route_profile import RouteProfile

    starts = np.array([a for a, _, _ in pieces], dtype=float)
    lengths = np.array([b - a for a, b, _ in pieces], dtype=float)
    n = len(pieces)
    return RouteProfile(edges=[f"e{i}" for i in range(n)], starts_m=starts, lengths_m=lengths, speeds_ms=np.full(n, 80.0),
                        gradients=np.array([g for _, _, g in pieces], dtype=float), tunnel_factors=np.ones(n), sections=["main"] * n,
                        km_from=starts / 1000.0, km_to=(starts + lengths) / 1000.0, point_limits=[])


def _level_profile(length):
    return _profile([(0.0, length, 0.0)])


def _brute_force_closing(rule, s_f, v_f, s_l, v_l, dead, dt=1e-3):
    """max_t [x_f(t) − x_l(t)] by small time steps: the follower at constant speed for the dead time,
    then each train at the deceleration the rule's run gives where its front is (brake part at the
    speed the braking starts from, as the model)."""
    xf = xl = 0.0
    vf, vl = v_f, v_l
    t = best = 0.0
    while vf > 0.0 or vl > 0.0:
        af = 0.0 if t < dead else (rule.follower.decel_at(s_f + xf, v_f) if vf > 0.0 else 0.0)
        al = rule.leader.decel_at(s_l + xl, v_l) if vl > 0.0 else 0.0
        nvf, nvl = max(vf - af * dt, 0.0), max(vl - al * dt, 0.0)
        xf += 0.5 * (vf + nvf) * dt
        xl += 0.5 * (vl + nvl) * dt
        vf, vl = nvf, nvl
        t += dt
        best = max(best, xf - xl)
    return best


def test_relative_braking_counts_a_climb_inside_the_leaders_run_and_is_continuous(typical):
    """A light follower behind a heavy leader (the follower out-brakes it on level track): a 200 m
    climb of 25 permille lies inside the leader's braking run (and the follower brakes on an 18
    permille descent that ends where the climb begins). The rule's closing equals a brute-force
    integration of both runs (within 0.1 m) and moves continuously with the trains. One deceleration
    per train taken at the two ends of each run (the rule before) missed the climb: 8.9 m instead of
    36.9 m here — unsafe — and jumped by tens of metres when an end crossed a gradient change (an
    unseen mountain line's freight-led convoy: 93 to 220 m from one step to the next). (Until unseen7
    the descent ended at 800 m, and the follower was charged it to 2,150 m all the same — the whole
    edge its front was on when its rear was still on the descent: 38.9 m; the braking under the body
    is now exact, and the descent runs to the climb to keep the case.)"""
    from vcsumo.signalling.separation import RelativeBraking

    heavy = load_rolling_stock("etr1000").model_copy(update={"name": "heavy", "emergency_brake_decel_mps2": 0.6, "service_brake_decel_mps2": 0.4,
                                                             "uncertainty": None})
    light = load_rolling_stock("regional_emu160").model_copy(update={"emergency_brake_decel_mps2": 1.2, "uncertainty": None})
    prof = _profile([(0.0, 800.0, -0.018), (800.0, 2150.0, -0.018), (2150.0, 2350.0, 0.025), (2350.0, 2560.0, 0.0), (2560.0, 20000.0, 0.0)])
    rule = RelativeBraking(SeparationModel(typical), light, heavy, prof)
    assert not rule.never_outbrakes
    dead = typical.dead_time_s
    for s_f, v_f, s_l, v_l in ((500.0, 30.0, 1500.0, 27.0), (1000.0, 30.0, 2050.0, 27.0), (1000.0, 40.0, 1700.0, 40.0), (1900.0, 35.0, 2300.0, 20.0)):
        assert rule.closing(s_f, v_f, s_l, v_l, dead) == pytest.approx(_brute_force_closing(rule, s_f, v_f, s_l, v_l, dead), abs=0.1)
    # the two-point form: decelerations at the ends of each run only
    s_f, v_f, s_l, v_l = 1000.0, 40.0, 1700.0, 40.0
    d_f, d_l = rule.follower.stopping_distance(s_f, v_f, dead), rule.leader.stopping_distance(s_l, v_l, 0.0)
    assert s_l < 2150.0 and s_l + d_l > 2560.0  # the climb lies inside the leader's run, neither end on it (nor its body)
    a_f = min(rule.follower.decel_at(x, v_f) for x in (s_f, s_f + d_f))
    a_l = max(rule.leader.decel_at(x, v_l) for x in (s_l, s_l + d_l))
    two_point = relative_braking_gap(v_f, v_l, a_f, a_l, dead)
    assert rule.closing(s_f, v_f, s_l, v_l, dead) > two_point + 20.0  # it under-estimated the closing: unsafe
    # continuous: 1 m of movement of both trains changes the closing by little, all along the gradient changes
    prev = None
    for k in range(0, 2000):
        c = rule.closing(s_f - 500.0 + k, 30.0, s_l - 500.0 + k, 27.0, dead)
        if prev is not None:
            assert abs(c - prev) < 1.0, (k, prev, c)
        prev = c
