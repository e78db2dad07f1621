"""The controller contract (issue 9): every registered controller, built by name through the registry
with its default parameters, stops a follower behind a leader that brakes to a stop at its emergency
rate — without SUMO, in the offline loop.  And the registry itself: unknown names, parameter files,
and a controller registered here (a tiny real ACC law) usable by name with no other module touched.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcsumo.control.base import Command, Observation
from vcsumo.control.registry import (
    CONTROLLERS, SUPERVISORS, ControllerEntry, Nominal, StackContext, build_follower_stack, check_controller, controller_names, parse_controller,
    register_controller,
)
from vcsumo.errors import InputError
from vcsumo.plant import PlantState
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.sim.offline import EmergencyBrake, OfflineTrain, SpeedProfile, flat_profile, run_convoy, simulate_convoy, steady_force
from vcsumo.studies.safety import barrier_gap_m

DT = 0.2
V0 = 55.0  # m/s, 198 km/h
T_BRAKE = 40.0
STOCK = load_rolling_stock("etr1000")
P = STOCK.params()
L = STOCK.length_m


def _run_pair(name: str, record_property=None):
    """Leader cruising at V0 then braking at its emergency rate (held to a stop); the follower at its
    controller's own spacing (with a CBF: at least the barrier's), driven by the registry's stack."""
    profile = flat_profile(60000.0, speed_limit_mps=90.0)
    stack = build_follower_stack(name, StackContext(ego=STOCK, predecessor=STOCK, step_s=DT, profile=profile, ego_id="F", predecessor_id="L"))
    s_l = 10000.0
    gap0 = stack.coupled_gap_m(V0)
    if stack.supervisor is not None:
        gap0 = max(gap0, 1.05 * barrier_gap_m(stack.supervisor, profile, s_l, V0, L))
    s_f = s_l - L - gap0
    leader = EmergencyBrake(SpeedProfile((0.0, 1e4), (V0, V0)), T_BRAKE)
    trains = [OfflineTrain("L", P, PlantState(s_l, V0, steady_force(P, V0, profile, s_l)), leader),
              OfflineTrain("F", P, PlantState(s_f, V0, steady_force(P, V0, profile, s_f)), stack)]
    run = run_convoy(trains, profile, DT, 300.0, send_plans=stack.uses_plans)
    df = run.frame
    f, ld = df[df.train == "F"], df[df.train == "L"]
    min_gap = float(f.gap_m.min())
    if record_property is not None:
        record_property("min_gap_m", round(min_gap, 2))
    print(f"{name}: initial gap {gap0:.1f} m, gap at the brake {float(f[f.time_s >= T_BRAKE].gap_m.iloc[0]):.1f} m, minimum gap {min_gap:.1f} m")
    return stack, gap0, f, ld, run


@pytest.mark.parametrize("name", controller_names())
def test_every_controller_stops_behind_an_emergency_braking_leader(name, record_property):
    stack, gap0, f, ld, run = _run_pair(name, record_property)
    # built by the registry with the default parameter files
    entry = CONTROLLERS[name.split("-")[-1]]
    assert stack.parameter_files["nominal"].endswith(f"{entry.default_params}.yaml")
    assert stack.guard is not None and (stack.supervisor is not None) == name.startswith("cbf-")
    # the leader really braked at its emergency rate: 1.2 m/s² + resistance once the brake has built up
    lb = ld[(ld.time_s > T_BRAKE + 4.0) & (ld.speed_mps > 5.0)]
    assert len(lb) > 10 and (-lb.accel_mps2 >= P.emergency_brake_decel_mps2 / P.rotating_mass_factor - 1e-6).all()
    # the follower was coupled (not fallen far behind) when the leader braked
    at_brake = float(f[f.time_s >= T_BRAKE].gap_m.iloc[0])
    assert at_brake < 1.5 * gap0 + 100.0
    # both stop, without collision
    assert f.gap_m.min() > 0.0
    assert all(e.action == "controller_fallback" for e in run.faults)  # no exception, NaN or unusable command on the way
    assert f.speed_mps.iloc[-1] < 0.01 and ld.speed_mps.iloc[-1] < 0.01


def test_unknown_names_and_parameter_sets_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="unknown controller 'pid'") as exc:
        parse_controller("pid", "controllers[1]")
    assert exc.value.field == "controllers[1]"
    for bad in ("cruise", "cbf-pid", "xyz-cbc", "cbf-cbf-cbc", ""):
        with pytest.raises(InputError, match="unknown controller"):
            parse_controller(bad)
    assert parse_controller("cbf-cbc:cbc_plf") == ("cbf-cbc", "cbc_plf")
    with pytest.raises(InputError, match="controller parameter set 'nope' not found") as exc:
        check_controller("cbc:nope", "--controller")
    assert exc.value.field == "--controller"
    # a relative path is taken from the caller's base folder (a study file's), not the working directory
    (tmp_path / "mine.yaml").write_text((CONTROLLERS_DIR() / "cbc.yaml").read_text())
    assert check_controller("cbc:mine.yaml", "controllers[0]", base_dir=tmp_path).params == "mine.yaml"
    with pytest.raises(InputError, match="'mine.yaml' not found") as exc:
        check_controller("cbc:mine.yaml", "controllers[0]")
    assert exc.value.field == "controllers[0]"


def CONTROLLERS_DIR():
    from vcsumo.control.params import controllers_dir

    return controllers_dir()


