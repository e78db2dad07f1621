"""An assumption set with ``absolute_braking: emergency``: the safe separation of FBS and MB is
certified with the emergency brake, the reserve; the trains are driven on the service brake.

Found by unseen7 (2026-11-28): regional_graded ``all_stations`` with etcs_typical +
``absolute_braking: emergency`` — the supervision planned every braking curve with the train's
guaranteed emergency brake, which SUMO (braking the trains it drives at their service rate) cannot
follow: 26 of 64 stops skipped.  Stops and speed restrictions were then planned on the service
brake, the approach to the end of authority and of the track still on the emergency brake: 2
authority overruns (0.6 m) and 2 gap violations (−8.6 m) under mb, 4 overruns (25 m) under fbs; on
the steep line below 2 collisions, 7 gap violations and 4 overruns under mb, 4 overruns and 3 SUMO
emergency stops under fbs.

Now (the ETCS arrangement: the service-brake curves lie before the emergency-brake intervention)
every curve the trains are driven on — ends of authority and of the track, stops, restrictions,
the interlocking's locking distances, the running curves and the analytic headways — is on the
service brake whatever the set says; the set's brake is what the run-health monitor certifies the
separation with.  An emergency set therefore runs exactly as the service set (the same
trajectories, the same headways) and certifies a larger margin.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from tests.conftest import write
from vcsumo.cli.main import main
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.regimes.base import SupervisedBraking
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.sim.health import HealthMonitor
from vcsumo.sim.supervision import BrakingCurveSupervisor
from vcsumo.timetable import load_timetable, plan_trains

ROOT = Path(__file__).resolve().parent.parent
TYPICAL = ROOT / "vcsumo" / "data" / "assumptions" / "etcs_typical.yaml"


def _emergency_set(folder: Path) -> Path:
    base = TYPICAL.read_text()
    assert "absolute_braking: service" in base
    return write(folder / "em.yaml", base.replace("name: etcs_typical", "name: em").replace("absolute_braking: service", "absolute_braking: emergency"))


def _per_train(out: Path) -> dict[str, dict]:
    import pandas as pd

    return pd.read_csv(out / "summary.csv").set_index("train").to_dict("index")


def _healthy(s: dict, trains: int, stops: int) -> None:
    assert s["healthy"] is True
    assert (s["trains_arrived"], s["stops_served"], s["stops_skipped"]) == (trains, stops, 0)
    assert (s["authority_overruns"], s["gap_violations"], s["collisions"], s["overspeed_events"]) == (0, 0, 0, 0)
    assert (s["beyond_service_brakings"], s["sumo_emergency_stops"], s["sumo_emergency_brakings"]) == (0, 0, 0)


def _both_sets(tmp: Path, line: str, timetable: str, regime: str) -> tuple[Path, Path]:
    em = _emergency_set(tmp)
    outs = []
    for name, spec in (("service", "etcs_typical"), ("emergency", str(em))):
        out = tmp / f"{regime}_{name}"
        main(["run", "--line", line, "--timetable", timetable, "--regime", regime, "--assumptions", spec, "--out", str(out)])
        outs.append(out)
    return outs[0], outs[1]


def _same_running_larger_certified_margin(service: Path, emergency: Path, reserve_shows: bool = True) -> None:
    """The emergency set drives every train as the service set does and certifies at least its margin
    (``reserve_shows``: more by 50 m for some train; not where every follower's smallest margin is
    where it stands behind the train ahead, margin and position errors under either brake)."""
    assert (emergency / "trajectories.csv").read_bytes() == (service / "trajectories.csv").read_bytes()
    srv, em = _per_train(service), _per_train(emergency)
    with_leader = [t for t, row in srv.items() if not math.isnan(row["min_margin_m"])]
    assert with_leader
    for t in with_leader:
        assert em[t]["min_margin_m"] >= srv[t]["min_margin_m"] - 0.01, t
    if reserve_shows:
        assert max(em[t]["min_margin_m"] - srv[t]["min_margin_m"] for t in with_leader) > 50.0  # the reserve is counted


@pytest.mark.sumo
@pytest.mark.parametrize("regime", ["mb", "fbs"])
def test_regional_graded_with_an_emergency_set_is_healthy_and_runs_as_the_service_set(tmp_path, regime):
    service, emergency = _both_sets(tmp_path, "regional_graded", "all_stations", regime)
    _healthy(json.loads((service / "summary.json").read_text()), 12, 64)
    _healthy(json.loads((emergency / "summary.json").read_text()), 12, 64)
    _same_running_larger_certified_margin(service, emergency)


PLUNGE = """
name: plunge
title: Steep descents into stations (unseen test), 24 km, 20 permille, 140 km/h
notes: test line of our own [A]
sources:
  A: assumed by the vcsumo developers
km_start: 0.0
km_end: 24.0
tracks: double
start_elevation_m: 600
line_speed_kmh: 140
directions: {up: Crest -> Foot, down: Foot -> Crest}
default_train: commuter.yaml
stations:
  - {id: CRE, name: Crest, km: 0.6, platform_length_m: 300, dwell_s: 60}
  - {id: LED, name: Ledge, km: 8.0, platform_length_m: 200, dwell_s: 120}
  - {id: STE, name: Steps, km: 15.5, platform_length_m: 200, dwell_s: 120}
  - {id: FOO, name: Foot, km: 23.4, platform_length_m: 300, dwell_s: 60}
gradients:
  - {from_km: 2.0, to_km: 8.3, permille: -20.0}
  - {from_km: 9.5, to_km: 15.8, permille: -20.0}
  - {from_km: 17.0, to_km: 23.0, permille: -20.0}
signalling:
  block_length_m: 1000
