"""Fifth round of unseen inputs — a convoy of three at a platform that holds two of them.

A commuter EMU (100 m) leads two regional EMUs (75 m) with per-stop dwells that differ between the
members; Shortb's 250 m platform holds the leader and the first follower 72 m behind it (247 m), and
the first follower and the second one (222 m), but not all three (394 m).  Before the fix a follower's
place in the platform was judged pair by pair (``stands_behind(ego, its predecessor)``): the second
follower, waiting outside the platform behind the first, was taken as standing in it, and the leader
and the first follower were held for its 60 s "dwell" served outside the platform — they left Shortb
at 26,012.4 s instead of 25,973.1 s (the first follower's own 45 s dwell: 84.3 s; the leader 109.2 s),
and the second follower then served its stop on its own.  Now the platform is judged with the members
standing ahead of the predecessor (``platform_queues``): the pair leaves once the first follower has
served its 45 s, the second one enters after and serves its 60 s, and ``vcsumo run`` warns of it."""

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write
from .test_unseen3_mountain import COMMUTER  # a 100 m, 260 t commuter EMU, 120 km/h

LINE = """
name: convoyline
title: Convoy test line (unseen5) [A]
km_start: 0.0
km_end: 40.0
line_speed_kmh: 160
default_train: regional_emu160
stations:
  - {id: ORG, name: Origin, km: 0.5, platform_length_m: 600, dwell_s: 60}
  - {id: SA, name: Steepa, km: 8.0, platform_length_m: 400, dwell_s: 40}
  - {id: SB, name: Shortb, km: 16.0, platform_length_m: 250, dwell_s: 30}
  - {id: SC, name: Splitc, km: 24.0, platform_length_m: 500, dwell_s: 30}
  - {id: END, name: Endham, km: 39.5, platform_length_m: 500, dwell_s: 60}
gradients:
  - {from_km: 6.0, to_km: 10.0, permille: 18.0}
  - {from_km: 14.0, to_km: 18.0, permille: -15.0}
signalling: {block_length_m: 1500}
"""
TT = """
name: three
line: convoyline
services:
  - {id: L, train: commuter.yaml, origin: ORG, destination: SC, departure: "07:00", stops: [{station: SA, dwell_s: 20}, {station: SB, dwell_s: 20}]}
  - {id: M, train: regional_emu160, origin: ORG, destination: END, departure: "07:00", stops: [{station: SA, dwell_s: 70}, {station: SB, dwell_s: 45}, {station: SC, dwell_s: 25}]}
  - {id: N, train: regional_emu160, origin: ORG, destination: END, departure: "07:00", stops: [{station: SA, dwell_s: 50}, {station: SB, dwell_s: 60}, {station: SC, dwell_s: 90}]}
convoys:
  - {id: C, services: [L, M, N]}
"""


def _plan(tmp_path):
    from vcsumo.line import load_line
    from vcsumo.sim.network import build_network
    from vcsumo.timetable import load_timetable, plan_trains

    write(tmp_path / "commuter.yaml", COMMUTER)
    line = load_line(write(tmp_path / "line.yaml", LINE))
    tt, path = load_timetable(write(tmp_path / "tt.yaml", TT), line)
    return plan_trains(tt, path, line, build_network(line).topology)


def test_platform_queues_count_the_members_standing_ahead(tmp_path):
    """At Shortb N's predecessor M stands 172 m short of the stopping point (behind L's 100 m and the
    72 m gap): N would need 394 m; at Steepa (400 m) all three fit (L 100 + 72 + M 75 + 72 + N 75)."""
    from vcsumo.sim.convoy_plan import follower_dwells, platform_queues

    trains = {t.id: t for t in _plan(tmp_path)}
    members = [trains["L"], trains["M"], trains["N"]]
    q = platform_queues(members, {"M": 72.0, "N": 72.0})
    assert q["M"] == {"SA_up": 172.0, "SB_up": 172.0} and q["N"] == {"SA_up": 319.0, "SC_up": 147.0}
    assert follower_dwells(trains["M"], trains["L"], 4, 72.0, q["L"]) == [70.0, 45.0, None, None]  # (L ends at SC)
    assert follower_dwells(trains["N"], trains["M"], 4, 72.0, q["M"]) == [50.0, None, 90.0, None]  # SB: waits outside


@pytest.mark.sumo
def test_a_convoy_of_three_is_not_held_for_a_member_waiting_outside_the_platform(tmp_path, monkeypatch, capsys):
    _plan(tmp_path)
    write(tmp_path / "tt.yaml", TT)
    monkeypatch.chdir(tmp_path)
    code = main(["run", "--line", "line.yaml", "--timetable", "tt.yaml", "--regime", "vc", "--controller", "cbc", "--out", "r"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "stops served 11/11 (skipped 0, short dwell 0)" in cap.out
    assert "convoy M+N: N (regional_emu160, 75 m) cannot stand behind M" in cap.err and "SB (250 m): 394 m needed" in " ".join(cap.err.split())
    ev = pd.read_csv(tmp_path / "r" / "stop_events.csv").set_index(["train", "station"])
    # the pair leaves Shortb once M has served its own 45 s (not N's 60 s, served outside the platform)
    assert ev.loc[("M", "SB"), "dwell_s"] == pytest.approx(45.0, abs=1.0)
    assert abs(ev.loc[("L", "SB"), "departure_s"] - ev.loc[("M", "SB"), "departure_s"]) <= 1.0
    assert ev.loc[("N", "SB"), "arrival_s"] > ev.loc[("M", "SB"), "departure_s"]  # N entered after the pair had left
    assert ev.loc[("N", "SB"), "dwell_s"] >= 60.0 - 0.5
    # at Steepa (400 m) all three stand in the platform: the convoy leaves together once M has served its 70 s
    assert ev.loc[("M", "SA"), "dwell_s"] >= 70.0 - 0.5 and ev.loc[("N", "SA"), "dwell_s"] >= 50.0 - 0.5
    assert ev.xs("SA", level="station").departure_s.max() - ev.xs("SA", level="station").departure_s.min() <= 4.0
