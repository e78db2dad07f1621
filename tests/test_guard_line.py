"""The separation guard's own braking curves (its stop and the line's lower limits) under the worst
case, on the offline train model (no SUMO).

A follower asks for full traction all the time; only the guard holds it back.  The plant is the
ETR1000 at the bottom of its uncertainty box where that hurts (540 t, its service brake at the
bottom of the assumption set's range, 0.65 − 10 % = 0.585 m/s², Davis at the bottom, the traction of
the top of the box), on a −11.5 ‰ descent, with its force lag (0.5 s) and jerk limit (0.7 m/s³):
the slowest brake build-up from full traction of the set.  The predecessor is far ahead (the
separation test never binds).  The guard's curves are service-brake curves: the train must keep
them on its service brake (the emergency brake is the reserve; a curve that needs it is not a
service curve).  On main@4c41627 the curves had 1.5 steps of dead time and no build-up, and the
guard's braking command was capped at the service force of the lightest train of the box (461 t ·
0.585 m/s², 0.50 m/s² on 540 t): from full traction, on its service brake, the follower overran its
stop by 44.8 m (from 600 m), 39.8 m (1,200 m), 12.4 m (2,500 m) and entered a 72 km/h limit at
75.0 km/h (600 m; the set's tolerance is 2 km/h); with its emergency brake it made them only by
47, 73 and 102 emergency activations (stops) and 14–32 (limits).  Now: 0 m, at most 72 km/h at the
limit, 0 emergency activations (the stop is reached 5–6 s later).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vcsumo.control.base import Command
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.guard import SeparationGuard
from vcsumo.plant import PlantState
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel, brake_range
from vcsumo.sim.offline import ForceProfile, OfflineTrain, run_convoy

STOCK = load_rolling_stock("etr1000")
P = STOCK.params()
BOX = STOCK.uncertainty_box()
MODEL = SeparationModel(load_assumptions())
DT = 0.2
DESCENT = -0.0115
START_M = 2000.0
TOL_MPS = MODEL.assumptions.speed_tolerance_kmh / 3.6

WORST = P.with_(
    mass_kg=BOX.mass_kg.high, service_brake_decel_mps2=brake_range(STOCK, MODEL.assumptions, "service")[0],
    emergency_brake_decel_mps2=brake_range(STOCK, MODEL.assumptions, "emergency")[0], davis_a_n=BOX.davis_a_n.low,
    davis_b_n_per_mps=BOX.davis_b_n_per_mps.low, davis_c_n_per_mps2=BOX.davis_c_n_per_mps2.low,
    max_traction_n=BOX.mass_kg.high * BOX.max_accel_mps2.high,
)
"""The follower's true parameters: the bottom of its box where that weakens its braking."""


def _route(limit_at_m: float, line_mps: float, limit_mps: float) -> RouteProfile:
    """A straight −11.5 ‰ descent, the line speed up to ``limit_at_m``, the lower limit after it."""
    starts = np.array([0.0, limit_at_m])
    lengths = np.array([limit_at_m, 80000.0])
    return RouteProfile(edges=["a", "b"], starts_m=starts, lengths_m=lengths, speeds_ms=np.array([line_mps, limit_mps]),
                        gradients=np.array([DESCENT, DESCENT]), tunnel_factors=np.array([1.0, 1.0]), sections=["x", "x"],
                        km_from=starts / 1000.0, km_to=(starts + lengths) / 1000.0, point_limits=[])


def _approach(distance_m: float, v0_mps: float, limit_mps: float | None, emergency_brake: bool):
    """The follower from ``START_M`` at ``v0_mps`` and full traction towards its stop (``limit_mps``
    None) or a lower limit ``distance_m`` ahead; returns (its recorded rows, the target position,
    its emergency activations, the guard)."""
    target = START_M + distance_m
    route = _route(target, 83.0, 83.0 if limit_mps is None else limit_mps)
    guard = SeparationGuard(STOCK, STOCK, 50.0, model=MODEL)
    stop = target if limit_mps is None else None

    class Greedy:
        def make_step(self, obs):
            return guard.limit(obs if stop is None else dataclasses.replace(obs, next_stop_m=stop), Command(1e9, mode="greedy"))

    trains = [OfflineTrain("L", P, PlantState(90000.0, 83.0, 0.0), ForceProfile((0.0,), (4e5,)), nominal=P),
              OfflineTrain("F", WORST, PlantState(START_M, v0_mps, 0.0), Greedy(), nominal=P)]
    run = run_convoy(trains, route, DT, 400.0, channel=Channel(ChannelConfig(period_s=DT)), known_at_start=True, emergency_brake=emergency_brake,
                     stop_when=lambda t, xs: xs[1].s_m > target + 3000.0 or (t > 5.0 and xs[1].v_mps < 1e-3))
    rows = run.frame[run.frame.train == "F"]
    return rows, target, run.emergency_activations["F"], guard


