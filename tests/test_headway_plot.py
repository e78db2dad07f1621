"""The headway study's plot reads as the other distance plots: station names along the km axis (from
the study's own infrastructure.csv), FBS / MB in capitals, the direction's label in the title.
Before, bare km ticks, 'fbs' / 'mb' and the direction id only (noticed by unseen9)."""

from __future__ import annotations

import pandas as pd

from vcsumo.infrastructure import infrastructure_table
from vcsumo.line import load_line
from vcsumo.plots.charts import plot_headway
from vcsumo.sim.network import build_network


def test_headway_plot_names_the_stations_on_its_distance_axis(tmp_path):
    line = load_line("regional_graded")
    infra = infrastructure_table(build_network(line).topology)
    df = pd.DataFrame([{"line": "regional_graded", "direction": "up", "regime": r, "train": "regional_emu160", "measuring_point_km": k,
                        "headway_sim_s": h, "headway_analytic_s": h + 0.5} for r, base in (("fbs", 90.0), ("mb", 45.0)) for k, h in ((10.0, base), (23.0, base + 20))])
    fig = plot_headway(df, tmp_path / "h.png", infra, {"up": line.direction_label("up")})
    assert (tmp_path / "h.png").stat().st_size > 10_000
    ax = fig.axes[0]
    top = ax.child_axes  # the secondary (station) axis
    names = {t.get_text() for a in top for t in a.get_xticklabels()}
    assert {"Castleford", "Dunmore"} <= names, names
    assert ax.get_title() == "regional_graded — up: Alder -> Glenrock"
    assert {t.get_text() for t in fig.legends[0].get_texts()} == {f"{r} regional_emu160 {k}" for r in ("FBS", "MB") for k in ("simulated", "analytic")}


def test_the_legend_hides_no_data(tmp_path):
    """Found by unseen-studies (2026-12-01): two trains on a line of our own (``mixed``: heavy1500 and
    light_fast, FBS and MB, three points per direction; the figures below are its headway.csv) — the
    down panel's legend, placed inside the axes, lay over the FBS heavy1500 line between km 12 and 25.
    Now one legend below the panels, outside every axes."""
    rows = []
    for d, fbs_h, fbs_l, mb_h, mb_l in (("up", (156.5, 180.0, 180.0), (77.5, 83.5, 83.5), (68.1, 91.5, 91.5), (43.5, 49.0, 49.0)),
                                        ("down", (169.5, 156.5, 156.5), (82.5, 77.5, 77.5), (81.0, 68.5, 68.1), (47.0, 43.5, 43.5))):
        for regime, train, hs in (("fbs", "heavy1500", fbs_h), ("fbs", "light_fast", fbs_l), ("mb", "heavy1500", mb_h), ("mb", "light_fast", mb_l)):
            rows += [{"line": "mixed", "direction": d, "regime": regime, "train": train, "measuring_point_km": k, "headway_sim_s": h,
                      "headway_analytic_s": h + 0.5} for k, h in zip((12.0, 25.0, 40.0), hs)]
    fig = plot_headway(pd.DataFrame(rows), tmp_path / "h.png")
    assert len(fig.legends) == 1 and len(fig.legends[0].get_texts()) == 8
    assert all(ax.get_legend() is None for ax in fig.axes)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)  # (the figure comes back closed: draw it again, as saved)
    canvas.draw()
    renderer = canvas.get_renderer()
    box = fig.legends[0].get_window_extent(renderer)
    for ax in fig.axes:
        assert not box.overlaps(ax.get_window_extent(renderer)), "the legend lies over a panel"
