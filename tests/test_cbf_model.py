"""The CBF on the separation model (``distance: model``, the default of every ``cbf-*`` controller).

* on level track the barrier is hand-computable: d = margin + 2 position errors, the follower's
  guaranteed emergency brake after the dead time against the leader's strongest, and eq. 15's
  b' / b'' when the follower cannot out-brake the leader;
* the heterogeneous case — a light follower behind a heavy leader, guaranteed to brake harder than
  the leader can: the paper's barrier (a difference of stopping points) lets the gap fall below d in
  the offline loop, the model's (the maximum over the braking episode) does not;
* for the shipped trains the spacing the barrier keeps at line speed is below the moving-block gap;
* the registry builds it with the context's assumption set and protects its d.
"""

from __future__ import annotations

import pytest

from vcsumo.control.base import Command
from vcsumo.control.cbf import CBFConfig, CBFSupervisor, SeparationBarrier, level_route
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.registry import StackContext, build_follower_stack
from vcsumo.plant import PlantState
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, SeparationModel, brake_range, relative_braking_gap
from vcsumo.sim.offline import EmergencyBrake, OfflineTrain, SpeedProfile, flat_profile, run_convoy, steady_force, tracking_force

MODEL = SeparationModel(load_assumptions())
PAPER_FORM_RIGHT_LEADER = CBFConfig(distance="fixed", leader_braking="emergency")
"""Eq. 15 with a fixed d = 1,000 m but the leader's true strongest braking: the only difference to
the default is the barrier's form (stopping points at one instant vs the whole braking episode)."""

HEAVY_LEADER = """\
name: heavy_leader
title: A heavy train braking at 0.3 m/s² (test data)
length_m: 75.0
mass_kg: 165000.0
rotating_mass_factor: 1.06
max_speed_kmh: 160.0
max_traction_n: 200000.0
max_power_w: 2600000.0
davis_a_n: 0.0
davis_b_n_per_mps: 0.0
davis_c_n_per_mps2: 0.0
service_brake_decel_mps2: 0.3
emergency_brake_decel_mps2: 0.3
max_jerk_mps3: 1.0
traction_lag_s: 0.4
uncertainty:
  mass_kg: {low: 160000.0, high: 170000.0}
  davis_a_n: {low: 0.0, high: 0.0}
  davis_b_n_per_mps: {low: 0.0, high: 0.0}
  davis_c_n_per_mps2: {low: 0.0, high: 0.0}
  max_accel_mps2: {low: 1.1, high: 1.3}
  service_brake_decel_mps2: {low: 0.28, high: 0.32}
  max_power_w: {low: 2470000.0, high: 2730000.0}
"""


@pytest.fixture(scope="module")
def heavy(tmp_path_factory):
    p = tmp_path_factory.mktemp("stock") / "heavy_leader.yaml"
    p.write_text(HEAVY_LEADER)
    return load_rolling_stock(p)


def test_barrier_on_level_track_is_the_relative_braking_rule_by_hand():
    """A train without force lag or jerk limit (terlizzi2024 data): b = d + closing − gap, by hand."""
    lead, fol = load_rolling_stock("terlizzi2024_leader"), load_rolling_stock("terlizzi2024_follower")
    sup = CBFSupervisor(lead, fol, CBFConfig(), model=MODEL)
    prof = level_route()
    m = sup.model_for(prof)
    assert isinstance(m, SeparationBarrier)
    assert sup.safety_distance_m == m.d_m == 50.0 + 2 * 10.0  # the set's margin + 2 × 10 m odometry error
    a = MODEL.assumptions
    # the follower: emergency 1.2 at the bottom of ±10 %, Davis A at the bottom of its box over the heaviest mass (ρ = 1)
    a_f = 1.2 * 0.9 + 25.11 / 5.5e5
    # the leader: emergency 1.2 at the top, its whole resistance at v over the lightest mass
    v_l, v_f = 40.0, 35.0
    res = 28.24 + 10.12 * v_l + 2.11 * 1.5 * v_l**2
    a_l = 1.2 * 1.1 + res / 4.5e5
    dead = a.reaction_time_s + 0.5 * a.brake_build_up_s
    assert dead == 2.0 and m.actuation_time(1e5) == 0.0
    s_l, s_f = 20000.0, 19000.0
    gap = s_l - 202.0 - s_f
    b, b2 = m.value(s_l, v_l, s_f, v_f)
    assert b2 == pytest.approx(70.0 - gap)
    # the follower cannot out-brake the leader (1.08 < 1.32): eq. 15 with the model's stopping points
    stop_f = v_f * dead + v_f**2 / (2 * a_f)
    stop_l = v_l**2 / (2 * a_l)
    assert b == pytest.approx(max(b2, 70.0 - gap + stop_f - stop_l), abs=0.05)
    assert b == pytest.approx(70.0 - gap + relative_braking_gap(v_f, v_l, a_f, a_l, dead), abs=0.05)
    # the run-health monitor's rule is the same gap for a follower without actuator dynamics
    rule = RelativeBraking(MODEL, fol, lead, prof)
    assert m.required_gap_m(s_l, v_l, s_f, v_f, 0.0) == pytest.approx(rule.required_gap(s_f, v_f, s_l, v_l, dead))


