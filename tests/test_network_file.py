"""Tier 1 — networks of lines: loading, checks, the stitched topology, routes across lines (no SUMO)."""

import warnings

import pytest

from vcsumo.errors import InputError
from vcsumo.line import Line, load_line
from vcsumo.network_file import Network, load_line_or_network, load_network
from vcsumo.network_topology import build_network_topology
from vcsumo.route_profile import RouteProfile
from vcsumo.timetable import load_timetable, plan_trains
from vcsumo.topology import build_topology, reachable

from .conftest import write

# Two lines with their own chainage: alpha (km 0-10) runs into beta (km 100-112) at beta's start;
# beta has a branch (spur) at km 105 leaving towards its end; gamma's start joins alpha at km 5
# running alongside it towards alpha's start (gamma's trains merge into alpha's up track).
ALPHA = """
name: alpha
km_start: 0.0
km_end: 10.0
line_speed_kmh: 160
default_train: etr1000
stations:
  - {id: AST, name: Alpha, km: 1.0, platform_length_m: 700, dwell_s: 30}
gradients:
  - {from_km: 6.0, to_km: 8.0, permille: 5.0}
signalling: {block_length_m: 1000}
"""
BETA = """
name: beta
km_start: 100.0
km_end: 112.0
start_elevation_m: 300.0
line_speed_kmh: 160
default_train: etr1000
stations:
  - {id: BEND, name: Beta, km: 111.0, platform_length_m: 400, dwell_s: 30}
signalling: {block_length_m: 1000}
branches:
  - id: spur
    name: Spur
    junction_km: 105.0
    leaves_towards: end
    length_m: 4000
    speed_kmh: 120
    diverging_speed_kmh: 80
    stations:
      - {id: SPUR, name: Spur, km: 3.0, platform_length_m: 400, dwell_s: 30}
"""
GAMMA = """
name: gamma
km_start: 0.0
km_end: 4.0
line_speed_kmh: 120
signalling: {block_length_m: 1000}
stations:
  - {id: GST, name: Gamma, km: 3.0, platform_length_m: 400}
"""
NET = """
name: twolines
lines:
  - {line: alpha.yaml}
  - {line: beta.yaml}
  - {line: gamma.yaml}
joins:
  - {id: ab, end: {line: alpha, at: end}, meets: {line: beta, km: 100.0}}
  - {id: gj, end: {line: gamma, at: start}, meets: {line: alpha, km: 5.0}, towards: start, diverging_speed_kmh: 60}
"""


def make_network(folder, net=NET, alpha=ALPHA, beta=BETA, gamma=GAMMA):
    write(folder / "alpha.yaml", alpha)
    write(folder / "beta.yaml", beta)
    write(folder / "gamma.yaml", gamma)
    return write(folder / "network.yaml", net)


@pytest.fixture
def two(tmp_path):
    return load_network(make_network(tmp_path / "net"))


def test_network_is_a_line_with_every_station(two):
    assert isinstance(two, Network) and two.name == "twolines"
    assert sorted(two.all_station_ids()) == ["AST", "BEND", "GST", "SPUR"]
    assert two.station("SPUR")[0] == "beta.spur" and two.station("AST")[0] == "alpha.main"
    assert two.default_train == "etr1000"
    assert len(two.source_files()) == 4
    with pytest.raises(InputError) as exc:
        two.data  # studies made for one line stop here, naming the network file
    assert "network.yaml" in str(exc.value) and "one line" in str(exc.value)


