"""The loop skips a train's braking curves only where they cannot matter (BrakingCurveSupervisor.quiet).

At every step of real SUMO runs — fixed block and moving block, fixed times, graded lines with
stops, junctions on a network, single track used both ways, a slow heavy freight train — every time
``quiet`` answers yes, the full :meth:`BrakingCurveSupervisor.permitted` is computed as well and must
say the same: no permitted speed (nothing within reach) and an end of movement authority beyond any
overrun.  The runs also check that the shortcut is taken (most steps on open line) and that the full
rule does act in them (finite permitted speeds), so the comparison is not empty."""

from __future__ import annotations

import math
import warnings

import pytest

from vcsumo.line import load_line
from vcsumo.sim import supervision as sup
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write
from .test_network_unseen import DSB, DSB_HEAD_ON, FREIGHT, _net
from .test_unseen3_mountain import ALPINE, COMMUTER

pytestmark = pytest.mark.sumo

MOUNTAIN_TT = """
name: mixed
line: alpine
services:
  - {id: U1, train: commuter.yaml, origin: VAL, destination: TOP, departure: "07:00", stops: [{station: MID}, {station: STP}]}
  - {id: U2, train: freight.yaml, origin: VAL, destination: TOP, departure: "07:02"}
  - {id: U3, train: commuter.yaml, origin: VAL, destination: TOP, departure: "07:03", stops: [{station: MID}]}
  - {id: D1, train: freight.yaml, origin: TOP, destination: VAL, departure: "07:00"}
  - {id: D2, train: commuter.yaml, origin: TOP, destination: VAL, departure: "07:01:30", stops: [{station: STP}, {station: MID}]}
"""
NETWORK_TT = """
name: t
line: ridge_net
services:
  - {id: F1, train: freight.yaml, origin: "coast:start", destination: "ridge:start", departure: "08:00"}
  - {id: R1, train: regional_emu160, origin: CST, destination: PRT, departure: "08:01", stops: [{station: EDG}]}
  - {id: E1, train: etr1000, origin: RDG, destination: PRT, departure: "08:03"}
  - {id: E2, train: etr1000, origin: PRT, destination: RDG, departure: "08:00"}
"""


@pytest.fixture
def checked(monkeypatch):
    """Every 'quiet' answer compared with the full braking curves; counts of what was seen."""
    seen = {"quiet": 0, "full": 0, "finite": 0}
    quiet, permitted = sup.BrakingCurveSupervisor.quiet, sup.BrakingCurveSupervisor.permitted

    def checked_quiet(self, train_id, now_s, s_m, v_mps, gap_m=math.inf, leader_id=None):
        answer = quiet(self, train_id, now_s, s_m, v_mps, gap_m, leader_id)
        if answer:
            seen["quiet"] += 1
            p = permitted(self, train_id, now_s, s_m, v_mps, gap_m, leader_id)
            assert p.speed_mps == math.inf and p.authority_m > 0.0, (train_id, now_s, s_m, v_mps, gap_m, p)
        return answer

    def counted_permitted(self, *args, **kw):
        p = permitted(self, *args, **kw)
        seen["full"] += 1
        seen["finite"] += p.speed_mps < math.inf
        return p

    monkeypatch.setattr(sup.BrakingCurveSupervisor, "quiet", checked_quiet)
    monkeypatch.setattr(sup.BrakingCurveSupervisor, "permitted", counted_permitted)
    return seen



def _simulate(tmp_path, line, trains, regime, **kw):
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.sim.network import build_network

    return simulate(Scenario(line, build_network(line), trains, regime, step_length_s=0.5, full_outputs=False, **kw), tmp_path / "out")


def _assert_exercised(seen, min_quiet=100):
    assert seen["quiet"] >= min_quiet, seen
    assert seen["finite"] > 0, seen  # the full rule braked somewhere in the run


@pytest.mark.parametrize("regime,fixed", [("fbs", None), ("mb", None), ("mb", 6.0), ("fbs", 6.0)])
def test_mountain_line_mixed_trains(tmp_path, checked, regime, fixed):
    """25 ‰ climbs and descents, stations on grades, speed restrictions, a 1,000 t freight among
    commuter EMUs both ways; with and without ETCS fixed times (authorities built from older positions)."""
    write(tmp_path / "commuter.yaml", COMMUTER)
    write(tmp_path / "freight.yaml", FREIGHT)
    line = load_line(write(tmp_path / "line.yaml", ALPINE))
    tt, path = load_timetable(write(tmp_path / "tt.yaml", MOUNTAIN_TT), line)
    from vcsumo.sim.network import build_network

    trains = plan_trains(tt, path, line, build_network(line).topology)
    res = _simulate(tmp_path, line, trains, regime, fixed_time_s=fixed)
    assert res.summary["trains_arrived"] == 5
    _assert_exercised(checked)