def test_follower_actuation_adds_its_equivalent_dead_time():
    """ETR1000 (lag 0.5 s, jerk 0.7 m/s³): τ + (F/M + a_g)/(2j) from the applied force, 0 once braking."""
    st = load_rolling_stock("etr1000")
    m = CBFSupervisor(st, st, CBFConfig(), model=MODEL).model_for(level_route())
    a_g = brake_range(st, MODEL.assumptions, "emergency")[0]
    assert m.actuation_time(0.0) == pytest.approx(0.5 + a_g / (2 * 0.7))
    f = 0.1 * 461000.0  # a little traction, over the lightest mass
    assert m.actuation_time(f) == pytest.approx(0.5 + (0.1 + a_g) / (2 * 0.7))
    assert m.actuation_time(-540000.0 * a_g) == 0.0
    assert m.actuation_time(None) == pytest.approx(0.5 + (0.8 * 540 / 461 + a_g) / (2 * 0.7))  # full traction


class _Tracking:
    """A nominal controller that holds 30 m/s whatever is ahead, filtered by the supervisor."""

    def __init__(self, sup: CBFSupervisor):
        self.sup = sup

    def make_step(self, obs):
        return self.sup.filter(obs, Command(force_n=tracking_force(obs, 30.0, 0.0, 0.5), mode="track"))


def _light_behind_heavy(heavy, cfg: CBFConfig):
    """hcmc_l1 at 30 m/s on its barrier's boundary behind a heavy leader at 20 m/s that brakes at
    once at the top of its emergency range; the follower's emergency brake at the bottom of its
    range (both the separation model's worst case); level track, messages every 0.5 s, 0.2 s old."""
    light = load_rolling_stock("hcmc_l1")
    prof = flat_profile(80000.0, 97.0, 0.0)
    sup = CBFSupervisor(heavy, light, cfg, leader_id="L", model=MODEL)
    s_l, v_l, v_f = 10000.0, 20.0, 30.0
    gap0 = sup.required_gap_m(prof, s_l, v_l, s_l - 5000.0, v_f) + 1.0
    pl = heavy.params().with_(emergency_brake_decel_mps2=brake_range(heavy, MODEL.assumptions, "emergency")[1])
    pf = light.params().with_(emergency_brake_decel_mps2=brake_range(light, MODEL.assumptions, "emergency")[0])
    trains = [
        OfflineTrain("L", pl, PlantState(s_l, v_l, steady_force(pl, v_l, prof, s_l)), EmergencyBrake(SpeedProfile((0, 1000), (v_l, v_l)), 0.2),
                     nominal=heavy.params()),
        OfflineTrain("F", pf, PlantState(s_l - heavy.length_m - gap0, v_f, steady_force(pf, v_f, prof, 0.0)), _Tracking(sup), nominal=light.params(),
                     sends=False),
    ]
    rule = RelativeBraking(MODEL, light, heavy, prof)
    margins = []

    def monitor(step):
        xl, xf = step.states
        gap = xl.s_m - heavy.length_m - xf.s_m
        margins.append(gap - rule.required_gap(xf.s_m, xf.v_mps, xl.s_m, xl.v_mps, MODEL.dead_time_s))

    run = run_convoy(trains, prof, 0.2, 120.0, channel=Channel(ChannelConfig(model="constant", period_s=0.5, delay_s=0.2)), known_at_start=True,
                     on_step=monitor)
    df = run.frame
    fol = df[df.train == "F"]
    assert fol.speed_mps.iloc[-1] == 0.0 and df[df.train == "L"].speed_mps.iloc[-1] == 0.0  # both stood still
    return sup, float(fol.gap_m.min()), min(margins), rule


