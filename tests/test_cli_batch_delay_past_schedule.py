"""A train delayed at its origin past the scheduled departure of a stop is served there and the run
is healthy: the stop has no ``until`` left to wait for.

Found running the README's batch on the shipped Bologna-Firenze ``peak`` timetable (fbs and mb, seeds
1-3): seed 2 delays FR9502.2 by 586.7 s at its origin, beyond its 07:26 departure from the next
stop; SUMO warned ``stop for vehicle 'FR9502.2' ... set to end at 26760.00 earlier than departure
at 27106.70``, a stop warning, so 2 of 12 runs were "not healthy" (exit 1) although every stop was
served for its whole dwell.  Without the ``until`` the stop events, delays and margins are the same
to the digit (21 stops, mean arrival delay 16.57 s fbs / 11.82 s mb) and both runs are healthy."""

from __future__ import annotations

import pytest

from vcsumo.cli.main import main
from vcsumo.results import read_results_csv

TIMETABLE = """\
name: late
line: regional_graded
services:
  - id: R1
    train: regional_emu160
    origin: ALD
    destination: CAS
    departure: "08:00"
    stops:
      - {station: BRK, arrival: "08:06", departure: "08:07"}
    arrival: "08:15"
"""

DELAYS = """\
origin: {probability: 1.0, distribution: uniform, min_s: 600, max_s: 600}
dwell: {distribution: none}
"""


@pytest.mark.sumo
def test_a_train_late_past_a_scheduled_departure_is_served_and_healthy(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "late.yaml").write_text(TIMETABLE)
    (tmp_path / "delays.yaml").write_text(DELAYS)
    code = main(["-q", "batch", "--line", "regional_graded", "--timetables", "late.yaml", "--regimes", "fbs", "--seeds", "1",
                 "--delay-config", "delays.yaml", "--workers", "1", "--out", "b"])
    out = capsys.readouterr().out
    row = read_results_csv(tmp_path / "b" / "batch.csv").iloc[0]
    assert row.status == "ok" and row.primary_delay_s == 600.0
    assert row.sumo_stop_warnings == 0 and bool(row.healthy) and row.stops_skipped == 0 and row.short_dwells == 0, out
    assert code == 0, out
    run = tmp_path / "b" / row.run_dir
    stops = read_results_csv(run / "stop_events.csv")
    brk = stops[stops.station == "BRK"].iloc[0]
    assert brk.arrival_s >= 8 * 3600 + 600 and brk.departure_s - brk.arrival_s >= 40.0 - 0.5  # served, its whole 40 s dwell
    assert brk.departure_delay_s > 0  # left late: measured against the schedule, which the delay does not change
    assert "until=" not in (run / "routes.rou.xml").read_text()
