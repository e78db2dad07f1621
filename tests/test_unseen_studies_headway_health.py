"""A headway row says why it is (or is not) healthy: every counter the run's verdict rests on is a column.

Found by unseen-studies (2026-12-01): ``headway.csv`` carried ``healthy``, ``gap_violations``,
``collisions`` and ``min_margin_m`` only, so a row made unhealthy by overspeed, a braking beyond the
service rate, an authority overrun, a SUMO emergency braking or a train that did not arrive read
``healthy`` False with every health column 0 (the class of defect unseen7 fixed in the capacity
table). The rows now carry the same counters as ``capacity.csv`` (and ``unhealthy_probes``: the
bisection's runs that were not healthy), and the terminal's note names the ones that are not 0.
"""

from __future__ import annotations

import pandas as pd
import pytest

from vcsumo.cli.commands import UNHEALTHY
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.studies.capacity import CAPACITY_COLUMNS
from vcsumo.studies.headway import HEADWAY_COLUMNS, run_headway_study


def test_every_counter_of_the_run_verdict_is_a_headway_column():
    assert {k for k, _ in UNHEALTHY} <= set(HEADWAY_COLUMNS)
    health = set(CAPACITY_COLUMNS[CAPACITY_COLUMNS.index("healthy"):CAPACITY_COLUMNS.index("assumptions")]) - {"min_gap_m"}
    assert health <= set(HEADWAY_COLUMNS), health - set(HEADWAY_COLUMNS)


@pytest.mark.sumo
def test_a_headway_row_carries_the_counters_of_its_run(line_factory, network_factory, tmp_path):
    line = line_factory("felez_test")
    df = run_headway_study(line, network_factory("felez_test"), [load_rolling_stock(line.data.default_train)], ["mb"], tmp_path, [1.5],
                           directions=("up",))
    row = pd.read_csv(tmp_path / "headway.csv").iloc[0]
    probe = sorted((tmp_path / "runs" / "up_mb_felez2019" / "probes").iterdir())
    assert len(probe) == 1  # the run at the reported headway is kept
    summary = pd.read_json(probe[0] / "summary.json", typ="series")
    for k, _ in UNHEALTHY:
        assert row[k] == summary[k], k
    assert row["trains_arrived"] == row["trains"] == 2
    assert bool(row["healthy"]) == (all(row[k] == 0 for k, _ in UNHEALTHY) and row["trains_arrived"] == row["trains"])
    assert 0 <= row["unhealthy_probes"] < row["simulations"]
    assert list(df.columns) == HEADWAY_COLUMNS

