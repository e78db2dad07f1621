"""Tier 1/2 — one configuration model per command (issue 9) and the input defects of issue 13.

The command line and a study file build the same typed model: a bound is checked once for both, a
bad option value is one line ``error: --option: ...`` (exit 2, nothing written), a bad file value
names the file and field.  Inputs the models cannot check alone (the line's default train, its
stations and platforms, convoys) are checked before anything runs; a run that is not healthy and a
table that is empty exit 1 with one line saying so.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from vcsumo.cli.main import main

from .conftest import DATA, write

FELEZ_LINE = (DATA / "networks" / "felez_test" / "line.yaml").read_text()
FELEZ_TRAIN = (DATA / "networks" / "rolling_stock" / "felez2019.yaml").read_text()
CONVOY = (DATA / "routes" / "felez_test" / "convoy.yaml").read_text()
TEST_TT = DATA / "routes" / "felez_test" / "test.yaml"


def _one_error(capsys, code: int, args: list[str], expected: int = 2) -> str:
    assert code == expected, args
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# -------------------------------------------------------------------------------------------
# Bounds: the same for an option and a file field


COMMANDS = {
    "build-network": ["build-network", "--line", "felez_test"],
    "run": ["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", "o"],
    "study headway": ["study", "headway", "--line", "felez_test", "--out", "o"],
    "study capacity": ["study", "capacity", "--line", "felez_test", "--out", "o"],
    "batch": ["batch", "--line", "felez_test", "--timetables", "test", "--out", "o"],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
@pytest.mark.parametrize("value", ["-500", "10", "0", "1e9", "nan", "ten"])
def test_block_length_option_is_bounded_like_the_file_field(in_tmp, capsys, command, value):
    line = _one_error(capsys, main([*COMMANDS[command], "--block-length-m", value]), COMMANDS[command])
    assert line.startswith(f"error: --block-length-m: {value}: "), line
    assert not any(in_tmp.iterdir())  # no results folder, no empty results/


@pytest.mark.parametrize("args,words", [
    (["--vc-step-length", "0"], "--vc-step-length: 0: Input should be greater than 0"),
    (["--step-length", "-0.5"], "--step-length: -0.5: Input should be greater than 0"),
    (["--fixed-time-s", "1e9"], "--fixed-time-s: 1e9: Input should be less than or equal to 120"),
    (["--fixed-time-s", "-1"], "--fixed-time-s: -1: Input should be greater than or equal to 0"),
    (["--convoy-sizes", "1,0"], "--convoy-sizes (item 2): 0: Input should be greater than or equal to 1"),
    (["--directions", "up,sideways"], "--directions (item 2): sideways: Input should be 'up' or 'down'"),
    (["--seed", "-3"], "--seed: -3: Input should be greater than or equal to 0"),
    (["--workers", "0"], "--workers: 0: must be 1 or more"),
    (["--scheduler", "localhost"], "--scheduler: localhost: String should match pattern"),
])
def test_capacity_options_are_bounded(in_tmp, capsys, args, words):
    line = _one_error(capsys, main([*COMMANDS["study capacity"], *args]), args)
    assert words in line, line
    assert not any(in_tmp.iterdir())


@pytest.mark.parametrize("out", [".", "", "..", "results/.."])
def test_run_out_must_name_a_folder(in_tmp, capsys, out):
    line = _one_error(capsys, main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", out]), out)
    assert line.startswith("error: --out: ") and "is not a results folder" in line, line
    assert not any(in_tmp.iterdir())


def test_the_same_value_in_a_study_file_names_the_file_and_field(in_tmp, capsys):
    for field, value, words in [("block_length_m", 10, "greater than or equal to 100"), ("vc_step_length_s", 0, "greater than 0"),
                                ("fixed_time_s", 1e9, "less than or equal to 120")]:
        f = write(in_tmp / "s.yaml", f"study: capacity\nline: felez_test\n{field}: {value}\nout: o\n")
        line = _one_error(capsys, main(["study", "run", str(f)]), field)
        assert line.startswith(f"error: {f}: {field}: ") and words in line, line
        assert not (in_tmp / "o").exists()


def _numbers(schema: dict) -> list[dict]:
    """The numeric (sub)schemas of a field's JSON schema (through ``X | None`` and lists)."""
    if schema.get("type") in ("number", "integer"):
        return [schema]
    subs = schema.get("anyOf", []) + ([schema["items"]] if "items" in schema else [])
    return [n for s in subs for n in _numbers(s)]


