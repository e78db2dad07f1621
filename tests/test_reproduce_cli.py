"""Tier 3 — `vcsumo reproduce` writes the papers' tables and figures (golden numbers with tolerance)."""

from pathlib import Path

import pandas as pd
import pytest

from vcsumo.cli.main import main


def test_reproduce_felez2019_mb_cli(in_tmp, capsys):
    assert main(["reproduce", "felez2019", "--strategies", "MB", "--no-sweep", "--no-convoy", "--out", "fz"]) == 0
    df = pd.read_csv("fz/felez2019.csv")
    assert {"strategy", "stop_distance_m", "stop_delay_s", "min_gap_m", "collisions"} <= set(df.columns)
    row = df.iloc[0]
    assert row.strategy == "MB" and row.collisions == 0
    # paper: 352.4 m and 23 s; bar 25 %
    assert row.stop_distance_m == pytest.approx(352.4, rel=0.25)
    assert row.min_gap_m >= 4.0 - 0.05
    assert Path("fz/felez2019.png").stat().st_size > 20_000 and Path("fz/felez2019_MB_trajectory.csv").is_file()


def test_reproduce_bad_strategy(in_tmp, capsys):
    assert main(["reproduce", "felez2019", "--strategies", "XX", "--out", "fz"]) == 2
    assert "unknown strategy" in capsys.readouterr().err and not Path("fz").exists()


def test_reproduce_terlizzi2024_os2_cli(in_tmp, capsys):
    assert main(["reproduce", "terlizzi2024", "--scenario", "os2", "--out", "tz"]) == 0
    df = pd.read_csv("tz/terlizzi2024_os2.csv").set_index("run")
    # fewer emergency brakings with the delay estimator; the true barrier never positive
    assert df.loc["os2_estimator_on", "emergency_activations"] < df.loc["os2_estimator_off", "emergency_activations"]
    assert (df.true_barrier_max <= 0).all()
    assert Path("tz/terlizzi2024_os2_estimator_on.png").stat().st_size > 20_000
