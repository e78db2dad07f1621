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
    for f in ("trajectories.csv", "stop_events.csv", "summary.csv", "summary.json", "meta.json", "fcd.xml", "tripinfo.xml",
              "stops.xml", "scenario.sumocfg", "routes.rou.xml", "network/line.net.xml", "time_distance.png"):
        assert (out / f).is_file(), f
    summary = json.loads((out / "summary.json").read_text())
    assert summary["trains_arrived"] == 3 and summary["collisions"] == 0 and summary["gap_violations"] == 0
    traj = pd.read_csv(out / "trajectories.csv")
    assert {"time_s", "train", "km", "speed_mps", "accel_mps2", "gap_m"} <= set(traj.columns)
    assert traj.km.max() == pytest.approx(3.7, abs=0.01)
    stops = pd.read_csv(out / "stop_events.csv")
    assert set(stops.station) == {"STOP"} and len(stops) == 3
    meta = json.loads((out / "meta.json").read_text())
    assert meta["versions"]["eclipse-sumo"] == "1.28.0" and "line" in meta["inputs"]
    assert "wrote r" in capsys.readouterr().out
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
    assert "headway — felez_test" in capsys.readouterr().out


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
