"""Reproduction of Felez, Kim & Borrelli (2019) §IV-A (Fig. 11, 12): bars on order and magnitude.

The shipped files (``felez2019_{sh,np,mb}.yaml``) run one a^f for every predictor; the paper's
figures are compared with their labelled variant ``fitted`` (a^f 0.75 for SH, 0.5 for NP and MB)."""

from __future__ import annotations

import pytest

from vcsumo.reproduce.felez2019 import PAPER, horizon_sweep, load_scenario, run_felez2019, simulate


@pytest.fixture(scope="module")
def table():
    return run_felez2019(("SH", "NP", "MB"), horizon=40, n_trains=2, variant="fitted").set_index("strategy")


def test_columns_and_trajectories(table):
    for col in ("gap_at_rest_m", "stop_delay_s", "min_gap_m", "collisions", "stop_distance_m", "paper_stop_distance_m", "paper_stop_delay_s"):
        assert col in table.columns
    traj = table.attrs["trajectories"]["SH"]
    assert {"time_s", "s0_m", "v0_mps", "s1_m", "v1_mps", "gap1_m", "u1_n"} <= set(traj.columns)
    assert traj["time_s"].iloc[-1] > 200.0


def test_order_and_paper_values(table):
    d = table["stop_distance_m"]
    assert d["SH"] < d["NP"] < d["MB"]
    for strat in ("SH", "NP", "MB"):
        paper = PAPER[strat]["stop_distance_m"]
        assert abs(d[strat] - paper) <= 0.25 * paper, (strat, d[strat], paper)
    delay = table["stop_delay_s"]  # the paper: 2 / 17 / 23 s
    assert 0.0 <= delay["SH"] < delay["NP"] < delay["MB"]
    assert delay["SH"] <= 5.0  # "no significant delay"
    assert abs(delay["MB"] - PAPER["MB"]["stop_delay_s"]) <= 0.25 * PAPER["MB"]["stop_delay_s"]
    assert abs(delay["NP"] - PAPER["NP"]["stop_delay_s"]) <= 0.25 * PAPER["NP"]["stop_delay_s"]  # 17 s; measured 13.4 s (-21 %)


def test_safe_and_feasible(table):
    d_min = load_scenario().settings.d_min_m
    assert (table["collisions"] == 0).all()
    assert (table["min_gap_m"] >= d_min - 0.05).all()
    assert (table["gap_at_rest_m"] >= d_min - 0.05).all()  # both at rest: between d_min and d_des
    assert (table["gap_at_rest_m"] <= 10.0 + 0.5).all()
    assert (table["infeasible_steps"] == 0).all()
    # the leader stops 3,700 m from its start (§IV-A)
    assert ((table["leader_stop_position_m"] - 3700.0).abs() < 1.0).all()


def test_longer_horizon_shortens_sh_distance():
    """Fig. 11: with SH the distance between trains decreases as N_p grows."""
    sweep = horizon_sweep((20, 50)).set_index("horizon")
    assert sweep.loc[50, "stop_distance_m"] < sweep.loc[20, "stop_distance_m"]
    assert (sweep["min_gap_m"] >= 3.95).all()


def test_unannounced_emergency_braking_is_unsafe_for_close_sh():
    """Why SH needs the leader's braking in its plan: an unannounced emergency stop of the leader
    with a^f = 0.75 ends below d_min (the terminal set 12m only covers braking after the horizon)."""
    sc = load_scenario(leader_braking="emergency", variant="fitted")
    res = simulate("SH", 2, 40, sc)
    assert res.metrics["min_gap_m"] < sc.settings.d_min_m


def test_one_af_for_all_cannot_reach_the_paper_sh_distance(table):
    """The files' own run: a^f = 0.5 for every predictor.  NP and MB are the fitted runs (their fit is
    0.5); SH stays above the bound of constraint 12m at 20 m/s — d ≥ d_min + v_N²/(2a^f) − v̄²/(2a^l)
    with the ≤ 3.7 m/s the train sheds in the 4 s horizon, ≈ 110 m — far from the paper's 28.5 m."""
    one = run_felez2019(("SH",), horizon=40, n_trains=2).set_index("strategy")
    assert one.loc["SH", "variant"] == "one_af" and one.loc["SH", "a_follower_mps2"] == 0.5
    v_n = 20.0 - 3.7
    bound = 4.0 + v_n**2 / (2 * 0.5) - 20.0**2 / (2 * 1.25)
    assert one.loc["SH", "stop_distance_m"] >= bound
    assert one.loc["SH", "stop_distance_m"] > 3 * table.loc["SH", "stop_distance_m"]
    assert one.loc["SH", "collisions"] == 0 and one.loc["SH", "min_gap_m"] >= 4.0 - 0.05
