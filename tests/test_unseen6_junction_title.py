"""Sixth round of unseen inputs — the junction study on a line of our own whose default train is a
train file next to it (``default_train: dmu90.yaml``).

Defect found (cosmetic): the table's title named the train by the path the line file gives
("junction — dale_spur (/tmp/…/dmu90.yaml)"), where every other study names the rolling stock
("capacity — dale (dmu90)"); now the stock's name."""

import pytest

from vcsumo.cli.main import main

from .conftest import write
from .test_unseen6_junction_fouling import DMU, SPUR_LINE

pytestmark = pytest.mark.sumo


def test_the_junction_table_names_the_train(in_tmp, capsys):
    write(in_tmp / "dmu90.yaml", DMU)
    line = write(in_tmp / "line.yaml", SPUR_LINE)
    code = main(["study", "junction", "--line", str(line), "--directions", "up", "--first", "main", "--controllers", "cbc",
                 "--offsets", "30,60", "--out", "j"])
    out = capsys.readouterr().out
    assert "junction — dale_spur (dmu90)" in out, out
    assert code == 0, out  # every case healthy
