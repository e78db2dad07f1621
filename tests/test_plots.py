"""The figures, drawn from real results tables of short runs on the Felez test track, checked on
their matplotlib objects: clock time and station names on the axes, signal marks, legends,
values and gains on bars, failed and unhealthy cases marked, zoomed punctuality, visible zeros."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.lines import Line2D

from vcsumo.cli.main import main
from vcsumo.plots.batch import plot_punctuality, zoomed_percent_range
from vcsumo.plots.capacity import plot_capacity, plot_time_distance_stairs
from vcsumo.plots.charts import plot_run
from vcsumo.plots.common import train_styles
from vcsumo.plots.safety import plot_safety, share_text

from .conftest import write

pytestmark = pytest.mark.sumo


def texts(fig) -> list[str]:
    out = [t.get_text() for t in fig.texts]
    for ax in fig.axes:
        out += [t.get_text() for t in ax.texts]
    return out


def tick_labels(axis) -> list[str]:
    return [t.get_text() for t in axis.get_ticklabels()]


def legend_labels(fig) -> list[str]:
    return [t.get_text() for lg in fig.legends + [ax.get_legend() for ax in fig.axes if ax.get_legend()] for t in lg.get_texts()]


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    """A run (3 trains), a 24-train run, a capacity study with VC and a batch, all on felez_test, and a
    3-scenario safety campaign."""
    base = tmp_path_factory.mktemp("plots")
    assert main(["-q", "run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", str(base / "run")]) == 0
    tt = write(base / "many.yaml", "name: many\nline: felez_test\nservices:\n"
               "  - {id: T, train: felez2019, origin: ORIG, destination: STOP, departure: 0, repeat: {count: 24, every_s: 60}}\n")
    assert main(["-q", "run", "--line", "felez_test", "--timetable", str(tt), "--regime", "mb", "--out", str(base / "many")]) == 0
    assert main(["-q", "study", "capacity", "--line", "felez_test", "--controllers", "cbc", "--convoy-sizes", "1,2", "--directions", "up",
                 "--patterns", "non-stop", "--workers", "1", "--out", str(base / "cap")]) == 0
    assert main(["-q", "batch", "--line", "felez_test", "--timetables", "convoy", "--regimes", "fbs,mb", "--seeds", "2", "--workers", "1",
                 "--out", str(base / "batch")]) == 0
    assert main(["-q", "study", "safety", "--scenarios", "3", "--controllers", "cbc,cbf-cbc", "--workers", "1", "--out", str(base / "safety")]) == 0
    return base


def test_infrastructure_table_of_a_run(results):
    infra = pd.read_csv(results / "run" / "infrastructure.csv", keep_default_na=False)
    assert list(infra.columns) == ["kind", "id", "name", "section", "km", "track", "direction"]
    st = infra[infra.kind == "station"].set_index("id")
    assert st.loc["ORIG", "name"] == "Origin" and st.loc["STOP", "km"] == pytest.approx(3.6)
    up = infra[(infra.kind == "signal") & (infra.direction == "up")].km.tolist()
    # 500 m blocks and the platform exits (0.2 and 3.7 km) on the 5 km up track
    assert {0.275, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.7, 4.0, 4.5} <= set(np.round(up, 3))


def test_run_plot_has_clock_time_station_names_signals_and_a_legend(results, tmp_path):
    fig = plot_run(results / "run" / "trajectories.csv", tmp_path / "td.png", "felez_test test fbs", results / "run" / "infrastructure.csv")
    assert (tmp_path / "td.png").stat().st_size > 10_000
    td = fig.axes[0]
    names = tick_labels(td.yaxis)
    assert "Origin" in names and "Stop at 3700 m" in names
    clock = [t for t in tick_labels(td.xaxis) if t]
    assert clock and all(re.fullmatch(r"\d\d:\d\d", t) for t in clock) and "00:02" in clock
    infra = pd.read_csv(results / "run" / "infrastructure.csv")
    up = infra[(infra.kind == "signal") & (infra.direction == "up")].km.to_numpy()
    marks = [ln for ln in td.lines if ln.get_label() == "signal (up)"]
    lo, hi = sorted(td.get_ylim())
    assert len(marks) == 1 and sorted(marks[0].get_ydata()) == pytest.approx(sorted(up[(up >= lo) & (up <= hi)]))
    assert not [ln for ln in td.lines if ln.get_label() == "signal (down)"]  # only up trains ran
    assert fig.legends and legend_labels(fig)[:3] == ["T.1", "T.2", "T.3"] and "signal (up)" in legend_labels(fig)


def test_run_plot_of_24_trains_keeps_them_apart(results, tmp_path):
    fig = plot_run(results / "many" / "trajectories.csv", tmp_path / "td.png", "many", results / "many" / "infrastructure.csv")
    td = fig.axes[0]
    trains = [ln for ln in td.lines if ln.get_label().startswith("T.")]
    assert len(trains) == 24
    assert len({(tuple(ln.get_color()), ln.get_linestyle()) for ln in trains}) == 24
    labels = legend_labels(fig)
    assert len([x for x in labels if x.startswith("T.")]) == 24
    # the legend is outside the axes
    fig.canvas.draw()
    assert fig.legends[0].get_window_extent().x0 >= td.get_window_extent().x1


def test_train_styles_group_services_and_stay_distinct():
    styles, labels = train_styles([f"S{k}.{i}" for i in range(1, 41) for k in range(3)])
    assert len({s["color"] for s in styles.values()}) == 3 and len(labels) == 3 and labels["S0.1"] == "S0 (40 trains)"
    styles, labels = train_styles([f"X{i}" for i in range(200)])
    assert len({(s["color"], s["ls"]) for s in styles.values()}) == 80 and len(labels) == 200


def test_capacity_chart_values_gain_failed_and_unhealthy(results, tmp_path):
    cap = pd.read_csv(results / "cap" / "capacity.csv", dtype={"error": str, "controller": str})
    fig = plot_capacity(results / "cap" / "capacity.csv", tmp_path / "cap.png")
    t = texts(fig)
    fbs, mb, vc2 = (cap.loc[(cap.regime == r) & (cap.convoy_size == n), ["capacity_trains_per_h", "gain_vs_fbs"]].iloc[0] for r, n in
                    (("fbs", 1), ("mb", 1), ("vc", 2)))
    assert f"{fbs.capacity_trains_per_h:.0f}" in t
    assert f"{mb.capacity_trains_per_h:.0f}\n×{mb.gain_vs_fbs:.2f}" in t and f"{vc2.capacity_trains_per_h:.0f}\n×{vc2.gain_vs_fbs:.2f}" in t
    assert "VC cbc" in t and "n=2" in tick_labels(fig.axes[0].xaxis)
    assert "failed" not in t and not any("unhealthy" in x for x in t)
    # a failed VC case (its real row, with an error) and an unhealthy MB row
    bad = cap[(cap.regime == "vc") & (cap.convoy_size == 2)].copy()
    bad[["capacity_trains_per_h", "gain_vs_fbs", "headway_sim_s"]] = np.nan
    bad["convoy_size"], bad["error"] = 3, "SumoError: SUMO failed during the simulation"
    both = pd.concat([cap, bad], ignore_index=True)
    both["healthy"] = both.regime != "mb"
    fig = plot_capacity(both, tmp_path / "cap2.png")
    t = texts(fig)
    assert "failed" in t and any(x.startswith("unhealthy\n") for x in t)
    assert "n=3" in tick_labels(fig.axes[0].xaxis)
    assert {"failed (no result)", "unhealthy (not clean)"} <= set(legend_labels(fig))


def test_capacity_time_distance_has_legend_signals_and_keeps_a_failed_vc_panel(results, tmp_path):
    td = pd.read_csv(results / "cap" / "time_distance.csv", keep_default_na=False)
    assert set(td.regime) == {"fbs", "mb", "vc"} and {"block", "band", "schedule", "train"} <= set(td.kind)
    fig = plot_time_distance_stairs(results / "cap" / "time_distance.csv", tmp_path / "td.png", "felez_test", results / "cap" / "infrastructure.csv")
    assert len(fig.axes) >= 3 and "signals (▲ up, ▼ down)" in legend_labels(fig) and "simulated trains" in legend_labels(fig)
    fbs = fig.axes[0]
    assert "Stop at 3700 m" in tick_labels(fbs.yaxis)
    marks = [ln for ln in fbs.lines if ln.get_label() == "signal (up)"]
    blocks = td[(td.regime == "fbs") & (td.kind == "block")]
    # FBS blocks begin and end at signals (the last one at the end of the track)
    edges = set(np.round(pd.concat([pd.to_numeric(blocks.km_from), pd.to_numeric(blocks.km_to)]), 3)) - {5.0}
    assert marks and len(edges) >= 6 and edges <= set(np.round(marks[0].get_ydata(), 3))
    # the largest convoy failed: its panel stays, with the error
    failed = td[td.regime != "vc"].copy()
    row = dict(td[td.regime == "vc"].iloc[0])
    row.update(kind="failed", note="SumoError: SUMO failed during the simulation after t = 120 s", t_from_s="", t_to_s="", km_from="", km_to="")
    failed = pd.concat([failed, pd.DataFrame([row])], ignore_index=True)
    fig = plot_time_distance_stairs(failed, tmp_path / "td2.png", "felez_test", results / "cap" / "infrastructure.csv")
    titles = [ax.get_title() for ax in fig.axes]
    assert any("VC cbc n=2 — failed" in x for x in titles) and titles.index(next(x for x in titles if "failed" in x)) == 2
    assert any("SUMO failed during the simulation" in x for x in texts(fig))


def test_moving_block_band_is_the_separation_models_reservation(results):
    """The MB band of the time–distance figure at a point lasts from the time the leader's reservation
    (its supervised braking distance + margin and position errors) reaches it until its rear has
    passed (a VC convoy's last train at the coupled spacing the analytic headway takes): its longest
    is the analytic MB / VC headway of capacity.csv less the position-report period and the fixed
    time the headway adds (until 2026-11-28 the band took the nominal service brake and 50 m, and a
    convoy's median gap in the run: MB 17.9 s against 27.3 s on the Felez track, VC n=2 31.8 s against
    41.3 s — a figure that did not show the table's headway)."""
    from vcsumo.signalling.assumptions import load_assumptions

    sets = load_assumptions()
    td = pd.read_csv(results / "cap" / "time_distance.csv", keep_default_na=False)
    cap = pd.read_csv(results / "cap" / "capacity.csv")
    for regime, size in (("mb", 1), ("vc", 2)):
        band = td[(td.regime == regime) & (td.kind == "band") & (td.unit == 0)]
        longest = float((pd.to_numeric(band.t_to_s) - pd.to_numeric(band.t_from_s)).max())
        analytic = float(cap.loc[(cap.regime == regime) & (cap.convoy_size == size), "headway_analytic_s"].iloc[0])
        assert longest == pytest.approx(analytic - sets.position_report_period_s - sets.fixed_time_s, abs=0.2), regime


def test_reservation_reaches_a_point_braking_distance_and_margin_ahead_of_the_front():
    """Tier 1, constant speed: the reservation reaches x when the front is D(v) + margin before it."""
    from vcsumo.signalling.blocking_time import BrakingRule, mb_headway_profile
    from vcsumo.studies.time_distance import reserved_from

    v, rule, margin = 50.0, BrakingRule(0.5, 2.0), 80.0
    t = np.arange(0.0, 200.0, 0.5)
    run = pd.DataFrame({"time_s": t, "s_m": v * t, "speed_mps": np.full_like(t, v)})
    reserved = mb_headway_profile(run, 200.0, rule, margin_m=margin)[["s_m", "reserved_to_m"]]
    ahead = v * v / 1.0 + 2.0 * v + margin  # 2,680 m
    x = run.s_m.to_numpy()
    expected = np.where(x > ahead, (x - ahead) / v, 0.0)
    assert np.allclose(reserved_from(reserved, run), expected, atol=1e-6)


def test_time_distance_table_of_a_failed_case():
    from vcsumo.studies.capacity import Case
    from vcsumo.studies.time_distance import TIME_DISTANCE_COLUMNS, time_distance_table

    df = time_distance_table({}, {}, failed={"vc": (Case("up", "vc", "cbc", 4, "non-stop"), "boom")})
    assert list(df.columns) == TIME_DISTANCE_COLUMNS and df.kind.tolist() == ["failed"] and df.note.tolist() == ["boom"]


def test_punctuality_axis_is_zoomed_and_the_legend_is_outside(results, tmp_path):
    runs = pd.read_csv(results / "batch" / "report" / "batch_runs.csv")
    fig = plot_punctuality(results / "batch" / "report" / "batch_runs.csv", tmp_path / "p.png")
    ax = fig.axes[0]
    shares = 100 * runs[["punctuality_3min_share", "punctuality_5min_share"]].to_numpy()
    lo, hi = ax.get_ylim()
    assert lo <= shares.min() and (lo > 0) == (shares.min() >= 55) and hi > 100
    assert fig.legends and not ax.get_legend()
    fig.canvas.draw()
    assert fig.legends[0].get_window_extent().y0 >= ax.get_window_extent().y1 - 1
    mb = runs[runs.regime == "mb"]
    assert f"{100 * mb.punctuality_3min_share.mean():.1f}" in texts(fig) and f"{100 * mb.punctuality_5min_share.mean():.1f}" in texts(fig)
    assert "failed" not in texts(fig)
    # a group whose runs all failed keeps its place, marked
    failed = runs[runs.regime == "mb"].copy()
    failed["regime"], failed["controller"], failed["status"], failed["error"] = "vc", "cbc", "failed", "SumoError: boom"
    failed[["punctuality_3min_share", "punctuality_5min_share"]] = np.nan
    pd.concat([runs, failed]).to_csv(tmp_path / "runs.csv", index=False)
    fig = plot_punctuality(tmp_path / "runs.csv", tmp_path / "p2.png")
    assert "failed" in texts(fig) and any("vc\ncbc\n(0 of 2 runs)" in t for t in tick_labels(fig.axes[0].xaxis))


def test_zoomed_percent_range():
    assert zoomed_percent_range(np.array([93.0, 95.5, 98.0]))[0] == 90.0
    assert zoomed_percent_range(np.array([40.0, 100.0]))[0] == 0.0
    assert zoomed_percent_range(np.array([100.0, 100.0])) == pytest.approx((95.0, 100.6))


def test_safety_chart_shows_a_zero_share(results, tmp_path):
    runs = pd.read_csv(results / "safety" / "report" / "safety_runs.csv", dtype={"error": str}, keep_default_na=False)
    fig = plot_safety(results / "safety" / "report" / "safety_runs.csv", tmp_path / "s.png")
    ax2 = fig.axes[1]
    labels = [t.get_text() for t in ax2.texts]
    shares = [float((runs.loc[runs.controller == c, col] > 0).mean()) for col in ("separation_violations", "collisions") for c in ("cbc", "cbf-cbc")]
    assert shares[1] == 0 and shares[3] == 0  # the CBF-supervised controller: no violation, no collision
    assert sorted(labels) == sorted(share_text(v) for v in shares) and labels.count("0") == shares.count(0.0)
    zeros = [ln for ln in ax2.lines if isinstance(ln, Line2D) and list(ln.get_ydata()) == [0.0]]
    assert len(zeros) == shares.count(0.0)