@pytest.mark.parametrize("regime", ["fbs", "mb"])
def test_network_with_a_join_and_a_direction_change(tmp_path, checked, regime):
    """Three lines joined at a line end and mid-line (merging junctions with approach locking)."""
    net = _net(tmp_path)
    write(tmp_path / "freight.yaml", FREIGHT)
    tt, path = load_timetable(write(tmp_path / "t.yaml", NETWORK_TT), net)
    from vcsumo.sim.network import build_network

    trains = plan_trains(tt, path, net, build_network(net).topology)
    res = _simulate(tmp_path, net, trains, regime)
    assert res.summary["trains_arrived"] == 4
    _assert_exercised(checked)


@pytest.mark.parametrize("regime", ["fbs", "mb"])
def test_single_track_branch_used_both_ways(tmp_path, checked, regime):
    """A train waits in front of a single-track branch another train holds (its authority ends there)."""
    from vcsumo.sim.network import build_network

    line = load_line(write(tmp_path / "dsb" / "line.yaml", DSB))
    built = build_network(line)
    tt, path = load_timetable(write(tmp_path / "h.yaml", DSB_HEAD_ON), line)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        trains = plan_trains(tt, path, line, built.topology)
    res = _simulate(tmp_path, line, trains, regime)
    assert res.summary["trains_arrived"] == 2
    _assert_exercised(checked, min_quiet=10)


@pytest.mark.parametrize("regime", ["fbs", "mb"])
def test_shipped_regional_line_all_stations(tmp_path, checked, regime, line_factory, network_factory):
    line = line_factory("regional_graded")
    tt, path = load_timetable("all_stations", line)
    trains = plan_trains(tt, path, line, network_factory("regional_graded").topology)
    _simulate(tmp_path, line, trains, regime)
    _assert_exercised(checked)


def test_network_of_lines_morning(tmp_path, checked):
    """italy_av_north's full day to 06:30: junctions at Bologna, through services, 300 km/h."""
    from vcsumo.network_file import load_line_or_network
    from vcsumo.sim.network import build_network
    from vcsumo.units import parse_clock

    net = load_line_or_network("italy_av_north")
    tt, path = load_timetable("full_day", net)
    trains = plan_trains(tt, path, net, build_network(net).topology)
    _simulate(tmp_path, net, trains, "fbs", end_time_s=parse_clock("06:30"))
    _assert_exercised(checked, min_quiet=1000)


def _locking_events(tmp_path, monkeypatch, line, trains, regime, look_every_step: bool):
    """Every order change and constraint of the approach locking, with its time."""
    from vcsumo.sim import interlocking

    events = []
    update = interlocking.MergeLocking.update

    def recorded(self, states):
        new = update(self, states)
        events.append((len(events), self.version, tuple(new), tuple((n, tuple(j.order)) for n, j in sorted(self.junctions.items()))))
        return new

    monkeypatch.setattr(interlocking.MergeLocking, "update", recorded)
    if look_every_step:
        monkeypatch.setattr(interlocking.MergeLocking, "_quiet_until", lambda self, tid, s_m, v, pending: (self.version, s_m, -math.inf, -math.inf))
    _simulate(tmp_path, line, trains, regime)
    monkeypatch.undo()
    return events


@pytest.mark.parametrize("regime", ["fbs", "mb"])
def test_approach_locking_skips_nothing_it_would_do(tmp_path, monkeypatch, regime):
    """MergeLocking.update leaves out trains with no junction within reach (its quiet stretch): the
    orders and constraints it makes, step by step, are those of looking at every train every step
    (italy_av_north's morning: services from Milano, Venezia and Firenze converging on Bologna)."""
    from vcsumo.network_file import load_line_or_network
    from vcsumo.sim.network import build_network
    from vcsumo.units import parse_clock

    net = load_line_or_network("italy_av_north")
    tt, path = load_timetable("full_day", net)
    trains = [t for t in plan_trains(tt, path, net, build_network(net).topology) if t.depart_s < parse_clock("07:00")]
    fast = _locking_events(tmp_path / "a", monkeypatch, net, trains, regime, look_every_step=False)
    full = _locking_events(tmp_path / "b", monkeypatch, net, trains, regime, look_every_step=True)
    assert len(full) > 1000 and len({ev[3] for ev in full}) > 10  # trains locked and cleared the junctions
    assert fast == full


def test_virtual_coupling_convoys_on_the_regional_line(tmp_path, checked, line_factory, network_factory):
    """Under vc the supervision drives the convoy leaders and every follower SUMO drives (stops,
    released followers): the same check, with the convoys' trains ahead."""
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.sim.vc_driver import make_vc_driver

    line = line_factory("regional_graded")
    tt, path = load_timetable("convoy", line)
    trains = plan_trains(tt, path, line, network_factory("regional_graded").topology, dt=0.1)
    driver = make_vc_driver(tt, path, trains, "cbc", 0.1, 42)
    simulate(Scenario(line, network_factory("regional_graded"), trains, "vc", step_length_s=0.1, driver=driver, full_outputs=False), tmp_path / "out")
    _assert_exercised(checked, min_quiet=10000)
