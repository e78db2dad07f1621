"""``vcsumo batch --assumptions``: every run of a batch is supervised and judged, and UIC 406 computed,
under the assumption set the user names — as ``run``, ``study headway`` and ``study capacity`` are
(until 2026-11-28 the batch had no such option and always took the shipped ``etcs_typical``: a study
of one's own set ran its capacity under it and its delay batch under another)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write

pytestmark = pytest.mark.sumo

DATA = Path(__file__).resolve().parent.parent / "vcsumo" / "data"


def _wide_set(path: Path) -> Path:
    """etcs_typical with 40 m odometry errors and a 150 m margin behind the leader, named 'wide'."""
    text = (DATA / "assumptions" / "etcs_typical.yaml").read_text()
    text = text.replace("name: etcs_typical", "name: wide").replace("position_error_m: 10.0", "position_error_m: 40.0")
    text = text.replace("safety_margin_m: 50.0", "safety_margin_m: 150.0")
    return write(path, text)


def test_a_batch_runs_under_the_set_it_names_and_does_not_resume_another_sets_runs(tmp_path):
    out = tmp_path / "b"
    args = ["-q", "batch", "--line", "felez_test", "--timetables", "test", "--regimes", "mb", "--seeds", "1", "--workers", "1", "--out", str(out)]
    assert main(args) == 0
    assert main([*args, "--assumptions", str(_wide_set(tmp_path / "wide.yaml"))]) == 0
    runs = pd.read_csv(out / "batch.csv")
    assert len(runs) == 2 and runs.run_key.nunique() == 2  # the second set's run is a run of its own, not resumed
    sets = {}
    for d in runs.run_dir:
        meta = json.loads((out / d / "meta.json").read_text())
        sets[meta["parameters"]["assumptions"]["name"]] = json.loads((out / d / "summary.json").read_text())
    assert set(sets) == {"etcs_typical", "wide"}
    assert sets["wide"]["assumptions"] == "wide" and sets["etcs_typical"]["assumptions"] == "etcs_typical"
    # the wider margin is the one its trains were judged with (the same trains, a larger safe separation)
    assert sets["wide"]["min_margin_m"] < sets["etcs_typical"]["min_margin_m"] - 100.0
    uic = pd.read_csv(out / "uic406.csv")
    mb = uic.groupby("assumptions").consumption_pct.max()
    assert set(mb.index) == {"etcs_typical", "wide"} and mb["wide"] > mb["etcs_typical"]
    report = json.loads((out / "report" / "meta.json").read_text())
    assert report["parameters"]["assumptions"]["name"] == "wide"


def test_an_unknown_set_is_one_clear_error(tmp_path, capsys):
    code = main(["batch", "--line", "felez_test", "--timetables", "test", "--assumptions", "nosuchset", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and "--assumptions" in err and "nosuchset" in err and not (tmp_path / "x").exists()
