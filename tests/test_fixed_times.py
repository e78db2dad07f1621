"""Tier 1 — ETCS fixed times: the movement authority a SUMO-driven train sees is T seconds old."""

import math

import pytest

from vcsumo.signalling.fixed_times import DelayedAuthority, authority_speed


def test_authority_speed_stops_exactly_at_the_end_of_authority():
    b, tr = 0.65, 0.25
    for d in (1.0, 500.0, 5363.0):
        v = authority_speed(d, b, tr)
        assert v * v / (2 * b) + tr * v == pytest.approx(d, rel=1e-9)
    assert authority_speed(0.0, b, tr) == 0.0 and authority_speed(-3.0, b, tr) == 0.0
    # 300 km/h needs about 5.36 km at 0.65 m/s² (v²/2b + 0.25 s · v)
    assert authority_speed(83.333**2 / 1.3 + 0.25 * 83.333, b, tr) == pytest.approx(83.333, rel=1e-6)


class _St:
    def __init__(self, s, v, leader=None, gap=math.inf):
        self.s_m, self.speed_mps, self.leader, self.gap_m = s, v, leader, gap


def _feed(auth, T, v_lead=50.0, s_follow=0.0, gap=3000.0, t_end=30.0, dt=0.5):
    caps = {}
    t = 0.0
    while t <= t_end + 1e-9:
        lead_s = 10_000.0 + v_lead * t
        caps = auth.caps(t, {"L": _St(lead_s, v_lead), "F": _St(s_follow + v_lead * t, v_lead, "L", gap)})
        t += dt
    return caps


def test_moving_block_authority_ends_where_the_rear_was_T_ago():
    T, b = 10.0, 0.65
    auth = DelayedAuthority(T, "mb", 0.5, {"F": b, "L": b})
    caps = _feed(auth, T)
    # the rear T ago was v·T = 500 m behind where it is now; margin 50 m at speed
    expected = authority_speed(3000.0 - 500.0 - 50.0, b, 0.25)
    assert caps["F"] == pytest.approx(expected, rel=1e-6)
    # no fixed time: no cap at all (SUMO's own moving block decides)
    assert _feed(DelayedAuthority(0.0, "mb", 0.5, {"F": b}), 0.0) == {}


def test_fixed_block_authority_ends_at_the_signal_behind_the_delayed_rear():
    T, b = 10.0, 0.65
    # follower frame: follower at 1500 m at t = 30 s; rear now at 4500 m, T ago at 4000 m
    signals = {"F": [1000.0, 2600.0, 3900.0, 4200.0, 5000.0]}
    auth = DelayedAuthority(T, "fbs", 0.5, {"F": b}, signals)
    caps = _feed(auth, T, s_follow=0.0, gap=3000.0)
    s_f = 0.0 + 50.0 * 30.0
    assert caps["F"] == pytest.approx(authority_speed(3900.0 - s_f, b, 0.25), rel=1e-6)


def test_no_cap_without_a_train_ahead_or_before_the_history_is_T_long():
    auth = DelayedAuthority(10.0, "mb", 0.5, {"F": 0.65})
    assert auth.caps(0.0, {"L": _St(5000.0, 50.0), "F": _St(0.0, 50.0, "L", 4000.0)}) == {}
    assert auth.caps(0.5, {"F": _St(0.0, 50.0)}) == {}
    with pytest.raises(ValueError):
        DelayedAuthority(-1.0, "mb", 0.5, {})
