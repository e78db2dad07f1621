"""Tier 2 — a capacity-study convoy follower released at its start gap does not brake at its release.

Found on Bologna–Firenze (2026-11-25): every VC follower released at 160 km/h at its start gap
(466 m up) braked in its first steps — the separation guard commanded −600 kN with the emergency
flag at the first step — because the start gap was the level-track spacing (503 m) while the stack
keeps the relative-braking rule over the grades ahead on the route (531 m there).  The start gap,
the analytic VC headway and the *formed* test now use the route spacing of the stack the loop
builds (:func:`vcsumo.studies.capacity_route.convoy_spacing` on the route).

The lines here put a steep descent (20–25 ‰) right at the release point, and the trains are slow
(a 160 km/h regional EMU released at 120 km/h, a freight train at 80 km/h): there the route spacing
differs most from level track.  Real SUMO, one convoy of two, the first 30 s after the release.
"""

import math

import pandas as pd
import pytest

from vcsumo.line import load_line
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel
from vcsumo.sim.convoy_formation import within_spacing
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import VCDriver, load_channel
from vcsumo.studies.capacity import cruise_records
from vcsumo.studies.capacity_route import Case, analytic_headway, check_position_m, convoy_spacing, initial_convoy_gaps, leader_run, route_setup, unit_trains

from .conftest import write
from .test_unseen2_capacity import FREIGHT  # a 700 m, 2,000 t freight train (0.5 / 0.7 m/s²)

pytestmark = pytest.mark.sumo