def test_joined_topology(two):
    topo = build_network_topology(two)
    # alpha's up track runs on into beta's up track at one node, which is a signal
    a_last, b_first = topo.tracks["alpha.main_up"].edges[-1], topo.tracks["beta.main_up"].edges[0]
    assert b_first in topo.successors[a_last]
    assert topo.edges[a_last].to_node == topo.edges[b_first].from_node
    assert topo.edges[b_first].from_node in topo.signal_nodes()
    assert topo.tracks["beta.main_down"].edges[-1] in topo.edges and topo.tracks["alpha.main_down"].edges[0] in topo.successors[topo.tracks["beta.main_down"].edges[-1]]
    # the nodes meet in the plane and in elevation: beta is moved to alpha's end (z 10 m after +5 ‰ over 2 km)
    n = topo.nodes[topo.edges[b_first].from_node]
    assert (n.x, n.y, n.z) == pytest.approx((10000.0, 0.0, 10.0), abs=1e-6)
    # chainage stays per line; open ends are named per line, joined ends are not open
    assert set(topo.endpoints) == {"alpha:start", "beta:end", "beta:branch:spur", "gamma:end"}
    assert {p.station_id: p.km_stop for p in topo.platforms.values() if p.track == "beta.main_up"} == {"BEND": pytest.approx(111.2)}
    # gamma leaves alpha through a junction at km 5 with the turnout speed both ways
    into_g, out_g = topo.tracks["gamma.main_up"].edges[0], topo.tracks["gamma.main_down"].edges[-1]
    diverge = [(a, b) for (a, b) in topo.turnout_speed_ms if b == into_g]
    merge = [(a, b) for (a, b) in topo.turnout_speed_ms if a == out_g]
    assert len(diverge) == 1 and topo.edges[diverge[0][0]].track == "alpha.main_down" and topo.edges[diverge[0][0]].km_to == pytest.approx(5.0)
    assert len(merge) == 1 and topo.edges[merge[0][1]].track == "alpha.main_up" and topo.edges[merge[0][1]].km_from == pytest.approx(5.0)
    assert topo.turnout_speed_ms[diverge[0]] == pytest.approx(60 / 3.6)
    assert set(topo.named_nodes) == {"ab", "gj"}
    # every edge can be reached from an open end
    seen = set()
    for starts, _ in topo.endpoints.values():
        seen |= reachable(topo, starts[0])
    assert seen == set(topo.edges)
    # lengths are the lines' own
    assert sum(topo.edges[e].length_m for e in topo.tracks["alpha.main_up"].edges) == pytest.approx(10000.0)
    assert sum(topo.edges[e].length_m for e in topo.tracks["beta.spur_up"].edges) == pytest.approx(4000.0)


TT = """
name: t
line: twolines
services:
  - {id: THRU, train: etr1000, origin: AST, destination: BEND, departure: "07:00"}
  - {id: SP, train: etr1000, origin: AST, destination: SPUR, departure: "07:00:30"}
  - {id: G, train: etr1000, origin: GST, destination: "beta:end", departure: "07:00", via: [gj]}
  - {id: BACK, train: etr1000, origin: "beta:branch:spur", destination: "alpha:start", departure: "07:00", stops: [{station: AST}], repeat: {every_s: 1800, until: "08:00"}}
"""


def test_services_route_across_lines(tmp_path, two):
    topo = build_network_topology(two)
    tt, path = load_timetable(write(tmp_path / "tt.yaml", TT), two)
    trains = {t.id: t for t in plan_trains(tt, path, two, topo)}
    thru = trains["THRU"]
    assert {topo.edges[e].section for e in thru.edges} == {"alpha.main", "beta.main"}
    assert thru.final_stop.station == "BEND"
    prof = RouteProfile.from_edges(topo, thru.edges)
    # alpha from the platform end (km 1.35) to 10, beta from 100 to the platform end (111.2)
    assert thru.final_stop.s_m - thru.start_s_m == pytest.approx((10.0 - 1.35 + 111.2 - 100.0) * 1000.0, abs=0.5)
    assert prof.km_at(thru.final_stop.s_m - 1.0) == ("beta.main", pytest.approx(111.199, abs=1e-3))
    assert any(topo.edges[e].section == "beta.spur" for e in trains["SP"].edges)
    assert [topo.edges[e].section for e in trains["G"].edges][0] == "gamma.main"
    assert [s.station for s in trains["BACK.1"].stops] == ["AST"] and trains["BACK.3"].depart_s == pytest.approx(8 * 3600)
    assert "BACK.4" not in trains


