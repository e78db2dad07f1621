"""The leader's strongest braking counts the tunnels of the route it brakes on, checked on the plant.

The rule's train ahead brakes with its whole running resistance, the quadratic term at the largest
tunnel factor (the shared note *safe-separation*).  A line may give a tunnel an ``aero_factor`` up
to 4.0 (`vcsumo/line.py`: a narrow single-bore tunnel), and the offline plant brakes a train in it
with that factor; the separation model took 1.5 whatever the route (`RouteBraking`'s strongest
brake part).  The terlizzi2024 leader (shipped, no rotating-mass factor) at the top of its box —
its emergency brake at the top of the set's range, the lightest mass, the highest Davis terms —
braking from 300 km/h at once in a tunnel with factor 4.0 on the offline plant stopped in 2,506.7 m,
26.3 m short of the 2,533.0 m the model's "strongest" leader needed: every rule behind it (the
guard, the CBF on the model, cbc's spacing, the run-health monitor) had that much less than it
assumed.  Now the strongest brake part takes the route's largest tunnel factor (at least 1.5: the
shipped lines' figures are unchanged): 2,391.0 m, and the terlizzi2024 follower's gap behind it at
300 km/h in that tunnel 918.5 → 1,060.5 m.
"""

from __future__ import annotations

import numpy as np
import pytest

from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel, brake_range

MODEL = SeparationModel(load_assumptions())
V0 = 300.0 / 3.6


def _tunnel(factor: float, length_m: float = 20000.0) -> RouteProfile:
    return RouteProfile(edges=["t"], starts_m=np.array([0.0]), lengths_m=np.array([length_m]), speeds_ms=np.array([90.0]), gradients=np.array([0.0]),
                        tunnel_factors=np.array([factor]), sections=["t"], km_from=np.array([0.0]), km_to=np.array([length_m / 1000.0]), point_limits=[])


def _plant_stop(stock, profile, dt: float = 0.01) -> float:
    """Where the train at the top of its box stands after an emergency brake applied at once from V0, m."""
    box = stock.uncertainty
    p = stock.params().with_(mass_kg=box.mass_kg.low, davis_a_n=box.davis_a_n.high, davis_b_n_per_mps=box.davis_b_n_per_mps.high,
                             davis_c_n_per_mps2=box.davis_c_n_per_mps2.high,
                             emergency_brake_decel_mps2=brake_range(stock, MODEL.assumptions, "emergency")[1])
    plant = TrainPlant(p, PlantState(1000.0, V0, 0.0), profile, apply_lag=False, apply_jerk=False)
    while plant.x.v_mps > 0.0:
        plant.step(-1e9, dt, emergency=True)
    return plant.x.s_m - 1000.0


@pytest.mark.parametrize("factor", [1.0, 1.5, 3.0, 4.0])
def test_no_leader_of_the_box_stops_shorter_than_the_rules_strongest(factor):
    stock = load_rolling_stock("terlizzi2024_leader")
    prof = _tunnel(factor)
    model_stop = RouteBraking(MODEL, stock, prof, "emergency", strongest=True).stopping_distance(1000.0, V0, 0.0)
    assert _plant_stop(stock, prof) >= model_stop - 0.05  # Euler at 10 ms


def test_the_figures_of_the_module_doc_and_the_shipped_lines_unchanged():
    stock = load_rolling_stock("terlizzi2024_leader")
    assert _plant_stop(stock, _tunnel(4.0)) == pytest.approx(2506.7, abs=0.5)
    assert RouteBraking(MODEL, stock, _tunnel(1.5), "emergency", strongest=True).stopping_distance(1000.0, V0, 0.0) == pytest.approx(2533.0, abs=0.1)
    # a route without a tunnel above 1.5 keeps the 1.5 of every shipped figure
    for f in (1.0, 1.3, 1.5):
        assert RouteBraking(MODEL, stock, _tunnel(f), "emergency", strongest=True).brake_part(V0) == \
            RouteBraking(MODEL, stock, _tunnel(1.5), "emergency", strongest=True).brake_part(V0)
    # and the rule behind such a leader needs more room in the 4.0 tunnel than in a 1.5 one
    follower = load_rolling_stock("terlizzi2024_follower")
    gaps = [RelativeBraking(MODEL, follower, stock, _tunnel(f)).required_gap(5000.0, V0, 7000.0, V0, MODEL.dead_time_s) for f in (1.5, 4.0)]
    assert gaps == pytest.approx([918.5, 1060.5], abs=0.1)
    assert RouteBraking(MODEL, stock, _tunnel(4.0), "emergency", strongest=True).stopping_distance(1000.0, V0, 0.0) == pytest.approx(2391.0, abs=0.1)
