"""The braking curve is the inverse of the stopping distance where the gradient changes within the
dead-time run.

Found on a network of our own (tests of issue 14): under moving block an ETR 1000 at 160 km/h,
supervised towards a regional train standing in a station, came 16 m inside the health monitor's
safe separation just after the end of a 15 ‰ descent.  The braking curve
(:meth:`RouteBraking.permitted_speed`) charged the whole dead-time run at the deceleration under
the train's front *now* (on the descent, low); the stopping distance the health monitor checks
charges it where it is run (past the descent, higher).  So the curve let the train run faster than
the speed from which it stops within the distance it was given.
"""

from __future__ import annotations

import numpy as np
import pytest

from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RouteBraking, SeparationModel


def _profile(pieces):
    starts = np.array([a for a, _, _ in pieces], dtype=float)
    lengths = np.array([b - a for a, b, _ in pieces], dtype=float)
    n = len(pieces)
    return RouteProfile(edges=[f"e{i}" for i in range(n)], starts_m=starts, lengths_m=lengths, speeds_ms=np.full(n, 80.0),
                        gradients=np.array([g for _, _, g in pieces], dtype=float), tunnel_factors=np.ones(n), sections=["main"] * n,
                        km_from=starts / 1000.0, km_to=(starts + lengths) / 1000.0, point_limits=[])


@pytest.fixture(scope="module")
def model():
    return SeparationModel(load_assumptions("etcs_typical"))


# the coast line of the test network: a 15 ‰ descent in 1.5 km blocks, then level; and the other way round
DESCENT_THEN_LEVEL = [(0.0, 1500.0, -0.015), (1500.0, 3000.0, -0.015), (3000.0, 4500.0, 0.0), (4500.0, 9000.0, 0.0)]
LEVEL_THEN_DESCENT = [(0.0, 3000.0, 0.0), (3000.0, 4500.0, -0.015), (4500.0, 9000.0, -0.015)]
CLIMB_THEN_DESCENT = [(0.0, 3000.0, 0.02), (3000.0, 3200.0, -0.01), (3200.0, 9000.0, 0.0)]


@pytest.mark.parametrize("pieces", [DESCENT_THEN_LEVEL, LEVEL_THEN_DESCENT, CLIMB_THEN_DESCENT])
@pytest.mark.parametrize("train", ["etr1000", "regional_emu160"])
def test_a_train_at_the_permitted_speed_stops_within_the_distance(model, pieces, train):
    """At the permitted speed towards a stop, after the dead time, the train stands by the target
    (the stopping distance, as the health monitor measures it, is never longer), wherever the front
    is relative to the change of gradient; and the curve is not lower than needed (it is the
    inverse: the stopping distance from it reaches the target within a metre)."""
    stock = load_rolling_stock(train)
    br = RouteBraking(model, stock, _profile(pieces))
    dead = model.dead_time_s + 0.75  # as the supervisor's authority curve at a 0.5 s step
    worst = np.inf
    for s in np.arange(0.0, 6000.0, 13.0):  # the front before, across and past every change of the guaranteed deceleration
        for d in (300.0, 1600.0, 2600.0):
            target = s + d
            for v_now in (20.0, 44.4):
                vp = br.permitted_speed(s, target, 0.0, dead, v_now)
                slack = target - s - br.stopping_distance(s, vp, dead)
                worst = min(worst, slack)
                assert slack >= -1e-6, (s, d, v_now, vp, slack)
                assert slack < 1.0, (s, d, v_now, vp, slack)
    assert worst < 0.01


COAST = """
name: coast_test
km_start: 100.0
km_end: 118.0
tracks: double
start_elevation_m: 5
line_speed_kmh: 160
stations:
  - {id: CST, name: Coastby, km: 100.4, platform_length_m: 500, dwell_s: 60}
  - {id: BAY, name: Baybridge, km: 109.0, platform_length_m: 240, dwell_s: 30}
gradients:
  - {from_km: 112.0, to_km: 118.0, permille: 15.0}
signalling: {block_length_m: 1500}
"""

CLOSING = """
name: closing
line: coast_test
services:
  - {id: R20, train: regional_emu160, origin: end, destination: CST, departure: 0, stops: [{station: BAY}]}
  - {id: EX40, train: etr1000, origin: end, destination: start, departure: 100}
"""


@pytest.mark.sumo
def test_moving_block_follower_off_a_descent_keeps_the_safe_separation(tmp_path):
    """The run that found it: under MB the ETR 1000 comes off the 15 ‰ descent at 160 km/h towards the
    regional standing at Baybridge; supervised on its braking curve it never comes inside the safe
    separation (it came 16 m inside before the fix)."""
    from vcsumo.line import load_line
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.sim.network import build_network
    from vcsumo.timetable import load_timetable, plan_trains

    from .conftest import write

    line = load_line(write(tmp_path / "coast_test" / "line.yaml", COAST))
    built = build_network(line)
    tt, path = load_timetable(write(tmp_path / "closing.yaml", CLOSING), line)
    res = simulate(Scenario(line, built, plan_trains(tt, path, line, built.topology), "mb", step_length_s=0.5), tmp_path / "out")
    s = res.summary
    assert s["trains_arrived"] == 2 and s["stops_served"] == s["stops_scheduled"]
    assert s["min_gap_m"] < 800.0  # it did close up on the standing train
    assert s["gap_violations"] == 0 and s["min_margin_m"] >= 0.0
    assert s["healthy"]
