"""``vcsumo lines`` with a bad train file in ``$VCSUMO_HOME``: its errors alone, nothing listed.

Found by unseen-studies (2026-12-01): a home folder with three good lines and a train file whose
``uncertainty`` gave only ``mass_kg`` printed the three lines and the three train types read before
it, then six ``error:`` lines (one per missing interval) and exit status 2 — a listing cut off in
the middle, the errors after it.  Every file is now read before anything is printed.
"""

from __future__ import annotations

import shutil

from tests.conftest import DATA, write
from vcsumo.cli.main import main

LINE = """name: one
km_start: 0.0
km_end: 5.0
line_speed_kmh: 120
stations:
  - {id: AAA, name: Ashby, km: 4.5, platform_length_m: 200}
signalling: {block_length_m: 1500}
"""

BAD = """name: zz_heavy
length_m: 500.0
mass_kg: 1500000.0
rotating_mass_factor: 1.06
max_speed_kmh: 80.0
max_traction_n: 300000.0
max_power_w: 4000000.0
davis_a_n: 15000.0
davis_b_n_per_mps: 300.0
davis_c_n_per_mps2: 15.0
service_brake_decel_mps2: 0.35
emergency_brake_decel_mps2: 0.55
uncertainty:
  mass_kg: {low: 1400000.0, high: 1600000.0}
"""


def test_a_bad_train_file_gives_its_errors_alone(in_tmp, monkeypatch, capsys):
    home = in_tmp / "home"
    write(home / "networks" / "one" / "line.yaml", LINE)
    shutil.copytree(DATA / "networks" / "rolling_stock", home / "networks" / "rolling_stock")
    monkeypatch.setenv("VCSUMO_HOME", str(home))
    assert main(["lines"]) == 0
    assert "one:" in capsys.readouterr().out
    write(home / "networks" / "rolling_stock" / "zz_heavy.yaml", BAD)  # listed last: every other file is read before it
    assert main(["lines"]) == 2
    cap = capsys.readouterr()
    assert cap.out.strip() == "", cap.out  # nothing listed
    errors = [x for x in cap.err.splitlines() if x.strip()]
    assert errors and all(x.startswith("error: ") and "zz_heavy.yaml: uncertainty." in x for x in errors), errors