def test_every_option_is_a_field_of_the_commands_model_with_bounds_unit_and_description():
    from vcsumo.cli.main import cli
    from vcsumo.config import option_name
    from vcsumo.studies.configs import CONFIGS

    for path, model in CONFIGS.items():
        cmd = cli
        for part in path.split():
            cmd = cmd.commands[part]
        assert cmd.config_model is model
        options = {o for p in cmd.params for o in p.opts if p.name not in ("verbose", "quiet")}
        assert options == {option_name(model, f) for f in model.model_fields}, path
        for name, prop in model.model_json_schema()["properties"].items():
            assert prop.get("description"), (path, name)
            for num in _numbers(prop):
                assert {"minimum", "exclusiveMinimum"} & set(num) and {"maximum", "exclusiveMaximum"} & set(num), (path, name, num)
                assert prop.get("unit") or num.get("unit"), (path, name)


def test_command_line_and_study_file_build_the_same_configuration(in_tmp):
    from vcsumo.cli.options import option_values
    from vcsumo.cli.study_files import load_study
    from vcsumo.studies.configs import CapacityConfig

    raw = {"line": "felez_test", "controllers": "cbc", "convoy_sizes": "1,2", "directions": "up", "vc_step_length_s": "0.1", "fixed_time_s": "8",
           "workers": "2", "seed": "7"}
    from_cli = CapacityConfig.from_options(option_values(CapacityConfig, raw))
    f = write(in_tmp / "s.yaml", "study: capacity\ntitle: t\nline: felez_test\ncontrollers: [cbc]\nconvoy_sizes: [1, 2]\ndirections: [up]\n"
              "vc_step_length_s: 0.1\nfixed_time_s: 8\nworkers: 2\nseed: 7\n")
    from_file = load_study(f)
    fields = set(CapacityConfig.model_fields)
    assert from_file.model_dump(include=fields) == from_cli.model_dump(include=fields)
    assert from_file.source == f and from_cli.source is None


# -------------------------------------------------------------------------------------------
# Every problem of an input, one line each


