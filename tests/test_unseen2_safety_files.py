"""Tier 2 — the safety campaign on a user's own line and trains, given as files (found trying
vcsumo on lines nobody tuned for): ``vcsumo study safety --lines my_line.yaml --rolling-stock
my_train.yaml`` failed every run ("unknown line 'my_line'", "unknown train 'emu'"): each scenario
kept the line's *name* and its default train's *name*, and the run loaded them by name."""

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write

pytestmark = pytest.mark.sumo

LINE = """
name: suburb
km_start: 0.0
km_end: 8.0
line_speed_kmh: 100
default_train: emu.yaml
stations:
  - {id: AA, name: Aa, km: 0.3, platform_length_m: 150}
  - {id: BB, name: Bb, km: 4.0, platform_length_m: 150}
  - {id: CC, name: Cc, km: 7.7, platform_length_m: 150}
gradients:
  - {from_km: 2.0, to_km: 3.5, permille: 12.0}
signalling: {block_length_m: 1000}
"""
EMU = """
name: emu
length_m: 60.0
mass_kg: 120000.0
rotating_mass_factor: 1.08
max_speed_kmh: 100.0
max_traction_n: 150000.0
max_power_w: 1500000.0
davis_a_n: 2000.0
davis_b_n_per_mps: 25.0
davis_c_n_per_mps2: 3.0
service_brake_decel_mps2: 0.9
emergency_brake_decel_mps2: 1.3
max_jerk_mps3: 1.0
traction_lag_s: 0.3
"""


@pytest.mark.parametrize("heterogeneous", ["0", "1"])
def test_safety_campaign_on_a_line_file_and_train_files(in_tmp, capsys, heterogeneous):
    write(in_tmp / "suburb.yaml", LINE)
    write(in_tmp / "emu.yaml", EMU)
    code = main(["study", "safety", "--scenarios", "2", "--lines", "suburb.yaml", "--controllers", "cbc", "--rolling-stock", str(in_tmp / "emu.yaml") + ",regional_emu160",
                 "--heterogeneous-probability", heterogeneous, "--workers", "1", "--out", "s"])
    cap = capsys.readouterr()
    rows = pd.read_csv(in_tmp / "s" / "safety.csv")
    assert len(rows) == 2 and rows["error"].isna().all(), rows["error"].tolist()
    assert set(rows["line"]) == {"suburb.yaml"}
    if heterogeneous == "0":
        assert all(s.endswith("emu.yaml") for s in rows["leader_stock"])  # the line's train file
    # the runs ran: the monitor's rule measured (not skipped), and held
    assert (rows["separation_violations"] == 0).all() and (rows["collisions"] == 0).all()
    assert code == 0, cap.err
