"""Approach locking at merging junctions: a route is never set against a train that cannot stop.

SUMO's rail signals give a merging junction to whichever train asks first, judging "can it still
stop?" with the vType's planning deceleration.  A train on the other line that is already inside its
*guaranteed* braking distance of the junction may then face a red signal it cannot stop at (seen on
the graded regional line: a main-line train 1.2 km from the junction at 160 km/h, a branch train let
in ahead of it).

:class:`MergeLocking` orders the trains at every merging junction (a rail signal where two tracks
join) by the moment each one *locks* the junction: when it comes within its guaranteed stopping
distance of the junction plus ``lock_time_s`` of running (and at the latest when it cannot stop
before it).  The order is first come, first served, unless a scenario fixes it.  Every train behind
another one from a different track then

* is held by SUMO: vcsumo adds a rail-signal constraint (``predecessor``: it may pass the junction
  signal only after the other train has), so SUMO never sets its route first;
* has its movement authority end at the junction (less the margin and the position errors, as
  behind any rear: the other train's rear may stand at the fouling point) until the other
  train's rear has cleared the junction far enough for the regime's own authority behind that rear
  to reach past the junction (overlap or margin, position errors, and the age of a report) — so
  the supervision brakes it there on its guaranteed braking curve, in time, and the hand-over to
  the authority behind the train ahead is seamless.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.timetable import PlannedTrain
from vcsumo.topology import Topology

LOCK_TIME_S = 20.0
"""A train locks a junction this long before it would have to start braking for it, s."""


@dataclass
class _Approach:
    node: str
    s_m: float
    """Route position of the junction signal (the end of the incoming edge)."""
    track: str
    """The track the train comes from."""


@dataclass
class _Junction:
    node: str
    order: list[str] = field(default_factory=list)
    """Trains that locked the junction, first first (removed once their rear has cleared it)."""
    fixed: list[str] = field(default_factory=list)
    """An order the scenario imposes (e.g. the junction study's main/branch first)."""


def merge_nodes(topo: Topology) -> set[str]:
    """Signal nodes where edges of two or more tracks come together."""
    tracks: dict[str, set[str]] = {}
    for e in topo.edges.values():
        tracks.setdefault(e.to_node, set()).add(e.track)
    signals = topo.signal_nodes()
    return {n for n, ts in tracks.items() if len(ts) >= 2 and n in signals}


class MergeLocking:
    """Orders trains at merging junctions and gives the ones that must wait their end of authority."""

    def __init__(self, model: SeparationModel, topo: Topology, trains: list[PlannedTrain], braking: dict[str, RouteBraking],
                 fixed_orders: dict[str, list[str]] | None = None, lock_time_s: float = LOCK_TIME_S):
        self.model = model
        self.lock_time_s = lock_time_s
        self.braking = braking
        self.plans = {t.id: t for t in trains}
        merges = merge_nodes(topo)
        self.approaches: dict[str, list[_Approach]] = {}
        for t in trains:
            out = []
            for i, eid in enumerate(t.edges[:-1]):
                e = topo.edges[eid]
                if e.to_node in merges:
                    out.append(_Approach(e.to_node, float(t.profile.starts_m[i] + t.profile.lengths_m[i]), e.track))
            self.approaches[t.id] = out
        self._last_approach = {tid: max((a.s_m for a in aps), default=-math.inf) for tid, aps in self.approaches.items()}
        """The farthest junction signal on each train's route: past it nothing here concerns the train, m."""
        self.junctions: dict[str, _Junction] = {n: _Junction(n) for n in merges}
        for node, order in (fixed_orders or {}).items():
            if node in self.junctions:
                self.junctions[node].fixed = list(order)
        self.gone: set[str] = set()
        self.constraints: set[tuple[str, str, str]] = set()
        """(junction, train, foe) constraints added to SUMO."""
        self.track_of: dict[tuple[str, str], str] = {(a.node, tid): a.track for tid, aps in self.approaches.items() for a in aps}
        self.position: dict[tuple[str, str], float] = {(a.node, tid): a.s_m for tid, aps in self.approaches.items() for a in aps}

    def update(self, states: dict[str, tuple[float, float]]) -> list[tuple[str, str, str]]:
        """Advance the orders with this step's (route position, speed) of the trains running;
        returns the new constraints (junction, train, foe) to add to SUMO."""
        a = self.model.assumptions
        new: list[tuple[str, str, str]] = []
        for tid, (s_m, v) in states.items():
            stop = None  # the train's stopping distance, integrated once and only for a junction within its bound
            for ap in self.approaches.get(tid, ()):
                j = self.junctions[ap.node]
                if tid in j.order or s_m > ap.s_m:
                    continue
                d = ap.s_m - s_m
                if stop is None:
                    br = self.braking[tid]
                    if s_m >= 0.0 and d > br.stopping_bound(v, a.dead_time_s) + v * self.lock_time_s + a.position_error_m:
                        break  # this junction and the ones after it are farther than the train can need
                    stop = br.stopping_distance(s_m, v, a.dead_time_s)
                if d <= stop + v * self.lock_time_s + a.position_error_m:
                    self._lock(j, tid, new)
        # a train leaves the order once its rear has cleared the junction (or it has left the network)
        for j in self.junctions.values():
            keep = []
            for tid in j.order:
                st = states.get(tid)
                length = self.plans[tid].stock.length_m
                # released once the authority behind its rear reaches past the junction under either
                # rule: FBS (overlap) and MB (margin, a report period and the fixed times old)
                clear = max(a.overlap_m, a.safety_margin_m) + a.position_error_m + (st[1] if st else 0.0) * (a.position_report_period_s + a.fixed_time_s) + 1.0
                if st is not None and st[0] - length <= self.position[(j.node, tid)] + clear:
                    keep.append(tid)
                elif st is None and tid not in self.gone:
                    keep.append(tid)  # not yet departed: keeps its place
            j.order = keep
        return new

    def arrived(self, gone: list[str]) -> None:
        """Trains that left the network."""
        self.gone.update(gone)

    def _lock(self, j: _Junction, tid: str, new: list) -> None:
        if j.fixed and tid in j.fixed:
            k = j.fixed.index(tid)
            ahead = [x for x in j.fixed[:k]]
            j.order = [x for x in j.order if x in ahead] + [tid] + [x for x in j.order if x not in ahead]
        else:
            j.order.append(tid)
        track = self.track_of[(j.node, tid)]
        for foe in j.order[: j.order.index(tid)]:
            if self.track_of[(j.node, foe)] != track and (j.node, tid, foe) not in self.constraints:
                self.constraints.add((j.node, tid, foe))
                new.append((j.node, tid, foe))

    def authority_distance(self, tid: str, s_m: float) -> float:
        """Distance to the end of authority a junction ahead sets (inf: none), m."""
        best = math.inf
        if s_m > self._last_approach.get(tid, -math.inf):
            return best
        for ap in self.approaches.get(tid, ()):
            if ap.s_m < s_m:
                continue
            j = self.junctions[ap.node]
            if not j.order:
                continue  # nobody has locked it
            track = ap.track
            if tid in j.order:
                before = j.order[: j.order.index(tid)]
            else:  # not locked yet: every train that has locked it goes first
                before = j.order
            if any(self.track_of[(j.node, x)] != track for x in before):
                # the train ahead may stand with its rear at the fouling point: the same margin and
                # position errors as behind any rear
                best = min(best, ap.s_m - s_m - self.model.margin_m)
        return best

    def fouling_gap(self, tid: str, s_m: float, leader: str, leader_s_m: float) -> float | None:
        """While a train crossing into this train's route at a merge still has its rear on the other
        track, the gap that matters runs to the junction (the fouling point), not to where SUMO
        projects that rear: the distance from the front to the junction, m (None: no such merge)."""
        if s_m > self._last_approach.get(tid, -math.inf):
            return None
        length = self.plans[leader].stock.length_m if leader in self.plans else 0.0
        for ap in self.approaches.get(tid, ()):
            if ap.s_m < s_m:
                continue
            pos_l = self.position.get((ap.node, leader))
            if pos_l is None or self.track_of[(ap.node, leader)] == ap.track:
                continue
            if leader_s_m >= pos_l and leader_s_m - length < pos_l:
                return ap.s_m - s_m
        return None
