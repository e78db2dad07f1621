"""Eighth round of unseen inputs — a user's convoy definitions that the command line must refuse
with one clear line per problem (exit 2, the file and the field named, no results folder).

Found 2026-11-28 on a line of our own (10 stations in 30 km, 160–200 m platforms):

* ``convoys[].couple_at`` / ``decouple_at`` were accepted by the timetable schema and used nowhere:
  ``couple_at: S3`` on a convoy leaving S0 together ran coupled from S0 and was reported healthy
  (exit 0) — a run that did not do what its file said, reported clean.  They are now refused.
* a 200 m train stopping at three 180 m platforms was refused for the first one only; every
  platform it does not fit is now one line.
"""

from __future__ import annotations

import pytest

from vcsumo.cli.main import main

from .conftest import write

LINE = """
name: stopline
km_start: 0.0
km_end: 12.0
line_speed_kmh: 120
stations:
  - {id: S0, name: Zero, km: 0.5, platform_length_m: 600, dwell_s: 40}
  - {id: S1, name: One, km: 3.5, platform_length_m: 180, dwell_s: 30}
  - {id: S2, name: Two, km: 6.5, platform_length_m: 200, dwell_s: 30}
  - {id: S3, name: Three, km: 9.0, platform_length_m: 180, dwell_s: 30}
  - {id: S9, name: Nine, km: 11.5, platform_length_m: 600, dwell_s: 40}
signalling: {block_length_m: 800}
"""
HEAVY = """name: heavy
length_m: 200.0
mass_kg: 520000.0
rotating_mass_factor: 1.08
max_speed_kmh: 120.0
max_traction_n: 300000.0
max_power_w: 3000000.0
davis_a_n: 6000.0
davis_b_n_per_mps: 80.0
davis_c_n_per_mps2: 8.0
service_brake_decel_mps2: 0.6
emergency_brake_decel_mps2: 0.9
"""


def _run(tmp_path, monkeypatch, timetable: str) -> int:
    write(tmp_path / "heavy.yaml", HEAVY)
    write(tmp_path / "line.yaml", LINE)
    write(tmp_path / "tt.yaml", timetable)
    monkeypatch.chdir(tmp_path)
    return main(["run", "--line", "line.yaml", "--timetable", "tt.yaml", "--regime", "vc", "--controller", "cbc", "--out", "r"])


@pytest.mark.parametrize("field", ["couple_at", "decouple_at"])
def test_a_convoy_field_the_run_would_ignore_is_refused(tmp_path, monkeypatch, capsys, field):
    tt = f"""name: tt
line: stopline
services:
  - {{id: A, train: heavy.yaml, origin: S0, destination: S9, departure: "07:00", stops: [{{station: S2}}]}}
  - {{id: B, train: heavy.yaml, origin: S0, destination: S9, departure: "07:00:30", stops: [{{station: S2}}]}}
convoys:
  - {{id: C, services: [A, B], {field}: S2}}
"""
    assert _run(tmp_path, monkeypatch, tt) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("error: ") and "tt.yaml: convoys[0]." + field + ": 'S2': not supported" in err[0]
    assert not (tmp_path / "r").exists()


def test_every_platform_a_train_does_not_fit_is_one_line(tmp_path, monkeypatch, capsys):
    tt = """name: tt
line: stopline
services:
  - {id: A, train: heavy.yaml, origin: S0, destination: S9, departure: "07:00", stops: [{station: S1}, {station: S2}, {station: S3}]}
"""
    assert _run(tmp_path, monkeypatch, tt) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert [e.split(": ")[2] for e in err] == ["services[0].stops[0].station", "services[0].stops[2].station"], err
    assert all("train heavy is 200 m long, longer than the 180 m platform" in e for e in err)
    assert not (tmp_path / "r").exists()
