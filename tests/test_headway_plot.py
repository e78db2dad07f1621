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
    assert {t.get_text() for t in ax.get_legend().get_texts()} == {f"{r} regional_emu160 {k}" for r in ("FBS", "MB") for k in ("simulated", "analytic")}
