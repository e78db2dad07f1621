"""The train ahead from vcsumo's own route index (vcsumo.sim.trains_ahead, issue 14) is the one the
loop got from SUMO before: getLeader (30 km, minGap added back), else the route walk with driving
distances — the same train and the same gap to 1e-6 m at every step of real runs: convoys driven by
the VC driver, fixed blocks, trains joining and leaving at junctions, single track used both ways.

Where the two differ, tests/train_ahead_check.py names why (trains crossing a junction into the
route or turning off it, the edge of the look-ahead); any other difference fails.
"""

from __future__ import annotations

import warnings

import pytest

from vcsumo.sim import loop
from vcsumo.timetable import load_timetable, plan_trains
from vcsumo.units import parse_clock

from .conftest import write
from .train_ahead_check import TOLERANCE_M, CheckLog, checked_trains_ahead


def _run(tmp_path, monkeypatch, line, net, trains, regime, dt, **kw) -> tuple[CheckLog, dict]:
    logs: list[CheckLog] = []
    monkeypatch.setattr(loop, "TrainsAhead", checked_trains_ahead({t.id: t for t in trains}, logs))
    res = loop.simulate(loop.Scenario(line, net, trains, regime, step_length_s=dt, full_outputs=False, **kw), tmp_path / "run")
    (log,) = logs
    unexplained = [d for d in log.differ if d.why is None]
    assert not unexplained, f"{log}\n" + "\n".join(map(str, unexplained[:10]))
    assert log.max_gap_error_m <= TOLERANCE_M, log
    assert log.searches * 50 < log.train_steps, log  # the train ahead is kept from step to step
    return log, res.summary


def _shipped(line_factory, network_factory, line: str, timetable: str, dt: float):
    from vcsumo.network_file import load_line_or_network
    from vcsumo.sim.network import build_network

    if line == "italy_av_north":  # a network of lines
        ln = load_line_or_network(line)
        net = build_network(ln)
    else:
        ln, net = line_factory(line), network_factory(line)
    tt, p = load_timetable(timetable, ln)
    return ln, net, tt, p, plan_trains(tt, p, ln, net.topology, dt=dt)


@pytest.mark.sumo
def test_fixed_blocks_on_one_line(tmp_path, monkeypatch, line_factory, network_factory):
    """felez_test dense (20 trains, fbs): every answer is getLeader's, to the last bits."""
    ln, net, _, _, trains = _shipped(line_factory, network_factory, "felez_test", "dense", 0.5)
    log, summary = _run(tmp_path, monkeypatch, ln, net, trains, "fbs", 0.5)
    assert not log.differ and log.found > 4000, log
    assert summary["healthy"]


@pytest.mark.sumo
def test_virtually_coupled_convoys(tmp_path, monkeypatch, line_factory, network_factory):
    """regional_graded convoy under vc with cbc: the followers driven by the VC driver get the same
    train ahead; trains on the branch join and leave the main line."""
    from vcsumo.sim.vc_driver import make_vc_driver

    ln, net, tt, p, trains = _shipped(line_factory, network_factory, "regional_graded", "convoy", 0.1)
    driver = make_vc_driver(tt, p, trains, "cbc", 0.1, 42)
    log, summary = _run(tmp_path, monkeypatch, ln, net, trains, "vc", 0.1, driver=driver)
    assert log.found > 80000 and log.from_walk > 1000, log  # beyond SUMO's look-ahead too
    assert len(log.differ) < log.found / 300, log
    assert summary["healthy"] and driver.summary()["coupled_steps"] > 1000


@pytest.mark.sumo
def test_junctions_of_a_network(tmp_path, monkeypatch, line_factory, network_factory):
    """italy_av_north full_day under fbs until 07:00: lines join and part at junctions; trains turning
    off the route count until their rear has left it (as getLeader sees them), trains crossing
    into it from the moment their front is inside the junction."""
    ln, net, _, _, trains = _shipped(line_factory, network_factory, "italy_av_north", "full_day", 0.5)
    log, _ = _run(tmp_path, monkeypatch, ln, net, trains, "fbs", 0.5, end_time_s=parse_clock("07:00"))
    why = log.why()
    assert log.found > 80000 and log.turning_off > 20, log  # getLeader sees a train turning off: so does the index
    assert why.get("junction", 0) > 0 and why.get("crossing in", 0) > 0 and why.get("turning off", 0) > 0, log  # (exercised)
    assert len(log.differ) < log.found / 300, log


@pytest.mark.sumo
@pytest.mark.parametrize("supervise", [True, False])
def test_single_track_used_both_ways(tmp_path, monkeypatch, supervise):
    """Single track (an edge and its twin per piece of track): followers behind each other on it,
    an opposing train never the train ahead — also when, without supervision, two opposing trains
    run into each other on a single-track branch (tests/test_single_track.py's fixtures)."""
    from vcsumo.line import load_line
    from vcsumo.sim.network import build_network

    from .test_network_unseen import DSB, DSB_HEAD_ON
    from .test_single_track import THREE, _net

    if supervise:
        line = _net(tmp_path)
        text = THREE
    else:
        line = load_line(write(tmp_path / "dsb" / "line.yaml", DSB))
        text = DSB_HEAD_ON
    built = build_network(line)
    tt, path = load_timetable(write(tmp_path / "tt.yaml", text), line)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (timetabled onto the same single track in opposite directions)
        trains = plan_trains(tt, path, line, built.topology)
    log, summary = _run(tmp_path, monkeypatch, line, built, trains, "fbs", 0.5, supervise=supervise)
    assert not log.differ, log
    assert log.found > 1000 if supervise else log.found == 0, log  # (head on: nobody ahead, for either)
    assert summary["trains_arrived"] == len(trains)