@pytest.mark.parametrize("distance_m", [600.0, 1200.0, 2500.0])
def test_from_full_traction_the_follower_makes_its_stop_on_its_service_brake(distance_m):
    """From a stand at full traction towards its stop: it stands at the stop (not past it) on the
    service brake alone, and with its emergency brake available never calls for it."""
    rows, stop, _, guard = _approach(distance_m, 0.0, None, emergency_brake=False)
    assert rows.position_m.max() <= stop + 1e-6
    assert rows.speed_mps.iloc[-1] < 0.05 and rows.position_m.iloc[-1] > stop - 1.0  # it did run to the stop
    assert guard.interventions > 0 and not rows.emergency.any()
    rows, stop, emergencies, _ = _approach(distance_m, 0.0, None, emergency_brake=True)
    assert emergencies == 0 and rows.position_m.max() <= stop + 1e-6


@pytest.mark.parametrize(("distance_m", "v0_mps", "limit_mps"), [(600.0, 20.0, 20.0), (1200.0, 20.0, 20.0), (1200.0, 10.0, 30.0)])
def test_from_full_traction_the_follower_enters_a_lower_limit_at_it(distance_m, v0_mps, limit_mps):
    """Towards a lower limit at full traction: its front enters the limit at no more than the limit
    (the health monitor counts overspeed above the limit + 2 km/h; the guard's curve ends at the limit
    itself), on the service brake, with no emergency brake called for."""
    for emergency_brake in (False, True):
        rows, at, emergencies, guard = _approach(distance_m, v0_mps, limit_mps, emergency_brake=emergency_brake)
        inside = rows[rows.position_m >= at]
        assert len(inside) > 10 and guard.interventions > 0
        assert inside.speed_mps.iloc[0] <= limit_mps + 1e-3  # the curve ends at the limit
        assert inside.speed_mps.max() <= limit_mps + TOL_MPS  # holding it on the descent (the nominal model, 40 t lighter)
        assert emergencies == 0 and not rows.emergency.any()
    before = rows[rows.position_m < at - 3000.0]
    assert before.empty or before.speed_mps.max() > limit_mps + TOL_MPS  # it was running faster than the limit before it


def test_the_line_tests_boundary_by_hand():
    """ETR1000 at 40 m/s and full traction (370 kN), level track, its stop ahead: the guard keeps full
    traction one more step down to the distance computed by hand, and not 5 cm closer — one step at
    full traction (Davis A̲, M̲ = 461 t, ρ = 1.04), the build-up from 370 kN to the service brake
    (0.5 + (370/461 + 0.585)/1.4 s) with the traction held, half a step, then the guaranteed service
    brake (0.585 + 8,096 N / 540 t, over ρ)."""
    from vcsumo.control.base import Observation, TrainStateMsg
    from vcsumo.sim.offline import flat_profile

    level = flat_profile(50000.0, speed_limit_mps=90.0)
    v, f = 40.0, 370e3
    v1 = v + DT * (f - 8096.0) / (1.04 * 461e3)
    t_act = 0.5 + (f / 461e3 + 0.585) / 1.4
    v_dead = v1 + f / (1.04 * 461e3) * t_act
    b = (0.585 + 8096.0 / 540e3) / 1.04
    hand = v * DT + v_dead * (t_act + 0.5 * DT) + v_dead * v_dead / (2.0 * b)

    def passes(distance_m: float) -> bool:
        guard = SeparationGuard(STOCK, STOCK, 50.0, model=MODEL)
        obs = Observation(time_s=10.0, step_s=DT, ego_id="F", ego=TrainStateMsg(10.0, 1000.0, v, 0.0, f), params=P, profile=level,
                          received={}, predecessor=None, next_stop_m=1000.0 + distance_m)
        line = guard.line(obs)  # the line test alone (no predecessor here)
        assert line.targets == [(1000.0 + distance_m, 0.0)]
        return line.fits(f)

    assert passes(hand + 0.05) and not passes(hand - 0.05)
    assert hand == pytest.approx(1552.1, abs=0.1)
    # the curve of a brake already applied (1.5 steps of dead time, main@4c41627's) is 153 m shorter
    old = v * 1.5 * DT + v * v / (2.0 * b)
    assert hand - old == pytest.approx(153.4, abs=0.1)
