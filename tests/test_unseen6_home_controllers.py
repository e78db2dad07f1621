"""Sixth round of unseen inputs — a user's own data folder (``VCSUMO_HOME``) with a line, a train, a
timetable and the assumption set, but no ``controllers/``.

Defect found (message): ``vcsumo run --regime vc --controller cbc`` said "controller parameter set
'cbc' not found (available: ; or a path to a .yaml file)" — an empty list; now it says where it
looked: "(available: none in <VCSUMO_HOME>/controllers; …)"."""

import pytest

from vcsumo.cli.main import main

from .conftest import DATA, write
from .test_unseen6_junction_fouling import DMU
from .test_unseen6_network_markers import DALE

TT = """name: pair
line: dale
services:
  - {id: A, train: dmu90, origin: ASH, destination: YEW, departure: "07:00"}
  - {id: B, train: dmu90, origin: ASH, destination: YEW, departure: "07:00:30"}
convoys:
  - {id: K, services: [A, B]}
"""


def test_a_home_without_controllers_says_where_it_looked(in_tmp, capsys, monkeypatch):
    home = in_tmp / "home"
    write(home / "networks" / "rolling_stock" / "dmu90.yaml", DMU)
    write(home / "networks" / "dale" / "line.yaml", DALE.replace("default_train: dmu90.yaml", "default_train: dmu90"))
    write(home / "routes" / "dale" / "pair.yaml", TT)
    write(home / "assumptions" / "etcs_typical.yaml", (DATA / "assumptions" / "etcs_typical.yaml").read_text())
    monkeypatch.setenv("VCSUMO_HOME", str(home))
    code = main(["run", "--line", "dale", "--timetable", "pair", "--regime", "vc", "--controller", "cbc", "--out", "r"])
    err = capsys.readouterr().err
    assert code == 2
    assert f"(available: none in {home / 'controllers'}; or a path to a .yaml file)" in err, err
    assert not (in_tmp / "r").exists()
