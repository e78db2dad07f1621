"""Tier 1 — topology built from line files: signals, platforms, elevations, routes (no SUMO)."""

import pytest

from vcsumo.line import load_line
from vcsumo.route_profile import RouteProfile
from vcsumo.topology import build_topology, reachable


@pytest.fixture(scope="module")
def bofi():
    return build_topology(load_line("firenze_bologna"))


def test_track_lengths_equal_the_line(bofi):
    for direction in ("up", "down"):
        tr = bofi.track_for("main", direction)
        assert sum(bofi.edges[e].length_m for e in tr.edges) == pytest.approx(91500.0, abs=0.5)
    br = bofi.track_for("san_ruffillo", "up")
    assert sum(bofi.edges[e].length_m for e in br.edges) == pytest.approx(5200.0, abs=0.5)


def test_block_signals_every_1350_m_on_the_open_line(bofi):
    sig = sorted(n.km for n in bofi.nodes.values() if n.signal and n.id.startswith("main_up"))
    open_line = [k for k in sig if 10 < k < 70]
    gaps = [round((b - a) * 1000) for a, b in zip(open_line, open_line[1:])]
    assert set(gaps) == {1350}
    # signals up to the last block before the end of the line
    assert max(sig) > 83.9 - 1.35


def test_block_length_override(bofi):
    topo = build_topology(load_line("firenze_bologna"), block_length_m=2700)
    n_default = sum(1 for n in bofi.nodes.values() if n.signal)
    n_long = sum(1 for n in topo.nodes.values() if n.signal)
    assert n_long < 0.6 * n_default


def test_elevation_follows_the_gradient_profile(bofi):
    # DATASHEET: z = 75 m at SFS 0, 413 m summit at SFS 33, 49.3 m at 78.5
    z = {round(n.km, 3): n.z for n in bofi.nodes.values() if n.id.startswith("main_up")}
    assert z[0.0] == pytest.approx(75.0, abs=0.01)
    assert z[33.0] == pytest.approx(413.0, abs=0.2)
    assert z[78.5] == pytest.approx(49.3, abs=0.2)


def test_platforms_on_both_tracks(bofi):
    plats = bofi.platforms_of("FIRI")
    assert {p.track for p in plats} == {"main_up", "main_down"}
    up = next(p for p in plats if p.track == "main_up")
    assert up.km_stop == pytest.approx(81.1 + 0.225)


def test_branch_connects_both_ways_with_turnout_speed(bofi):
    start, _ = bofi.end_edges("branch:san_ruffillo")
    _, goal = bofi.end_edges("end")
    route = bofi.route_edges(start, goal)
    assert route is not None and bofi.edges[route[-1]].km_to == pytest.approx(83.9)
    prof = RouteProfile.from_edges(bofi, route)
    assert [round(v * 3.6) for _, v in prof.point_limits] == [160]
    # Firenze -> San Ruffillo (down direction diverges at Bivio Emilia)
    s2, _ = bofi.end_edges("end")
    _, g2 = bofi.end_edges("branch:san_ruffillo")
    assert bofi.route_edges(s2, g2) is not None
    # no way from the up track back onto the down track (no reversing)
    assert not (reachable(bofi, bofi.track_for("main", "up").edges[0]) & set(bofi.track_for("main", "down").edges))


def test_curves_become_equivalent_gradient_per_direction(tmp_path):
    from .conftest import write

    p = write(tmp_path / "c" / "line.yaml", """
name: c
km_start: 0
km_end: 4
line_speed_kmh: 160
curves: [{from_km: 1.0, to_km: 2.0, radius_m: 600}]
signalling: {block_length_m: 1000}
""")
    topo = build_topology(load_line(p))
    for d in ("up", "down"):
        prof = RouteProfile.from_edges(topo, topo.track_for("main", d).edges)
        i = prof.index_at(prof.s_of("main", 1.5))
        # 600 m radius ~ 1 permille of equivalent gradient opposing motion in both directions
        assert prof.gradients[i] == pytest.approx(6.0 / (9.81 * 600), rel=1e-9)