LINE = """
name: descent
km_start: 0.0
km_end: 9.0
line_speed_kmh: LIMIT
default_train: regional_emu160
stations:
  - {id: AA, name: Aa, km: 0.5, platform_length_m: 200}
  - {id: ZZ, name: Zz, km: 8.5, platform_length_m: 200}
gradients:
  - {from_km: FROM, to_km: 8.0, permille: GRADE}
signalling: {block_length_m: 1500}
headway: {measuring_points_km: [6.0], release_km: {up: RELEASE, down: 1.0}}
"""
DT = 0.2
CHANNEL = load_channel(None).model_copy(update={"loss_probability": 0.0})
"""The shipped channel (period, delays) without its message losses: this is about the release, not
about the guard's answer to a stale message."""
WINDOW_S = 20.0
"""The release: a follower's first 20 s."""
SPEED_DROP_TOL_MPS = 0.25
"""A follower that does not brake at its release loses at most its controller's trim (measured
0.13 m/s (EMU) and 0.00 m/s (freight) here, 0.03 m/s on Bologna–Firenze, started at the route
spacing); the release braking of the level-track start gap cost 2.0 m/s (EMU) and 2.3 m/s with 5
emergency commands (freight) here, 3.5 m/s there."""
CASES = {
    # a 160 km/h regional EMU released at 139 km/h (what it reaches in 1.5 km) at the top of a 25 ‰ descent
    "emu_25": ("regional_emu160", None, "160", "-25.0", "1.5", "1.5"),
    # a 2,000 t freight train at 80 km/h, its follower (700 m long) already on a 20 ‰ descent
    "freight_20": ("freight", FREIGHT, "80", "-20.0", "1.0", "3.0"),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def released(request, tmp_path_factory):
    """One convoy of two released as the capacity study releases it, 30 s in SUMO."""
    stock_name, stock_text, limit, grade, start_km, release_km = CASES[request.param]
    tmp = tmp_path_factory.mktemp(request.param)
    line = load_line(write(tmp / "descent.yaml", LINE.replace("LIMIT", limit).replace("GRADE", grade).replace("FROM", start_km).replace("RELEASE", release_km)))
    stock = load_rolling_stock(str(write(tmp / "freight.yaml", stock_text)) if stock_text else stock_name)
    net = build_network(line)
    assumptions = load_assumptions()
    model = SeparationModel(assumptions)
    setup = route_setup(line, net, stock, "up", DT, model)
    case = Case("up", "vc", "cbc", 2, "non-stop")
    spacing = convoy_spacing("cbc", stock, DT, assumptions, setup.full, CHANNEL.age_budget_s())  # the message age the loop's stack budgets
    gaps = initial_convoy_gaps(spacing, model, stock, setup, 2)
    units = unit_trains(net.topology, setup, stock, case, 1, 0.0, gaps)
    driver = VCDriver(units, "cbc", DT, 42, CHANNEL, assumptions=assumptions, record_every_s=DT)
    sim = simulate(Scenario(line, net, [t for u in units for t in u], "vc", step_length_s=DT, record_period_s=3600.0, full_outputs=False,
                            driver=driver, seed=42, assumptions=assumptions, end_time_s=30.0), tmp / "run")
    return dict(line=line, net=net, stock=stock, model=model, setup=setup, case=case, spacing=spacing, gaps=gaps, units=units, driver=driver,
                records=pd.DataFrame(driver.records), sim=sim)


def test_the_route_spacing_at_release_is_wider_than_on_level_track(released):
    """The case is one where level track is wrong: the stack keeps more on the descent."""
    r = released
    assert r["spacing"](r["setup"].v0, r["setup"].release_s - r["stock"].length_m - r["gaps"][0]) > r["spacing"](r["setup"].v0) + 20.0


def test_the_start_gap_is_the_stacks_own_route_spacing_where_the_follower_starts(released):
    r = released
    follower = r["units"][0][1]
    # the stack the SUMO loop built, on the follower's own route, at its release position and speed
    own = r["driver"].coupled_spacing_m(follower.id, follower.depart_speed_mps, follower.depart_pos_m)
    assert r["gaps"][0] == pytest.approx(own, abs=1.0)
    first = r["records"][r["records"].train == follower.id].iloc[0]
    assert first.gap_m == pytest.approx(own, abs=2.0)  # SUMO placed it there


def test_a_follower_released_at_its_start_gap_does_not_brake(released):
    r = released
    rec = r["records"]
    follower = r["units"][0][1]
    first = rec[(rec.train == follower.id) & (rec.time_s <= rec.time_s.min() + WINDOW_S)]
    assert len(first) >= WINDOW_S / DT
    assert not first.emergency.astype(bool).any(), first[first.emergency.astype(bool)][["time_s", "force_n", "gap_m"]]
    assert (first.speed_mps >= follower.depart_speed_mps - SPEED_DROP_TOL_MPS).all(), first[["time_s", "speed_mps", "force_n", "gap_m"]].to_string()
    summ = r["sim"].summary  # the run stops after 30 s, before the trains arrive: its safety counters only
    assert summ["gap_violations"] == 0 and summ["collisions"] == 0 and summ["min_margin_m"] > 0.0


def test_the_formed_test_uses_the_spacing_where_the_follower_is(released):
    r = released
    setup, driver = r["setup"], r["driver"]
    follower = r["units"][0][1]
    cruise = cruise_records(r["records"], setup, {follower.id: follower}, driver.coupled_spacing_m)
    assert len(cruise) > 0
    level = r["spacing"](setup.v0)
    for _, row in cruise.iterrows():
        s_full = setup.full.s_of("main", row.km)
        assert row.spacing_m == pytest.approx(r["spacing"](row.speed_mps, s_full), abs=0.5)  # the study's spacing = the loop's
    assert cruise.spacing_m.median() > level + 20.0
    # released at its spacing, the follower is formed by the route spacing
    assert within_spacing(cruise.gap_m.median(), cruise.spacing_m.median())


def test_the_analytic_convoy_starts_at_the_route_spacing(released):
    r = released
    setup, stock, model, case = r["setup"], r["stock"], r["model"], r["case"]
    run = leader_run(setup, stock, case, DT, model)
    on_route = analytic_headway(r["net"], setup, run, stock, case, model, DT, check_position_m(setup), r["spacing"], on_route=True)
    level = analytic_headway(r["net"], setup, run, stock, case, model, DT, check_position_m(setup), r["spacing"])
    assert on_route.coupled_gap_level_m == pytest.approx(r["spacing"](setup.v0))
    assert on_route.coupled_gap_m == pytest.approx(r["gaps"][0], abs=1.0)
    # the convoy is longer on the descent (its follower keeps more there): its rear clears later
    # (measured: EMU 77.7 vs 70.9 s, freight 139.7 vs 130.0 s)
    gained = (on_route.coupled_gap_m - on_route.coupled_gap_level_m) / setup.v0
    assert math.isfinite(on_route.headway_s) and on_route.headway_s > level.headway_s + 0.5 * gained
