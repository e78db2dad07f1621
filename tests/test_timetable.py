"""Tier 1 — timetables resolved against a line: routes, stops, bad input (no SUMO)."""

import pytest

from vcsumo.errors import InputError
from vcsumo.line import load_line
from vcsumo.timetable import load_timetable, plan_trains, routes_xml
from vcsumo.topology import build_topology

from .conftest import write


@pytest.fixture(scope="module")
def bofi():
    line = load_line("firenze_bologna")
    return line, build_topology(line)


def test_shipped_timetables_plan(root):
    from vcsumo.line import shipped_lines

    for name in shipped_lines():
        line = load_line(name)
        topo = build_topology(line)
        files = sorted((root / "vcsumo" / "data" / "routes" / name).glob("*.yaml"))
        assert files, f"no timetable shipped for {name}"
        for f in files:
            tt, path = load_timetable(f, line)
            trains = plan_trains(tt, path, line, topo)
            assert trains and all(t.edges for t in trains)


def test_peak_routes_and_stops(bofi):
    line, topo = bofi
    tt, path = load_timetable("peak", line)
    trains = {t.id: t for t in plan_trains(tt, path, line, topo)}
    fr = trains["FR9501.1"]
    assert fr.direction == "up" and [s.station for s in fr.stops] == ["FIRI"]
    assert fr.final_stop.station == "FISMN"
    assert trains["FR9501.2"].depart_s - fr.depart_s == pytest.approx(1200.0)
    assert any(e.startswith("san_ruffillo") for e in trains["FA8801"].edges)
    xml = routes_xml(list(trains.values()), topo)
    plat = topo.platforms["FIRI_up"]
    assert f'<stop lane="{plat.edge}_0"' in xml and "etr1000@tf1.50" in xml and 'carFollowModel="Rail"' in xml


TT = """
name: t
line: firenze_bologna
services:
  - id: S1
    train: etr1000
    origin: BOAV
    destination: FISMN
    departure: "07:00"
    stops: [{station: FIRI, dwell_s: 30}]
"""


@pytest.mark.parametrize(
    "old,new,field,words",
    [
        ("station: FIRI", "station: XXX", "services[0].stops[0].station", "unknown station 'XXX'"),
        ("train: etr1000", "train: tgv", "services[0].train", "unknown train 'tgv'"),
        ("destination: FISMN", "destination: BOAV", "services[0].destination", "equals origin"),
        ('destination: FISMN\n    departure: "07:00"\n    stops: [{station: FIRI', 'destination: FIRI\n    departure: "07:00"\n    stops: [{station: FISMN', "services[0].stops[0].station", "not on the route"),
        ('departure: "07:00"', 'departure: "07:00"\n    arrival: "07:10"', "services[0].arrival", "infeasible"),
        ("stops: [{station: FIRI, dwell_s: 30}]", "stops: [{station: FIRI, dwell_s: 30, departure: '07:30'}]\n    arrival: '07:31'", "services[0].arrival", "from its previous departure"),
        ('departure: "07:00"', 'departure: "7h"', "services[0].departure", "not a time"),
        ("line: firenze_bologna", "line: hcmc_line1", "line", "not 'firenze_bologna'"),
        ("    stops:", "    colour: red\n    stops:", "services[0].colour", "unknown key"),
        ("origin: BOAV", "origin: branch:nowhere", "services[0].origin", "unknown branch"),
    ],
)
def test_bad_timetable(tmp_path, bofi, old, new, field, words):
    line, topo = bofi
    assert old in TT
    path = write(tmp_path / "t.yaml", TT.replace(old, new))
    with pytest.raises(InputError) as exc:
        tt, p = load_timetable(path, line)
        plan_trains(tt, p, line, topo)
    assert str(path) in str(exc.value) and field in str(exc.value) and words in str(exc.value), str(exc.value)


def test_convoy_naming_unknown_service(tmp_path, bofi):
    line, topo = bofi
    path = write(tmp_path / "t.yaml", TT + "convoys:\n  - {id: C1, services: [S1, S9]}\n")
    tt, p = load_timetable(path, line)
    with pytest.raises(InputError) as exc:
        plan_trains(tt, p, line, topo)
    assert "convoys[0].services[1]" in str(exc.value) and "'S9'" in str(exc.value)
