"""Every study row that carries a run's health carries every counter the verdict rests on.

Found by unseen9 (2026-11-28): the run's verdict (``healthy``) rests on eleven counters
(:data:`vcsumo.sim.run_results.HEALTH_COUNTERS`), but ``batch.csv`` had no ``sumo_emergency_stops``,
``sumo_emergency_brakings``, ``sumo_stop_warnings`` or ``teleports``, ``junction.csv`` no
``short_dwells`` or ``sumo_stop_warnings``, and ``tradeoff_check.csv`` no ``sumo_emergency_brakings``,
``sumo_stop_warnings`` or ``teleports``: a row unhealthy for one of them showed ``healthy`` False
with every counter beside it 0, and the trade-off check's line said "NOT healthy (a train did not
arrive or a stop was not reached)" for it.  The capacity study already carried them all.
"""

from __future__ import annotations

import json

import pandas as pd

from vcsumo.cli.commands import UNHEALTHY
from vcsumo.cli.main import main
from vcsumo.cli.tradeoff import UNHEALTHY_COUNTERS
from vcsumo.sim.run_results import HEALTH_COUNTERS
from vcsumo.studies.batch_run import BATCH_COLUMNS
from vcsumo.studies.capacity import CAPACITY_COLUMNS
from vcsumo.studies.junction.study import HEALTH_SUMS, JUNCTION_COLUMNS
from vcsumo.studies.tradeoff import CHECK_COLUMNS


def test_every_study_carries_every_counter_of_the_verdict():
    need = set(HEALTH_COUNTERS)
    assert {k for k, _ in UNHEALTHY} == need
    assert need <= set(CAPACITY_COLUMNS) and need <= set(BATCH_COLUMNS) and need <= set(CHECK_COLUMNS) and need <= set(UNHEALTHY_COUNTERS)
    assert need <= set(HEALTH_SUMS) and need - {"gap_violations", "collisions"} <= set(JUNCTION_COLUMNS)
    assert {"gap_violations_all_runs", "collisions_all_runs"} <= set(JUNCTION_COLUMNS)


def test_a_batch_row_carries_the_runs_counters(in_tmp):
    assert main(["-q", "batch", "--line", "felez_test", "--timetables", "base", "--regimes", "fbs", "--seeds", "1", "--workers", "1", "--out", "b"]) == 0
    row = pd.read_csv(in_tmp / "b" / "batch.csv").iloc[0]
    summary = json.loads((in_tmp / "b" / row.run_dir / "summary.json").read_text())
    for k in HEALTH_COUNTERS:
        assert row[k] == summary[k], k
