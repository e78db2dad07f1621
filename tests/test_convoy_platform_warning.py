"""The warning that a convoy cannot stand in a platform names two different trains.

The capacity study builds its convoys as units whose members share one service name
(``unit0``): the warning, grouped by pair of services, named the same train as leader and
follower ("convoy unit0+unit0 (3 trains each): unit0 ... cannot stand behind unit0").  Members
of one service are now named by train, all such pairs of one rolling stock in one warning.
"""

from __future__ import annotations

import re

from vcsumo.cli.commands import network
from vcsumo.line import load_line
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel
from vcsumo.sim.convoy_plan import warn_short_platforms
from vcsumo.studies.capacity_route import Case, route_setup, unit_trains


def test_members_of_one_service_are_named_by_train(recwarn):
    line = load_line("firenze_bologna")
    net = network(line, None)
    stock = load_rolling_stock("etr1000")
    setup = route_setup(line, net, stock, "up", 0.5, SeparationModel(load_assumptions()))
    units = unit_trains(net.topology, setup, stock, Case("up", "vc", "cbc", 3, "all-stops"), 2, 600.0, 100.0)
    assert all(len({t.service for t in u}) == 1 for u in units)  # one service per unit
    out = warn_short_platforms(units, {t.id: 72.0 for u in units for t in u})
    # 2 × 202 m + 72 m = 476 m do not fit a 450 m platform: one warning for the 4 pairs of the same stock
    assert len(out) == 1, out
    assert len(recwarn) == 1
    msg = out[0]
    assert msg.startswith("convoy up_u0_m0+up_u0_m1 (and 3 more such pairs): up_u0_m1 (etr1000, 202 m) cannot stand behind up_u0_m0 (etr1000, 202 m)")
    assert "476 m needed with the 72 m standstill gap" in msg
    assert "until up_u0_m0 has left" in msg
