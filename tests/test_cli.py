"""Tier 2 — the vcsumo command end to end: results folders, clear errors, nothing half-written."""

import json
import re
import subprocess
from pathlib import Path

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write

pytestmark = pytest.mark.sumo


def test_run_writes_a_complete_results_folder(in_tmp, capsys):
    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "mb", "--out", "r"]) == 0
    out = Path("r")
    for f in ("trajectories.csv", "stop_events.csv", "summary.csv", "summary.json", "meta.json", "tripinfo.xml",
              "stops.xml", "scenario.sumocfg", "routes.rou.xml", "network/line.net.xml", "time_distance.png"):
        assert (out / f).is_file(), f
    assert not (out / "fcd.xml").exists()  # the same samples as trajectories.csv: only on request (--sumo-fcd)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["trains_arrived"] == 3 and summary["collisions"] == 0 and summary["gap_violations"] == 0
    traj = pd.read_csv(out / "trajectories.csv")
    assert {"time_s", "train", "km", "speed_mps", "accel_mps2", "gap_m"} <= set(traj.columns)
    assert traj.km.max() == pytest.approx(3.7, abs=0.01)
    stops = pd.read_csv(out / "stop_events.csv")
    assert set(stops.station) == {"STOP"} and len(stops) == 3
    meta = json.loads((out / "meta.json").read_text())
    assert meta["versions"]["eclipse-sumo"] == "1.28.0" and "line" in meta["inputs"]
    shown = capsys.readouterr().out
    assert "wrote r" in shown
    head = shown.splitlines()[1]
    assert "SUMO e-stops" in head and "emerg. brakes" not in head  # the column counts SUMO's emergency stops (summary.csv emergency_brakes)
    # the scenario opens in SUMO on its own (sumo-gui uses the same file)
    from vcsumo.sim.sumo_paths import sumo_binary

    proc = subprocess.run([sumo_binary("sumo"), "-c", "scenario.sumocfg", "--end", "60"], cwd=out, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_default_out_is_a_new_folder_under_results(in_tmp, capsys):
    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs"]) == 0
    made = list(Path("results").iterdir())
    assert len(made) == 1 and made[0].name.startswith("run-felez_test-test-fbs-")
    assert not [p for p in Path("results").iterdir() if ".partial" in p.name]


@pytest.mark.parametrize(
    "args,words",
    [
        (["run", "--line", "atlantis", "--timetable", "x", "--regime", "fbs", "--out", "r"], "--line: unknown line 'atlantis'"),
        (["run", "--line", "felez_test", "--timetable", "nope", "--regime", "fbs", "--out", "r"], "--timetable: unknown timetable 'nope'"),
        (["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--controller", "mpc", "--out", "r"], "--controller"),
        (["study", "headway", "--line", "felez_test", "--train", "maglev", "--out", "r"], "unknown train 'maglev'"),
    ],
)
def test_bad_input_exits_2_with_one_message_and_no_folder(in_tmp, capsys, args, words):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err
    assert len([ln for ln in err.strip().splitlines() if ln.startswith("error:")]) == 1
    assert not Path("r").exists() and not list(in_tmp.glob("r.partial*"))


def test_sumo_failure_is_reported_and_leaves_nothing(in_tmp, capsys, monkeypatch):
    monkeypatch.setenv("VCSUMO_CACHE", str(in_tmp / "cache"))
    line = write(in_tmp / "myline" / "line.yaml", "name: myline\nkm_start: 0\nkm_end: 5\nline_speed_kmh: 100\n"
                 "stations: [{id: A, name: A, km: 0.2, platform_length_m: 150}, {id: B, name: B, km: 4.8, platform_length_m: 150}]\n"
                 "signalling: {block_length_m: 500}\n")
    tt = write(in_tmp / "tt.yaml", "name: t\nline: myline\nservices: [{id: S, train: felez2019, origin: A, destination: B, departure: 0}]\n")
    assert main(["build-network", "--line", str(line)]) == 0
    net = next((in_tmp / "cache" / "networks" / "myline").glob("*/line.net.xml"))
    net.write_text(net.read_text()[:2000])  # a truncated network file in the cache
    assert main(["run", "--line", str(line), "--timetable", str(tt), "--regime", "fbs", "--out", "r"]) == 2
    err = capsys.readouterr().err
    assert "SUMO failed" in err
    assert not Path("r").exists() and not list(in_tmp.glob("r.partial*"))


def test_headway_study_cli(in_tmp, capsys):
    assert main(["study", "headway", "--line", "felez_test", "--regime", "both", "--out", "h"]) == 0
    df = pd.read_csv("h/headway.csv")
    assert {"line", "direction", "regime", "train", "measuring_point_km", "headway_sim_s", "headway_analytic_s"} <= set(df.columns)
    assert (abs(df.headway_sim_s - df.headway_analytic_s) / df.headway_analytic_s < 0.05).all()
    shown = capsys.readouterr().out
    assert "headway — felez_test" in shown
    head = shown.splitlines()[1:4]
    assert any("healthy" in x for x in head), head  # every row's verdict in the table, not only below it
    assert sum(x.rstrip().endswith("yes") for x in shown.splitlines()) == len(df)


def test_the_readme_example_line_works(in_tmp, root, capsys):
    """A line file written from the README alone builds, runs a timetable and a headway study."""
    readme = (root / "README.md").read_text()
    blocks = dict(re.findall(r"<!-- example: (\S+) -->\s*```yaml\n(.*?)```", readme, re.S))
    assert {"line", "timetable"} <= set(blocks)
    line = write(in_tmp / "my_line" / "line.yaml", blocks["line"])
    tt = write(in_tmp / "my_timetable.yaml", blocks["timetable"])
    assert main(["build-network", "--line", str(line)]) == 0
    assert main(["run", "--line", str(line), "--timetable", str(tt), "--regime", "fbs", "--out", "run"]) == 0
    assert json.loads(Path("run/summary.json").read_text())["collisions"] == 0
    assert main(["study", "headway", "--line", str(line), "--out", "hw"]) == 0
    df = pd.read_csv("hw/headway.csv")
    assert len(df) >= 2 and (abs(df.headway_sim_s - df.headway_analytic_s) / df.headway_analytic_s < 0.05).all()


def test_single_track_line_runs_opposing_trains_and_headway(in_tmp):
    line = write(in_tmp / "single" / "line.yaml", """
name: single
km_start: 0
km_end: 12
tracks: single
line_speed_kmh: 120
default_train: hcmc_l1
stations:
  - {id: A, name: A, km: 0.2, platform_length_m: 150}
  - {id: B, name: B, km: 11.8, platform_length_m: 150}
signalling: {block_length_m: 1000}
headway: {measuring_points_km: [6.0]}
""")
    tt = write(in_tmp / "tt.yaml", "name: t\nline: single\nservices:\n"
               "  - {id: E, train: hcmc_l1, origin: A, destination: B, departure: 0}\n"
               "  - {id: W, train: hcmc_l1, origin: B, destination: A, departure: 10}\n")
    assert main(["run", "--line", str(line), "--timetable", str(tt), "--regime", "fbs", "--out", "r"]) == 0
    s = pd.read_csv("r/summary.csv").set_index("train")
    # the opposing train is held at B until E has cleared the single-track section
    assert s.loc["W", "departure_s"] >= s.loc["E", "arrival_s"] - 60.0
    assert s.collisions.sum() == 0 and s.arrived.all()
    assert main(["study", "headway", "--line", str(line), "--out", "h"]) == 0
    df = pd.read_csv("h/headway.csv")
    assert set(df.direction) == {"up", "down"} and (abs(df.deviation_pct) < 5).all()


# ---------------------------------------------------------------------------------------------
# Terminal: help texts, -v/-q, tables that fit, SUMO's messages off the terminal (issue 13)


def _commands(cmd, path=()):
    yield path, cmd
    for name, sub in getattr(cmd, "commands", {}).items():
        yield from _commands(sub, path + (name,))


def test_every_help_shows_an_example_and_study_names_all_its_subcommands(capsys):
    from vcsumo.cli.main import cli

    for path, cmd in _commands(cli):
        assert main([*path, "--help"]) == 0
        out = capsys.readouterr().out
        assert re.search(r"Example:\n\s+vcsumo " + " ".join(path), out), path
        assert "-v, --verbose" in out and "-q, --quiet" in out, path
        if any(p.name == "seed" for p in cmd.params):
            assert next(p for p in cmd.params if p.name == "seed").help, path
    study = cli.commands["study"]
    first = study.help.split("\n\n")[0]
    assert set(study.commands) == {"capacity", "headway", "junction", "safety", "tradeoff", "run"}
    assert all(name in first for name in study.commands)


def test_verbose_and_quiet_on_the_group_and_on_the_command(capsys):
    assert main(["build-network", "--line", "felez_test"]) == 0
    assert "network of felez_test" not in capsys.readouterr().err
    for args in (["-v", "build-network", "--line", "felez_test"], ["build-network", "--line", "felez_test", "-v"]):
        assert main(args) == 0
        cap = capsys.readouterr()
        assert "network of felez_test reused from the cache" in cap.err and "reused (cached) " in cap.out and "wrote " not in cap.out


def test_quiet_run_prints_results_only(in_tmp, capsys):
    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", "r", "-q"]) == 0
    cap = capsys.readouterr()
    assert cap.err == "" and "wrote r" in cap.out and "T.3" in cap.out


def test_python_warnings_are_one_log_line(in_tmp, capsys):
    line = write(in_tmp / "curvy" / "line.yaml", "name: curvy\nkm_start: 0\nkm_end: 6\ntracks: single\nline_speed_kmh: 120\n"
                 "stations: [{id: A, name: A, km: 0.2, platform_length_m: 150}, {id: B, name: B, km: 5.8, platform_length_m: 150}]\n"
                 "curves: [{from_km: 2, to_km: 3, radius_m: 1500}]\nsignalling: {block_length_m: 1000}\n")
    assert main(["build-network", "--line", str(line)]) == 0
    err = capsys.readouterr().err
    assert "curves on single track are not in the SUMO plant" in err and "warnings.warn" not in err and "UserWarning" not in err
    assert main(["-q", "build-network", "--line", str(line), "--force"]) == 0
    assert capsys.readouterr().err == ""


def test_lines_with_an_empty_home_is_an_error(in_tmp, capsys, monkeypatch):
    monkeypatch.setenv("VCSUMO_HOME", str(in_tmp))
    assert main(["lines"]) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err.count("\n") == 1 and cap.err.startswith(f"error: {in_tmp / 'networks'}: no line files")


def test_study_run_takes_a_shipped_study_name(in_tmp, capsys, monkeypatch, root):
    import shutil

    home = in_tmp / "home"
    shutil.copytree(root / "vcsumo" / "data", home)
    write(home / "studies" / "tiny.yaml", "study: headway\nline: felez_test\nregime: mb\n")
    monkeypatch.setenv("VCSUMO_HOME", str(home))
    assert main(["study", "run", "tiny", "--out", "h"]) == 0
    assert set(pd.read_csv("h/headway.csv").regime) == {"mb"}
    assert main(["study", "run", "no_such_study"]) == 2
    assert "no_such_study" in capsys.readouterr().err


def test_capacity_table_fits_100_columns_with_failed_cases_and_their_error(in_tmp, capsys):
    from rich.console import Console

    from vcsumo.cli.ui import print_table

    assert main(["study", "capacity", "--line", "felez_test", "--controllers", "cbc", "--convoy-sizes", "1,2", "--directions", "up",
                 "--out", "c", "--workers", "1"]) == 0
    shown = capsys.readouterr().out
    df = pd.read_csv("c/capacity.csv", dtype={"error": str, "controller": str})
    failed = df[(df.regime == "vc") & (df.convoy_size == 2)].copy()
    failed[["headway_sim_s", "headway_analytic_s", "intra_convoy_gap_m", "capacity_trains_per_h", "gain_vs_fbs", "min_gap_m",
            "gap_violations", "collisions"]] = float("nan")
    failed["convoy_size"] = 4
    failed["error"] = "SumoError: c/runs/x: SUMO failed during the simulation after t = 812.4 s (simulationStep): Error: train up_u1_m3 has no route"
    df = pd.concat([df, failed], ignore_index=True)
    cols = ["direction", "stopping_pattern", "regime", "controller", "convoy_size", "headway_sim_s", "headway_analytic_s", "intra_convoy_gap_m",
            "capacity_trains_per_h", "gain_vs_fbs", "min_gap_m", "gap_violations", "collisions"]
    con = Console(width=100, record=True)
    print_table(df, "capacity — felez_test (felez2019)", cols, csv_path="c/capacity.csv", to=con)
    text = con.export_text()
    lines = text.splitlines()
    assert max(len(x) for x in lines) <= 100
    assert "…" not in text and "nan" not in text.lower()
    head = " ".join(lines[1:4])
    for word in ("dir", "pattern", "regime", "controller", "sim", "theory", "capacity", "tr/h", "×FBS", "viol.", "coll."):
        assert word in head, word
    body = [x for x in lines if x.startswith("up ")]
    assert len(body) == len(df) and all("non-stop" in x for x in body)
    assert any(x.split()[-2:] == ["0", "0"] for x in body)  # counts as integers, not 0.0
    fbs = df[df.regime == "fbs"].iloc[0]
    assert f"{fbs.headway_sim_s:.1f}" in body[0] and f"{fbs.capacity_trains_per_h:.1f}" in body[0] and "1.00" in body[0]
    assert "failed" in body[-1]
    joined = " ".join(text.split())
    assert "failed: up non-stop vc cbc n=4: SumoError: c/runs/x: SUMO failed during the simulation after t = 812.4 s" in joined
    # the command's own table: all the rows, piped at 100 columns (no column left out at this width)
    assert "more column" not in shown and shown.count("non-stop") == 4


def test_tables_too_wide_leave_columns_out_and_name_the_csv():
    from rich.console import Console

    from vcsumo.cli.ui import print_table

    df = pd.DataFrame({"direction": ["up"], "stopping_pattern": ["non-stop"], "capacity_trains_per_h": [201.8234], "gain_vs_fbs": [2.547],
                       "headway_analytic_s": [18.11], "min_gap_m": [285.19]})
    con = Console(width=40, record=True)
    print_table(df, "t", list(df.columns), csv_path="out/capacity.csv", to=con, drop_first=["headway_analytic_s"])
    text = con.export_text()
    assert max(len(x) for x in text.splitlines()) <= 40
    assert "201.8" in text and "…" not in text
    assert "headway_analytic_s" in " ".join(text.split()) and "out/capacity.csv" in text


def test_piped_tables_are_100_columns_wide():
    import os
    import sys

    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    proc = subprocess.run([sys.executable, "-c", "from vcsumo.cli.ui import out_console; print(out_console.width)"], capture_output=True, text=True, env=env)
    assert proc.stdout.strip() == "100"


def test_sumo_warnings_go_to_the_log_not_the_terminal(in_tmp, capfd, network_factory):
    """SUMO in this process (a run, or a study with --workers 1) writes its warnings into the run's
    sumo_errors.log only: here a train type whose emergency deceleration is below its service one."""
    from vcsumo.sim.sumo_backend import SumoBackend

    net = network_factory("felez_test")
    routes = write(in_tmp / "w.rou.xml", '<routes>\n<vType id="t" vClass="rail" decel="5" emergencyDecel="2" length="50"/>\n'
                   '<vehicle id="v" type="t" depart="0"><route edges="main_up_0 main_up_1"/></vehicle>\n</routes>\n')
    log = in_tmp / "sumo_errors.log"
    with SumoBackend(["-n", str(net.net_file), "-r", str(routes), "--end", "10", "--no-step-log", "true"], error_log=log) as sim:
        for _ in range(5):
            sim.step()
    assert "Warning" not in capfd.readouterr().err
    assert "Warning: Value of 'emergencyDecel' (2.00) should be higher than 'decel'" in log.read_text()


def test_a_study_in_this_process_keeps_sumo_off_the_terminal(in_tmp, capfd):
    """--workers 1: the capacity cases (here CBF-CBC convoys, whose followers SUMO reports braking
    hard) run in this process; the terminal gets the progress bar and the table only."""
    assert main(["study", "capacity", "--line", "felez_test", "--controllers", "cbf-cbc", "--convoy-sizes", "2", "--directions", "up",
                 "--patterns", "non-stop", "--workers", "1", "--out", "c"]) == 0
    cap = capfd.readouterr()
    assert "Warning" not in cap.err and "Warning" not in cap.out and "Loading net-file" not in cap.out + cap.err
    assert "wrote c/capacity.csv" in cap.out
