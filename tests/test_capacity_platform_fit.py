"""The capacity study says when an all-stops VC convoy does not fit the platforms (as the trade-off
study does): its members then stop one after another and the analytic VC headway, which stands the
convoy in the platform as one train, is short — on regional_graded's 240 m platforms a convoy of two
120 m trains (312 m with the standstill gap) simulated 214.7 s against 134.1 s analytic (+60 %),
without a word before."""

from __future__ import annotations

import warnings

from vcsumo.line import load_line
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel
from vcsumo.sim.network import build_network
from vcsumo.studies.capacity_route import STANDSTILL_EXTRA_M, convoys_longer_than_platforms, route_setup

from .conftest import write

SLOW = """name: slow80
length_m: 120.0
mass_kg: 250000.0
rotating_mass_factor: 1.08
max_speed_kmh: 80.0
max_traction_n: 180000.0
max_power_w: 1500000.0
davis_a_n: 3000.0
davis_b_n_per_mps: 40.0
davis_c_n_per_mps2: 6.0
service_brake_decel_mps2: 0.7
emergency_brake_decel_mps2: 1.1
max_jerk_mps3: 0.8
traction_lag_s: 0.6
"""


def test_the_capacity_study_warns_of_convoys_longer_than_its_platforms(tmp_path, monkeypatch):
    from vcsumo.studies import capacity as cap

    stock = load_rolling_stock(write(tmp_path / "slow80.yaml", SLOW))
    line = load_line("regional_graded")
    net = build_network(line)
    model = SeparationModel(load_assumptions())
    stops = route_setup(line, net, stock, "up", 0.5, model).stops_full
    msgs = convoys_longer_than_platforms(stops, stock, [2], model.margin_m + STANDSTILL_EXTRA_M)
    assert len(msgs) == 1 and "2 × 120 m + 1 × 72 m standstill gap = 312 m) does not fit the platform of BRK (240 m)" in msgs[0]
    # the study says it before running anything (stopped here at its first case: the warning is all this test needs)

    class Stop(Exception):
        pass

    def stop(*a, **k):
        raise Stop

    monkeypatch.setattr(cap, "study_params", stop)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            cap.run_capacity_study(line, net, stock, tmp_path / "c", ["cbc"], [2], ("up",), ("all-stops",), 0.5, 0.2, 42, workers=1)
        except Stop:
            pass
    texts = [str(w.message) for w in caught]
    assert any(t.startswith("up: all-stops: a VC convoy of 2") and "BRK (240 m)" in t for t in texts), texts
