"""Bad values in an assumption set or a rolling-stock file: exit 2, one line naming the file and the
field, no results folder.

Found by unseen7 (2026-11-28): a number written as a YAML boolean loaded silently — ``overlap_m: true``
as a 1 m overlap, ``traction_lag_s: on`` as 1 s, and ``overlap_m: off`` (YAML 1.1 reads on/off/yes/no as
booleans) as no overlap at all — and the run went on with it (exit 0, healthy).  Booleans are now
refused wherever a field takes no boolean.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import write
from vcsumo.cli.main import main

ROOT = Path(__file__).resolve().parent.parent
ASSUMPTIONS = (ROOT / "vcsumo" / "data" / "assumptions" / "etcs_typical.yaml").read_text()
STOCK = (ROOT / "vcsumo" / "data" / "networks" / "rolling_stock" / "felez2019.yaml").read_text()


def _run(in_tmp, assumptions: str | None = None, stock: str | None = None) -> int:
    args = ["run", "--line", "felez_test", "--regime", "fbs", "--out", "r"]
    if assumptions is not None:
        write(in_tmp / "set.yaml", assumptions)
        args += ["--assumptions", "set.yaml"]
    if stock is not None:
        write(in_tmp / "train.yaml", stock)
        write(in_tmp / "tt.yaml", "name: tt\nline: felez_test\nservices:\n  - {id: T, train: train.yaml, origin: ORIG, destination: STOP, departure: 0}\n")
        args += ["--timetable", "tt.yaml"]
    else:
        args += ["--timetable", "test"]
    return main(args)


@pytest.mark.parametrize("old, new, field", [
    ("overlap_m: 50.0", "overlap_m: true", "overlap_m"),
    ("overlap_m: 50.0", "overlap_m: off", "overlap_m"),
    ("position_error_m: 10.0", "position_error_m: -5", "position_error_m"),
    ("reaction_time_s: 0.5", "reaction_time_s: .nan", "reaction_time_s"),
    ("safety_margin_m: 50.0\n", "", "safety_margin_m"),
    ("position_report_period_s: 2.0", "position_report_period_s: 2000", "position_report_period_s"),
])
def test_a_bad_assumption_set_is_one_error_line_and_nothing_written(in_tmp, capsys, old, new, field):
    assert old in ASSUMPTIONS
    assert _run(in_tmp, assumptions=ASSUMPTIONS.replace(old, new)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: set.yaml: " + field + ":"), err
    assert not list(in_tmp.glob("r*"))


@pytest.mark.parametrize("old, new, field", [
    ("traction_lag_s: 0.25", "traction_lag_s: on", "traction_lag_s"),
    ("max_jerk_mps3: 0.98", "max_jerk_mps3: yes", "max_jerk_mps3"),
    ("mass_kg: 160800.0", "mass_kg: -160800", "mass_kg"),
    ("davis_b_n_per_mps: 633.6", "davis_b_n_per_mps: .nan", "davis_b_n_per_mps"),
    # a power in kW (1,200 for 1.2 MW): 0.0075 W/kg; the train crawled at 0.13 m/s and the run failed 1.4 h later
    ("max_power_w: 1200000.0", "max_power_w: 1200", "max_power_w"),
])
def test_a_bad_rolling_stock_file_is_one_error_line_and_nothing_written(in_tmp, capsys, old, new, field):
    assert old in STOCK
    assert _run(in_tmp, stock=STOCK.replace(old, new)) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert err.startswith("error: ") and "train.yaml: " + field + ":" in err, err
    assert not list(in_tmp.glob("r*"))
