"""``vcsumo reproduce`` runs the papers' own (shipped) experiment files whatever ``$VCSUMO_HOME`` holds.

Found by unseen9 (2026-11-28): with ``VCSUMO_HOME`` set to a folder of our own lines (the README's
way of using one's own lines, timetables and trains by name), ``vcsumo reproduce felez2019`` stopped
at once with ``error: FILE: unknown experiment 'felez2019_sh' (shipped: kestrel_pair; ...)``: the
reproduction looked for the paper's experiment files, and the trains and controller parameters they
name, in the user's folder.
"""

from __future__ import annotations

import shutil

import pandas as pd

from tests.conftest import DATA, write
from vcsumo.cli.main import main


def test_reproduce_with_a_home_of_ones_own(in_tmp, monkeypatch):
    home = in_tmp / "home"
    write(home / "networks" / "one" / "line.yaml", """name: one
km_start: 0.0
km_end: 5.0
line_speed_kmh: 120
stations:
  - {id: AAA, name: Ashby, km: 4.5, platform_length_m: 200}
signalling: {block_length_m: 1500}
""")
    shutil.copytree(DATA / "networks" / "rolling_stock", home / "networks" / "rolling_stock", ignore=shutil.ignore_patterns("felez*"))
    monkeypatch.setenv("VCSUMO_HOME", str(home))
    rc = main(["reproduce", "felez2019", "--strategies", "MB", "--no-sweep", "--no-convoy", "-q", "--out", "o"])
    assert rc == 0
    table = pd.read_csv(in_tmp / "o" / "felez2019.csv")
    assert set(table.strategy) == {"MB"} and (table.collisions == 0).all()
    from vcsumo.line import project_root

    assert project_root() == home.resolve()  # the user's folder again after the command
