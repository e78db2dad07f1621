"""Counted words in the terminal output agree with their number (unseen9, 2026-11-28).

``vcsumo lines`` on a VCSUMO_HOME of our own said "1 stations, 0 branches" and "1 branches"; a
capacity table with one column left out said "1 more column (headway_analytic_s) are in ...".
"""

from __future__ import annotations

import pandas as pd

from tests.conftest import DATA, write
from vcsumo.cli.main import main
from vcsumo.cli.ui import build_table


def test_one_column_left_out_is_said_in_the_singular():
    df = pd.DataFrame({"a_long_column_name_s": [1.0], "another_long_column_m": [2.0]})
    _table, notes = build_table(df, "t", width=12, csv_path="o/x.csv")
    assert notes == ["1 more column (another_long_column_m) is in o/x.csv"]


def test_lines_counts_stations_and_branches_in_words(tmp_path, monkeypatch, capsys):
    import shutil

    home = tmp_path / "home"
    write(home / "networks" / "one" / "line.yaml", """name: one
km_start: 0.0
km_end: 5.0
line_speed_kmh: 120
stations:
  - {id: AAA, name: Ashby, km: 4.5, platform_length_m: 200}
signalling: {block_length_m: 1500}
branches:
  - {id: spur, name: Spur, junction_km: 2.0, leaves_towards: end, length_m: 2000, speed_kmh: 80, diverging_speed_kmh: 40}
""")
    shutil.copytree(DATA / "networks" / "rolling_stock", home / "networks" / "rolling_stock")
    monkeypatch.setenv("VCSUMO_HOME", str(home))
    assert main(["lines"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "1 station, 1 branch)" in out


def test_safety_and_batch_tables_name_the_csv_of_a_column_left_out(in_tmp, monkeypatch, capsys):
    """At 100 columns the safety table left out time_lost_s_mean and the batch table uic406_cyc_% and
    collisions, saying only "are left out": the README promises the CSV that holds them is named."""
    monkeypatch.setenv("COLUMNS", "100")
    assert main(["-q", "study", "safety", "--scenarios", "2", "--controllers", "cbc,cbf-cbc", "--workers", "1", "--out", "s"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "left out" not in out and "is in s/report/safety_summary.csv" in out
    assert main(["-q", "batch", "--line", "felez_test", "--timetables", "base", "--regimes", "fbs", "--seeds", "1", "--workers", "1", "--out", "b"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "left out" not in out and "are in b/report/batch_summary.csv" in out


def test_build_network_says_wrote_only_when_it_built(in_tmp, capsys):
    """'vcsumo build-network' printed 'wrote <cache>/line.net.xml' also when it reused the cached network."""
    line = write(in_tmp / "l" / "line.yaml", """name: cached_u9
km_start: 0.0
km_end: 4.0
line_speed_kmh: 120
stations:
  - {id: AAA, name: Ashby, km: 3.5, platform_length_m: 200}
signalling: {block_length_m: 1500}
""")
    assert main(["build-network", "--line", str(line), "--force"]) == 0
    out = capsys.readouterr().out
    assert "wrote " in out and "reused" not in out
    assert main(["build-network", "--line", str(line)]) == 0
    out = capsys.readouterr().out
    assert "wrote " not in out and out.count("reused (cached) ") == 2
