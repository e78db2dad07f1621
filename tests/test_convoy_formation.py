"""Tier 1 — the formation account of a convoy follower (sim/convoy_formation.py)."""

from __future__ import annotations

import math

from vcsumo.sim.convoy_formation import REASONS, Formation


def test_a_follower_within_a_tenth_and_ten_metres_is_formed():
    f = Formation()
    for k in range(10):
        f.update(100.0 + k, 1.0, 40.0, 1.1 * 300.0 + 10.0, 300.0, 44.4, 40.0, 40.0)
    assert f.formed_at_s == 100.0 and f.formed_share == 1.0 and f.reason() == ""


def test_standing_and_starting_trains_are_not_judged():
    f = Formation()
    f.update(0.0, 1.0, 2.0, 5000.0, 70.0, 44.4, 2.0, 2.0)
    assert f.running_s == 0.0 and math.isnan(f.formed_share) and f.reason() == "never ran coupled above 5 m/s"


def test_the_dominant_cause_is_named():
    at_limit, traction, held, other = Formation(), Formation(), Formation(), Formation()
    for k in range(10):
        at_limit.update(k, 1.0, 44.3, 800.0, 440.0, 44.4, 44.3, 44.3)  # at the line speed, 360 m too far behind
        traction.update(k, 1.0, 23.3, 400.0, 217.0, 27.8, 23.4, 23.4, at_full_traction=True)  # felez_test down: power-limited
        held.update(k, 1.0, 30.0, 800.0, 440.0, 44.4, 31.0, 29.0)  # the guard commanded less than the controller
        other.update(k, 1.0, 30.0, 800.0, 440.0, 44.4, 31.0, 31.0)
    assert [f.reason() for f in (at_limit, traction, held, other)] == list(REASONS)
    assert at_limit.max_excess_m == 360.0 and math.isnan(at_limit.formed_at_s) and at_limit.formed_share == 0.0
    row = held.row()
    assert row["not_formed_reason"] == REASONS[2] and row["formed_at_s"] is None and row["running_coupled_s"] == 10.0