def test_light_follower_behind_heavy_leader_keeps_d_where_the_stopping_point_barrier_breaches(heavy):
    # the follower is guaranteed to brake harder than the leader can, even with the paper's service-box follower
    light = load_rolling_stock("hcmc_l1")
    assert brake_range(light, MODEL.assumptions, "emergency")[0] > brake_range(heavy, MODEL.assumptions, "emergency")[1]
    sup, min_gap, min_margin, rule = _light_behind_heavy(heavy, CBFConfig())
    assert not rule.never_outbrakes and not sup.model_for(None).rule.never_outbrakes
    assert min_gap >= sup.safety_distance_m  # never below margin + position errors (front-to-rear; + L front-to-front)
    assert min_margin >= 0.0  # the run-health monitor's rule held at every step
    assert sup.stats.max_true_barrier_m <= 0.0 and sup.stats.emergency_activations >= 1
    # eq. 15 (stopping points at one instant) with the same d-protection and the leader's true strongest braking:
    # b' < b'' on the boundary, so only the present gap is protected and it closes mid-braking
    old, old_min_gap, _, _ = _light_behind_heavy(heavy, PAPER_FORM_RIGHT_LEADER)
    assert old_min_gap < old.safety_distance_m - 20.0
    assert old.stats.max_true_barrier_m > 20.0


@pytest.mark.parametrize("name, kmh", [("etr1000", 300.0), ("regional_emu160", 160.0), ("hcmc_l1", 110.0)])
def test_barrier_spacing_at_line_speed_is_below_moving_block(name, kmh):
    """The documented default is not worse than MB: the gap at which b = 0 for a pair of the shipped
    train at steady speed (traction holding the speed, a 0.5 s old packet), against the MB gap."""
    st = load_rolling_stock(name)
    sup = CBFSupervisor(st, st, CBFConfig(), model=MODEL)
    prof = level_route()
    v = kmh / 3.6
    s_l = 1.0e6
    age = MODEL.assumptions.t2t_delay_bound_s
    e0, _ = sup.model_for(prof).rlp_reset(s_l, v)
    s_rlp, v_rlp = s_l + v * age - 0.5 * e0 * age * age, v - e0 * age  # Algorithm 1 from a packet `age` old
    gap = sup.required_gap_m(prof, s_rlp, v_rlp, s_l - 5000.0, v, steady_force(st.params(), v, prof, 0.0)) + (s_l + v * age - s_rlp)
    mb = MODEL.mb_gap(st, v)
    assert MODEL.vc_gap(st, st, v) < gap < mb
    paper = CBFSupervisor(st, st, CBFConfig(distance="fixed", leader_braking="service"), model=MODEL).required_gap_m(prof, s_l, v, s_l - 5000.0, v)
    assert gap < paper


def test_registry_builds_the_model_barrier_under_the_context_assumptions():
    st = load_rolling_stock("etr1000")
    a = load_assumptions().model_copy(update={"safety_margin_m": 80.0, "position_error_m": 5.0})
    stack = build_follower_stack("cbf-cbc", StackContext(ego=st, predecessor=st, step_s=0.2, assumptions=a))
    sup = stack.supervisor
    assert sup.cfg.distance == "model" and sup.cfg.leader_braking is None  # the set's relative braking (emergency)
    assert sup.safety_distance_m == 90.0 and stack.d_min_m == 90.0
    paper = build_follower_stack("cbf-cbc", StackContext(ego=st, predecessor=st, step_s=0.2, supervisor_params="cbf_terlizzi2024"))
    assert paper.supervisor.cfg.distance == "fixed" and paper.d_min_m == 1000.0
