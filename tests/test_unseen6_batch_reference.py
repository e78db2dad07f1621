"""Sixth round of unseen inputs — a batch on a network of two lines of our own (90 km/h DMUs, 200 m
platforms, a 20 permille descent into a station), timetables without scheduled arrival times.

Defect found: a train without a scheduled arrival is measured against its *reference arrival*, its
scheduled departure + its unhindered running time; that running time was SUMO's own driving (its
nominal service brake, 0.7 m/s²), while every train SUMO drives in the run is supervised on its
guaranteed, gradient-compensated braking curve (0.63 m/s² and less on descents, as the capacity
study's leader run).  So a train alone on the line, without any primary delay, arrived 26.5 s "late"
(3 stops) and 21.5 s (2 stops), and the batch counted that as knock-on (secondary) delay: 171.9 s per
run of a timetable whose trains never met.  Now the reference run is the supervised one (the run's
assumption set): 3.5 s and 4.5 s left (the creep onto the stopping point)."""

import pandas as pd
import pytest

from vcsumo.delays import NO_DELAYS
from vcsumo.studies.batch import run_batch

from .conftest import write
from .test_unseen6_junction_fouling import DMU

pytestmark = pytest.mark.sumo

LINE = """name: dale_batch
km_start: 0.0
km_end: 20.0
line_speed_kmh: 100
default_train: dmu90.yaml
stations:
  - {id: ASH, name: Ash, km: 0.3, platform_length_m: 200, dwell_s: 40}
  - {id: BIR, name: Birch, km: 6.0, platform_length_m: 200, dwell_s: 30}
  - {id: CED, name: Cedar, km: 12.0, platform_length_m: 200, dwell_s: 30}
  - {id: ELD, name: Elder, km: 19.7, platform_length_m: 200, dwell_s: 40}
gradients:
  - {from_km: 8.0, to_km: 11.8, permille: -20.0}
signalling: {block_length_m: 1200}
"""
TIMETABLE = """name: alone
line: dale_batch
services:
  - {id: R, train: dmu90.yaml, origin: ASH, destination: ELD, departure: "07:00", stops: [{station: BIR}, {station: CED}]}
"""


def test_a_train_alone_and_on_time_has_no_knock_on_delay(tmp_path):
    write(tmp_path / "dmu90.yaml", DMU)
    line = write(tmp_path / "line.yaml", LINE)
    tt = write(tmp_path / "alone.yaml", TIMETABLE)
    df = run_batch(str(line), str(tt), ["fbs", "mb"], [1], delays=NO_DELAYS, out=tmp_path / "b", workers=1)
    assert (df.status == "ok").all() and df.healthy.all()
    trains = pd.read_csv(tmp_path / "b" / "batch_trains.csv")
    assert (trains.primary_delay_s == 0).all()
    # main: 18.0 s in both regimes, all of it knock-on delay (2 stops, one on a 20 permille descent)
    assert (trains.arrival_delay_s.abs() < 6.0).all(), trains[["regime", "arrival_delay_s"]]
    assert (df.knock_on_delay_s < 6.0).all()
