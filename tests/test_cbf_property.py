"""Tier 1 — the CBF supervisor against an adversary (hypothesis, no SUMO).

The follower's nominal controller always demands full traction (the worst a nominal controller can
do); the leader drives with an arbitrary force sequence — traction, coasting and sudden full brakes —
and its packets reach the follower with arbitrary delays (0–6 s), out of order, or not at all.  Both
trains are plants with true parameters inside (or at a corner of) the ETR1000's uncertainty box
(Terlizzi eq. 7) on a level, falling or rising line.  The invariant of Theorem VI.1: started in the
safe set with a first packet, the barrier b(x) evaluated on the *true* states stays ≤ 0 at every
step, so the gap never falls below the safety distance d — for the default barrier on the separation
model (the leader may also apply its emergency brake at the top of its range; the run-health
monitor's relative-braking rule holds at every step too) and for the paper's eq. 15 (d = 1,000 m,
the leader within its service box).
"""

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vcsumo.control.base import Command, Message, Observation, TrainStateMsg
from vcsumo.control.cbf import CBFConfig, CBFSupervisor, barrier_from_stops
from vcsumo.control.proxies import sample_params
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, SeparationModel, brake_range
from vcsumo.sim.offline import flat_profile

DT = 0.2
STEPS = 400  # 80 s
STOCK = load_rolling_stock("etr1000")
L = STOCK.length_m
FORMS = {"model": CBFConfig(), "paper": CBFConfig(distance="fixed", leader_braking="service")}
MODEL = SeparationModel(load_assumptions())


class FullTraction:
    def make_step(self, obs: Observation) -> Command:
        return Command(force_n=1e12, mode="adversary")


segments = st.lists(st.floats(min_value=-1.0, max_value=1.0), min_size=4, max_size=20)
packets = st.lists(st.tuples(st.floats(min_value=0.0, max_value=6.0), st.booleans()), min_size=STEPS // 5, max_size=STEPS // 5)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    forces=segments, packets=packets, v0=st.floats(min_value=5.0, max_value=83.0), slack=st.floats(min_value=1.0, max_value=1.5),
    grade=st.sampled_from([0.0, -0.012, 0.012]), corners=st.tuples(st.booleans(), st.booleans()), seed=st.integers(0, 2**31 - 1),
    form=st.sampled_from(sorted(FORMS)),
)
def test_true_barrier_never_positive(forces, packets, v0, slack, grade, corners, seed, form):
    rng = np.random.default_rng(seed)
    profile = flat_profile(60000.0, speed_limit_mps=97.0, gradient=grade)
    cfg = FORMS[form]
    sup = CBFSupervisor(STOCK, STOCK, cfg, record=False, model=MODEL)
    pl, pf = (sample_params(STOCK, rng, corner=c) for c in corners)
    emergency = form == "model"  # the leader may brake at the top of its emergency range
    low, high = brake_range(STOCK, MODEL.assumptions, "emergency")
    pl, pf = pl.with_(emergency_brake_decel_mps2=high), pf.with_(emergency_brake_decel_mps2=low)  # the worst case of the separation model
    rule = RelativeBraking(MODEL, STOCK, STOCK, profile)
    s_l = 20000.0
    gap0 = slack * sup.required_gap_m(profile, s_l, v0, s_l - L - 5000.0, v0) + 1.0
    leader = TrainPlant(pl, PlantState(s_l, v0, 0.0), profile)
    follower = TrainPlant(pf, PlantState(s_l - L - gap0, v0, 0.0), profile)
    model = sup.model_for(profile)
    nominal = FullTraction()
    in_flight: list[tuple[float, Message]] = []
    latest: Message | None = None
    worst_b, min_gap = -math.inf, math.inf
    for k in range(STEPS):
        t = k * DT
        xl, xf = leader.x, follower.x
        if k % 5 == 0:  # the leader sends every second
            msg = Message("L", t, TrainStateMsg(t, xl.s_m, xl.v_mps, xl.accel_mps2, xl.force_n), L)
            delay, lost = packets[k // 5]
            if k == 0:
                delay, lost = 0.0, False  # Algorithm 1 starts from a first packet
            if not lost:
                in_flight.append((t + delay, msg))
        arrived = [m for due, m in in_flight if due <= t + 1e-9]
        in_flight = [(due, m) for due, m in in_flight if due > t + 1e-9]
        for m in arrived:  # out-of-order arrivals: the receiver shows the last one that arrived
            latest = m
        obs = Observation(time_s=t, step_s=DT, ego_id="F", ego=TrainStateMsg(t, xf.s_m, xf.v_mps, xf.accel_mps2, xf.force_n), params=pf,
                          profile=profile, received={"L": latest} if latest else {}, predecessor="L")
        cmd = sup.filter(obs, nominal.make_step(obs))
        gap = xl.s_m - L - xf.s_m
        min_gap = min(min_gap, gap)
        if emergency:
            b = model.value(xl.s_m, xl.v_mps, xf.s_m, xf.v_mps, xf.force_n)[0]
            # the run-health monitor's rule (relative braking on the true states, the set's dead time)
            assert gap >= rule.required_gap(xf.s_m, xf.v_mps, xl.s_m, xl.v_mps, MODEL.dead_time_s) - 1e-6
        else:
            b = barrier_from_stops(xl.s_m, model.leader_stop(xl.s_m, xl.v_mps), xf.s_m, model.follower_stop(xf.s_m, xf.v_mps, 0.0, xf.force_n), L,
                                   cfg.safety_distance_m)[0]
        worst_b = max(worst_b, b)
        u = forces[min(int(t // 5.0), len(forces) - 1)]
        leader.step(u * 1e12, DT, emergency=emergency and u < -0.5)
        follower.step(cmd.force_n, DT, emergency=cmd.emergency and emergency)
    assert worst_b <= 1e-6, f"true barrier reached {worst_b:.3f} m"
    assert min_gap >= sup.safety_distance_m - 1e-6