@pytest.mark.parametrize(
    "mutation,field,words",
    [
        (("origin: AST, destination: BEND", "origin: AST, destination: alpha:end"), "services[0].destination", "no open end"),
        (("via: [gj]", "via: [nowhere]"), "services[2].via[0]", "unknown node or station"),
        (("destination: \"beta:end\", departure: \"07:00\", via: [gj]", "destination: \"alpha:start\", departure: \"07:00\", via: [ab]"),
         "services[2].destination", "no route"),
        (("until: \"08:00\"", "until: \"06:00\""), "services[3].repeat.until", "before the departure"),
        (("repeat: {every_s: 1800, until: \"08:00\"}", "repeat: {every_s: 1800, until: \"08:00\", count: 2}"), "services[3].repeat", "count or until"),
    ],
)
def test_bad_network_timetable(tmp_path, two, mutation, field, words):
    topo = build_network_topology(two)
    assert mutation[0] in TT
    path = write(tmp_path / "tt.yaml", TT.replace(*mutation))
    with pytest.raises(InputError) as exc:
        tt, path = load_timetable(path, two)
        plan_trains(tt, path, two, topo)
    assert str(path) in str(exc.value) and field in str(exc.value) and words in str(exc.value)


@pytest.mark.parametrize(
    "old,new,field,words",
    [
        ("{line: gamma.yaml}", "{line: delta.yaml}", "lines[2].line", "not found"),
        ("{line: gamma.yaml}", "{line: atlantis}", "lines[2].line", "unknown line 'atlantis'"),
        ("at: end}", "at: km 10}", "joins[0].end.at", "should match pattern"),
        ("at: end}", "at: branch:spur}", "joins[0].end.at", "no branch 'spur'"),
        ("km: 100.0}", "km: 99.0}", "joins[0].meets.km", "outside line beta"),
        ("km: 100.0}", "km: 100.005}", "joins[0].meets.km", "within 10 m of an end"),
        ("km: 5.0}, towards: start", "km: 11.0}, towards: start", "joins[1].meets.km", "outside line alpha"),
        ("km: 5.0}, towards: start", "km: 1.1}, towards: start", "joins[1].meets.km", "inside the platform of station 'AST'"),
        (", towards: start", "", "joins[1].towards", "needs towards"),
        ("meets: {line: beta, km: 100.0}}", "meets: {line: beta, km: 100.0}, towards: end}", "joins[0].towards", "continue into each other"),
        ("{line: beta, km: 100.0}", "{line: omega, km: 100.0}", "joins[0].meets.line", "not a line of the network"),
        ("{line: beta, km: 100.0}", "{line: alpha, km: 0.0}", "joins[0].meets.line", "cannot join itself"),
        ("{id: gj,", "{id: ab,", "joins[1].id", "duplicate node name"),
        ("{id: gj,", "{id: AST,", "joins[1].id", "also a station id"),
        ("  - {id: gj, end: {line: gamma, at: start}, meets: {line: alpha, km: 5.0}, towards: start, diverging_speed_kmh: 60}\n", "",
         "lines[2].line", "not joined to line alpha"),
        ("joins:\n", "joins:\n  - {id: ba, end: {line: beta, at: end}, meets: {line: alpha, km: 0.0}}\n", "joins[1]", "loop"),
        ("{line: alpha.yaml}", "{line: alpha.yaml, to_km: 1.1}", "lines[0].to_km", "cuts through the platform of station 'AST'"),
        ("{line: alpha.yaml}", "{line: alpha.yaml, from_km: -1.0}", "lines[0].from_km", "outside line alpha"),
        ("{line: beta.yaml}", "{line: beta.yaml, branches: [spurious]}", "lines[1].branches[0]", "no branch 'spurious'"),
        ("name: twolines", "name: twolines\nstations: []", "stations", "unknown key"),
        # a turnout faster than the joining line (120 km/h), as a line file refuses for a branch (until 2026-12-01 accepted)
        ("diverging_speed_kmh: 60}", "diverging_speed_kmh: 400}", "joins[1].diverging_speed_kmh", "400 km/h exceeds the line speed of gamma (120 km/h)"),
    ],
)
def test_bad_network_file_names_file_and_field(tmp_path, old, new, field, words):
    assert old in NET
    path = make_network(tmp_path / "net", net=NET.replace(old, new))
    with pytest.raises(InputError) as exc:
        load_line_or_network(path)
    msg = str(exc.value)
    assert str(path) in msg and field in msg and words in msg, msg
    assert "\n" not in msg