# ------------------------------------------------------------------------------------------ without SUMO
class _Track:
    """A made-up network for :class:`TrainsAhead` without SUMO: edge lengths and junction passages."""

    LENGTHS = {"a": 1000.0, "b": 800.0, "c": 1200.0, "d": 900.0, "e": 700.0}
    PASSAGES = {("a", "b"): 0.1, ("b", "c"): 12.5, ("c", "a"): 0.1, ("b", "d"): 20.0, ("e", "c"): 18.0, ("d", "e"): 0.1}

    def __init__(self):
        self.gone: list[str] = []

    def arrived(self):
        return list(self.gone)

    def train_length(self, vid):
        return 150.0 if vid != "long" else 400.0

    def edge_length(self, edge):
        return self.LENGTHS[edge]

    def junction_passage(self, a, b):
        return [(f":{a}{b}", self.PASSAGES[(a, b)])]

    def where(self, route: list[str], x: float) -> tuple[str, float, int]:
        """(edge or junction, position on it, route index) of route position x."""
        s = 0.0
        for k, e in enumerate(route):
            if x < s + self.LENGTHS[e] or k == len(route) - 1:
                return e, x - s, k
            s += self.LENGTHS[e]
            inner = self.PASSAGES[(e, route[k + 1])]
            if x < s + inner:
                return f":{e}{route[k + 1]}", x - s, k
            s += inner
        raise AssertionError


def _ahead_by_definition(track: _Track, routes, fronts, lengths, vid, look):
    """The nearest train whose body lies on ``vid``'s route ahead of its front, from scratch: every
    edge of every other train's body (a front inside a junction counts on the edge it enters) at
    every place the route passes that edge ahead of ``vid``; beyond the look-ahead where the track
    holding its rear begins within it (an edge begins where the junction before it begins)."""
    def spans(route):
        out, s = [], 0.0
        for k, e in enumerate(route):
            before = track.PASSAGES[(route[k - 1], e)] if k else 0.0
            out.append((e, s + before, s + before + track.LENGTHS[e], before))
            s += before + track.LENGTHS[e]
        return out

    mine = spans(routes[vid])
    x = fronts[vid]
    k_front = max(j for j, (_, start, _, before) in enumerate(mine) if start - before <= x)
    best = None
    for oid, xo in fronts.items():
        if oid == vid:
            continue
        for e, start, end, before in spans(routes[oid]):
            if not (xo - lengths[oid] < end and xo >= start - before):
                continue
            for j, (e2, start2, _, _) in enumerate(mine):
                if e2 == e and j >= k_front and start2 + xo - start > x:
                    gap = start2 + xo - lengths[oid] - start - x
                    if best is None or gap < best[1] - 1e-9:
                        best = (oid, gap)
                    break
    if best is None or best[1] <= look:
        return best
    rear = x + best[1]  # beyond the look-ahead: seen where the track (edge, or junction before it) holding its rear begins within it
    for j, (_, start, end, before) in enumerate(mine):
        if start - before <= rear < end:
            return best if j <= k_front or start - before - x <= look else None
    return None


def test_trains_ahead_on_routes_passing_an_edge_twice():
    """Without SUMO, on a made-up network where a route runs round a loop (a b c a b d e c): trains
    departing mid-route (also behind it, on the edges it passes again), joining from another line,
    turning off, a long train over several edges; at every step the kept answers are those found
    from scratch by definition."""
    from vcsumo.sim.trains_ahead import TrainsAhead

    track = _Track()
    routes = {"loop": ["a", "b", "c", "a", "b", "d", "e", "c"], "long": ["a", "b", "d", "e", "c"], "join": ["e", "c", "a", "b", "c"],
              "late": ["c", "a", "b", "d"], "hop": ["b", "d", "e"], "bc": ["b", "c"]}
    plan = {"loop": (0, 300.0, 31.0), "long": (40, 420.0, 27.0), "join": (150, 200.0, 22.0), "late": (90, 150.0, 24.0),
            "hop": (60, 300.0, 30.0), "bc": (160, 100.0, 20.0)}  # (step, x, m/step: none catches up with another)
    ends = {vid: sum(track.LENGTHS[e] for e in r) + sum(track.PASSAGES[p] for p in zip(r, r[1:])) for vid, r in routes.items()}
    lengths = {vid: track.train_length(vid) for vid in routes}
    finder = TrainsAhead(track, routes, 2500.0)
    fronts: dict[str, float] = {}
    found = compared = 0
    for step in range(196):  # (then "loop" would catch up with "bc" where they join)
        track.gone = [vid for vid, x in fronts.items() if x >= ends[vid] - 1.0]
        for vid in track.gone:
            del fronts[vid]
        for vid, (at, x0, v) in plan.items():
            if step == at:
                fronts[vid] = x0
            elif vid in fronts:
                fronts[vid] += v
        ids = sorted(fronts)
        observed = []
        for vid in ids:
            fronts[vid] = min(fronts[vid], ends[vid] - 0.5)
            e, pos, k = track.where(routes[vid], fronts[vid])
            observed.append((e, pos, 0.0, 0.0, 0.0, k))
        got = finder.leaders(ids, observed)
        for vid, answer in zip(ids, got):
            want = _ahead_by_definition(track, routes, fronts, lengths, vid, 2500.0)
            assert (answer is None) == (want is None) and (want is None or (answer[0] == want[0] and abs(answer[1] - want[1]) < 1e-6)), \
                (step, vid, answer, want, fronts)
            compared += 1
            found += want is not None
    assert compared > 600 and found > 300, (compared, found, finder.searches)
    assert finder.searches < compared / 5, (compared, found, finder.searches)
