"""The guaranteed braking under a train's body does not depend on how the network cuts the track.

Found by unseen7 (2026-11-28): :class:`RouteBraking` took, for every edge of the route, the lowest
gradient under the body *while the front is anywhere on that edge* — so a 600 m freight train whose
rear had left a −25 ‰ descent 1.4 km back was still charged the descent all along a 3 km climb edge
when the blocks were 8 km long (guaranteed deceleration 0.116 instead of 0.343 m/s², stopping
distance from 20 m/s 1,641 m instead of 624 m at km 17.6); with 600 m blocks the same place gave
0.343 m/s².  ``--block-length-m 8000`` thus lengthened every braking curve, margin and MB headway on
the line (MB analytic headway 179.3 → 183.3 s).  The pieces are now cut where the rear passes a
gradient change too, so the gradient under the body is exact on each piece.
"""

from __future__ import annotations

import pytest

from tests.conftest import write
from tests.test_unseen7_capacity_health_columns import FREIGHT  # the 600 m, 1,200 t freight of the unseen7 tests
from vcsumo.line import load_line
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.sim.network import build_network

LINE = """name: climb_after_descent
km_start: 0.0
km_end: 22.0
tracks: double
line_speed_kmh: 120
stations:
  - {id: ASH, name: Ashby, km: 0.8, platform_length_m: 750, dwell_s: 60}
  - {id: DAL, name: Dale, km: 21.0, platform_length_m: 750, dwell_s: 60}
gradients:
  - {from_km: 9.0, to_km: 15.5, permille: -25.0}
  - {from_km: 16.0, to_km: 19.0, permille: 20.0}
signalling: {block_length_m: 600}
"""



def _braking(tmp_path, block_m: float, **kw) -> tuple[RouteBraking, RouteProfile]:
    line = load_line(write(tmp_path / "line.yaml", LINE))
    net = build_network(line, block_m)
    prof = RouteProfile.from_edges(net.topology, net.topology.track_for("main", "up").edges)  # s = km of the line, m
    stock = load_rolling_stock(str(write(tmp_path / "freight.yaml", FREIGHT)))
    return RouteBraking(SeparationModel(load_assumptions()), stock, prof, **kw), prof


def test_the_braking_under_the_body_is_the_same_for_short_and_long_blocks(tmp_path, monkeypatch):
    monkeypatch.setenv("VCSUMO_CACHE", str(tmp_path / "cache"))
    short, p_short = _braking(tmp_path, 600.0)
    long_, p_long = _braking(tmp_path, 8000.0)
    s_climb = 17600.0  # km 17.6: the whole train on the 20 ‰ climb (its rear left the descent at km 15.5 + 0.6 = 16.1)
    level = (0.40 * 0.9 + 12000.0 / 1.2e6) / 1.08  # guaranteed service brake + Davis A over M·ρ, no descent counted
    assert short.decel_at(s_climb, 20.0) == pytest.approx(level, rel=1e-9)
    assert long_.decel_at(s_climb, 20.0) == pytest.approx(level, rel=1e-9)
    for s in (8000.0, 9500.0, 15400.0, 15800.0, 16099.0, 16101.0, 17600.0):  # km 8 … 17.6: on, over and after the descent
        assert long_.stopping_distance(s, 20.0, 2.0) == pytest.approx(short.stopping_distance(s, 20.0, 2.0), abs=1e-6), s
        assert long_.permitted_speed(s, s + 800.0, 0.0, 2.0, 20.0) == pytest.approx(short.permitted_speed(s, s + 800.0, 0.0, 2.0, 20.0), abs=1e-9), s