def test_duplicate_station_ids_across_lines(tmp_path):
    path = make_network(tmp_path / "net", gamma=GAMMA.replace("id: GST", "id: AST"))
    with pytest.raises(InputError) as exc:
        load_network(path)
    assert str(path) in str(exc.value) and "lines[2].line" in str(exc.value) and "station id 'AST'" in str(exc.value)


def test_part_of_a_line_keeps_its_signals_and_chainage(tmp_path):
    """A line used from km 2: the same block markers as the whole line, elevation continued."""
    net = NET.replace("{line: alpha.yaml}", "{line: alpha.yaml, from_km: 2.0}").replace(
        "{id: gj, end: {line: gamma, at: start}, meets: {line: alpha, km: 5.0}", "{id: gj, end: {line: gamma, at: start}, meets: {line: alpha, km: 5.5}")
    two = load_network(make_network(tmp_path / "net", net=net))
    assert "AST" not in two.all_station_ids()
    topo = build_network_topology(two)
    sig = sorted(round(topo.nodes[topo.edges[e].to_node].km, 3) for e in topo.tracks["alpha.main_up"].edges[:-1] if topo.edges[e].to_node in topo.signal_nodes())
    assert sig == [3.0, 4.0, 5.0, 5.5, 6.0, 7.0, 8.0, 9.0]
    whole = build_network_topology(load_network(make_network(tmp_path / "whole")))
    z_whole = {round(n.km, 3): n.z for k, n in whole.nodes.items() if k.startswith("alpha.main_up")}
    z_part = {round(n.km, 3): n.z for k, n in topo.nodes.items() if k.startswith("alpha.main_up")}
    assert z_part[8.0] - z_part[6.0] == pytest.approx(z_whole[8.0] - z_whole[6.0]) == pytest.approx(10.0)


def test_block_origin_counts_the_regular_markers(tmp_path):
    """``block_origin_km``: the markers of a line cut from a longer one, counted from the longer
    line's start; given without ``block_length_m`` it names the field."""
    two = load_network(make_network(tmp_path / "net"))
    d = two.lines["alpha"].data
    cut = Line(d.model_copy(update={"signalling": d.signalling.model_copy(update={"block_origin_km": 0.3})}), two.lines["alpha"].path)
    topo = build_topology(cut)
    sig = sorted(round(topo.nodes[topo.edges[e].to_node].km, 3) for e in topo.tracks["main_up"].edges[:-1] if topo.edges[e].to_node in topo.signal_nodes())
    assert [k for k in sig if 2.0 < k < 5.0] == [2.3, 3.3, 4.3]
    bad = write(tmp_path / "bad.yaml", ALPHA.replace("signalling: {block_length_m: 1000}", "signalling: {signals_km: [2.0], block_origin_km: 0.5}"))
    with pytest.raises(InputError) as exc:
        load_line(bad)
    assert "signalling" in str(exc.value) and "block_origin_km" in str(exc.value)


