"""The shared note's hand-checked worst case through every consumer of the separation model.

The note (*safe-separation*): at 300 km/h, emergency brake 1.2 m/s² ± 10 % (the follower sure of
1.08, the leader reaching 1.32), T = 1.5 s, d_min 50 m and 2 × 10 m of position error, the
relative-braking gap is v²/2·(1/1.08 − 1/1.32) ≈ 583 m + v·T ≈ 125 m + 70 m ≈ 780 m on level track.
Every rule that decides a VC follower's spacing must give that figure on the note's train (no
resistance, no rotating mass, no build-up of its own, a message 0 s old): the model's analytic
gap, the route rule the run-health monitor and the separation guard evaluate, the CBF's barrier on
the model (``distance: model``) and cbc's certified spacing less its buffer.  The same consumers
must also agree where the note warns: a follower braking harder than its leader can (the binding
moment mid-braking, never a negative term) and a leader slower than the follower.
"""

from __future__ import annotations

import math

import pytest

from vcsumo.control.cbf import CBFConfig, CBFSupervisor, level_route
from vcsumo.control.gap_reference import SeparationGap
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, SeparationModel, relative_braking_gap

from .conftest import write

TRAIN = """name: {name}
length_m: 200.0
mass_kg: 500000.0
max_speed_kmh: 320.0
max_traction_n: 370000.0
max_power_w: 9800000.0
davis_a_n: 0.0
davis_b_n_per_mps: 0.0
davis_c_n_per_mps2: 0.0
service_brake_decel_mps2: 0.65
emergency_brake_decel_mps2: {eb}
"""
NOTE_SET = """name: note_set
braking_uncertainty: 0.10
reaction_time_s: 0.5
brake_build_up_s: 2.0
t2t_delay_bound_s: 0.0
position_report_period_s: 2.0
position_error_m: 10.0
safety_margin_m: 50.0
overlap_m: 50.0
"""
V = 300.0 / 3.6
T = 1.5


@pytest.fixture(scope="module")
def note(tmp_path_factory):
    d = tmp_path_factory.mktemp("note")
    model = SeparationModel(load_assumptions(write(d / "note_set.yaml", NOTE_SET)))
    trains = {eb: load_rolling_stock(str(write(d / f"t{eb}.yaml", TRAIN.format(name=f"note_{eb}".replace(".", "_"), eb=eb)))) for eb in (1.2, 0.8, 1.6)}
    return model, trains


def _consumers(model, follower, leader, v_f, v_l):
    """The front-to-rear gap each consumer requires, follower at v_f behind a leader at v_l, m."""
    prof = level_route()
    s_f = 10000.0
    s_l = s_f + 2000.0 + leader.length_m  # the leader's front (what the rules are given), 2 km ahead
    rule = RelativeBraking(model, follower, leader, prof)
    cbf = CBFSupervisor(leader, follower, CBFConfig(), model=model).model_for(prof)
    ref = SeparationGap(model, follower, leader, prof, 0.0, 0.0)
    out = {"rule (monitor, guard)": rule.required_gap(s_f, v_f, s_l, v_l, model.dead_time_s),
           "cbf barrier": cbf.required_gap_m(s_l, v_l, s_f, v_f, 0.0),
           "cbc spacing": ref.gap_m(v_f, v_l, s_f)}
    if v_f == v_l:
        out["analytic vc_gap"] = model.vc_gap(follower, leader, v_f, message_age_s=0.0)
    return out


def test_the_notes_780_m_at_300_kmh_in_every_consumer(note):
    model, trains = note
    assert model.dead_time_s == pytest.approx(T) and model.margin_m == pytest.approx(70.0)
    quad = V * V / 2.0 * (1.0 / 1.08 - 1.0 / 1.32)
    assert quad == pytest.approx(583.0, abs=2.0)
    hand = 70.0 + V * T + quad
    assert hand == pytest.approx(780.0, abs=1.0)
    st = trains[1.2]
    for name, gap in _consumers(model, st, st, V, V).items():
        assert gap == pytest.approx(hand, abs=1e-6), name


def test_a_follower_braking_harder_than_its_leader_mid_braking_never_negative(note):
    """a_f,min = 0.9·1.6 = 1.44 ≥ a_l,max = 1.1·0.8 = 0.88: the stopping-point difference is
    v·T + v²/2·(1/1.44 − 1/0.88) = −1,409 m, the worst closing is at t* = a_f·T/(a_f − a_l) = 3.86 s, by hand."""
    model, trains = note
    a_f, a_l = 0.9 * 1.6, 1.1 * 0.8
    assert V * T + V * V / 2.0 * (1.0 / a_f - 1.0 / a_l) < -1000.0
    t = a_f * T / (a_f - a_l)
    closing = (V * T + V * (t - T) - 0.5 * a_f * (t - T) ** 2) - (V * t - 0.5 * a_l * t * t)
    # D(t) = a_l·t²/2 − a_f·(t − T)²/2 at its maximum: T²·a_f·a_l/(2·(a_f − a_l)) = 2.55 m, above D(T) = a_l·T²/2 = 0.99 m
    assert closing == pytest.approx(T * T * a_f * a_l / (2.0 * (a_f - a_l)), rel=1e-9) and closing == pytest.approx(2.546, abs=1e-3)
    assert closing > 0.5 * a_l * T * T > 0.0
    for name, gap in _consumers(model, trains[1.6], trains[0.8], V, V).items():
        assert gap == pytest.approx(70.0 + closing, abs=1e-6), name


def test_a_leader_slower_than_its_follower(note):
    """Follower at 300 km/h behind a leader at 200 km/h: both stop, v_f·T + v_f²/(2·1.08) − v_l²/(2·1.32)."""
    model, trains = note
    v_l = 200.0 / 3.6
    hand = 70.0 + V * T + V * V / (2 * 1.08) - v_l * v_l / (2 * 1.32)
    assert hand == pytest.approx(70.0 + relative_braking_gap(V, v_l, 1.08, 1.32, T), abs=1e-9)
    for name, gap in _consumers(model, trains[1.2], trains[1.2], V, v_l).items():
        assert gap == pytest.approx(hand, abs=1e-6), name
    assert math.isfinite(hand) and hand > 780.0 + 1000.0
