"""cbc's reference spacing (:class:`vcsumo.control.gap_reference.SeparationGap`) behind a braking
predecessor, and what it costs the separation guard (no SUMO).

On main@4c41627 the certified spacing ignored the predecessor's speed (both trains at the
follower's): behind a predecessor slowing down, cbc closed in to a spacing the relative-braking rule
did not allow, the guard held the follower at the rule's boundary, and every time the newest message
grew older than the spacing budgets (the set's 0.5 s plus 1.5 steps; the default 2 Hz channel's
messages are 0.6–0.8 s old before the next arrives) holding the rule needed more than the service
brake: one-step emergency brakings.  On italy_av_north ``full_day_vc`` (cbc, to 08:00) all 644
emergency activations of the followers were of this kind, at 200–300 km/h on the −15 ‰ approach to
Bologna (firenze_bologna km 7–2.5) with the predecessor braking; the offline case below had 336 in
200 s (1,729 guard interventions).
"""

from __future__ import annotations

import pytest

from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.gap_reference import SeparationGap
from vcsumo.plant import PlantState
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, SeparationModel
from vcsumo.sim.offline import OfflineTrain, SpeedProfile, flat_profile, follower_stacks, run_convoy, steady_force

STOCK = load_rolling_stock("etr1000")
P = STOCK.params()
MODEL = SeparationModel(load_assumptions())
DESCENT = flat_profile(60000.0, speed_limit_mps=90.0, gradient=-0.015)


def test_a_slower_predecessor_needs_the_rules_room():
    """At 80 m/s behind a predecessor at 72 m/s the spacing is the rule's required gap at those speeds
    (after the same delays and build-up) + the buffer — larger than at equal speeds; a faster
    predecessor does not shrink it below the equal-speed spacing."""
    ref = SeparationGap(MODEL, STOCK, STOCK, DESCENT, 0.15, 10.0)
    same, slower, faster = ref.gap_m(80.0, 80.0, 5000.0), ref.gap_m(80.0, 72.0, 5000.0), ref.gap_m(80.0, 83.0, 5000.0)
    assert faster == same == ref.gap_m(80.0, None, 5000.0)
    v_dead, t_act = ref.build_up_at(80.0, 5000.0)
    rule = RelativeBraking(MODEL, STOCK, STOCK, DESCENT)
    need = rule.required_gap(5000.0, v_dead, 5000.0 + 3000.0, 72.0, ref.delay_s + t_act)
    assert slower == pytest.approx(need + 10.0, abs=2.0)  # the leader's position only sets its gradients
    assert slower > same + 300.0  # (80² − 72²)/2 over the leader's strongest ≈ 1.4 m/s²: ≈ 430 m


@pytest.mark.parametrize("seed", [0, 1])
def test_cbc_behind_a_braking_predecessor_on_a_descent_needs_no_emergency_brake(seed):
    """Two ETR1000 at 300 km/h on a −15 ‰ descent, the follower (cbc, guard, fault stage) at its
    spacing; the predecessor slows to 144 km/h at 0.43 m/s² (as FR9600 into Bologna); the default
    channel (2 Hz, 0.1 s + exponential 0.2 s, 1 % losses, seeded).  The follower follows on its
    service brake: no emergency activation, the guard hardly acts."""
    v0, v1, decel = 83.3, 40.0, 0.43
    stacks = follower_stacks("cbc", [STOCK, STOCK], ["L", "F"], 0.1, DESCENT)
    follower = stacks[0]
    s_f = 2000.0
    s_l = s_f + follower.coupled_gap_m(v0, s_f) + P.length_m
    leader = SpeedProfile((0.0, 20.0, 20.0 + (v0 - v1) / decel, 200.0), (v0, v0, v1, v1))
    channel = Channel(ChannelConfig(period_s=0.5, delay_s=0.1, mean_extra_s=0.2, loss_probability=0.01, seed=seed))
    trains = [OfflineTrain("L", P, PlantState(s_l, v0, steady_force(P, v0, DESCENT, s_l)), leader),
              OfflineTrain("F", P, PlantState(s_f, v0, steady_force(P, v0, DESCENT, s_f)), follower)]
    run = run_convoy(trains, DESCENT, 0.1, 200.0, channel=channel, known_at_start=True, record_every=10)
    rows = run.frame[run.frame.train == "F"]
    assert rows.speed_mps.iloc[-1] < v1 + 5.0  # it did slow down behind the predecessor (from 83.3 m/s)
    assert run.emergency_activations["F"] == 0 and follower.guard.interventions <= 20


