"""The reason a convoy follower is not formed, when a platform too short for the pair split the convoy
(unseen round of 2026-11-28).

Two regional EMUs (75 m) stop at Shorty, whose 160 m platform cannot hold both with the 72 m standstill
gap (222 m): the follower waits outside until its leader has left (warned before the run), starts
63 s behind it and never catches up at the line speed (2,183 m too far behind, formed 37 % of its
coupled running).  ``vcsumo run`` printed "not formed: F: at its permitted speed" (with a leader at
its performance limit, "at full traction"): the speed the follower ran at afterwards, not why it was
behind.  Now the time behind after such a stop, until the follower is formed again, is the
platform's, and the reason names it."""

from __future__ import annotations

import json

import pytest

from vcsumo.cli.main import main
from vcsumo.sim.convoy_formation import REASONS, Formation

from .conftest import write

LINE = """
name: shortplat
title: Short platform test line [A]
km_start: 0.0
km_end: 30.0
line_speed_kmh: 160
default_train: regional_emu160
stations:
  - {id: ORG, name: Origin, km: 0.5, platform_length_m: 600, dwell_s: 60}
  - {id: SH, name: Shorty, km: 12.0, platform_length_m: 160, dwell_s: 30}
  - {id: END, name: Endham, km: 29.5, platform_length_m: 500, dwell_s: 60}
signalling: {block_length_m: 1500}
"""
TT = """
name: pair
line: shortplat
services:
  - {id: L, train: regional_emu160, origin: ORG, destination: END, departure: "07:00", stops: [{station: SH, dwell_s: 30}]}
  - {id: F, train: regional_emu160, origin: ORG, destination: END, departure: "07:00", stops: [{station: SH, dwell_s: 30}]}
convoys:
  - {id: C, services: [L, F]}
"""


@pytest.mark.sumo
def test_a_follower_split_off_by_a_short_platform_is_told_so(tmp_path, monkeypatch, capsys):
    write(tmp_path / "line.yaml", LINE)
    write(tmp_path / "tt.yaml", TT)
    monkeypatch.chdir(tmp_path)
    code = main(["run", "--line", "line.yaml", "--timetable", "tt.yaml", "--regime", "vc", "--controller", "cbc", "--out", "r"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "F (regional_emu160, 75 m) cannot stand behind L" in " ".join(cap.err.split())  # warned before the run
    f = json.loads((tmp_path / "r" / "vc_summary.json").read_text())["followers"][0]
    assert f["formed_share"] < 0.5 and f["max_gap_excess_m"] > 1000.0  # formed before Shorty only
    why = "its predecessor left SH without it: the platform (160 m) cannot hold both"
    assert f["not_formed_reason"] == why, f  # main: "at its permitted speed"
    assert f"not formed: F: {why}" in " ".join(cap.out.split())


def test_the_time_behind_after_such_a_stop_is_the_platforms_until_formed_again():
    f = Formation(outside=(None, "SH (160 m)"))
    f.passed_stop(0)
    for k in range(5):  # formed at first
        f.update(k, 1.0, 40.0, 300.0, 300.0, 44.4, 40.0, 40.0)
    f.passed_stop(1)
    for k in range(5, 20):  # behind at full traction after Shorty
        f.update(k, 1.0, 30.0, 2000.0, 300.0, 44.4, 31.0, 31.0, at_full_traction=True)
    assert f.reason() == "its predecessor left SH without it: the platform (160 m) cannot hold both"
    f.update(20, 1.0, 40.0, 300.0, 300.0, 44.4, 40.0, 40.0)  # formed again: later gaps have other causes
    for k in range(21, 60):
        f.update(k, 1.0, 30.0, 2000.0, 300.0, 44.4, 31.0, 31.0, at_full_traction=True)
    assert f.reason() == REASONS[1] == "at full traction"
