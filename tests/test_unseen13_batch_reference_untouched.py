"""Tier 1 — a batch measures every train against its timetable, not against the VC driver's
arrangement of the convoys (unseen-networks, 2026-12-01).

Found in ``vcsumo batch`` on a network of our own (hsnet, vc): the convoy leader SL drew a 474 s
primary delay, its follower SF none; the VC driver made SF leave behind SL, 444 s after its
timetable, and ``batch_trains.csv`` reported SF with ``scheduled_departure_s`` = 08:47:54 and an
arrival delay of 16.5 s — the delay its leader passed on to it hidden, under vc only (under fbs and
mb SF runs to time).  A train without a primary delay was the very object of the timetable the
reference arrivals are computed from, and the driver moves convoy departures (and a convoy's stop
departures) in place; a delayed train was a copy, so the same situation was measured two ways."""

import warnings

import pytest

from vcsumo.delays import TrainDelays, apply_delays
from vcsumo.network_file import load_network
from vcsumo.signalling.scheduled_run import reference_arrivals
from vcsumo.signalling.separation import SeparationModel
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.sim.vc_driver import make_vc_driver
from vcsumo.timetable import load_timetable, plan_trains
from vcsumo.topology import Topology

from .conftest import write
from .test_network_file import make_network

TT = """
name: late
line: twolines
services:
  - {id: L, train: etr1000, origin: AST, destination: BEND, departure: "07:00"}
  - {id: F, train: etr1000, origin: AST, destination: SPUR, departure: "07:00:30"}
convoys:
  - {id: C, services: [L, F]}
"""


def test_the_vc_driver_does_not_move_the_timetable_a_batch_measures_against(tmp_path):
    from vcsumo.network_topology import build_network_topology

    net = load_network(make_network(tmp_path / "net"))
    topo: Topology = build_network_topology(net)
    tt, path = load_timetable(write(tmp_path / "late.yaml", TT), net)
    planned = plan_trains(tt, path, net, topo, dt=0.5)
    timetabled = {t.id: (t.depart_s, t.depart_pos_m) for t in planned}
    model = SeparationModel(load_assumptions())
    ref_before = reference_arrivals(planned, 0.5, model)
    # the leader 474 s late at its origin, the follower on time (the batch's draw, made exact)
    trains = apply_delays(planned, {"L": TrainDelays("L", 474.0, ()), "F": TrainDelays("F", 0.0, ())})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        make_vc_driver(tt, path, trains, "cbc", 0.5, seed=1)
    run = {t.id: t for t in trains}
    # the run's follower leaves behind its late leader ...
    assert run["F"].depart_s >= run["L"].depart_s == pytest.approx(timetabled["L"][0] + 474.0)
    # ... and the timetable the batch measures it against is still the timetable
    assert {t.id: (t.depart_s, t.depart_pos_m) for t in planned} == timetabled
    assert reference_arrivals(planned, 0.5, model) == ref_before