# ---------------------------------------------------------------------------------------------
# The spacing cbc tracks against what the CBF certifies (README, Known gaps: "rides its own boundary")

from vcsumo.control.base import Command, Message, Observation, TrainStateMsg  # noqa: E402
from vcsumo.control.brake_build_up import BrakeBuildUp  # noqa: E402
from vcsumo.control.registry import StackContext, build_follower_stack  # noqa: E402
from vcsumo.dynamics import traction_limit  # noqa: E402
from vcsumo.sim.convoy_plan import load_channel  # noqa: E402
from vcsumo.sim.offline import simulate_convoy  # noqa: E402

LEVEL = flat_profile(200000.0, speed_limit_mps=90.0)
CHANNEL = load_channel(None)


def test_the_spacing_budgets_the_channels_age_when_it_is_older_than_the_sets():
    """The message age budgeted is max(the set's bound, the channel's): its delay grows by exactly the
    difference, and the spacing by the relative-braking gap of that much more dead time."""
    base = SeparationGap(MODEL, STOCK, STOCK, None, 0.15, 10.0)
    assert SeparationGap(MODEL, STOCK, STOCK, None, 0.15, 10.0, 0.2).delay_s == base.delay_s  # a faster channel: the set's spacing
    slow = SeparationGap(MODEL, STOCK, STOCK, None, 0.15, 10.0, 1.35)
    assert slow.delay_s - base.delay_s == pytest.approx(1.35 - MODEL.assumptions.t2t_delay_bound_s)
    v = 80.0
    v_dead, t_act = base.build_up_at(v)
    a_f, a_l = MODEL.vc_decels(STOCK, STOCK, v, v)
    from vcsumo.signalling.separation import relative_braking_gap

    want = relative_braking_gap(v_dead, v, a_f, a_l, slow.delay_s + t_act) - relative_braking_gap(v_dead, v, a_f, a_l, base.delay_s + t_act)
    assert slow.gap_m(v) - base.gap_m(v) == pytest.approx(want, rel=1e-9)
    assert want > 0.85 * v * 0.85  # at least the distance run at v over 0.85 s less what the leader's braking gives back


@pytest.mark.parametrize("name", ["regional_emu160", "etr1000"])
def test_the_build_up_is_counted_from_the_full_traction_the_follower_may_apply(name):
    """The spacing's build-up is the guard's (BrakeBuildUp.held) from the top of the box's traction at
    that speed, min(M̄·ā, P̄/v) — not from the force that holds the speed: a follower tracking it
    behind an accelerating predecessor applies that traction."""
    st = load_rolling_stock(name)
    ref = SeparationGap(MODEL, st, st, None, 0.15, 10.0)
    bu = BrakeBuildUp(st, MODEL.assumptions)
    box = st.uncertainty_box()
    for v in (5.0, 20.0, 0.9 * st.max_speed_ms):
        top = min(box.max_accel_mps2.high * box.mass_kg.high, box.max_power_w.high / v)
        assert ref.traction_top_n(v) == pytest.approx(top)
        assert ref.build_up_at(v) == pytest.approx(bu.held(None, 0.0, v, max(top, float(steady_force(st.params(), v, LEVEL, 0.0)))))
    # from full traction the build-up is longer than from coasting: τ + (F/M)/(2j)
    assert ref.build_up_at(20.0)[1] > bu.actuation_time(0.0) + 0.2