def test_shipped_network_and_line_names(root):
    net = load_line_or_network("italy_av_north")
    assert isinstance(net, Network) and set(net.lines) == {"milano_bologna", "firenze_bologna", "venezia_link"}
    assert sorted(net.all_station_ids()) == ["BOAV", "FIRI", "FISMN", "MIRO", "REAV"]
    assert not isinstance(load_line_or_network("milano_bologna"), Network)
    with pytest.raises(InputError) as exc:  # the single-line loader points at the network
        load_line("italy_av_north")
    assert "network of lines" in str(exc.value) and "network.yaml" in str(exc.value)
    with warnings.catch_warnings(record=True) as said:  # a line's regular block markers cut with it are not the user's signals
        warnings.simplefilter("always")
        topo = build_network_topology(net)
    assert not [str(w.message) for w in said if "signals_km" in str(w.message)]  # (milano_bologna's marker at 85.55 km was said)
    # Milano -> Firenze and Venezia -> Firenze run through; Firenze -> Venezia splits at Bivio Venezia
    for a, b in (("MIRO", "FISMN"), ("venezia_link:end", "FISMN"), ("FISMN", "venezia_link:end"), ("FISMN", "MIRO")):
        starts = [p.edge for p in topo.platforms_of(a)] if a in net.all_station_ids() else topo.end_edges(a)[0]
        goals = [p.edge for p in topo.platforms_of(b)] if b in net.all_station_ids() else topo.end_edges(b)[1]
        assert topo.route_edges(starts, goals) is not None, (a, b)
    # the Bologna passante is modelled once: firenze_bologna's, with its Bologna C.le AV platform
    assert {p.section for p in topo.platforms_of("BOAV")} == {"firenze_bologna.main"}
    assert topo.named_nodes["bivio_venezia"] and topo.named_nodes["bologna_av_nord"]


# -- fuzzing: any mutation of a valid network file loads or gives one VcsumoError naming the file
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
import yaml  # noqa: E402

from vcsumo.errors import VcsumoError  # noqa: E402

_NET = yaml.safe_load(NET)
_NET_PATHS = [("name",), ("lines", 0, "line"), ("lines", 1, "from_km"), ("lines", 1, "to_km"), ("lines", 1, "branches"),
              ("joins", 0, "id"), ("joins", 0, "end", "at"), ("joins", 0, "end", "line"), ("joins", 0, "meets", "km"),
              ("joins", 1, "meets", "km"), ("joins", 1, "towards"), ("joins", 1, "diverging_speed_kmh"), ("joins",), ("lines",)]
_HOSTILE = st.one_of(st.sampled_from([0, -1, 1e300, float("nan"), float("inf"), "", "end", "start", "branch:spur", "beta", [], {}, None, True]),
                     st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=6))


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(path=st.sampled_from(_NET_PATHS), value=_HOSTILE)
def test_fuzzed_network_files_never_crash(tmp_path_factory, path, value):
    import copy

    data = copy.deepcopy(_NET)
    node = data
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    folder = tmp_path_factory.mktemp("fz")
    net_path = make_network(folder, net=yaml.safe_dump(data))
    try:
        net = load_network(net_path)
    except VcsumoError as exc:
        assert str(net_path) in str(exc) or str(folder) in str(exc), str(exc)
        assert "\n" not in str(exc)
        return
    build_network_topology(net)  # a network that loads builds


def test_study_files_name_a_network_only_for_batch(tmp_path):
    from vcsumo.cli.study_files import load_study

    batch = write(tmp_path / "b.yaml", "study: batch\nline: italy_av_north\ntimetables: routes/italy_av_north/full_day.yaml\nregimes: [fbs]\nseeds: 1\n")
    assert load_study(batch).line == "italy_av_north"
    headway = write(tmp_path / "h.yaml", "study: headway\nline: italy_av_north\n")
    with pytest.raises(InputError) as exc:
        load_study(headway)
    assert "network of lines" in str(exc.value)


def test_every_problem_of_a_network_file_is_one_line(tmp_path, capsys, monkeypatch):
    """Two joins at a km outside their line: each problem is one line naming the file and the field,
    as a line file's are (until 2026-12-01 the first and '(and 1 more problem)', the second never shown)."""
    from vcsumo.cli.main import main

    monkeypatch.setenv("VCSUMO_CACHE", str(tmp_path / "cache"))
    path = make_network(tmp_path / "net", net=NET.replace("km: 100.0}", "km: 99.0}").replace("km: 5.0}, towards: start", "km: 11.0}, towards: start"))
    assert main(["build-network", "--line", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2, err
    assert err[0].startswith(f"error: {path}: joins[0].meets.km: 99.0 km lies outside line beta"), err
    assert err[1].startswith(f"error: {path}: joins[1].meets.km: 11.0 km lies outside line alpha"), err
    assert not (tmp_path / "cache").exists() or not list((tmp_path / "cache").rglob("*.net.xml"))
