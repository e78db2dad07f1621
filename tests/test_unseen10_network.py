"""Tier 2 — networks of lines on unseen inputs (round 10): four made-up lines (west with a branch
whose far end meets south mid-line, east continuing west with its own chainage, a single-track
north line joined inside east) and the defects they showed."""

from pathlib import Path

import pytest

from vcsumo.cli.main import main

from .conftest import write

pytestmark = pytest.mark.sumo

WEST = """
name: west
km_start: 0.0
km_end: 6.0
line_speed_kmh: 160
default_train: etr1000
stations:
  - {id: WA, name: Westa, km: 0.5, platform_length_m: 400, dwell_s: 30}
  - {id: WB, name: Westb, km: 5.5, platform_length_m: 400, dwell_s: 40}
signalling: {block_length_m: 1000}
branches:
  - {id: spur, name: Spur, junction_km: 3.0, leaves_towards: end, length_m: 2000, speed_kmh: 100, diverging_speed_kmh: 60}
"""
EAST = """
name: east
km_start: 20.0
km_end: 28.0
line_speed_kmh: 120
start_elevation_m: 100
stations:
  - {id: EA, name: Easta, km: 22.0, platform_length_m: 400, dwell_s: 35}
  - {id: EB, name: Eastb, km: 27.5, platform_length_m: 400, dwell_s: 30}
gradients:
  - {from_km: 23.0, to_km: 26.0, permille: 8.0}
signalling: {block_length_m: 1500}
"""
NORTH = """
name: north
km_start: 0.0
km_end: 5.0
tracks: single
line_speed_kmh: 100
stations:
  - {id: NA, name: Northa, km: 4.5, platform_length_m: 400, dwell_s: 30}
signalling: {block_length_m: 800}
"""
SOUTH = """
name: south
km_start: 0.0
km_end: 4.0
line_speed_kmh: 140
stations:
  - {id: SA, name: Southa, km: 0.5, platform_length_m: 400, dwell_s: 30}
  - {id: SB, name: Southb, km: 3.5, platform_length_m: 400, dwell_s: 30}
signalling: {block_length_m: 1000}
"""
EXTRA = """
name: extra
km_start: 0.0
km_end: 3.0
line_speed_kmh: 120
stations:
  - {id: XA, name: Extra, km: 2.5, platform_length_m: 400, dwell_s: 30}
signalling: {block_length_m: 1000}
"""
NET = """
name: n1
lines:
  - {line: west.yaml}
  - {line: east.yaml}
  - {line: north.yaml}
  - {line: south.yaml}
joins:
  - {id: we, end: {line: west, at: end}, meets: {line: east, km: 20.0}}
  - {id: nj, end: {line: north, at: start}, meets: {line: east, km: 25.0}, towards: end, diverging_speed_kmh: 60}
  - {id: sj, end: {line: west, at: "branch:spur"}, meets: {line: south, km: 2.0}, towards: start, diverging_speed_kmh: 60}
"""


def make_net(folder: Path, net: str = NET) -> Path:
    for name, text in (("west", WEST), ("east", EAST), ("north", NORTH), ("south", SOUTH), ("extra", EXTRA)):
        write(folder / f"{name}.yaml", text)
    return write(folder / "network.yaml", net)


@pytest.mark.parametrize("km,towards,words", [
    (25.0, "end", "closer than 200 m to the junction of joins[1] (nj) on the same side"),
    (25.05, "end", "closer than 200 m to the junction of joins[1] (nj) on the same side"),
])
def test_two_joins_at_one_junction_on_the_same_side_are_refused(in_tmp, capsys, monkeypatch, km, towards, words):
    """A second line joined within 200 m of another join's junction on the same side (the README's
    check, made for branches only): both lines were stitched to the same node (or 50 m apart),
    drawn on top of each other, and 'via' could not tell the two nodes apart — built without a word."""
    monkeypatch.setenv("VCSUMO_CACHE", str(in_tmp / "cache"))
    net = NET.replace("  - {line: south.yaml}\n", "  - {line: south.yaml}\n  - {line: extra.yaml}\n") + (
        f"  - {{id: xj, end: {{line: extra, at: start}}, meets: {{line: east, km: {km}}}, towards: {towards}, diverging_speed_kmh: 60}}\n")
    path = make_net(in_tmp / "net", net)
    assert main(["build-network", "--line", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "joins[3].meets.km" in err[0] and words in err[0], err
    assert not (in_tmp / "cache").exists() or not list((in_tmp / "cache").rglob("*.net.xml"))


def test_a_join_on_the_other_side_of_a_junction_is_kept(in_tmp, monkeypatch):
    monkeypatch.setenv("VCSUMO_CACHE", str(in_tmp / "cache"))
    net = NET.replace("  - {line: south.yaml}\n", "  - {line: south.yaml}\n  - {line: extra.yaml}\n") + (
        "  - {id: xj, end: {line: extra, at: start}, meets: {line: east, km: 25.0}, towards: start, diverging_speed_kmh: 60}\n")
    assert main(["build-network", "--line", str(make_net(in_tmp / "net", net))]) == 0


def test_a_network_file_listed_as_a_line_names_the_field(in_tmp, capsys):
    """A network listing another network file as a line: the error named the other network file
    with no field ('this is a network of lines: this needs one line'), not where it was listed."""
    other = make_net(in_tmp / "other")
    path = make_net(in_tmp / "net", NET.replace("{line: north.yaml}", f"{{line: {other}}}"))
    assert main(["build-network", "--line", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {path}: lines[2].line: ") and "is a network file" in err[0], err


def test_double_track_line_joined_inside_a_single_track_line_does_not_deadlock(in_tmp, monkeypatch):
    """extra (double track) joined inside north (single track) at km 2.0: U1 leaves north's single
    track onto extra while U2, coming off extra, waits for that single track. U2 stood at the
    junction signal, and SUMO's signal, seeing it there, kept U1 from leaving the single track through
    the crossing link — under mb nobody moved again (0/3 arrived at 09:33, 'not healthy'); under fbs
    U2 overran its end of authority by 10.2 m. Now extra's last edge is single track too (its two
    tracks converge one signal before the junction) and both regimes run clean."""
    import json

    monkeypatch.setenv("VCSUMO_CACHE", str(in_tmp / "cache"))
    net = write(in_tmp / "net" / "network.yaml", """
name: n5
lines:
  - {line: north.yaml}
  - {line: extra.yaml}
joins:
  - {id: xj, end: {line: extra, at: end}, meets: {line: north, km: 2.0}, towards: end, diverging_speed_kmh: 50}
""")
    write(in_tmp / "net" / "north.yaml", NORTH)
    write(in_tmp / "net" / "extra.yaml", EXTRA)
    tt = write(in_tmp / "tt.yaml", """
name: tt
line: n5
services:
  - {id: U1, train: etr1000, origin: "north:start", destination: XA, departure: "08:00"}
  - {id: U2, train: etr1000, origin: XA, destination: "north:start", departure: "08:00"}
  - {id: U3, train: etr1000, origin: NA, destination: "north:start", departure: "08:02"}
""")
    for regime in ("mb", "fbs"):
        rc = main(["run", "--line", str(net), "--timetable", str(tt), "--regime", regime, "--end-time", "08:20", "--out", regime])
        s = json.loads((in_tmp / regime / "summary.json").read_text())
        assert (rc, s["trains_arrived"], s["authority_overruns"], s["collisions"], s["healthy"]) == (0, 3, 0, 0, True), (regime, s)
