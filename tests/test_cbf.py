"""CBF safety layer (Terlizzi et al. 2024): barrier eq. 15, K_E^F, Algorithms 1–3, supervisor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcsumo.config import load_model
from vcsumo.control.base import Command, Message, Observation, TrainStateMsg
from vcsumo.control.cbf import (
    BarrierModel,
    CBFConfig,
    CBFSupervisor,
    DelayEstimator,
    LeaderRLPPredictor,
    barrier,
    barrier_from_stops,
    emergency_force_n,
    load_cbf_config,
)
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.proxies import BoxBounds, sample_params
from vcsumo.errors import InputError
from vcsumo.line import load_line, project_root
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.topology import build_topology

LEADER, FOLLOWER = "leader", "follower"
PAPER = CBFConfig(distance="fixed", leader_braking="service")
"""The paper's barrier (eq. 15, d = 1,000 m, the leader's service box): these tests check Terlizzi's
mechanism as the paper states it; tests/test_cbf_model.py checks the default barrier on the
separation model."""


@pytest.fixture(scope="module")
def stocks():
    return load_rolling_stock("terlizzi2024_leader"), load_rolling_stock("terlizzi2024_follower")


@pytest.fixture(scope="module")
def profile() -> RouteProfile:
    topo = build_topology(load_line("firenze_bologna"))
    return RouteProfile.from_edges(topo, topo.track_for("main", "up").edges)


# -------------------------------------------------------------------------------------------
# Barrier sign (eq. 15) on hand-computed states


def test_barrier_hand_computed():
    L, d = 200.0, 1000.0
    # both stopped 2000 m apart (front to front): b'' = 1200 − 2000 = −800, b' = b''
    assert barrier(5000, 0, 3000, 0, 0.8, 0.5, L, d) == (-800.0, -800.0, -800.0)
    # leader 40 m/s (stops in 1000 m at 0.8), follower 30 m/s (900 m at 0.5): b' = −800 − 100
    b, b1, b2 = barrier(5000, 40, 3000, 30, 0.8, 0.5, L, d)
    assert (b1, b2, b) == pytest.approx((-900.0, -800.0, -800.0))
    # follower 50 m/s (2500 m at 0.5): b' = −800 − (1000 − 2500) = +700 → unsafe
    b, b1, _ = barrier(5000, 40, 3000, 50, 0.8, 0.5, L, d)
    assert b1 == pytest.approx(700.0) and b > 0
    # exactly at the safety distance: on the boundary
    assert barrier(4200, 0, 3000, 0, 0.8, 0.5, L, d)[0] == pytest.approx(0.0)
    # a follower that cannot stop is never safe
    assert barrier(9e9, 0, 0, 10, 0.8, 0.0, L, d)[0] == math.inf
    # the stop-point form is the same function
    assert barrier_from_stops(5000, 6000, 3000, 3900, L, d)[0] == pytest.approx(-800.0)


def test_barrier_model_on_level_track_matches_eq15(stocks):
    lead, fol = stocks
    cfg = PAPER
    model = BarrierModel(BoxBounds.from_stock(lead), BoxBounds.from_stock(fol), cfg, None)
    bl, bf = model.leader.b, model.follower.b
    v_l, v_f = 40.0, 35.0
    # e̲^L: strongest brake + largest resistance at V_max over the lightest mass (level track)
    res_vmax = bl.davis_a_high_n + bl.davis_b_high_n_per_mps * bl.max_speed_ms + bl.davis_c_high_n_per_mps2 * bl.max_speed_ms**2
    e_l = 0.70 + res_vmax / 4.5e5
    # ē^F: ε·α̲(v) + A̲/M̄, α̲ = min(a̲_br, P̲_br/(M̄·v)) — no braking-power limit here: α̲ = a̲_br
    e_f = 0.98 * 0.59 + 25.11 / 5.5e5
    s_l, s_f = 20000.0, 15000.0
    b, b1, b2 = model.value(s_l, v_l, s_f, v_f)
    assert b2 == pytest.approx(202 + 1000 - 5000)
    assert b1 == pytest.approx(202 + 1000 - 5000 - 0.5 * (v_l**2 / e_l - v_f**2 / e_f), abs=1e-6)
    assert b == max(b1, b2)
    # windowed (paper-literal) variant gives the same on level track up to the speed of e̲^L's resistance
    wmodel = BarrierModel(BoxBounds.from_stock(lead), BoxBounds.from_stock(fol), cfg.model_copy(update={"stop_model": "window"}), None)
    assert wmodel.value(s_l, v_l, s_f, v_f)[0] <= b + 1e-9


def test_barrier_monotone_in_states(stocks, profile):
    """b decreases when the leader is further/faster and increases when the follower is (eq. 15)."""
    lead, fol = stocks
    model = BarrierModel(BoxBounds.from_stock(lead), BoxBounds.from_stock(fol), PAPER, profile)
    rng = np.random.default_rng(5)
    for _ in range(200):
        s_f = rng.uniform(0, 80000)
        s_l = s_f + rng.uniform(1200, 8000)
        v_l, v_f = rng.uniform(0, 80, 2)
        b = model.value(s_l, v_l, s_f, v_f)[0]
        assert model.value(s_l + 10, v_l, s_f, v_f)[0] < b
        assert model.value(s_l, v_l + 1, s_f, v_f)[0] <= b
        assert model.value(s_l, v_l, s_f + 10, v_f)[0] > b
        assert model.value(s_l, v_l, s_f, v_f + 1)[0] >= b


# -------------------------------------------------------------------------------------------
# Emergency controller (Definition 11, Theorem V.2)


def test_emergency_force(stocks):
    _, fol = stocks
    b = BoxBounds.from_stock(fol)
    assert emergency_force_n(b, 0.0) == pytest.approx(-5.5e5 * 0.70)  # holding brake at a stop
    assert emergency_force_n(b, 10.0) == pytest.approx(-5.5e5 * 0.70)
    assert emergency_force_n(b, 80.0) == pytest.approx(-5.5e5 * 0.70)  # no braking-power limit


@pytest.mark.parametrize("seed", range(6))
def test_emergency_controller_stops_before_the_robust_stop_point(stocks, profile, seed):
    """Under K_E^F every train in the box stops before S^F (the follower term of b')."""
    lead, fol = stocks
    rng = np.random.default_rng(seed)
    model = BarrierModel(BoxBounds.from_stock(lead), BoxBounds.from_stock(fol), PAPER, profile)
    fb = BoxBounds.from_stock(fol)
    dt = 0.1
    for _ in range(5):
        p = sample_params(fol, rng, corner=True)
        s0, v0 = float(rng.uniform(2000, 85000)), float(rng.uniform(5, 83))
        bound = model.follower_stop(s0, v0, dt)
        plant = TrainPlant(p, PlantState(s0, v0), profile)
        for _ in range(20000):
            x = plant.step(emergency_force_n(fb, plant.x.v_mps), dt)
            if x.v_mps == 0.0:
                break
        assert plant.x.v_mps == 0.0
        assert plant.x.s_m <= bound


def test_emergency_braking_keeps_the_true_barrier_nonpositive(stocks, profile):
    """Theorem V.2: from a safe state, leader full brake + follower K_E^F stays safe (gap ≥ d)."""
    lead, fol = stocks
    cfg = PAPER
    model = BarrierModel(BoxBounds.from_stock(lead), BoxBounds.from_stock(fol), cfg, profile)
    fb = BoxBounds.from_stock(fol)
    rng = np.random.default_rng(2)
    for _ in range(8):
        pl, pf = sample_params(lead, rng, corner=True), sample_params(fol, rng, corner=True)
        v_l, v_f = float(rng.uniform(20, 80)), float(rng.uniform(20, 80))
        s_f = float(rng.uniform(5000, 60000))
        # the closest safe start: b = 0 (bisection on the leader position)
        lo, hi = s_f + 1202, s_f + 60000
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if model.value(mid, v_l, s_f, v_f, 0.1)[0] > 0 else (lo, mid)
        plant_l, plant_f = TrainPlant(pl, PlantState(hi, v_l), profile), TrainPlant(pf, PlantState(s_f, v_f), profile)
        for _ in range(4000):
            plant_l.step(-1e9, 0.1)
            plant_f.step(emergency_force_n(fb, plant_f.x.v_mps), 0.1)
            assert plant_l.x.s_m - plant_f.x.s_m >= 202 + 1000
            if plant_f.x.v_mps == 0.0 and plant_l.x.v_mps == 0.0:
                break
        assert plant_f.x.v_mps == 0.0 and plant_l.x.v_mps == 0.0


# -------------------------------------------------------------------------------------------
# Algorithm 1 (RLP predictor) and Algorithm 3 (delay estimator)


def _msg(t: float, s: float, v: float, rx: float = math.nan) -> Message:
    return Message(sender=LEADER, sent_time_s=t, state=TrainStateMsg(t, s, v), length_m=202.0, received_time_s=rx)


def test_rlp_predictor_lower_bounds_the_leader(stocks, profile):
    lead, fol = stocks
    model = BarrierModel(BoxBounds.from_stock(lead), BoxBounds.from_stock(fol), PAPER, profile)
    rng = np.random.default_rng(7)
    for _ in range(20):
        p = sample_params(lead, rng, corner=True)
        s0, v0 = float(rng.uniform(1000, 80000)), float(rng.uniform(0, 83))
        pred = LeaderRLPPredictor(model)
        assert not pred.has_data and pred.predict(0.0) == (math.inf, math.inf)
        assert pred.update(_msg(10.0, s0, v0))
        assert not pred.update(_msg(9.0, s0, v0))  # older packet ignored (line 3)
        plant = TrainPlant(p, PlantState(s0, v0), profile)
        u = float(rng.choice([-1e9, 0.0, 2e5]))
        for k in range(1, 200):
            plant.step(u, 0.1)
            s, v = pred.predict(10.0 + 0.1 * k)
            pos, stop, _ = pred.bounds(10.0 + 0.1 * k)
            assert s <= plant.x.s_m + 1e-9 and v <= plant.x.v_mps + 1e-9
            assert pos <= plant.x.s_m + 1e-9
            assert stop <= model.leader_stop(plant.x.s_m, plant.x.v_mps) + 1e-6


def test_delay_estimator_converges_on_a_constant_delay():
    est = DelayEstimator(window_size=20, probability=0.95, initial_delay_s=1.0)
    assert est.estimate_s == 1.0
    for k in range(40):
        est.update(float(k), k + 2.5)
    assert est.estimate_s == pytest.approx(2.5)
    assert not est.update(10.0, 30.0)  # not newer than the last packet
    assert len(est.samples) == 20


def test_delay_estimator_quantile_of_exponential_delays():
    rng = np.random.default_rng(0)
    est = DelayEstimator(window_size=2000, probability=0.9, initial_delay_s=0.0)
    for k in range(2000):
        est.update(float(k), k + 0.5 + rng.exponential(1.0))
    assert est.estimate_s == pytest.approx(0.5 + math.log(10.0), rel=0.08)
    est2 = DelayEstimator(window_size=5, probability=1.0)
    for k, d in enumerate([1, 4, 2, 3, 2]):
        est2.update(float(k), k + d)
    assert est2.estimate_s == 4.0


# -------------------------------------------------------------------------------------------
# Supervisor (Algorithm 2 + T^max rule) in closed loop


def _run_closed_loop(stocks, profile, rng, nominal_policy, channel: ChannelConfig, duration_s: float, brake_at: float, brake_level: float, gap0: float, v0: float, s_f0: float, dt: float = 0.1, lag: bool = True, jerk: bool = True):
    lead, fol = stocks
    # hold the brake until the first packet (the follower starts right at the barrier)
    sup = CBFSupervisor(lead, fol, PAPER.model_copy(update={"brake_without_leader_data": True}), leader_id=LEADER)
    model = sup.model_for(profile)
    # start safe: b(x0) ≤ 0 with a random extra gap on top of the smallest safe gap
    lo, hi = s_f0 + 1202.0, s_f0 + 80000.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if model.value(mid, v0, s_f0, v0)[0] > 0 else (lo, mid)
    gap0 = hi - s_f0 - 202.0 + gap0
    pl, pf = sample_params(lead, rng, corner=True), sample_params(fol, rng, corner=True)
    plant_l = TrainPlant(pl, PlantState(s_f0 + 202 + gap0, v0), profile)
    plant_f = TrainPlant(pf, PlantState(s_f0, v0), profile, apply_lag=lag, apply_jerk=jerk)
    ch = Channel(channel)
    nom_params = fol.params()
    for k in range(int(duration_s / dt)):
        t = k * dt
        xl, xf = plant_l.x, plant_f.x
        if ch.due(LEADER, t):
            ch.send(_msg(t, xl.s_m, xl.v_mps), [FOLLOWER], t)
        obs = Observation(
            time_s=t, step_s=dt, ego_id=FOLLOWER, ego=TrainStateMsg(t, xf.s_m, xf.v_mps, force_n=xf.force_n), params=nom_params,
            profile=profile, received=ch.deliver(FOLLOWER, t), predecessor=LEADER, sensed_gap_m=xl.s_m - 202 - xf.s_m, sensed_speed_mps=xl.v_mps,
        )
        cmd = sup.filter(obs, Command(force_n=nominal_policy(obs), mode="nominal"))
        assert obs.sensed_gap_m >= 1000.0
        u_l = brake_level if t >= brake_at else 0.2 * pl.max_traction_n
        plant_l.step(u_l, dt)
        plant_f.step(cmd.force_n, dt)
    return sup


@pytest.mark.parametrize("seed", range(10))
def test_supervisor_keeps_true_barrier_nonpositive_under_random_leader_braking(stocks, profile, seed):
    """An aggressive nominal controller (full traction) filtered by the CBF never becomes unsafe."""
    rng = np.random.default_rng(100 + seed)
    lead, _ = stocks
    ch = ChannelConfig(model="exponential", delay_s=float(rng.uniform(0.2, 2.0)), mean_extra_s=float(rng.uniform(0.0, 1.5)), loss_probability=0.05, seed=seed)
    brake_level = -float(rng.uniform(0.2, 1.0)) * 1e9 if rng.random() < 0.5 else -float(rng.uniform(1e5, 3.5e5))
    sup = _run_closed_loop(
        stocks, profile, rng,
        nominal_policy=lambda obs: 5e5,  # always full traction: only the supervisor keeps it safe
        channel=ch, duration_s=220.0, brake_at=float(rng.uniform(20, 120)), brake_level=brake_level,
        gap0=float(rng.uniform(0, 1500)), v0=float(rng.uniform(30, 70)), s_f0=float(rng.uniform(3000, 60000)),
    )
    assert sup.stats.max_true_barrier_m <= 0.0
    assert np.nanmax(sup.history.true_barrier_m) <= 0.0
    assert sup.stats.emergency_activations >= 1 and sup.stats.interventions > 0


def test_supervisor_is_safety_compliant_from_an_unsafe_state(stocks, profile):
    """Definition 4 (ii): from b(x0) > 0 the true barrier does not increase while positive."""
    lead, fol = stocks
    rng = np.random.default_rng(42)
    sup = CBFSupervisor(lead, fol, PAPER, leader_id=LEADER)
    pl, pf = sample_params(lead, rng), sample_params(fol, rng)
    plant_l = TrainPlant(pl, PlantState(20000.0, 40.0), profile)
    plant_f = TrainPlant(pf, PlantState(18000.0, 60.0), profile)
    ch = Channel(ChannelConfig(model="constant", delay_s=0.5))
    last = math.inf
    for k in range(1500):
        t = 0.1 * k
        xl, xf = plant_l.x, plant_f.x
        if ch.due(LEADER, t):
            ch.send(_msg(t, xl.s_m, xl.v_mps), [FOLLOWER], t)
        obs = Observation(time_s=t, step_s=0.1, ego_id=FOLLOWER, ego=TrainStateMsg(t, xf.s_m, xf.v_mps), params=fol.params(), profile=profile,
                          received=ch.deliver(FOLLOWER, t), predecessor=LEADER, sensed_gap_m=xl.s_m - 202 - xf.s_m, sensed_speed_mps=xl.v_mps)
        cmd = sup.filter(obs, Command(force_n=5e5))
        b = cmd.info.get("cbf_true_barrier_m", math.nan)
        if k > 10 and b > 0:
            assert cmd.emergency and b <= last + 1e-6
            last = b
        plant_l.step(-1e9 if t > 30 else 0.0, 0.1)
        plant_f.step(cmd.force_n, 0.1)
    assert last < math.inf  # the start was indeed unsafe


def test_supervisor_passes_nominal_when_far_and_tmax_rule_fires(stocks, profile):
    lead, fol = stocks
    sup = CBFSupervisor(lead, fol, PAPER, leader_id=LEADER)
    nom = Command(force_n=1234.0, mode="mpc")

    def obs(t: float, received: dict) -> Observation:
        return Observation(time_s=t, step_s=0.1, ego_id=FOLLOWER, ego=TrainStateMsg(t, 10000.0 + 40 * t, 40.0), params=fol.params(), profile=profile, received=received, predecessor=LEADER)

    # before the first packet: pass-through (Algorithm 1 starts with the first packet)
    assert sup.filter(obs(0.0, {}), nom).force_n == 1234.0
    m = _msg(0.0, 30000.0, 40.0, 0.5)
    out = sup.filter(obs(0.5, {LEADER: m}), nom)
    assert out.force_n == 1234.0 and not out.emergency and out.info["cbf_barrier_m"] < 0
    # no newer packet for T^max = 8 s → K_E^F (eq. 18), although the barrier is far from zero
    out = sup.filter(obs(7.9, {LEADER: m}), nom)
    assert not out.emergency
    out = sup.filter(obs(8.0, {LEADER: m}), nom)
    assert out.emergency and out.info["cbf_reason"] == "t-max" and out.force_n < 0
    assert sup.stats.tmax_activations == 1 and sup.stats.emergency_activations == 1
    # a fresh packet releases it
    out = sup.filter(obs(8.1, {LEADER: _msg(8.0, 30320.0, 40.0, 8.1)}), nom)
    assert not out.emergency and out.force_n == 1234.0


def test_cbf_config_file():
    cfg = load_cbf_config(project_root() / "controllers" / "cbf.yaml")
    assert cfg.safety_distance_m == 1000.0 and cfg.t_max_s == 8.0 and cfg.packet_loss_probability == 0.01
    with pytest.raises(InputError):
        from vcsumo.config import parse_model

        parse_model(CBFConfig, {"safety_distance_m": 1000, "bogus": 1}, "x.yaml")
    sup = CBFSupervisor.from_files("terlizzi2024_leader", "terlizzi2024_follower")
    assert sup.cfg == cfg
    assert load_model(CBFConfig, project_root() / "controllers" / "cbf.yaml").epsilon < 1


@pytest.mark.parametrize("seed,lag,jerk", [(0, True, False), (1, False, True), (2, True, False)])
def test_supervisor_safe_with_force_lag_or_jerk_limit(profile, seed, lag, jerk):
    """ETR1000 (lag 0.5 s, jerk 0.7 m/s³): the actuation dead time keeps the true barrier ≤ 0."""
    etr = load_rolling_stock("etr1000")
    fb = BoxBounds.from_stock(etr)
    assert fb.actuation_delay_s() > 2.0 and fb.actuation_delay_s(-1e9) == 0.0
    rng = np.random.default_rng(300 + seed)
    ch = ChannelConfig(model="exponential", delay_s=0.5, mean_extra_s=0.5, loss_probability=0.05, seed=seed)
    sup = _run_closed_loop(
        (etr, etr), profile, rng, nominal_policy=lambda obs: 4e5, channel=ch, duration_s=200.0,
        brake_at=float(rng.uniform(20, 100)), brake_level=-1e9, gap0=float(rng.uniform(0, 500)), v0=float(rng.uniform(40, 80)),
        s_f0=float(rng.uniform(3000, 60000)), lag=lag, jerk=jerk,
    )
    assert sup.stats.max_true_barrier_m <= 0.0
    assert sup.stats.interventions > 0


@pytest.mark.parametrize("lag, jerk", [(0.0, math.inf), (0.5, 0.7), (0.0, 0.7), (0.5, math.inf)])
def test_fast_paths_compute_the_documented_formulas_exactly(profile, lag, jerk):
    """The supervisor's per-step shortcuts (constants evaluated once, S^F computed once per state, S^L
    remembered between steps) give bit-for-bit the values of the plain formulas."""
    from dataclasses import replace as dc_replace

    from vcsumo.control.cbf import sampled_stop_margin_m
    from vcsumo.units import G

    stock = load_rolling_stock("etr1000")
    fb = dc_replace(BoxBounds.from_stock(stock), traction_lag_s=lag, max_jerk_mps3=jerk)
    lb = BoxBounds.from_stock(stock)
    cfg = PAPER
    m = BarrierModel(lb, fb, cfg, profile)
    rng = np.random.default_rng(3)
    for _ in range(400):
        s = float(rng.uniform(-300.0, profile.length_m + 300.0))
        v = float(rng.choice([0.0, 0.05, rng.uniform(0.0, 95.0)]))
        force = [None, float(rng.uniform(-fb.strongest_brake_n(v) * 1.2, fb.mass_high_kg * fb.accel_high_mps2))][int(rng.integers(2))]
        dt = float(rng.choice([0.0, 0.2, 0.5]))
        # S^F: the formula of follower_stop (BoxBounds.actuation_delay_s, brake_decel_low)
        t_act = fb.actuation_delay_s(force)
        s1, v1 = s, v
        if t_act > 0.0:
            f_up = fb.mass_high_kg * fb.accel_high_mps2 if force is None else max(force, 0.0)
            a_up = f_up / (fb.rotating_mass_factor * fb.mass_low_kg) + G * max(0.0, -m.follower.route.global_bounds.grade_min)
            s1, v1 = s + v * t_act + 0.5 * a_up * t_act * t_act, v + a_up * t_act
        if v1 <= 0.0:
            want = s1
        else:
            a = cfg.epsilon * fb.brake_decel_low(v1) + fb.davis_a_low_n / (fb.rotating_mass_factor * fb.mass_high_kg)
            want = m.stops_follower.stop_point(s1, v1, a) + (sampled_stop_margin_m(v1, max(a, 0.0), dt) if dt > 0 else 0.0)
        assert m.follower_stop(s, v, dt, force) == want
        # S^L: cached or not, the stopping point at the leader's brake-plus-resistance deceleration
        want_l = s if v <= 0 else m.stops_leader.stop_point(s, v, m.leader_brake_decel(v))
        assert m.leader_stop(s, v) == want_l and m.leader_stop(s, v) == want_l
        m.new_step()
        assert m.leader_stop(s, v) == want_l
        # the RUP's first step over its window
        u = float(rng.uniform(-3e5, 3e5))
        step = float(rng.choice([0.2, 0.5]))
        assert m.follower.rup_step_accel(s, v, u, step) == m.follower.rup_accel(v, u, m.follower.window(s, v, step))


def test_supervisor_bounds_equal_the_rlp_branches(stocks, profile):
    """LeaderRLPPredictor.bounds (states and S^L written out) equals its definition on the branches."""
    lead, fol = stocks
    model = BarrierModel(BoxBounds.from_stock(lead), BoxBounds.from_stock(fol), PAPER, profile)
    pred = LeaderRLPPredictor(model, keep=2)
    for k, (s0, v0) in enumerate([(20000.0, 80.0), (20041.0, 79.5), (20080.0, 79.0)]):
        pred.update(Message(sender=LEADER, sent_time_s=0.5 * k, state=TrainStateMsg(0.5 * k, s0, v0, 0.0, 0.0), length_m=lead.length_m))
        for t in (0.5 * k, 0.5 * k + 0.2, 0.5 * k + 37.3, 0.5 * k + 400.0):
            pos, stop, v_out = -math.inf, -math.inf, 0.0
            for br in pred.branches:
                s, v = br.state(t)
                if s > pos:
                    pos, v_out = s, v
                stop = max(stop, s if v <= 0 else model.stops_leader.stop_point(s, v, model.leader_brake_decel(v)))
            assert pred.bounds(t) == (pos, stop, v_out)
