"""The capacity study's gain over FBS is quoted only between rows shown safe.

Found by unseen-studies (2026-12-01): ``gain_vs_fbs`` was capacity / FBS capacity whatever the health
of either row, so a healthy VC row read "×1.9" over an FBS capacity measured in a run that was not
healthy (the FBS row said so; the VC row, its bar and its label looked clean), and an unhealthy row
carried its gain like any other.  Now the gain is NaN unless both rows finished and are healthy.
"""

from __future__ import annotations

import math

import pandas as pd
import pytest

from vcsumo.cli.main import main
from vcsumo.studies.capacity_gain import gains_vs_fbs


def _rows(fbs_healthy: bool, vc_healthy: bool) -> pd.DataFrame:
    base = dict(direction="up", stopping_pattern="non-stop", error="")
    return pd.DataFrame([dict(base, regime="fbs", convoy_size=1, capacity_trains_per_h=20.0, healthy=fbs_healthy),
                         dict(base, regime="mb", convoy_size=1, capacity_trains_per_h=30.0, healthy=True),
                         dict(base, regime="vc", convoy_size=2, capacity_trains_per_h=40.0, healthy=vc_healthy)])


def test_gain_only_between_healthy_rows():
    assert gains_vs_fbs(_rows(True, True)).tolist() == [1.0, 1.5, 2.0]
    assert all(math.isnan(g) for g in gains_vs_fbs(_rows(False, True)))  # no FBS result shown safe: no gain at all
    g = gains_vs_fbs(_rows(True, False))
    assert g.tolist()[:2] == [1.0, 1.5] and math.isnan(g.iloc[2])
    text = _rows(True, True).astype({"healthy": str})  # as read back from a CSV
    assert gains_vs_fbs(text).tolist() == [1.0, 1.5, 2.0]
    failed = _rows(True, True)
    failed.loc[0, "error"] = "SumoError: SUMO failed"
    assert all(math.isnan(x) for x in gains_vs_fbs(failed))


@pytest.mark.sumo
def test_a_study_whose_fbs_case_is_not_healthy_quotes_no_gain(in_tmp):
    args = ["-q", "study", "capacity", "--line", "felez_test", "--controllers", "cbc", "--convoy-sizes", "2", "--directions", "up",
            "--patterns", "non-stop", "--workers", "1", "--out", "o"]
    assert main(args) == 0
    cap = pd.read_csv(in_tmp / "o" / "capacity.csv")
    assert (cap.gain_vs_fbs > 0).all() and cap.healthy.all()
    # the FBS case's stored row as an unhealthy run leaves it (a gap violation): the study, resumed, rebuilds its table
    store = in_tmp / "o" / "capacity_cases.csv"
    cases = pd.read_csv(store, dtype=str, keep_default_na=False)
    fbs = cases.regime == "fbs"
    cases.loc[fbs, "healthy"], cases.loc[fbs, "gap_violations"] = "False", "1"
    cases.to_csv(store, index=False)
    assert main(args) == 1  # not clean: the FBS row is not healthy
    cap = pd.read_csv(in_tmp / "o" / "capacity.csv")
    assert cap.gain_vs_fbs.isna().all(), cap[["regime", "healthy", "gain_vs_fbs"]]
    assert cap[cap.regime != "fbs"].healthy.all() and cap.capacity_trains_per_h.notna().all()
