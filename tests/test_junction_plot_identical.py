"""Junction figures: two VC controllers whose runs are identical (cbc and a CBF that never
intervened — every case of the shipped lines since the CBF takes the set's leader brake) are drawn
once and labelled together; until 2026-11-28 the second hid the first and the figures seemed to have
lost cbc."""

from __future__ import annotations

import pandas as pd
from matplotlib import pyplot as plt

from vcsumo.plots import junction as jp

CBC, CBF, MPC = ("vc", "cbc", "braking-curve"), ("vc", "cbf-cbc", "braking-curve"), ("vc", "mpc", "braking-curve")


def test_identical_runs_are_grouped_with_the_first_and_different_ones_kept():
    runs = {CBC: pd.DataFrame({"offset_s": [0, 30], "follower_lost_END_s": [20.0, 5.0]}),
            CBF: pd.DataFrame({"offset_s": [0, 30], "follower_lost_END_s": [20.0, 5.0]}),
            MPC: pd.DataFrame({"offset_s": [0, 30], "follower_lost_END_s": [21.0, 5.0]})}
    assert jp.identical_variants(runs, ["offset_s", "follower_lost_END_s"]) == {CBC: [CBC, CBF], CBF: None, MPC: [MPC]}


def test_the_sweep_figure_names_identical_runs_together(tmp_path, monkeypatch):
    rows = []
    for regime, ctrl, lost in (("mb", "", [30.0, 10.0, 0.0]), ("vc", "cbc", [20.0, 5.0, 0.0]), ("vc", "cbf-cbc", [20.0, 5.0, 0.0])):
        for off, x in zip((0.0, 30.0, 60.0), lost):
            rows.append(dict(line="regional_graded", junction="hill", direction="down", leader_service="main", regime=regime, controller=ctrl,
                             junction_signal="braking-curve" if regime == "vc" else "", offset_s=off, follower_lost_END_s=x, healthy=True))
    path = tmp_path / "junction_sweep.csv"
    pd.DataFrame(rows).to_csv(path, index=False)
    figures = []
    monkeypatch.setattr(plt, "close", lambda fig=None: figures.append(fig))  # keep the figure to read its legend
    assert jp.plot_junction_sweep(path, tmp_path / "sweep.png").is_file()
    labels = [t.get_text() for ax in figures[0].axes if ax.get_legend() for t in ax.get_legend().get_texts()]
    vc = [x for x in labels if x.startswith("VC")]
    assert vc == ["VC cbc (braking-curve) = VC cbf-cbc (braking-curve) (identical runs) (route end)"]
