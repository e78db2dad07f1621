"""Approach locking at a merge with the order a scenario fixes (``Scenario.merge_orders``, the
junction study's one merge-order mechanism), on the graded regional line's Hill Junction (the
branch merges into the down main line) — the locking alone, on train states we set."""

from __future__ import annotations

import math

import pytest

from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.sim.interlocking import MergeLocking
from vcsumo.studies.junction import build_setup, trains_for

MODEL = SeparationModel(load_assumptions())


@pytest.fixture(scope="module")
def hill(line_factory, network_factory):
    line = line_factory("regional_graded")
    net = network_factory("regional_graded")
    setup = build_setup(line, net, load_rolling_stock(line.data.default_train), "hill", "down")
    trains, _ = trains_for(setup, "main", 0.0, {"main": 0.0, "branch": 0.0})  # main first: it is the convoy leader
    braking = {t.id: RouteBraking(MODEL, t.stock, t.profile) for t in trains}
    return setup, net, trains, braking


def _locking(hill, order):
    setup, net, trains, braking = hill
    return MergeLocking(MODEL, net.topology, trains, braking, {setup.merge_node: order} if order else None)


def _at(setup, role: str, before_m: float) -> float:
    """Route position of a train's front ``before_m`` before the merge (negative: past it)."""
    return setup.s_merge[role] - before_m


def test_a_fixed_order_holds_before_the_first_train_has_locked_the_junction(hill):
    """The branch train is 300 m from the junction at 60 km/h, the main-line train (first in the
    fixed order) still 9 km away: the branch train's authority ends at the junction (less margin and
    position errors) from the first step, and SUMO is told at once to let it pass only after the
    main-line train."""
    setup = hill[0]
    lock = _locking(hill, ["main", "branch"])
    new = lock.update({"branch": (_at(setup, "branch", 300.0), 16.7), "main": (_at(setup, "main", 9000.0), 44.4)})
    assert new == [(setup.merge_node, "branch", "main")]
    d = lock.authority_distance("branch", _at(setup, "branch", 300.0))
    assert d == pytest.approx(300.0 - MODEL.margin_m)
    assert math.isinf(lock.authority_distance("main", _at(setup, "main", 9000.0)))
    assert lock.update({"branch": (_at(setup, "branch", 250.0), 10.0), "main": (_at(setup, "main", 8000.0), 44.4)}) == []  # once


def test_first_come_first_served_without_a_fixed_order(hill):
    """The same states without a fixed order: the branch train, near, locks the junction first and
    the main-line train has to wait once it comes to lock it."""
    setup = hill[0]
    lock = _locking(hill, None)
    assert lock.update({"branch": (_at(setup, "branch", 300.0), 16.7), "main": (_at(setup, "main", 9000.0), 44.4)}) == []
    assert math.isinf(lock.authority_distance("branch", _at(setup, "branch", 300.0)))
    assert lock.authority_distance("main", _at(setup, "main", 9000.0)) == pytest.approx(9000.0 - MODEL.margin_m)
    new = lock.update({"branch": (_at(setup, "branch", 200.0), 16.7), "main": (_at(setup, "main", 2000.0), 44.4)})
    assert new == [(setup.merge_node, "main", "branch")]