class ConstantTimeGapACC:
    """A tiny real controller: u = M·(k_g·(sensed gap − d − h·v) + k_v·(v_pred − v)) + resistance, held within the service envelope."""

    def __init__(self, d_m: float, h_s: float):
        self.d_m, self.h_s = d_m, h_s

    def make_step(self, obs: Observation) -> Command:
        p, v = obs.params, obs.ego.speed_mps
        if obs.sensed_gap_m is None:
            return Command(-p.mass_kg * p.service_brake_decel_mps2, mode="acc-blind")
        a = 0.05 * (obs.sensed_gap_m - self.d_m - self.h_s * v) + 0.6 * (obs.sensed_speed_mps - v)
        a = float(np.clip(a, -p.service_brake_decel_mps2, 0.5))
        return Command(p.mass_kg * p.rotating_mass_factor * a + steady_force(p, v, obs.profile, obs.ego.position_m), mode="acc")


def _build_acc(ctx: StackContext, params) -> Nominal:
    import yaml

    cfg = {"d_m": 80.0, "h_s": 2.0} if params is None else yaml.safe_load(params.read_text())
    return Nominal(ConstantTimeGapACC(cfg["d_m"], cfg["h_s"]), cfg["d_m"], lambda v: cfg["d_m"] + cfg["h_s"] * v)


@pytest.fixture
def acc_registered():
    register_controller(ControllerEntry("acc", _build_acc, None, uses_plans=False, doc="constant time-gap ACC (test)"))
    yield
    CONTROLLERS.pop("acc")


def test_a_new_controller_is_one_registry_entry(acc_registered, tmp_path):
    assert "acc" in controller_names() and all(f"{s}-acc" in controller_names() for s in SUPERVISORS)
    # usable by name in the offline loop, with the guard and the fault stage of every stack
    leader = EmergencyBrake(SpeedProfile((0.0, 1e4), (V0, V0)), 30.0)
    df = simulate_convoy(["etr1000"] * 2, "acc", leader, 150.0, DT, None, [80.0 + 2.0 * V0])
    f = df[df.train == "T1"]
    # (the ACC settles at its own d = 80 m, beyond the guard's 70 m margin, with a creep it damps
    # itself: the guard, which counts the brake build-up, stops it ≈ 3 m further back than the ACC's d
    # at ≈ 100 s and the ACC creeps on for a few tens of seconds)
    assert set(f["mode"]) >= {"acc"} and f.gap_m.min() > 70.0 and f.speed_mps.iloc[-1] < 0.05
    # a parameter file after the colon is resolved like any other (here: a path)
    (tmp_path / "acc.yaml").write_text("d_m: 150.0\nh_s: 1.0\n")
    stack = build_follower_stack(f"acc:{tmp_path / 'acc.yaml'}", StackContext(ego=STOCK, predecessor=STOCK, step_s=DT))
    assert stack.d_min_m == 150.0 and stack.coupled_gap_m(50.0) == 200.0 and stack.guard.d_min_m == 150.0
    # composed with the CBF like the shipped families
    sup = build_follower_stack("cbf-acc", StackContext(ego=STOCK, predecessor=STOCK, step_s=DT))
    # (the CBF's d on the separation model is 70 m, margin + 2 position errors: the stack keeps the larger d_min)
    assert sup.supervisor is not None and sup.supervisor.safety_distance_m == 70.0 and sup.d_min_m == 80.0


def test_registered_controllers_have_their_default_files_and_plans_flag():
    from vcsumo.control.params import resolve_params

    for name, e in CONTROLLERS.items():
        assert e.default_params is None or resolve_params(None, e.default_params).is_file(), name
    assert CONTROLLERS["mpc"].uses_plans and CONTROLLERS["cruise"].uses_plans and not CONTROLLERS["cbc"].uses_plans
    assert not CONTROLLERS["cruise"].standalone and "cruise" not in controller_names() and "cbf-cruise" in controller_names()
    # cbc tracks the certified spacing: the separation model's relative-braking gap (+ its 10 m buffer),
    # the follower's brake building up from the largest traction it may apply at 40 m/s (the top of its
    # box, min(M̄·ā, P̄/v) = min(540 t · 0.80, 10.1 MW / 40) = 252.5 kN; the force that holds 40 m/s,
    # Davis 8,800 + 61.8 v + 8.7 v² ≈ 25 kN, is less): τ + (F/M̲ + b)/(2j) more dead time, at the speed
    # that force may add meanwhile
    from vcsumo.signalling.assumptions import load_assumptions
    from vcsumo.signalling.separation import SeparationModel, relative_braking_gap

    model = SeparationModel(load_assumptions())
    gap40 = build_follower_stack("cbc", StackContext(ego=STOCK, predecessor=STOCK, step_s=DT)).coupled_gap_m(40.0)
    f_top = min(540e3 * 0.80, 10.1e6 / 40.0)
    assert f_top > 8800.0 + 61.8 * 40.0 + 8.7 * 40.0**2
    t_act = 0.5 + (f_top / 461e3 + 1.08) / (2 * 0.7)
    v_dead = 40.0 + f_top / (1.04 * 461e3) * t_act
    a_f, a_l = model.vc_decels(STOCK, STOCK, 40.0, 40.0)
    dead = model.dead_time_s + model.assumptions.t2t_delay_bound_s + 1.5 * DT + t_act
    assert math.isclose(gap40, model.margin_m + relative_braking_gap(v_dead, 40.0, a_f, a_l, dead) + 10.0)
    assert gap40 > model.vc_gap(STOCK, STOCK, 40.0, message_age_s=model.assumptions.t2t_delay_bound_s + 1.5 * DT) + 10.0 + 40.0 * t_act