"""
COMMUTER = """
name: commuter
title: heavy commuter EMU (unseen test) [A]
length_m: 100.0
mass_kg: 260000.0
rotating_mass_factor: 1.08
max_speed_kmh: 140.0
max_traction_n: 220000.0
max_power_w: 2000000.0
davis_a_n: 3500.0
davis_b_n_per_mps: 40.0
davis_c_n_per_mps2: 5.0
service_brake_decel_mps2: 0.7
emergency_brake_decel_mps2: 1.1
max_jerk_mps3: 0.8
traction_lag_s: 0.6
"""
# trains 90 s apart down three 20 permille descents into stations where each stands 120 s: every
# follower comes down a descent onto its end of authority behind the one standing in the platform
CLOSE = """
name: close
line: plunge
services:
  - {id: U1, train: commuter.yaml, origin: CRE, destination: FOO, departure: "07:00", stops: [{station: LED}, {station: STE}]}
  - {id: U2, train: commuter.yaml, origin: CRE, destination: FOO, departure: "07:01:30", stops: [{station: LED}, {station: STE}]}
  - {id: U3, train: commuter.yaml, origin: CRE, destination: FOO, departure: "07:03", stops: [{station: LED}, {station: STE}]}
  - {id: D1, train: commuter.yaml, origin: FOO, destination: CRE, departure: "07:00", stops: [{station: STE}, {station: LED}]}
  - {id: D2, train: commuter.yaml, origin: FOO, destination: CRE, departure: "07:01:30", stops: [{station: STE}, {station: LED}]}
"""


@pytest.mark.sumo
@pytest.mark.parametrize("regime", ["mb", "fbs"])
def test_a_steep_line_with_an_emergency_set_is_healthy_and_runs_as_the_service_set(tmp_path, regime):
    line = write(tmp_path / "plunge.yaml", PLUNGE)
    write(tmp_path / "commuter.yaml", COMMUTER)
    tt = write(tmp_path / "close.yaml", CLOSE)
    service, emergency = _both_sets(tmp_path, str(line), str(tt), regime)
    s_srv = json.loads((service / "summary.json").read_text())
    _healthy(s_srv, 5, 15)
    _healthy(json.loads((emergency / "summary.json").read_text()), 5, 15)
    if regime == "mb":  # the followers run onto their ends of authority: they stand at the margin behind the train ahead
        assert s_srv["min_gap_m"] == pytest.approx(70.0, abs=0.5)
    _same_running_larger_certified_margin(service, emergency, reserve_shows=regime == "fbs")


def test_the_supervision_the_analytic_headways_and_the_health_check_use_the_brakes_the_field_says(line_factory, network_factory):
    """Supervision and analytic headways brake on service under either set (the same distances); the
    run-health monitor certifies with the set's brake, and its check fires on that brake's distance."""
    line = line_factory("regional_graded")
    tt, p = load_timetable("all_stations", line)
    trains = plan_trains(tt, p, line, network_factory("regional_graded").topology)
    t = trains[0]
    service = load_assumptions()
    emergency = service.model_copy(update={"name": "em", "absolute_braking": "emergency"})
    dt, s, v = 0.5, 7000.0, 40.0  # km 7.0 of UP.1, 740 m past its first stop, 5.7 km before the next
    dead = service.dead_time_s + 1.5 * dt
    reference = RouteBraking(SeparationModel(service), t.stock, t.profile).stopping_distance(s, v, dead)
    em_distance = RouteBraking(SeparationModel(service), t.stock, t.profile, "emergency").stopping_distance(s, v, dead)
    assert em_distance < reference - 300.0
    for a in (service, emergency):
        model = SeparationModel(a)
        sup = BrakingCurveSupervisor(model, "mb", trains, dt)
        assert SupervisedBraking(model, t.stock, t.profile, dt).distance(v, s) == pytest.approx(reference, abs=1e-9)
        # an end of authority inside the service stopping distance: the permitted speed is the service curve's
        d_ma = 0.7 * reference
        got = sup.permitted(t.id, 0.0, s, v, gap_m=d_ma + model.margin_m, leader_id=trains[1].id)
        assert got.reason == "authority" and got.authority_m == pytest.approx(d_ma)
        assert got.speed_mps == pytest.approx(RouteBraking(model, t.stock, t.profile).permitted_speed(s, s + d_ma, 0.0, dead, v), abs=1e-9)
    for a in (service, emergency):  # the loop hands the supervision and the interlocking the monitor's service braking
        health = HealthMonitor(SeparationModel(a), trains)
        assert health.braking[t.id].kind == a.absolute_braking and health.service[t.id].kind == "service"
    # the certified check: a gap between the emergency and the service distance is a violation only under the service set
    for a, violations in ((service, 1), (emergency, 0)):
        model = SeparationModel(a)
        h = HealthMonitor(model, trains)
        certified = h.absolute_gap(t.id, s, v)
        assert certified == pytest.approx(model.margin_m + RouteBraking(model, t.stock, t.profile, a.absolute_braking).stopping_distance(s, v, a.dead_time_s))
        gap = model.margin_m + 0.5 * (RouteBraking(model, t.stock, t.profile, "emergency").stopping_distance(s, v, a.dead_time_s)
                                      + RouteBraking(model, t.stock, t.profile).stopping_distance(s, v, a.dead_time_s))
        h.step(t.id, dt, s, v, 0.0, gap, 1000.0, leader_id=None)
        assert h.trains[t.id].separation_violations == violations, a.name
        h.step(t.id, dt, s, v, 0.0, certified + 5.0, 1000.0)  # clear again
        h.step(t.id, dt, s, v, 0.0, certified - 1.0, 1000.0)  # 1 m inside the certified separation: fires under either set
        assert h.trains[t.id].separation_violations == violations + 1, a.name
