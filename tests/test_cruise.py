"""Cruise VC control (Terlizzi et al. 2024): Algorithm 4 (eq. 20–28), Algorithm 5 (eq. 35–37)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcsumo.control.base import Message, Observation, TrainStateMsg
from vcsumo.control.cbf import BarrierModel, CBFConfig, CBFSupervisor
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.cruise import (
    CondensedMPC,
    CruiseConfig,
    PositionReferenceGenerator,
    SwitchedCruiseController,
    Weights,
    DenseQP,
    box_qp,
    load_cruise_config,
)
from vcsumo.control.proxies import BoxBounds, GradeWindow, sample_params
from vcsumo.dynamics import acceleration
from vcsumo.line import project_root
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import load_rolling_stock

LEADER, FOLLOWER = "leader", "follower"


@pytest.fixture(scope="module")
def stocks():
    return load_rolling_stock("terlizzi2024_leader"), load_rolling_stock("terlizzi2024_follower")


def test_box_qp_is_optimal():
    """The active-set box QP agrees with DAQP and satisfies the KKT conditions."""
    rng = np.random.default_rng(0)
    qp = DenseQP(12, 12)
    for _ in range(150):
        M = rng.normal(size=(12, 12))
        H = M @ M.T + 0.1 * np.eye(12)
        g = rng.normal(size=12) * 5
        lb, ub = -rng.uniform(0, 1, 12), rng.uniform(0, 1, 12)
        u, ok = box_qp(H, g, lb, ub, H_inv=np.linalg.inv(H))
        assert ok and np.all(u >= lb - 1e-12) and np.all(u <= ub + 1e-12)
        grad = H @ u + g
        free = (u > lb + 1e-9) & (u < ub - 1e-9)
        assert np.allclose(grad[free], 0.0, atol=1e-8)
        assert np.all(grad[u <= lb + 1e-9] >= -1e-8) and np.all(grad[u >= ub - 1e-9] <= 1e-8)
        u2, ok2 = qp.solve(H, g, np.zeros((12, 12)), -np.ones(12), np.ones(12), lb, ub)
        f = lambda x: 0.5 * x @ H @ x + g @ x  # noqa: E731
        assert ok2 and f(u) <= f(u2) + 1e-7


def test_condensed_prediction_is_the_euler_model(stocks):
    """s = s_free + G_s·u, v = v_free + G_v·u reproduce eq. 5 integrated at ΔT^mpc."""
    _, fol = stocks
    p = fol.params()
    mpc = CondensedMPC(p, 12.0, 0.06, 12)
    route = GradeWindow(None)
    z = np.linspace(1000.0, 1700.0, mpc.N)
    v = np.full(mpc.N, 50.0)
    for _ in range(4):  # the resistance is evaluated along the previous prediction (RTI)
        sol = mpc.solve(0.0, 1000.0, 50.0, z, v, Weights(1.0, 0.0, 0.004), route, 83.0, False)
    s, vv = 1000.0, 50.0
    for k in range(mpc.N):
        a = float(acceleration(p, vv, sol.forces_n[k], 0.0))
        s, vv = s + vv * mpc.dt, vv + a * mpc.dt
        assert sol.positions_m[k + 1] == pytest.approx(s, abs=1e-4)
        assert sol.speeds_mps[k + 1] == pytest.approx(vv, abs=1e-6)
    # block structure: the force is piecewise constant over 12 blocks of 1 s
    assert len(np.unique(np.round(sol.forces_n, 6))) <= 12


def test_mpc_respects_force_and_speed_limits_in_closed_loop(stocks):
    _, fol = stocks
    p = fol.params()
    mpc = CondensedMPC(p, 12.0, 0.06, 12)
    route = GradeWindow(None)
    plant = TrainPlant(p, PlantState(0.0, 70.0), None)
    vmax = 0.0
    for k in range(600):
        t = 0.2 * k
        x = plant.x
        z = x.s_m + 5000.0 + np.zeros(mpc.N)  # unreachable reference: K3 pushes at full traction
        sol = mpc.solve(t, x.s_m, x.v_mps, z, np.zeros(mpc.N), Weights(1.0, 0.0, 0.004), route, p.max_speed_ms, False)
        u = sol.forces_n[0]
        assert u <= min(p.max_traction_n, p.max_power_w / max(x.v_mps, 0.1)) + 1e-6  # eq. 6a, 6b
        plant.step(u, 0.2)
        vmax = max(vmax, plant.x.v_mps)
    assert p.max_speed_ms - 0.5 < vmax <= p.max_speed_ms + 0.05  # eq. 6c


def _plain_msg(t: float, s: float, v: float) -> Message:
    return Message(sender=LEADER, sent_time_s=t, state=TrainStateMsg(t, s, v), length_m=202.0, received_time_s=t)


def test_reference_generator_hand_check_and_ordering(stocks):
    lead, fol = stocks
    cbf = CBFConfig(sampled_data_margin=False)
    cfg = CruiseConfig()
    model = BarrierModel(BoxBounds.from_stock(lead), BoxBounds.from_stock(fol), cbf, None)
    gen = PositionReferenceGenerator(model, cfg, 0.1)
    s_l, v = 50000.0, 40.0
    s_f, v_f = 45000.0, 40.0
    ref = gen.compute(_plain_msg(100.0, s_l, v), 1.0, s_f, v_f, 100.5)
    z = ref.at(100.0)
    assert z[0] >= z[1] >= z[2]  # τ1 < τ2 < τ3 (ω1 < ω2 < ω3)
    # eq. 24 at t_last for τ2 = 3 s: the leader cruises at 40 m/s (no plan in the packet)
    tau = 3.0
    lb = model.leader.b
    res = lb.davis_a_high_n + lb.davis_b_high_n_per_mps * v + lb.davis_c_high_n_per_mps2 * v * v
    e = res / lb.mass_low_kg + lb.brake_decel_high_mps2
    s_tau = s_l + v * tau - 0.5 * e * tau * tau
    z2 = s_tau - v * tau - 202 - 1000
    v_max_f = v_f + model.follower.b.accel_high(v_f) * tau
    z1 = model.leader_stop(s_l, v) - v * tau - 202 - 1000 - (model.follower_stop(s_f, v_max_f) - s_f)
    assert z[1] == pytest.approx(min(z1, z2), abs=1e-6)
    # a stopped leader: every reference lies at or behind s_L − L − d
    ref0 = gen.compute(_plain_msg(100.0, s_l, 0.0), 2.0, s_f, 0.0, 100.0)
    assert np.all(ref0.z_m <= s_l - 202 - 1000 + 1e-9)
    assert np.all(ref0.z_m[0] >= ref0.z_m[1]) and np.all(ref0.z_m[1] >= ref0.z_m[2])
    # a larger τ̄ moves the follower back (less time-critical spacing for a worse channel)
    ref_big = gen.compute(_plain_msg(100.0, s_l, v), 3.0, s_f, v_f, 100.5)
    assert np.all(ref_big.at(100.0) < z)


def test_mode_selection_algorithm5(stocks):
    lead, fol = stocks
    ctl = SwitchedCruiseController(lead, fol)
    z = np.array([1000.0, 800.0, 500.0])
    assert ctl.select_mode(400.0, z) == "cruise-3"
    assert ctl.select_mode(500.0, z) == "cruise-3"
    assert ctl.select_mode(700.0, z) == "cruise-2"
    assert ctl.select_mode(1000.0, z) == "cruise-2"
    assert ctl.select_mode(1000.1, z) == "cruise-1"


def test_closed_loop_vc_forms_safely_and_estimator_tracks_delay(stocks):
    """Follower 6 km behind on level track: K3 closes in, the VC settles in K2, never unsafe."""
    lead, fol = stocks
    rng = np.random.default_rng(4)
    cfg = CruiseConfig(line_speed_limits=False)
    cbf = CBFConfig()
    ctl = SwitchedCruiseController(lead, fol, cfg, cbf, leader_id=LEADER)
    sup = CBFSupervisor(lead, fol, cbf, leader_id=LEADER)
    plant_l = TrainPlant(sample_params(lead, rng), PlantState(6202.0 + 1000.0, 40.0), None)
    plant_f = TrainPlant(sample_params(fol, rng), PlantState(1000.0, 40.0), None)
    ch = Channel(ChannelConfig(model="constant", delay_s=2.0, seed=1))
    dt = 0.2
    modes = []
    for k in range(int(500 / dt)):
        t = k * dt
        xl, xf = plant_l.x, plant_f.x
        if ch.due(LEADER, t):
            ch.send(_plain_msg(t, xl.s_m, xl.v_mps), [FOLLOWER], t)
        obs = Observation(time_s=t, step_s=dt, ego_id=FOLLOWER, ego=TrainStateMsg(t, xf.s_m, xf.v_mps, force_n=xf.force_n), params=fol.params(), profile=None,
                          received=ch.deliver(FOLLOWER, t), predecessor=LEADER, sensed_gap_m=xl.s_m - 202 - xf.s_m, sensed_speed_mps=xl.v_mps)
        nom = ctl.make_step(obs)
        cmd = sup.filter(obs, nom)
        modes.append(cmd.mode)
        u_l = 0.0 if xl.v_mps > 40.0 else float(acceleration(lead.params(), xl.v_mps, 0.0)) * -lead.params().mass_kg + 2e3
        plant_l.step(u_l, dt)
        plant_f.step(cmd.force_n, dt)
        assert plant_f.x.v_mps <= fol.params().max_speed_ms + 0.05
    gap = plant_l.x.s_m - 202 - plant_f.x.s_m
    assert ctl.tau_bar_s == pytest.approx(2.0)  # Algorithm 3 on a constant delay
    assert "cruise-3" in modes[:500]  # the L3 → VC transition starts with K3
    assert modes[-1] == "cruise-2"
    assert 1000.0 < gap < 5800.0
    assert sup.stats.max_true_barrier_m <= 0.0
    assert sup.stats.emergency_activations == 0
    assert ctl.failed_solves == 0


def test_cruise_config_file(stocks):
    cfg = load_cruise_config(project_root() / "controllers" / "cruise_terlizzi2024.yaml")
    assert (cfg.horizon_s, cfg.mpc_step_s, cfg.omega_1, cfg.omega_2, cfg.omega_3) == (12.0, 0.06, 1.0, 3.0, 6.0)
    assert (cfg.theta1_s_per_m2, cfg.theta2_v_per_mps2, cfg.theta3_u_per_kn2) == (2.0, 10.0, 4e-3)
    ctl = SwitchedCruiseController.from_files("terlizzi2024_leader", "terlizzi2024_follower")
    assert ctl.cfg == cfg and math.isclose(ctl.cbf.safety_distance_m, 1000.0)