def test_every_problem_of_a_file_is_shown(in_tmp, capsys):
    line = write(in_tmp / "typo" / "line.yaml", FELEZ_LINE.replace("km_end: 5.0", "km_end: 5.0\ngradients: [{from_km: 1, to_km: 2, permile: 3}]"))
    assert main(["build-network", "--line", str(line)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {line}: gradients[0].permille: required field is missing",
                   f"error: {line}: gradients[0].permile: unknown key (did you mean 'permille'?) (allowed keys: from_km, permille, to_km)"]


def test_every_bad_option_is_shown(in_tmp, capsys):
    assert main(["study", "capacity", "--line", "felez_test", "--convoy-sizes", "1,x", "--vc-step-length", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(x.startswith("error: --") for x in err)
    assert not any(in_tmp.iterdir())


def test_a_missing_option_is_named(in_tmp, capsys):
    assert main(["run", "--line", "felez_test", "--regime", "fbs"]) == 2
    assert capsys.readouterr().err.strip() == "error: --timetable: required option is missing"


def test_channel_typo_names_the_channel(in_tmp, capsys):
    line = _one_error(capsys, main(["run", "--line", "felez_test", "--timetable", "convoy", "--regime", "vc", "--channel", "chanel", "--out", "o"]), [])
    assert line.startswith("error: --channel: ") and "'chanel' not found" in line
    assert not any(in_tmp.iterdir())


# -------------------------------------------------------------------------------------------
# Study files: paths relative to the file, recorded among the inputs


def test_paths_in_a_study_file_are_relative_to_it(in_tmp, capsys, monkeypatch):
    """A study, its line and its assumption set in one folder, run from another folder."""
    d = in_tmp / "project"
    write(d / "lines" / "felez_copy" / "line.yaml", FELEZ_LINE.replace("name: felez_test", "name: felez_copy"))
    write(d / "slow.yaml", (DATA / "assumptions" / "etcs_typical.yaml").read_text().replace("name: etcs_typical", "name: slow"))
    study = write(d / "studies" / "h.yaml", "study: headway\nline: ../lines/felez_copy/line.yaml\nregime: mb\nassumptions: ../slow.yaml\n"
                  "points_km: [2.5]\nout: hw\n")
    elsewhere = in_tmp / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert main(["study", "run", str(study)]) == 0
    meta = json.loads((elsewhere / "hw" / "meta.json").read_text())
    assert meta["inputs"]["study"]["path"] == str(study)
    assert Path(meta["inputs"]["line"]["path"]).resolve() == (d / "lines" / "felez_copy" / "line.yaml").resolve()
    assert meta["parameters"]["assumptions"]["name"] == "slow"
    capsys.readouterr()
    # the same names from the current folder are not found: nothing falls back to it
    bad = write(elsewhere / "s.yaml", "study: headway\nline: lines/felez_copy/line.yaml\n")
    line = _one_error(capsys, main(["study", "run", str(bad)]), [])
    assert str(elsewhere / "lines" / "felez_copy" / "line.yaml") in line


# -------------------------------------------------------------------------------------------
# Inputs the models cannot check alone


def test_an_unknown_default_train_names_the_line_file(in_tmp, capsys):
    line = write(in_tmp / "l" / "line.yaml", FELEZ_LINE.replace("default_train: felez2019", "default_train: maglev"))
    for cmd in (["study", "headway"], ["study", "capacity"]):
        msg = _one_error(capsys, main([*cmd, "--line", str(line), "--out", "o"]), cmd)
        assert msg.startswith(f"error: {line}: default_train: unknown train 'maglev'"), msg
    assert not (in_tmp / "o").exists()


def test_a_line_without_stations_is_blamed_not_the_timetable(in_tmp, capsys):
    text = re.sub(r"stations:\n(  - .*\n)+", "", FELEZ_LINE).replace("headway:\n  measuring_points_km: [1.5, 2.5]\n  release_km: {up: 1.2, down: 3.8}\n", "")
    line = write(in_tmp / "bare" / "line.yaml", text)
    msg = _one_error(capsys, main(["run", "--line", str(line), "--timetable", str(TEST_TT), "--regime", "fbs", "--out", "o"]), [])
    assert msg.startswith(f"error: {line}: stations: the line has no stations"), msg
    assert not (in_tmp / "o").exists()


def test_a_platform_shorter_than_the_train_is_refused(in_tmp, capsys):
    line = write(in_tmp / "short" / "line.yaml", FELEZ_LINE.replace("platform_length_m: 200", "platform_length_m: 20"))
    msg = _one_error(capsys, main(["run", "--line", str(line), "--timetable", str(TEST_TT), "--regime", "fbs", "--out", "o"]), [])
    assert msg.startswith(f"error: {TEST_TT}: services[0].destination: train felez2019 is 68 m long, longer than the 20 m platform of 'STOP'"), msg
    assert str(line) in msg and not (in_tmp / "o").exists()


def test_a_train_that_is_its_own_predecessor_is_refused(in_tmp, capsys):
    tt = write(in_tmp / "self.yaml", CONVOY.replace("services: [UL, UF]", "services: [UL, UL]"))
    msg = _one_error(capsys, main(["run", "--line", "felez_test", "--timetable", str(tt), "--regime", "vc", "--out", "o"]), [])
    assert msg.startswith(f"error: {tt}: convoys[0].services: service 'UL' is named twice"), msg
    assert not (in_tmp / "o").exists()


def test_convoy_members_that_never_run_together_are_refused(in_tmp, capsys):
    tt = write(in_tmp / "far.yaml", CONVOY.replace('departure: "00:00:20"', 'departure: "00:50:20"').replace('arrival: "00:03:50"', 'arrival: "00:53:50"'))
    msg = _one_error(capsys, main(["run", "--line", "felez_test", "--timetable", str(tt), "--regime", "vc", "--out", "o"]), [])
    assert msg.startswith(f"error: {tt}: convoys[0].services: train UF.1 departs at 00:50:20, when UL.1 of the same convoy is already at its destination"), msg
    assert not (in_tmp / "o").exists()


def test_headway_points_beyond_the_line_are_refused(in_tmp, capsys):
    msg = _one_error(capsys, main(["study", "headway", "--line", "felez_test", "--points", "25", "--out", "o"]), [])
    assert msg == "error: --points (item 1): measuring point 25 km lies beyond the line felez_test (0–5 km)"
    assert not any(in_tmp.iterdir())


# -------------------------------------------------------------------------------------------
# Results that are empty or not healthy: exit 1, one line, results kept


def test_an_empty_headway_table_exits_1(in_tmp, capsys):
    """The point lies behind both release points: nothing can be measured."""
    line = write(in_tmp / "l" / "line.yaml", FELEZ_LINE.replace("release_km: {up: 1.2, down: 3.8}", "release_km: {up: 3.0, down: 2.0}"))
    msg = _one_error(capsys, main(["study", "headway", "--line", str(line), "--points", "2.5", "--out", "h"]), [], expected=1)
    assert msg.startswith("error: no headway was measured"), msg
    assert (in_tmp / "h" / "headway.csv").is_file()


CLIMB = """name: climb
title: A 29 km climb at 10 permille (test line of our own) [A]
km_start: 0.0
km_end: 31.0
line_speed_kmh: 100
default_train: felez2019
stations:
  - {id: FOOT, name: Foot, km: 0.5, platform_length_m: 200, dwell_s: 30}
  - {id: TOP, name: Top, km: 30.5, platform_length_m: 200, dwell_s: 30}
gradients:
  - {from_km: 1.0, to_km: 30.0, permille: 10.0}
signalling: {block_length_m: 2000}
"""


def test_a_train_that_never_arrives_makes_the_run_exit_1(in_tmp, capsys):
    """A weak train (40 kW for 161 t, 0.25 W/kg: accepted) crawls up the climb at ≈ 1.6 m/s and is
    still on it when the run ends (last departure + 4 × route / 10 m/s + 1 h).  (A power given in kW
    — this test's old 1 kW train — is now refused on loading: test_unseen7_bad_values.)"""
    stock = write(in_tmp / "weak.yaml", FELEZ_TRAIN.replace("max_power_w: 1200000.0", "max_power_w: 40000.0").replace("name: felez2019", "name: weak"))
    line = write(in_tmp / "climb.yaml", CLIMB)
    tt = write(in_tmp / "tt.yaml", f"name: weak\nline: climb\nservices:\n  - {{id: W, train: {stock}, origin: FOOT, destination: TOP, departure: 0}}\n")
    msg = _one_error(capsys, main(["run", "--line", str(line), "--timetable", str(tt), "--regime", "fbs", "--out", "r"]), [], expected=1)
    assert msg.startswith("error: the run is not healthy: 0 of 1 trains arrived (1 stops not reached)"), msg  # never got there: not skipped
    summary = json.loads((in_tmp / "r" / "summary.json").read_text())  # kept, and valid JSON
    assert summary["healthy"] is False and summary["trains_arrived"] == 0
    assert (summary["stops_skipped"], summary["stops_not_reached"]) == (0, 1)


# -------------------------------------------------------------------------------------------
# Files: valid JSON, counts as integers, no float noise


def _strict_json(text: str):
    def refuse(c):
        raise ValueError(f"{c} is not JSON")

    return json.loads(text, parse_constant=refuse)


def test_json_and_csv_writers():
    import math

    import numpy as np
    import pandas as pd

    from vcsumo.results import write_csv, write_json

    d = Path(__import__("tempfile").mkdtemp())
    write_json(d / "s.json", {"a": math.nan, "b": [np.float64(1.5), math.inf], "c": np.int64(2)})
    assert _strict_json((d / "s.json").read_text()) == {"a": None, "b": [1.5, None], "c": 2}
    write_csv(pd.DataFrame({"simulations": [2.0, math.nan], "arrival_delay_s": [-23.599999999999994, 1.0], "km": [0.1 + 0.2, 3.0]}), d / "t.csv")
    assert (d / "t.csv").read_text() == "simulations,arrival_delay_s,km\n2,-23.6,0.3\n,1.0,3.0\n"


def test_a_run_writes_valid_json_and_clean_numbers(in_tmp, capsys):
    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", "r"]) == 0
    _strict_json((in_tmp / "r" / "summary.json").read_text())
    for name in ("summary.csv", "stop_events.csv"):
        cells = [c for row in (in_tmp / "r" / name).read_text().splitlines()[1:] for c in row.split(",")]
        floats = [c for c in cells if re.fullmatch(r"-?\d+\.\d+", c)]
        assert floats and all(len(c.lstrip("-").replace(".", "").lstrip("0")) <= 12 for c in floats), name


def test_vc_summary_is_valid_json_when_followers_never_coupled_or_released(in_tmp, capsys):
    """Cut at 25 s the convoy's followers have not coupled (nor been released): their times are null, not NaN."""
    assert main(["run", "--line", "felez_test", "--timetable", "convoy", "--regime", "vc", "--controller", "cbc", "--end-time", "25", "--out", "r"]) == 0
    followers = _strict_json((in_tmp / "r" / "vc_summary.json").read_text())["followers"]
    assert any(f["released_at_s"] is None for f in followers)
    _strict_json((in_tmp / "r" / "summary.json").read_text())


def test_junction_and_safety_study_files_fill_their_commands_parameters(root):
    """Not yet generated from one model: their file models hand values to the commands by name."""
    from vcsumo.cli.junction import junction_cmd
    from vcsumo.cli.safety import safety_cmd
    from vcsumo.cli.study_files import load_study

    for name, cmd in (("junction_milano_bologna", junction_cmd), ("safety", safety_cmd)):
        values = load_study(root / "vcsumo" / "data" / "studies" / f"{name}.yaml").command_values()
        assert set(values) <= {p.name for p in cmd.params}, name
