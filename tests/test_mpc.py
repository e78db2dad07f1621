"""Leader/follower NMPC (Felez et al. 2019, eq. 11-12) and the predictors (eq. 16-18)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcsumo.config import load_model
from vcsumo.control.base import Message, Observation, TrainStateMsg
from vcsumo.control.route_lookup import RouteLookup, route_profile_from_arrays, straight_route_profile
from vcsumo.control.mpc import FollowerMPC, LeaderMPC, MPCSettings, fallback_force, load_mpc_settings
from vcsumo.control.predictors import (
    LeaderPrediction,
    model_step,
    predict_mb,
    predict_np,
    predict_sh,
    predict_sh_from_plan,
)
from vcsumo.dynamics import TrainParams, brake_force_limit, traction_limit
from vcsumo.errors import InputError
from vcsumo.line import project_root
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import load_rolling_stock

N = 40
DT = 0.1


@pytest.fixture(scope="module")
def params() -> TrainParams:
    return load_rolling_stock("felez2019").params()


@pytest.fixture(scope="module")
def settings() -> MPCSettings:
    return load_mpc_settings(project_root() / "controllers" / "mpc.yaml")


@pytest.fixture(scope="module")
def route():
    return straight_route_profile(4000.0, 27.78)


@pytest.fixture(scope="module")
def restricted_route():
    """27.78 m/s with a 12 m/s restriction from 1200 m to 1500 m and a 10 ‰ climb after it."""
    return route_profile_from_arrays([0.0, 1200.0, 1500.0], [27.78, 12.0, 27.78], [0.0, 0.0, 0.01], length_m=4000.0)


# -------------------------------------------------------------------------------------------
# Plan checks


def check_plan(sol, p: TrainParams, cfg: MPCSettings, route=None, leader: LeaderPrediction | None = None, terminal=None, tol_speed=None, rti=False):
    """Every NMPC constraint on the plan the controller returned (and the plan is the model's).

    A converged SQP (``rti=False``) meets the power limits to 0.1 %; a real-time iteration to the
    controller's ``tol_power_rel`` (the first command, u_0·v_0 with v_0 measured, is exact)."""
    assert sol.ok, sol.violation
    s, v, F, u = sol.positions_m, sol.speeds_mps, sol.forces_n, sol.commands_n
    lk = RouteLookup(route, p.length_m) if route is not None else None
    # the plan is the prediction model (eq. 6b/7 with 1c) driven by the planned inputs (in a
    # real-time iteration the gradient is taken at the a-priori positions of eq. 14: tiny differences)
    x = (s[0], v[0], F[0])
    tol = 1e-3 if rti else 1e-6
    for k in range(len(u)):
        g = float(lk.gradient(np.array([x[0]]))[0]) if lk else 0.0
        x = model_step(p, x[0], x[1], x[2], u[k], DT, g, 1.0, cfg.stop_smoothing_mps)
        assert x[0] == pytest.approx(s[k + 1], abs=tol) and x[1] == pytest.approx(v[k + 1], abs=tol) and x[2] == pytest.approx(F[k + 1], abs=1e-3)
    M = p.mass_kg
    assert np.all(u <= M * 0.9 + 1.0) and np.all(u >= -M * p.service_brake_decel_mps2 - 1.0)  # 4a (a_dr = 0.9, Table II)
    ptol = 1.0 + (cfg.tol_power_rel if rti else 1e-3)
    assert np.all(u * v[:-1] <= p.max_power_w * ptol)  # 4b traction power
    assert np.all(-u * v[:-1] <= p.max_brake_power_w * ptol)  # 4b braking power
    assert np.all(u <= traction_limit(p, v[:-1]) * ptol + 1.0) and np.all(u >= -brake_force_limit(p, v[:-1]) * ptol - 1.0)
    assert -float(brake_force_limit(p, v[0])) - 1.0 <= u[0] <= float(traction_limit(p, v[0])) + 1.0
    assert np.all(np.abs(np.diff(F)) <= p.max_jerk_mps3 * M * DT * (1 + 1e-9))  # 4c / 12o
    assert np.all(v >= 0.0)
    tol_speed = cfg.tol_speed_mps if tol_speed is None else tol_speed
    if lk is not None:
        assert np.all(v[1:] <= lk.speed_limit(s[1:]) + tol_speed)  # 11e / 12g
    if terminal is not None:
        beta, _ = terminal.beta(float(s[-1]))
        assert v[-1] ** 2 <= max(beta, 0.0) + 2 * tol_speed * math.sqrt(max(beta, 0.0)) + tol_speed**2 + 1e-9  # 11i / 12k
    if leader is not None:
        d = leader.rear_m - s
        assert np.all(d[1:] >= cfg.d_min_m - cfg.tol_gap_m)  # 12f, 12l
        h = d[-1] + leader.speeds_mps[-1] ** 2 / (2 * cfg.a_leader_mps2) - v[-1] ** 2 / (2 * cfg.a_follower_mps2)
        assert h >= cfg.d_min_m - cfg.tol_gap_m  # 12m


# -------------------------------------------------------------------------------------------
# Settings


def test_settings_files_load_and_are_strict(tmp_path):
    for name in ("mpc.yaml", "mpc_felez2019.yaml"):
        cfg = load_mpc_settings(project_root() / "controllers" / name)
        assert cfg.step_s == 0.1 and cfg.horizon_steps == 40 and cfg.d_des_m == 10.0
        assert cfg.d_min_m == pytest.approx(4.0)  # eq. 9: d0 + 2 e_s
        assert cfg.a_leader_mps2 == 1.25 and 0.5 <= cfg.a_follower_mps2 <= 1.0
        assert (cfg.k_v_leader, cfg.k_j_leader, cfg.k_d, cfg.k_v_follower, cfg.k_j_follower) == (100.0, 0.5, 100.0, 100.0, 0.5)
        assert (cfg.dp.k_vdp, cfg.dp.k_ldp, cfg.dp.ds_min_m, cfg.dp.ds_max_m) == (1.0, 1.0e5, 0.25, 5.0)
    bad = tmp_path / "bad.yaml"
    bad.write_text("step_s: 0.1\nhorizon: 40\n")
    with pytest.raises(InputError, match="unknown key"):
        load_mpc_settings(bad)
    bad.write_text("d_des_m: 2.0\n")
    with pytest.raises(InputError, match="d_des_m"):
        load_model(MPCSettings, bad)


# -------------------------------------------------------------------------------------------
# Predictors (eq. 16-18), hand-computed


def test_predict_np_eq17():
    s, v = predict_np(100.0, 10.0, 1.25, 0.1, 3)
    assert v.tolist() == pytest.approx([10.0, 9.875, 9.75, 9.625])
    assert s.tolist() == pytest.approx([100.0, 100.99375, 101.975, 102.94375])
    # stopping: the literal 17b rolls a stopped leader backwards by a·Δt²/2 per step, the default stays put
    s, v = predict_np(50.0, 0.1, 1.25, 0.1, 3, literal=True)
    assert v.tolist() == pytest.approx([0.1, 0.0, 0.0, 0.0])
    assert s.tolist() == pytest.approx([50.0, 50.00375, 49.9975, 49.99125])
    s, v = predict_np(50.0, 0.1, 1.25, 0.1, 3)
    assert s.tolist() == pytest.approx([50.0, 50.004, 50.004, 50.004])  # v²/(2a) = 0.004 m, then at rest


def test_predict_mb_eq18():
    s, v = predict_mb(1234.5, 4)
    assert s.tolist() == [1234.5] * 5 and v.tolist() == [0.0] * 5


def test_predict_sh_eq16():
    # frictionless 1000 kg train, no lag: v_{k+1} = v_k + Δt·u/M, s_{k+1} = s_k + Δt·v_k
    p = TrainParams(length_m=10, mass_kg=1000.0, rotating_mass_factor=1.0, max_speed_ms=50, max_traction_n=1e6, max_power_w=1e9,
                    davis_a_n=0.0, davis_b_n_per_mps=0.0, davis_c_n_per_mps2=0.0, service_brake_decel_mps2=1.0, emergency_brake_decel_mps2=1.5)
    # previous plan u*_{·|t-1} = [100, 200, 300]: used shifted (16c), the last one repeated (16d)
    s, v, F = predict_sh(p, 20.0, 1.0, 0.0, [100.0, 200.0, 300.0], 0.1, 3, eps_mps=0.0)
    assert F.tolist() == pytest.approx([0.0, 200.0, 300.0, 300.0])
    assert v.tolist() == pytest.approx([1.0, 1.02, 1.05, 1.08])
    assert s.tolist() == pytest.approx([20.0, 20.1, 20.202, 20.307])
    # no previous plan: zero inputs
    s, v, _ = predict_sh(p, 0.0, 2.0, 0.0, None, 0.1, 2, eps_mps=0.0)
    assert v.tolist() == pytest.approx([2.0, 2.0, 2.0]) and s.tolist() == pytest.approx([0.0, 0.2, 0.4])


def test_predict_sh_from_plan_resamples_and_extends():
    T = 10.0 + 0.1 * np.arange(5)  # plan sent at t−1 = 10.0
    P = 100.0 + 2.0 * (T - 10.0)
    V = np.full(5, 2.0)
    s, v = predict_sh_from_plan(T, P, V, 10.1, 0.1, 5)
    assert s.tolist() == pytest.approx([100.2, 100.4, 100.6, 100.8, 101.0, 101.2])  # last point extrapolated
    assert v.tolist() == pytest.approx([2.0] * 6)
    s, v = predict_sh_from_plan(T, P, V, 10.1, 0.1, 2, measured=(100.5, 1.9))  # measured state (16a)
    assert s.tolist() == pytest.approx([100.5, 100.7, 100.9]) and v[0] == 1.9
    # a braking plan is continued with its last deceleration until rest
    Vb = np.array([1.0, 0.8, 0.6, 0.4, 0.2])
    Pb = 50.0 + np.concatenate([[0.0], np.cumsum(Vb[:-1] * 0.1)])
    s, v = predict_sh_from_plan(T, Pb, Vb, 10.4, 0.1, 4)
    assert v.tolist() == pytest.approx([0.2, 0.0, 0.0, 0.0, 0.0])
    assert s[-1] == pytest.approx(Pb[-1] + 0.2**2 / (2 * 2.0))


# -------------------------------------------------------------------------------------------
# Leader NMPC (eq. 11)


@pytest.mark.parametrize("x0", [(100.0, 0.0, 0.0), (500.0, 10.0, 60000.0), (1500.0, 20.0, 40000.0), (3000.0, 23.0, -20000.0)])
def test_leader_plan_satisfies_constraints(params, settings, route, x0):
    ctrl = LeaderMPC(params, settings)
    sol = ctrl.solve_arrays(x0, route, v_max_mps=25.0, max_iterations=30)
    _, terminal = ctrl.route_data(route)
    check_plan(sol, params, settings, route, terminal=terminal)
    assert sol.speeds_mps[-1] > x0[1] - 1e-6 or x0[1] > 22.0  # it accelerates towards v_max


def test_leader_power_limit_is_active(params, settings, route):
    ctrl = LeaderMPC(params, settings)
    sol = ctrl.solve_arrays((800.0, 15.0, 80000.0), route, v_max_mps=25.0, max_iterations=30)
    check_plan(sol, params, settings, route)
    pw = sol.commands_n * sol.speeds_mps[:-1]
    assert pw.max() == pytest.approx(params.max_power_w, rel=2e-3)  # full power while below v_max


def test_leader_brakes_for_restriction_and_end(params, settings, restricted_route):
    ctrl = LeaderMPC(params, settings)
    _, terminal = ctrl.route_data(restricted_route)
    for x0 in [(950.0, 22.0, 40000.0), (1050.0, 17.0, -60000.0), (1190.0, 12.0, -20000.0), (3850.0, 16.0, -80000.0), (3990.0, 3.0, -140000.0)]:
        sol = ctrl.solve_arrays(x0, restricted_route, v_max_mps=27.78, max_iterations=30)
        check_plan(sol, params, settings, restricted_route, terminal=terminal)
        assert float(terminal.terminal_bound(sol.positions_m[-1])) >= sol.speeds_mps[-1] - settings.tol_speed_mps



@pytest.mark.parametrize("jerk_on,plant_jerk", [("force", True), ("force", False), ("command", True)])
def test_leader_stops_at_route_end_on_plant(params, settings, restricted_route, jerk_on, plant_jerk):
    """Closed loop on TrainPlant: the leader stops at the end of the route without passing it,
    with or without the plant's own jerk limit (eq. 12o, the NMPC's constraint) and with the
    stricter command-rate jerk model."""
    cfg = settings.model_copy(update={"jerk_limit_on": jerk_on})
    ctrl = LeaderMPC(params, cfg)
    plant = TrainPlant(params, PlantState(3700.0, 20.0, 40000.0), restricted_route, apply_jerk=plant_jerk)
    for k in range(700):
        cmd = ctrl.make_step(_obs(k * DT, plant, params, restricted_route, target=27.78))
        assert not cmd.infeasible, ctrl.last_solution.violation
        plant.step(cmd.force_n, DT)
    assert plant.x.v_mps < 1e-3 and 3990.0 < plant.x.s_m <= 4000.0


def test_command_jerk_mode(params, settings, route):
    cfg = settings.model_copy(update={"jerk_limit_on": "command"})
    sol = LeaderMPC(params, cfg).solve_arrays((500.0, 10.0, 0.0), route, v_max_mps=25.0, max_iterations=30)
    check_plan(sol, params, cfg, route)
    assert np.all(np.abs(sol.commands_n - sol.forces_n[:-1]) <= params.max_jerk_mps3 * params.mass_kg * DT * (1 + 1e-9))


def test_leader_closed_loop_rti_plans_are_feasible(params, settings, restricted_route):
    """Real-time iterations from the warm start: every plan holds the constraints within the tolerances."""
    ctrl = LeaderMPC(params, settings)
    plant = TrainPlant(params, PlantState(0.0, 0.0, 0.0), restricted_route)
    _, terminal = ctrl.route_data(restricted_route)
    iters = []
    for k in range(1500):
        cmd = ctrl.make_step(_obs(k * DT, plant, params, restricted_route, target=27.78))
        sol = ctrl.last_solution
        check_plan(sol, params, settings, restricted_route, terminal=terminal, rti=True)
        iters.append(sol.iterations)
        plant.step(cmd.force_n, DT)
        assert plant.x.v_mps <= restricted_route.speed_limit_train(plant.x.s_m, params.length_m) + 0.05
    assert ctrl.stats.infeasible == 0
    assert np.mean(iters) < 1.3  # mostly one SQP iteration per step
    assert plant.x.s_m > 1500.0  # it passed the restriction


# -------------------------------------------------------------------------------------------
# Follower NMPC (eq. 12)


def _leader_prediction(strategy, s_l, v_l, params, cfg):
    if strategy == "SH":  # leader cruising at v_l according to its plan
        s = s_l + v_l * DT * np.arange(N + 1)
        v = np.full(N + 1, v_l)
    elif strategy == "NP":
        s, v = predict_np(s_l, v_l, cfg.a_leader_mps2, DT, N)
    else:
        s, v = predict_mb(s_l, N)
    return LeaderPrediction(times_s=DT * np.arange(N + 1), positions_m=s, speeds_mps=v, length_m=params.length_m, strategy=strategy)


@pytest.mark.parametrize("strategy,gap,v", [("SH", 30.0, 20.0), ("SH", 12.0, 10.0), ("NP", 150.0, 20.0), ("NP", 30.0, 5.0), ("MB", 400.0, 20.0), ("MB", 30.0, 3.0)])
def test_follower_plan_satisfies_constraints(params, settings, route, strategy, gap, v):
    ctrl = FollowerMPC(params, settings, predictor=strategy)
    s_f = 1000.0
    lead = _leader_prediction(strategy, s_f + params.length_m + gap, v, params, settings)
    sol = ctrl.solve_arrays((s_f, v, 40000.0), lead, route, v_max_mps=20.0, max_iterations=30)
    _, terminal = ctrl.route_data(route)
    check_plan(sol, params, settings, route, leader=lead, terminal=terminal)


def test_follower_infeasible_falls_back_to_full_brake(params, settings, route):
    ctrl = FollowerMPC(params, settings, predictor="MB")
    lead = _leader_prediction("MB", 1000.0 + params.length_m + 20.0, 0.0, params, settings)  # standing 20 m ahead
    sol = ctrl.solve_arrays((1000.0, 15.0, 0.0), lead, route)  # cannot stop in 16 m from 15 m/s
    assert not sol.ok
    assert sol.force_n == pytest.approx(fallback_force(params, 15.0)) == pytest.approx(-float(brake_force_limit(params, 15.0)))
    # through make_step: a command, flagged and counted, never an exception
    lead_plant = TrainPlant(params, PlantState(1000.0 + params.length_m + 20.0, 0.0, 0.0), route)
    plant = TrainPlant(params, PlantState(1000.0, 15.0, 0.0), route)
    cmd = ctrl.make_step(_follower_obs(0.0, plant, lead_plant, None, params, route))
    assert cmd.infeasible and cmd.mode == "fallback" and cmd.force_n < 0
    assert ctrl.stats.infeasible == 1


def test_make_step_never_raises(params, settings, route):
    ctrl = FollowerMPC(params, settings, predictor="SH")
    ego = TrainStateMsg(time_s=0.0, position_m=float("nan"), speed_mps=10.0)
    obs = Observation(time_s=0.0, step_s=DT, ego_id="f", ego=ego, params=params, profile=route, predecessor="l")
    cmd = ctrl.make_step(obs)  # no information about the predecessor and a NaN state
    assert cmd.infeasible and cmd.force_n < 0
    leader = LeaderMPC(params, settings)
    cmd = leader.make_step(obs)
    assert cmd.infeasible and cmd.force_n < 0 and leader.stats.infeasible == 1


def test_follower_closed_loop_keeps_d_min(params, settings, route):
    """Leader NMPC + SH follower on the plant: the gap never drops below d_min, no fallback."""
    lead_ctrl, fol_ctrl = LeaderMPC(params, settings), FollowerMPC(params, settings, predictor="SH")
    lp = TrainPlant(params, PlantState(300.0, 10.0, 0.0), route)
    fp = TrainPlant(params, PlantState(300.0 - params.length_m - 30.0, 10.0, 0.0), route)
    last = None
    gaps = []
    for k in range(800):
        t = k * DT
        cl = lead_ctrl.make_step(_obs(t, lp, params, route, target=20.0))
        cf = fol_ctrl.make_step(_follower_obs(t, fp, lp, last, params, route))
        assert not cf.infeasible
        check_plan(fol_ctrl.last_solution, params, settings, route, leader=fol_ctrl.last_solution.leader, rti=True)
        lp.step(cl.force_n, DT)
        fp.step(cf.force_n, DT)
        last = cl
        gaps.append(lp.x.s_m - params.length_m - fp.x.s_m)
    assert min(gaps) >= settings.d_min_m - settings.tol_gap_m
    assert gaps[-1] < 30.0  # it closed up towards d_des


def test_warm_start_matches_cold_converged(params, settings, route):
    ctrl = LeaderMPC(params, settings)
    a = ctrl.solve_arrays((1000.0, 18.0, 50000.0), route, v_max_mps=20.0, max_iterations=40)
    b = ctrl.solve_arrays((1000.0 + 18.0 * DT, a.speeds_mps[1], a.forces_n[1]), route, v_max_mps=20.0, z_warm=a.warm_start(), max_iterations=40)
    c = ctrl.solve_arrays((1000.0 + 18.0 * DT, a.speeds_mps[1], a.forces_n[1]), route, v_max_mps=20.0, max_iterations=40)
    assert b.ok and c.ok
    assert np.max(np.abs(b.commands_n - c.commands_n)) < 50.0  # N
    assert b.iterations <= c.iterations


# -------------------------------------------------------------------------------------------
# helpers


def _obs(t, plant, params, route, target=None):
    x = plant.x
    ego = TrainStateMsg(time_s=t, position_m=x.s_m, speed_mps=x.v_mps, accel_mps2=x.accel_mps2, force_n=x.force_n)
    return Observation(time_s=t, step_s=DT, ego_id="l", ego=ego, params=params, profile=route, target_speed_mps=target)


def _follower_obs(t, plant, lead_plant, lead_cmd, params, route):
    x, xl = plant.x, lead_plant.x
    ego = TrainStateMsg(time_s=t, position_m=x.s_m, speed_mps=x.v_mps, accel_mps2=x.accel_mps2, force_n=x.force_n)
    st = TrainStateMsg(time_s=t, position_m=xl.s_m, speed_mps=xl.v_mps)
    kw = {}
    if lead_cmd is not None:
        kw = dict(plan_times_s=lead_cmd.plan_times_s, plan_positions_m=lead_cmd.plan_positions_m, plan_speeds_mps=lead_cmd.plan_speeds_mps,
                  plan_forces_n=lead_cmd.plan_forces_n)
    msg = Message(sender="l", sent_time_s=t, state=st, length_m=params.length_m, **kw)
    return Observation(time_s=t, step_s=DT, ego_id="f", ego=ego, params=params, profile=route, received={"l": msg}, predecessor="l",
                       sensed_gap_m=xl.s_m - params.length_m - x.s_m, sensed_speed_mps=xl.v_mps, target_speed_mps=20.0)


def test_solve_never_raises_on_bad_input(params, settings, route):
    ctrl = LeaderMPC(params, settings)
    for x0 in [(float("nan"), 10.0, 0.0), (100.0, float("inf"), 0.0), ("x", 1.0, 0.0)]:
        sol = ctrl.solve_arrays(x0, route)
        assert not sol.ok and sol.force_n < 0
    sol = ctrl.solve_arrays((100.0, 10.0, 0.0), route, z_warm=np.full(N, np.nan))  # a broken warm start is replaced
    assert sol.ok
