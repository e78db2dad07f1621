"""The NMPC's speed limit where no plan can keep it: the speed floor of the lag and the jerk limit.

A train at its limit on a steep descent that arrives with a force the lag and the jerk limit cannot
bring down in time (e.g. after a plant that applied the previous command at once, as the SUMO loop
does) exceeds the limit over the first steps of every plan.  Before the floor the NMPC called such a
plan infeasible and commanded the full service brake, so a follower chattered between plan and brake
on every long descent (the alpine line: 1,430 infeasible steps); now the limit is raised to the floor
only at the steps where it is unavoidable (``MPCSolution.speed_relaxation_mps``).
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from vcsumo.control.mpc import LeaderMPC, MPCSettings, load_mpc_settings
from vcsumo.control.mpc_solver import speed_floor
from vcsumo.control.route_lookup import straight_route_profile
from vcsumo.dynamics import acceleration
from vcsumo.line import project_root
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.sim.offline import SpeedProfile, simulate_convoy
from vcsumo.control.route_lookup import route_profile_from_arrays

# a heavy, slow-to-respond commuter EMU (the unseen alpine test stock of this session): 0.6 s lag, 0.8 m/s³
COMMUTER = {
    "name": "commuter", "title": "heavy slow commuter EMU (alpine test stock)", "length_m": 100.0, "mass_kg": 260000.0,
    "rotating_mass_factor": 1.08, "max_speed_kmh": 120.0, "max_traction_n": 220000.0, "max_power_w": 2.0e6, "davis_a_n": 3500.0,
    "davis_b_n_per_mps": 40.0, "davis_c_n_per_mps2": 5.0, "service_brake_decel_mps2": 0.7, "emergency_brake_decel_mps2": 1.1,
    "max_jerk_mps3": 0.8, "traction_lag_s": 0.6,
}
V_LIM = 120.0 / 3.6
DESCENT = -0.025  # 25 ‰ down


@pytest.fixture(scope="module")
def stock_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("stock") / "commuter.yaml"
    path.write_text(yaml.safe_dump(COMMUTER))
    return path


@pytest.fixture(scope="module")
def params(stock_path):
    return load_rolling_stock(stock_path).params()


@pytest.fixture(scope="module")
def settings() -> MPCSettings:
    return load_mpc_settings(project_root() / "controllers" / "mpc.yaml")


@pytest.fixture(scope="module")
def descent():
    return straight_route_profile(20000.0, V_LIM, gradient=DESCENT)


def holding_force(p, v: float) -> float:
    """The force that holds v on the descent (a = 0), N."""
    return float(acceleration(p, v, 0.0, DESCENT, 1.0)) * -p.mass_kg * p.rotating_mass_factor


def floor_of(ocp, x0, lookup):
    """The speed floor from x0 on a route (the model simulated along its own positions)."""
    return speed_floor(ocp, x0, lambda z: np.array(ocp.simulate(x0, z, lookup)[1]))


def test_no_admissible_plan_is_slower_than_the_floor(params, settings, descent):
    """Random plans within the jerk bounds and the service brake (4a, 4c) never go below the floor."""
    ctrl = LeaderMPC(params, settings)
    ocp, lookup = ctrl.ocp, ctrl.route_data(descent)[0]
    x0 = (1000.0, V_LIM, 60000.0)
    floor = floor_of(ocp, x0, lookup)
    rng = np.random.default_rng(7)
    lowest = np.full(ocp.N, np.inf)
    for _ in range(200):
        z, F = rng.uniform(-ocp.z_max, ocp.z_max, ocp.N), x0[2]
        for k in range(ocp.N):  # the command u_k = F_k + ΔF_k/α within the service brake
            z[k] = max(z[k], ocp.alpha * (ocp.u_min - F) / ocp.z_scale)
            F += z[k] * ocp.z_scale
        lowest = np.minimum(lowest, ocp.simulate(x0, z, lookup)[1])
    assert np.all(lowest >= floor - 1e-9)
    # the floor is reached (it is a plan itself) and it first rises above the limit: the force cannot turn in time
    assert floor.max() > V_LIM + settings.tol_speed_mps
    assert floor[-1] < V_LIM


def test_speed_limit_relaxed_only_where_unavoidable(params, settings, descent):
    """At the limit with +60 kN on 25 ‰ down the limit cannot be kept within the tolerance by any plan
    (the old check made this step infeasible); the plan is feasible against max(v_lim, floor), keeps
    v_lim wherever the floor allows, and reports the relaxation."""
    ctrl = LeaderMPC(params, settings)
    x0 = (1000.0, V_LIM - 0.01, 60000.0)
    floor = floor_of(ctrl.ocp, x0, ctrl.route_data(descent)[0])
    assert floor.max() - V_LIM > settings.tol_speed_mps  # unavoidable beyond the tolerance
    sol = ctrl.solve_arrays(x0, descent, v_max_mps=V_LIM)
    assert sol.ok, sol.violation
    assert sol.force_n < 0.0  # brakes: the plan, not the fallback
    assert sol.speed_relaxation_mps == pytest.approx(floor.max() - V_LIM, abs=1e-9)
    np.testing.assert_allclose(sol.v_limit_mps, np.maximum(V_LIM, floor), atol=1e-9)
    assert np.all(sol.speeds_mps[1:] <= np.maximum(V_LIM, floor) + settings.tol_speed_mps)
    after = floor <= V_LIM
    assert after.sum() > ctrl.ocp.N // 2 and np.all(sol.speeds_mps[1:][after] <= V_LIM + settings.tol_speed_mps)
    # holding the limit with the force that holds it: nothing to relax
    steady = ctrl.solve_arrays((1000.0, V_LIM, holding_force(params, V_LIM)), descent, v_max_mps=V_LIM)
    assert steady.ok and steady.speed_relaxation_mps == 0.0


@pytest.mark.parametrize("lag", [False, True])
def test_follower_at_its_limit_on_a_long_descent_keeps_planning(stock_path, lag):
    """A follower closing a long gap runs at its limit down 11 km of 25 ‰.  With a plant that applies
    each command at once (``lag=False``, as the SUMO loop does) its NMPC starts every step from a force
    the lag and jerk of its model cannot turn in time: before the floor, 123 of 601 steps were
    infeasible (full service brake, chatter); now none, and the train never exceeds its limit."""
    route = route_profile_from_arrays([0.0, 600.0, 12000.0], [V_LIM] * 3, [0.0, DESCENT, 0.0], length_m=20000.0)
    df = simulate_convoy([str(stock_path)] * 2, "mpc", SpeedProfile((0.0, 400.0), (V_LIM, V_LIM)), 60.0, 0.1, None, [2000.0],
                         initial_speeds_mps=[V_LIM, 28.0], profile=route, leader_position_m=2400.0, apply_lag=lag, apply_jerk=lag)
    f = df[df.train == "T1"]
    on_descent = f[(f.position_m > 700.0) & (f.position_m < 12000.0)]
    assert on_descent.speed_mps.max() > V_LIM - 0.05  # the case is exercised: at its limit on the descent
    assert int(f.infeasible.sum()) == 0
    assert float(f.speed_mps.max()) <= V_LIM + 1e-9
    assert not f.emergency.any()
