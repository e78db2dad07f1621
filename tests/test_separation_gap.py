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
