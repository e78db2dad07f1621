"""Tier 2/3 — headway study on every shipped line: SUMO vs blocking-time theory within 5 %, MB < FBS."""

import pandas as pd
import pytest

from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.studies.headway import HEADWAY_COLUMNS, run_headway_study

pytestmark = pytest.mark.sumo


@pytest.mark.parametrize("name", ["felez_test", "hcmc_line1", "firenze_bologna", "milano_bologna"])
def test_headway_agrees_with_blocking_time_theory(name, line_factory, network_factory, tmp_path):
    line = line_factory(name)
    net = network_factory(name)
    df = run_headway_study(line, net, [load_rolling_stock(line.data.default_train)], ["fbs", "mb"], tmp_path)
    assert list(df.columns) == HEADWAY_COLUMNS
    assert set(df.direction) == {"up", "down"}
    assert (df.headway_sim_s.notna()).all()
    dev = (df.headway_sim_s - df.headway_analytic_s).abs() / df.headway_analytic_s
    assert dev.max() < 0.05, df[["direction", "regime", "measuring_point_km", "headway_sim_s", "headway_analytic_s"]]
    fbs = df[df.regime == "fbs"].set_index(["direction", "measuring_point_km"]).headway_sim_s
    mb = df[df.regime == "mb"].set_index(["direction", "measuring_point_km"]).headway_sim_s
    assert (mb < fbs).all()
    assert (df.collisions == 0).all() and (df.gap_violations == 0).all()
    written = pd.read_csv(tmp_path / "headway.csv")
    assert len(written) == len(df) and (tmp_path / "headway.png").stat().st_size > 10_000


def test_longer_blocks_increase_fbs_headway_only(line_factory, network_factory, tmp_path):
    line = line_factory("firenze_bologna")
    stock = load_rolling_stock("etr1000")
    short = run_headway_study(line, network_factory("firenze_bologna"), [stock], ["fbs"], tmp_path / "a", points_km=[40.0], directions=("up",))
    long = run_headway_study(line, network_factory("firenze_bologna", 2700.0), [stock], ["fbs"], tmp_path / "b", points_km=[40.0], directions=("up",))
    # +1350 m of block: the blocking time grows by what theory says for the new critical block (about
    # +1350 m / 83 m/s on a uniform section; the signals move, so the critical block moves too)
    d_sim = long.headway_sim_s.iloc[0] - short.headway_sim_s.iloc[0]
    d_theory = long.headway_analytic_s.iloc[0] - short.headway_analytic_s.iloc[0]
    assert 5.0 < d_sim < 1350 / 82.9 + 2.0 and d_sim == pytest.approx(d_theory, abs=1.5)
