"""The speed panel of a network run's ``time_distance.png`` names the stations of the line it draws.

Found by unseen9 (2026-11-28): on a network of two lines of our own (vale_net: kestrel + heron) the
speed–distance panel below the graphical timetable had bare km ticks on its top axis and no station
lines: the station names were looked up on section ``main``, which a network does not have (its
sections are ``<line>.main``).  The time–distance panel above was right.
"""

from __future__ import annotations

import pandas as pd

from vcsumo.plots.charts import plot_run


def test_speed_panel_of_a_network_run_names_the_stations(tmp_path):
    rows = []
    for k in range(0, 501):  # one train up kestrel.main from km 0.4 to 8.0 at 15 m/s
        rows.append({"time_s": 28800.0 + k, "train": "T1", "section": "kestrel.main", "km": min(0.4 + 0.015 * k, 8.0), "s_m": 15.0 * k,
                     "speed_mps": 15.0, "accel_mps2": 0.0, "gap_m": None, "leader": None, "edge": "kestrel.main_up_1"})
    traj = pd.DataFrame(rows)
    infra = pd.DataFrame([
        {"kind": "station", "id": "ASH", "name": "Ashby", "section": "kestrel.main", "km": 0.4, "track": "", "direction": ""},
        {"kind": "station", "id": "BRM", "name": "Bramley", "section": "kestrel.main", "km": 5.0, "track": "", "direction": ""},
        {"kind": "station", "id": "HRN", "name": "Heronsgate", "section": "heron.main", "km": 8.5, "track": "", "direction": ""},
        {"kind": "junction", "id": "colwick_jn", "name": "Colwick Junction", "section": "kestrel.main", "km": 8.0, "track": "", "direction": ""},
    ])
    fig = plot_run(traj, tmp_path / "td.png", "network", infra)
    td, speed = fig.axes[0], fig.axes[1]
    assert {"Ashby", "Bramley"} <= {t.get_text() for t in td.get_yticklabels()}
    top = [t.get_text() for ax in speed.child_axes for t in ax.get_xticklabels()]
    assert {"Ashby", "Bramley"} <= set(top), top
    assert "Heronsgate" not in top  # another line's km
