"""The SUMO-loop safety campaign judges each run by every run-health counter, not only separation and
collisions: until 2026-11-28 its rows of safety.csv left out overspeed, braking beyond service,
authority overruns, SUMO emergency stops and teleports, so such a run was reported clean (the
campaign-speed round's finding)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from vcsumo.studies.safety import SAFETY_COLUMNS, bar_met, run_faults, scenario_task, summarize_safety
from vcsumo.studies.safety_scenarios import HEALTH_FAULT_COLUMNS, SafetyCampaign


def _row(**over) -> dict:
    row = {c: 0 for c in SAFETY_COLUMNS}
    row.update(loop="sumo", controller="cbc", supervised=False, error="", initial_true_barrier_m=math.nan, max_true_barrier_m=math.nan,
               time_lost_s=math.nan, min_gap_m=100.0, min_margin_m=5.0)
    row.update(over)
    return row


@pytest.mark.parametrize("counter", HEALTH_FAULT_COLUMNS)
def test_a_run_with_a_health_fault_is_not_clean_and_the_bar_is_not_met(counter):
    df = pd.DataFrame([_row(scenario="s00000"), _row(scenario="s00001", **{counter: 1})])
    faults = run_faults(df)
    assert faults["health_fault"].tolist() == [False, True] and not faults.iloc[0].any()
    summary = summarize_safety(df)
    assert summary["runs_with_health_fault"].tolist() == [1] and not bar_met(summary, min_scenarios=2)
    assert bar_met(summarize_safety(df.iloc[:1]), min_scenarios=1)


def test_offline_rows_do_not_measure_them_and_are_judged_as_before():
    df = pd.DataFrame([_row(scenario="s00000", loop="offline", **{c: np.nan for c in HEALTH_FAULT_COLUMNS})])
    assert not run_faults(df).iloc[0].any()


@pytest.mark.sumo
def test_a_sumo_loop_row_carries_every_health_counter():
    rows = scenario_task((SafetyCampaign(loop="sumo", scenarios=1, controllers=["cbc"]), 0, ("cbc",)))
    assert len(rows) == 1 and rows[0]["error"] == ""
    assert all(isinstance(rows[0][c], int) and rows[0][c] == 0 for c in HEALTH_FAULT_COLUMNS)
