"""The headway study at a coarse SUMO step: a start delayed by SUMO's insertion at the next step is
no hindrance (as in the capacity study, tests/test_unseen7_capacity_coarse_step.py).

Noticed by unseen7 (2026-11-28), fixed by the lead: ``vcsumo study headway --step-length 1.0`` on a
steep line of our own (600 m freight) gave simulated headways 12.7–44.5 % above blocking-time theory
(up 156.0 / 258.0 s against 111.6 / 178.5 s, down 193.0 / 192.0 s against 171.2 / 145.4 s) while the
0.5 s step agrees within 0.2 %: every probe whose second train SUMO inserted 0.99 s after its release
was judged hindered, so the bisection climbed.  Now within 0.9 % at 1.0 s.
"""

from __future__ import annotations

import pandas as pd

from tests.conftest import write
from tests.test_unseen7_capacity_health_columns import FREIGHT, LINE
from vcsumo.cli.main import main


def test_fbs_headway_at_a_one_second_step_agrees_with_theory(in_tmp):
    write(in_tmp / "line.yaml", LINE)
    write(in_tmp / "freight.yaml", FREIGHT)
    assert main(["study", "headway", "--line", "line.yaml", "--regime", "fbs", "--step-length", "1.0", "--out", "o"]) == 0
    rows = pd.read_csv(in_tmp / "o" / "headway.csv")
    assert len(rows) == 4 and rows["headway_sim_s"].notna().all()
    # within 2 % of blocking-time theory (0.5 s step: -0.13 … +0.20 %); the old rule gave +12.7 … +44.5 %
    assert (rows["deviation_pct"].abs() < 2.0).all(), rows[["direction", "measuring_point_km", "headway_sim_s", "headway_analytic_s"]]
