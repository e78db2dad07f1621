"""The junction study's signal exposure (``merge_red_inside_braking_s``): the time a red junction
signal lay inside the follower's *guaranteed* service braking distance — the separation model's
stopping distance on its route (dead time, grades, the brake at the low end of its box), not the
nominal v²/2b (until 2026-11-28: on the graded regional line's Hill Junction the nominal brake
counted 20.5 s of the 27.5 s a follower at 120 km/h spent inside its guaranteed distance of a red signal)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.studies.junction import build_setup, signal_exposure, signal_links
from vcsumo.studies.junction.model import RunResult, link_of
from vcsumo.sim.sumo_io import SumoLogCounts

MODEL = SeparationModel(load_assumptions())


def _approach(setup, role: str, v: float, before_m: float, dt: float = 0.5):
    """A follower running at v from ``before_m`` before the merge to 10 m before it, the signal red all along."""
    s_end = setup.s_merge[role] - 10.0
    s = np.arange(setup.s_merge[role] - before_m, s_end, v * dt)
    t = np.arange(len(s)) * dt
    return t, s, np.full(len(s), v)


def test_red_signal_exposure_counts_the_guaranteed_braking_distance(line_factory, network_factory):
    line = line_factory("regional_graded")
    setup = build_setup(line, network_factory("regional_graded"), load_rolling_stock(line.data.default_train), "hill", "down")
    node, role = setup.merge_node, "branch"
    links = signal_links(setup)
    li, _ = link_of(setup, role, node, links)
    assert li is not None
    t, s, v = _approach(setup, role, 120 / 3.6, 3000.0)
    signals = pd.DataFrame({"time_s": [0.0], "signal": [node], "state": ["r" * (li + 1)]})
    run = RunResult(0.0, {role: 0.0}, {}, {}, pd.DataFrame(), {role: (t, s, v)}, pd.DataFrame(), signals, SumoLogCounts())
    req, inside = signal_exposure(setup, run, role, node, setup.s_merge, links)

    braking = RouteBraking(MODEL, setup.stock, setup.profiles[role], "service")
    d = setup.s_merge[role] - s
    guaranteed = sum(braking.stopping_distance(float(x), float(u), MODEL.dead_time_s) >= dk for x, u, dk in zip(s, v, d)) * 0.5
    nominal = float((v * v / (2 * setup.stock.service_brake_decel_mps2) >= d).sum() * 0.5)
    assert inside == pytest.approx(guaranteed) and inside > nominal + 5.0
    assert req == pytest.approx(float((v * v / (2 * np.maximum(d, 0.5))).max()))


def test_the_junction_study_runs_under_the_set_it_names(line_factory, network_factory, tmp_path):
    """``study junction --assumptions``: its runs are supervised and judged under the set named (until
    2026-11-28 the junction study had no such option and always ran the shipped etcs_typical)."""
    from vcsumo.signalling.assumptions import load_assumptions as load
    from vcsumo.studies.junction.model import Case, simulate_pair

    shipped = (Path(__file__).resolve().parent.parent / "vcsumo" / "data" / "assumptions" / "etcs_typical.yaml").read_text()
    wide = tmp_path / "wide.yaml"
    wide.write_text(shipped.replace("name: etcs_typical", "name: wide").replace("safety_margin_m: 50.0", "safety_margin_m: 150.0"))
    line = line_factory("regional_graded")
    setup = build_setup(line, network_factory("regional_graded"), load_rolling_stock(line.data.default_train), "hill", "down",
                        assumptions=load(str(wide)))
    assert setup.model.margin_m == pytest.approx(150.0 + 20.0)
    run = simulate_pair(setup, Case("hill", "down", "branch", "mb"), 0.0, None, tmp_path / "solo", 0.5, roles=("branch",))
    assert run.summary["assumptions"] == "wide"


def test_an_unknown_set_for_the_junction_study_is_one_clear_error(tmp_path, capsys):
    from vcsumo.cli.main import main

    code = main(["study", "junction", "--line", "regional_graded", "--assumptions", "nosuchset", "--out", str(tmp_path / "j")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--assumptions" in err[0] and "nosuchset" in err[0] and not (tmp_path / "j").exists()


def test_a_junction_study_file_names_its_set_as_the_command_does(in_tmp, capsys):
    from vcsumo.cli.main import main
    from vcsumo.cli.study_files import load_study

    tmp_path = in_tmp
    good = tmp_path / "j.yaml"
    good.write_text("study: junction\nline: regional_graded\nassumptions: etcs_typical\n")
    assert load_study(good).command_values()["assumptions"] == "etcs_typical"
    bad = tmp_path / "k.yaml"
    bad.write_text("study: junction\nline: regional_graded\nassumptions: nosuchset\nout: res\n")
    assert main(["study", "run", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "assumptions" in err[0] and "nosuchset" in err[0] and not (tmp_path / "res").exists()
