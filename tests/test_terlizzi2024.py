"""Offline reproduction of Terlizzi et al. (2024) §VII (OS1, OS2) on a compressed timeline.

The full scenarios (``run_all``) take about a minute; these runs use the same code with shorter
phases and a 0.2 s step, and check the paper's qualitative results:

* OS1: closer coupling with the smaller channel delay; both trains stop with a gap ≥ d;
* OS2: fewer emergency brakings with the delay estimator;
* the true barrier is never positive.
"""

from __future__ import annotations

import math

import pandas as pd
import pytest

from vcsumo.reproduce.terlizzi2024 import OS1Spec, OS2Spec, line_profile, run_os1, run_os2

OS1_COMPACT = OS1Spec(duration_s=800.0, dt_s=0.2, speed_schedule=((0.0, 45.0), (300.0, 35.0)), brake_time_s=500.0, steady_window_s=100.0)
OS2_COMPACT = OS2Spec(
    duration_s=600.0, dt_s=0.2, leader_start_m=40000.0,
    degradations=((150.0, 250.0, 1.0, 0.5, 0.02), (250.0, 330.0, 2.0, 1.0, 0.05), (330.0, 400.0, 3.5, 1.5, 0.10)),
    outage=(400.0, 430.0), steady_window=(100.0, 150.0), degraded_window=(330.0, 400.0),
)

REQUIRED = {"scenario", "delay_s", "delay_estimator", "coupled_distance_m", "emergency_activations", "min_gap_m", "true_barrier_max", "robust_barrier_max", "both_stopped_gap_m"}


@pytest.fixture(scope="module")
def runs():
    prof = line_profile()
    out = {}
    for d in (3.0, 0.8):
        out[("os1", d)] = run_os1(d, spec=OS1_COMPACT, profile=prof)
    for est in (True, False):
        out[("os2", est)] = run_os2(est, spec=OS2_COMPACT, profile=prof)
    return out


def test_rows_are_csv_ready(runs):
    rows = [r for r, _ in runs.values()]
    assert all(REQUIRED <= set(r) for r in rows)
    df = pd.DataFrame(rows)
    assert len(df) == 4 and set(df.scenario) == {"OS1", "OS2"}
    traj = runs[("os1", 0.8)][1]
    assert {"time_s", "gap_m", "mode", "robust_barrier_m", "true_barrier_m", "tau_bar_s"} <= set(traj.columns)


def test_os1_closer_coupling_with_smaller_delay(runs):
    slow, fast = runs[("os1", 3.0)][0], runs[("os1", 0.8)][0]
    assert fast["coupled_distance_m"] < slow["coupled_distance_m"] - 300.0
    assert fast["tau_bar_s"] == pytest.approx(0.8) and slow["tau_bar_s"] == pytest.approx(3.0)
    # the follower closed in from the 6,000 m L3 separation
    assert fast["coupled_distance_m"] < 6000.0 and slow["coupled_distance_m"] < 6000.0


def test_os1_both_trains_stop_at_least_d_apart(runs):
    for d in (3.0, 0.8):
        row, traj = runs[("os1", d)]
        assert row["both_stopped"], d
        assert row["both_stopped_gap_m"] >= row["safety_distance_m"]
        assert row["min_gap_m"] >= row["safety_distance_m"]
        assert traj.gap_m.min() >= 1000.0


def test_os2_fewer_emergency_brakings_with_the_delay_estimator(runs):
    with_est, without = runs[("os2", True)][0], runs[("os2", False)][0]
    assert with_est["emergency_activations"] < without["emergency_activations"]
    assert with_est["emergency_activations"] <= 0.2 * without["emergency_activations"]
    # the estimator sees the degradation and widens the spacing
    assert with_est["tau_bar_degraded_s"] > 3.0 * with_est["tau_bar_s"]
    assert with_est["degraded_distance_m"] > without["degraded_distance_m"]
    # the outage triggers the T^max rule (eq. 18) in both cases
    assert with_est["tmax_activations"] >= 1


def test_true_barrier_never_positive(runs):
    for key, (row, traj) in runs.items():
        assert row["true_barrier_max"] <= 0.0, key
        assert not (traj.true_barrier_m > 0).any(), key
        assert math.isfinite(row["robust_barrier_max"])
