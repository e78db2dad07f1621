"""Fourth round of unseen inputs — a platform cut by a gradient change (found running a suburban line
of our own with a station exactly where the gradient changes, km 8.0 of 15 ‰ → 5 ‰): the 150 m
platform became the 75 m of its last edge, and a 120 m metro train was refused with "longer than the
75 m platform of 'S04'" — a length that is in no file. A gradient, speed, curve or tunnel change
inside a platform splits it into edges, and SUMO's stop lies on the last one only; a train stands in
the whole platform. Now every check uses the line file's platform length."""

import json

import pytest

from vcsumo.cli.main import main
from vcsumo.line import load_line
from vcsumo.topology import build_topology

from .conftest import write

LINE = """
name: cutplat
km_start: 0.0
km_end: 6.0
line_speed_kmh: 100
default_train: metro.yaml
stations:
  - {id: AA, name: Aa, km: 0.3, platform_length_m: 150, dwell_s: 30}
  - {id: MM, name: Middle, km: 3.0, platform_length_m: 150, dwell_s: 30}
  - {id: ZZ, name: Zz, km: 5.7, platform_length_m: 150, dwell_s: 30}
gradients:
  - {from_km: 1.0, to_km: 3.0, permille: 15.0}
  - {from_km: 3.0, to_km: 5.0, permille: 5.0}
signalling: {block_length_m: 600}
"""
METRO = """
name: metro
length_m: 120.0
mass_kg: 260000.0
rotating_mass_factor: 1.08
max_speed_kmh: 100.0
max_traction_n: 310000.0
max_power_w: 3600000.0
davis_a_n: 4000.0
davis_b_n_per_mps: 60.0
davis_c_n_per_mps2: 8.0
service_brake_decel_mps2: 1.0
emergency_brake_decel_mps2: 1.3
"""
TT = """
name: tt
line: cutplat
services:
  - {id: U, train: metro.yaml, origin: AA, destination: ZZ, departure: "07:00", stops: [{station: MM}]}
  - {id: D, train: metro.yaml, origin: ZZ, destination: AA, departure: "07:00", stops: [{station: MM}]}
"""


def _files(tmp_path):
    write(tmp_path / "metro.yaml", METRO)
    write(tmp_path / "tt.yaml", TT)
    return write(tmp_path / "line.yaml", LINE)


def test_platform_length_is_the_line_files_where_a_gradient_change_cuts_it(tmp_path):
    topo = build_topology(load_line(_files(tmp_path)))
    for d in ("up", "down"):
        p = topo.platforms[f"MM_{d}"]
        assert p.length_m == 150.0
        assert p.end_pos_m - p.start_pos_m == pytest.approx(75.0)  # SUMO's stop: the last edge only


@pytest.mark.sumo
def test_a_train_longer_than_the_cut_but_not_than_the_platform_runs_and_serves_its_stop(tmp_path, monkeypatch, capsys):
    line = _files(tmp_path)
    monkeypatch.chdir(tmp_path)
    code = main(["run", "--line", str(line), "--timetable", "tt.yaml", "--regime", "fbs", "--out", "r"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert s["healthy"] and s["stops_served"] == s["stops_scheduled"] == 4 and s["stops_skipped"] == 0


def test_a_train_longer_than_the_platform_is_still_refused_with_its_true_length(tmp_path, monkeypatch, capsys):
    line = _files(tmp_path)
    write(tmp_path / "metro.yaml", METRO.replace("length_m: 120.0", "length_m: 160.0"))
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--line", str(line), "--timetable", "tt.yaml", "--regime", "fbs", "--out", "r"]) == 2
    err = capsys.readouterr().err
    assert "services[0].origin" in err and "160 m long, longer than the 150 m platform of 'AA'" in err
    assert not (tmp_path / "r").exists()


CONVOY_LINE = LINE.replace("km: 3.0, platform_length_m: 150", "km: 3.0, platform_length_m: 400").replace(
    "to_km: 3.0, permille: 15.0", "to_km: 3.05, permille: 15.0").replace("from_km: 3.0, to_km: 5.0", "from_km: 3.05, to_km: 5.0")
CONVOY_TT = """
name: pair
line: cutplat
services:
  - {id: L, train: metro.yaml, origin: AA, destination: ZZ, departure: "07:00", stops: [{station: MM}]}
  - {id: F, train: metro.yaml, origin: AA, destination: ZZ, departure: "07:00:20", stops: [{station: MM}]}
convoys:
  - {id: C, services: [L, F]}
"""


def test_a_convoy_that_fits_the_platform_but_not_the_stop_of_its_last_edge_is_warned(tmp_path):
    """A 400 m platform cut 50 m past its centre (km 3.05): two 120 m trains 72 m apart fit it (312 m),
    but SUMO's stop is its last 150 m and the follower's front would stand 192 m short of the
    platform end: it waits outside until its leader has left, which the warning now says (it said
    nothing once the platform's length was the line file's)."""
    import warnings

    from vcsumo.sim.convoy_plan import convoys_from_timetable, warn_short_platforms
    from vcsumo.timetable import load_timetable, plan_trains

    write(tmp_path / "metro.yaml", METRO)
    line = load_line(write(tmp_path / "line.yaml", CONVOY_LINE))
    tt, path = load_timetable(write(tmp_path / "pair.yaml", CONVOY_TT), line)
    trains = plan_trains(tt, path, line, build_topology(line))
    convoys = convoys_from_timetable(tt, path, trains)
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        msgs = warn_short_platforms(convoys, {"F": 72.0})
    assert len(msgs) == 1 and "MM (400 m, cut by a gradient, speed, curve or tunnel change: SUMO's stop is its last 150 m)" in msgs[0]