def test_the_junction_is_released_behind_the_train_ahead(hill):
    """Behind the main-line train, the branch train's authority at the junction lasts until the
    main-line train's rear has cleared it far enough for the authority behind that rear to reach
    past it; a virtually coupled follower (``coupled_to``) is released as soon as its predecessor's
    front has passed it."""
    setup, _, trains, _ = hill
    length = trains[0].stock.length_m
    lock = _locking(hill, ["main", "branch"])
    s_b = _at(setup, "branch", 400.0)
    lock.update({"branch": (s_b, 10.0), "main": (_at(setup, "main", 2000.0), 44.4)})
    assert lock.authority_distance("branch", s_b) == pytest.approx(400.0 - MODEL.margin_m)
    assert lock.authority_distance("branch", s_b, coupled_to="main") == pytest.approx(400.0 - MODEL.margin_m)
    lock.update({"branch": (s_b, 10.0), "main": (_at(setup, "main", -5.0), 44.4)})  # its front just past the junction
    assert lock.authority_distance("branch", s_b) == pytest.approx(400.0 - MODEL.margin_m)
    assert math.isinf(lock.authority_distance("branch", s_b, coupled_to="main"))
    lock.update({"branch": (s_b, 10.0), "main": (_at(setup, "main", -(length + 20.0)), 44.4)})  # rear 20 m past: not yet
    assert lock.authority_distance("branch", s_b) == pytest.approx(400.0 - MODEL.margin_m)
    lock.update({"branch": (s_b, 10.0), "main": (_at(setup, "main", -(length + 1000.0)), 44.4)})
    assert math.isinf(lock.authority_distance("branch", s_b))
    assert "main" in lock.junctions[setup.merge_node].cleared
    # a train the fixed order puts first that has left the network no longer holds the junction
    lock2 = _locking(hill, ["main", "branch"])
    lock2.update({"branch": (s_b, 10.0)})
    assert lock2.authority_distance("branch", s_b) < 400.0
    lock2.arrived(["main"])
    assert math.isinf(lock2.authority_distance("branch", s_b))


def test_under_fixed_blocks_the_train_waits_at_the_signal_whose_overlap_ends_before_the_junction(hill):
    """The network's merge signal stands at the junction node: its overlap would run into the
    junction the other train occupies, so under FBS the branch train's authority ends at the signal
    before (less its position error), as the supervision's FBS rule gives behind a rear standing at
    the junction — no end of authority that jumps back when that train's body fouls the junction."""
    setup, net, trains, braking = hill
    a = MODEL.assumptions
    signals = {t.id: t.profile.signal_positions(net.topology) for t in trains}
    lock = MergeLocking(MODEL, net.topology, trains, braking, {setup.merge_node: ["main", "branch"]}, signals=signals)
    s_b = _at(setup, "branch", 4000.0)
    lock.update({"branch": (s_b, 27.0), "main": (_at(setup, "main", 9000.0), 44.4)})
    junction = setup.s_merge["branch"]
    before = max(x for x in signals["branch"] if x <= junction - a.overlap_m - a.position_error_m)
    assert junction - before > a.overlap_m  # the signal before the junction's, not the junction's own
    assert lock.authority_distance("branch", s_b) == pytest.approx(before - s_b - a.position_error_m)


def test_a_convoy_follower_never_locks_a_junction_before_its_predecessor(hill):
    """First come, first served would give the junction to the main-line train that comes first; as
    the branch train's convoy follower it waits for it (else each would wait for the other: the
    leader held at the signal, the follower held behind its leader by its guard)."""
    setup, net, trains, braking = hill
    lock = MergeLocking(MODEL, net.topology, trains, braking, convoys={"main": "branch"})
    s_m = _at(setup, "main", 2000.0)
    new = lock.update({"main": (s_m, 44.4)})  # the leader is not in the simulation yet
    assert new == [(setup.merge_node, "main", "branch")] and lock.junctions[setup.merge_node].order == ["main"]
    assert lock.authority_distance("main", s_m) == pytest.approx(2000.0 - MODEL.margin_m)
    lock.update({"main": (s_m, 44.4), "branch": (_at(setup, "branch", 500.0), 16.7)})
    assert lock.junctions[setup.merge_node].order == ["branch", "main"]
    assert math.isinf(lock.authority_distance("branch", _at(setup, "branch", 500.0)))
    lock.update({"main": (s_m, 44.4), "branch": (_at(setup, "branch", -1.0), 16.7)})  # its front is past: the coupled follower may go on
    assert math.isinf(lock.authority_distance("main", s_m, coupled_to="branch"))
