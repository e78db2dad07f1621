"""Fifth round of unseen inputs — a 350 km line of our own: ETR 1000s (350 km/h stock) on a 250 km/h
line with a 300 km/h stretch, a 1,000 t freight train (100 km/h) on a 27 permille descent where its
guaranteed service brake barely holds it (0.305 − 0.265 = 0.04 m/s² over the box), three junctions within
3 km (branches leaving towards both ends, one of them single track), a station 125 m after a junction
and stations at both ends of the route.

Defect found: the north branch is single track.  F1 (freight) runs to its far end through Northby, R1
follows it onto the branch, and R2 is timetabled to leave Northby the other way while F1 is still in
the platform.  The single-track lock gave a train whose origin lies on the stretch the stretch at its
departure, whatever held it ("SUMO's insertion keeps it in its platform"), but SUMO's insertion checks
only the track at the insertion place: it inserted R2 the moment F1 had left (26,799.5 s), with R1
already 250 m into the branch's first block (two one-way edges, which SUMO's signals do not protect),
and R2 ran into R1 standing at the 1.8 km signal at 120 km/h (fbs, 26,901 s).  Now a train entering
on a stretch asks for it at its departure time and SUMO keeps it out (an insertion constraint at its
first signal) until the lock gives it the stretch: R2 leaves Northby when R1 has arrived.

The same runs check the supervision's quiet windows (``checked``: every quiet answer against the full
braking curves) under fbs and under mb with 10 s of ETCS fixed times."""

import warnings

import pandas as pd
import pytest

from vcsumo.line import load_line
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write
from .test_supervision_quiet import _assert_exercised, _simulate, checked  # noqa: F401 (a fixture)
from .test_network_unseen import FREIGHT  # a 450 m, 1,000 t freight train (0.35 / 0.5 m/s²), 100 km/h

pytestmark = pytest.mark.sumo

LONG = """name: longhaul
title: A 350 km high-speed line with a steep descent and clustered junctions (unseen5) [A]
km_start: 0.0
km_end: 350.0
tracks: double
start_elevation_m: 100
line_speed_kmh: 250
default_train: etr1000
stations:
  - {id: AAA, name: Alpha, km: 0.25, platform_length_m: 450, dwell_s: 60}
  - {id: BRG, name: Bridge, km: 120.0, platform_length_m: 450, dwell_s: 90}
  - {id: JNS, name: Junction South, km: 150.35, platform_length_m: 450, dwell_s: 40}
  - {id: DSC, name: Descent, km: 205.0, platform_length_m: 500, dwell_s: 60}
  - {id: ZZZ, name: Zulu, km: 349.75, platform_length_m: 450, dwell_s: 60}
speed_limits:
  - {from_km: 0.0, to_km: 2.0, speed_kmh: 100}
  - {from_km: 60.0, to_km: 110.0, speed_kmh: 300}
  - {from_km: 148.0, to_km: 156.0, speed_kmh: 160}
  - {from_km: 230.0, to_km: 232.0, speed_kmh: 80}
  - {from_km: 348.0, to_km: 350.0, speed_kmh: 100}
gradients:
  - {from_km: 180.0, to_km: 215.0, permille: -27.0}
  - {from_km: 215.0, to_km: 240.0, permille: 12.0}
signalling: {block_length_m: 1800}
branches:
  - {id: east, name: East spur, junction_km: 150.0, leaves_towards: end, length_m: 9000, speed_kmh: 140, diverging_speed_kmh: 100,
     stations: [{id: EST, name: Eastby, km: 8.6, platform_length_m: 300, dwell_s: 30}]}
  - {id: west, name: West spur, junction_km: 151.5, leaves_towards: start, length_m: 7000, speed_kmh: 120, diverging_speed_kmh: 80,
     stations: [{id: WST, name: Westby, km: 6.6, platform_length_m: 300, dwell_s: 30}]}
  - {id: north, name: North spur, junction_km: 153.0, leaves_towards: end, length_m: 5000, speed_kmh: 120, diverging_speed_kmh: 80, tracks: single,
     stations: [{id: NTH, name: Northby, km: 4.7, platform_length_m: 250, dwell_s: 30}]}
"""
LONG_TT = """name: t
line: longhaul
services:
  - {id: E1, train: etr1000, origin: AAA, destination: ZZZ, departure: "06:00", stops: [{station: BRG}, {station: DSC}]}
  - {id: F1, train: freight.yaml, origin: AAA, destination: "branch:north", departure: "05:50"}
  - {id: E2, train: etr1000, origin: AAA, destination: ZZZ, departure: "06:06"}
  - {id: R1, train: regional_emu160, origin: "branch:west", destination: "branch:north", departure: "07:20", stops: [{station: WST}, {station: NTH}]}
  - {id: R2, train: regional_emu160, origin: NTH, destination: WST, departure: "07:25"}
  - {id: R3, train: regional_emu160, origin: EST, destination: AAA, departure: "07:24", stops: [{station: BRG}]}
  - {id: E3, train: etr1000, origin: AAA, destination: ZZZ, departure: "06:20", stops: [{station: JNS}]}
  - {id: E4, train: etr1000, origin: AAA, destination: EST, departure: "06:30"}
  - {id: D1, train: etr1000, origin: ZZZ, destination: AAA, departure: "06:00", stops: [{station: DSC}, {station: JNS}]}
  - {id: D2, train: freight.yaml, origin: "end", destination: JNS, departure: "05:40"}
"""


def _run(tmp_path, regime, fixed=None):
    from vcsumo.sim.network import build_network

    write(tmp_path / "freight.yaml", FREIGHT)
    line = load_line(write(tmp_path / "line.yaml", LONG))
    tt, path = load_timetable(write(tmp_path / "tt.yaml", LONG_TT), line)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (F1, R1 and R2 are timetabled onto the north branch at the same time: a wait, said)
        trains = plan_trains(tt, path, line, build_network(line).topology)
    res = _simulate(tmp_path, line, trains, regime, fixed_time_s=fixed)
    return res.summary, pd.read_csv(tmp_path / "out" / "summary.csv").set_index("train")


def test_a_train_entering_on_single_track_waits_for_the_opposing_train_on_it(tmp_path, checked):
    s, per = _run(tmp_path, "fbs")
    assert s["collisions"] == 0 and s["healthy"], s
    assert s["trains_arrived"] == 10 and s["stops_served"] == 16
    assert per.loc["R2", "departure_s"] >= per.loc["R1", "arrival_s"]  # R1 held the branch: R2 left Northby after it arrived
    _assert_exercised(checked)


def test_moving_block_with_fixed_times_on_the_long_line(tmp_path, checked):
    s, _ = _run(tmp_path, "mb", 10.0)
    assert s["healthy"] and s["trains_arrived"] == 10, s
    _assert_exercised(checked)