def _cbf_passes_full_traction(name: str, v: float, age_s: float, message_age_s: float | None) -> bool:
    """A cbf-cbc follower at cbc's coupled spacing behind a predecessor cruising at v on level track,
    applying (and commanded) the full traction its plant has at v, the predecessor's newest packet
    ``age_s`` old: does the CBF pass the command (True) or enforce K_E^F (False)?"""
    st = load_rolling_stock(name)
    p = st.params()
    stack = build_follower_stack("cbf-cbc", StackContext(ego=st, predecessor=st, step_s=0.1, profile=LEVEL, ego_id="F", predecessor_id="L",
                                                         message_age_s=message_age_s))
    t, s_f = 100.0, 20000.0
    gap = stack.coupled_gap_m(v, position_m=s_f)
    s_l = s_f + gap + st.length_m
    force = float(traction_limit(p, v))
    msg = Message("L", t - age_s, TrainStateMsg(t - age_s, s_l - v * age_s, v), st.length_m)
    obs = Observation(time_s=t, step_s=0.1, ego_id="F", ego=TrainStateMsg(t, s_f, v, 0.0, force), params=p, profile=LEVEL,
                      received={"L": msg}, predecessor="L", convoy=("L", "F"))
    return not stack.supervisor.filter(obs, Command(force)).emergency


@pytest.mark.parametrize("name", ["regional_emu160", "etr1000"])
def test_cbc_tracks_a_spacing_the_cbf_accepts_at_full_traction_with_the_channels_age(name):
    """On main the spacing budgeted the set's 0.5 s and the build-up from the force that holds the
    speed, while the CBF counts the true age and the build-up from the force applied: at that
    spacing, at full traction, with the default channel's packet as old as it keeps it (1.35 s),
    the CBF's only answer was its emergency brake.  With the channel's age and the traction's
    build-up the CBF passes the command at every speed; with a packet older by what runs 30 m at v
    (three times the 10 m buffer: the barrier rises by about v per second of age) it brakes; with the
    set's 0.5 s alone the spacing is inside its boundary at that age wherever the age it misses runs
    clearly more than the 10 m buffer, (1.35 − 0.5) s·v > 20 m (above 24 m/s; near 10 m the look-ahead
    step and the sampled-data margins decide)."""
    st = load_rolling_stock(name)
    budget = CHANNEL.age_budget_s()
    for v in (5.0, 12.0, 20.0, 30.0, 0.5 * st.max_speed_ms, 0.98 * st.max_speed_ms):
        assert _cbf_passes_full_traction(name, v, budget, budget), v
        assert not _cbf_passes_full_traction(name, v, budget + 30.0 / v, budget), v
        if (budget - MODEL.assumptions.t2t_delay_bound_s) * v > 20.0:
            assert not _cbf_passes_full_traction(name, v, budget, None), v


def test_one_step_emergency_brakes_behind_an_equal_traction_leader_are_as_rare_as_the_channels_excursions():
    """Two regional EMUs (cbf-cbc, the default channel), the leader running 15 → 30 → 20 → 40 → 15 m/s
    for 15 min.  The follower's CBF acts on the true message age: once cbc tracks a spacing that
    budgets the age the channel keeps in 99 % of its sending periods, an emergency brake can only
    follow an excursion of the age beyond it — at most (1 − 0.99)·3,600/0.5 = 72 per hour.  On main
    (the set's 0.5 s, the build-up from the holding force) the follower rode the CBF's boundary:
    524 one-step emergency applications in the 15 min (2,096 per hour)."""
    duration = 900.0
    st = load_rolling_stock("regional_emu160")
    stack = follower_stacks("cbf-cbc", [st, st], ["T0", "T1"], 0.1, message_age_s=CHANNEL.age_budget_s())[0]
    v0 = 15.0
    leader = SpeedProfile([0, 60, 90, 300, 330, 420, 460, 700, 740, 900], [v0, v0, 30, 30, 20, 20, 40, 40, 15, 15])
    df = simulate_convoy(["regional_emu160"] * 2, "cbf-cbc", leader, duration, 0.1, CHANNEL.model_copy(update={"seed": 1}),
                         [float(stack.coupled_gap_m(v0)) + 30.0])
    f = df[df.train == "T1"]
    em = f.emergency.to_numpy(bool)
    applications = int(em[0]) + int((em[1:] & ~em[:-1]).sum())
    bound = (1.0 - 0.99) * 3600.0 / CHANNEL.period_s * duration / 3600.0
    assert applications <= bound
    assert f.speed_mps.max() > 38.0  # it did follow the leader up to 40 m/s
