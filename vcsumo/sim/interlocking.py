"""Approach locking at merging junctions: a route is never set against a train that cannot stop.

SUMO's rail signals give a merging junction to whichever train asks first, judging "can it still
stop?" with the vType's planning deceleration.  A train on the other line that is already inside its
*guaranteed* braking distance of the junction may then face a red signal it cannot stop at (seen on
the graded regional line: a main-line train 1.2 km from the junction at 160 km/h, a branch train let
in ahead of it).

:class:`MergeLocking` orders the trains at every merging junction (a rail signal where two tracks
join) by the moment each one *locks* the junction: when it comes within its guaranteed stopping
distance of the junction plus ``lock_time_s`` of running (and at the latest when it cannot stop
before it).  The order is first come, first served, unless a scenario fixes it
(``Scenario.merge_orders``: then a train waits for every train the fixed order puts before it that
has not cleared the junction yet, whether or not that train has locked it) — and a convoy
follower never goes before its predecessor (``convoys``: first come, first served would let a fast
follower lock the junction first, and its leader and it would wait for each other).  Every train behind
another one from a different track then

* is held by SUMO: vcsumo adds a rail-signal constraint (``predecessor``: it may pass the junction
  signal only after the other train has), so SUMO never sets its route first;
* has its movement authority end as behind a rear standing at the junction (the fouling point,
  where the other train's rear may stand) under the regime's own rule — MB and VC: the margin and
  the position errors before it; FBS: the last signal whose overlap ends before it (the rail signal
  of the SUMO network stands at the junction node, so the overlap beyond the merge signal would run
  into the junction: the train waits at the signal before) — until the other train's rear has
  cleared the junction far enough for the regime's own authority behind that rear to reach past
  the junction (overlap or margin, position errors, and the age of a report).  So the supervision
  brakes it there on its guaranteed braking curve, in time, and the hand-over to the authority
  behind the train ahead (also while that train's body still fouls the junction) is seamless.

A virtually coupled follower (driven by vcsumo, not by SUMO) gets the same end of authority from
:meth:`MergeLocking.authority_distance` (the loop hands it to the driver in its ``Snapshot``), with
one difference: behind its own convoy predecessor (``coupled_to``) the junction is released as soon
as the predecessor's front has passed it — from there the relative-braking rule on the virtual gap
keeps the follower behind the predecessor's rear, which then clears the junction ahead of it.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field

from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.sim.single_track_lock import SingleTrackLocking
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
    first: dict[str, set[str]] = field(default_factory=dict)
    """Train -> the trains that must pass before it whenever they come (the order a scenario fixes,
    e.g. the junction study's; a convoy follower's predecessors), transitively closed."""
    cleared: set[str] = field(default_factory=set)
    """Trains whose rear has cleared the junction (or that left the network)."""


def merge_nodes(topo: Topology) -> set[str]:
    """Signal nodes where edges of two or more tracks come together and run on over a common edge.

    (A node of a single track, where the two directions' edges end, is no merge: those trains run
    towards each other, which :mod:`vcsumo.sim.single_track_lock` keeps apart.)"""
    tracks: dict[tuple[str, str], set[str]] = {}
    for e in topo.edges.values():
        for nxt in topo.successors.get(e.id, ()):
            tracks.setdefault((e.to_node, nxt), set()).add(e.track)
    signals = topo.signal_nodes()
    return {n for (n, _), ts in tracks.items() if len(ts) >= 2 and n in signals}


class MergeLocking:
    """Orders trains at merging junctions and gives the ones that must wait their end of authority."""

    def __init__(self, model: SeparationModel, topo: Topology, trains: list[PlannedTrain], braking: dict[str, RouteBraking],
                 fixed_orders: dict[str, list[str]] | None = None, lock_time_s: float = LOCK_TIME_S, signals: dict[str, list[float]] | None = None,
                 convoys: dict[str, str] | None = None):
        self.model = model
        self.signals = {tid: sorted(x) for tid, x in (signals or {}).items()}
        """FBS: route positions of every train's signals (the end of authority at a junction is one of them)."""
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
        self._approach_s = {tid: sorted(a.s_m for a in aps) for tid, aps in self.approaches.items()}
        """Route positions of each train's junction signals, sorted."""
        self._last_approach = {tid: max((a.s_m for a in aps), default=-math.inf) for tid, aps in self.approaches.items()}
        """The farthest junction signal on each train's route: past it nothing here concerns the train, m."""
        self.junctions: dict[str, _Junction] = {n: _Junction(n) for n in merges}
        self.gone: set[str] = set()
        self.constraints: set[tuple[str, str, str]] = set()
        """(junction, train, foe) constraints added to SUMO."""
        self.track_of: dict[tuple[str, str], str] = {(a.node, tid): a.track for tid, aps in self.approaches.items() for a in aps}
        self.position: dict[tuple[str, str], float] = {(a.node, tid): a.s_m for tid, aps in self.approaches.items() for a in aps}
        for node, order in (fixed_orders or {}).items():
            if node in self.junctions:  # only the trains that pass the junction
                fixed = [tid for tid in order if (node, tid) in self.track_of]
                for k, tid in enumerate(fixed):
                    self.junctions[node].first.setdefault(tid, set()).update(fixed[:k])
        for tid, pred in (convoys or {}).items():  # a follower never passes a junction before its predecessor
            for ap in self.approaches.get(tid, ()):
                if (ap.node, pred) in self.track_of:
                    self.junctions[ap.node].first.setdefault(tid, set()).add(pred)
        for j in self.junctions.values():  # transitively: behind a follower's predecessor's predecessor too
            changed = True
            while changed:
                changed = False
                for tid, firsts in j.first.items():
                    more = set().union(*(j.first.get(x, set()) for x in firsts)) - firsts - {tid}
                    if more:
                        firsts |= more
                        changed = True
        self.s_m: dict[str, float] = {}
        """Latest route position of every running train's front, m."""
        self.version = 0
        self._quiet: dict[str, tuple[int, float, float, float]] = {}
        """Per train: the stretch where :meth:`update` has nothing to do for it (:meth:`_quiet_until`)."""
        """Counts the changes of the orders at the junctions and on single track (a bound built on them,
        :meth:`authority_floor`, holds while it is unchanged)."""
        self.single = SingleTrackLocking(model, topo, trains, braking, self.behind_rear, lock_time_s, on_change=self._changed)
        """One direction at a time on every stretch of single track (its end of authority and SUMO
        constraints come with this class's)."""

    def update(self, states: dict[str, tuple[float, float]]) -> list[tuple[str, str, str]]:
        """Advance the orders with this step's (route position, speed) of the trains running;
        returns the new constraints (junction, train, foe) to add to SUMO.  (The stretches of
        single track advance in ``self.single.update``, which returns its own.)"""
        a = self.model.assumptions
        dead, err, lock_s = a.dead_time_s, a.position_error_m, self.lock_time_s
        new: list[tuple[str, str, str]] = []
        self.s_m.update({tid: st[0] for tid, st in states.items()})
        approaches, junctions, quiet = self.approaches, self.junctions, self._quiet
        for tid, (s_m, v) in states.items():
            aps = approaches.get(tid)
            if not aps:
                continue
            q = quiet.get(tid)
            if q is not None and q[0] == self.version and q[1] <= s_m < q[2] and v <= q[3]:
                continue  # no junction ahead within reach, no order changed since the last look (_quiet_until)
            version = self.version
            stop = None  # the train's stopping distance, integrated once and only for a junction within its bound
            bound = None
            pending = []
            for ap in aps:
                j = junctions[ap.node]
                if tid in j.order or tid in j.cleared:
                    continue
                if tid in j.first:
                    self._constrain(j, tid, new)  # a fixed order holds from the start: SUMO never sets the route first
                pending.append(ap.s_m)
                d = ap.s_m - s_m
                if stop is None:
                    br = self.braking[tid]
                    if bound is None:
                        bound = br.stopping_bound(v, dead) + v * lock_s + err
                    if s_m >= 0.0 and d > bound:
                        continue  # farther than the train can need (and so are the junctions after it; a fixed order is constrained above)
                    stop = br.stopping_distance(s_m, v, dead)
                if d <= stop + v * lock_s + err:  # also a train already past the signal
                    self._lock(j, tid, new)
            if self.version == version and s_m >= 0.0:
                quiet[tid] = self._quiet_until(tid, s_m, v, pending)
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
                else:
                    j.cleared.add(tid)
            if len(keep) != len(j.order):
                self.version += 1
            j.order = keep
        return new

    def _quiet_until(self, tid: str, s_m: float, v: float, pending: list[float]) -> tuple[int, float, float, float]:
        """(order version, from, until, speed): while the orders stay as they are, with the front in
        [from, until) and at most that speed, no junction still to lock is within the train's reach
        (the stopping bound at that speed, which rises with the speed, + the lock time's run + the
        position error): :meth:`update` has nothing to do for it — the fixed orders were constrained
        at this look and change only with the version."""
        a = self.model.assumptions
        v_q = min(self.braking[tid].stock.max_speed_ms, 1.1 * v + 5.0)
        reach = self.braking[tid].stopping_bound(v_q, a.dead_time_s) + v_q * self.lock_time_s + a.position_error_m
        until = min(pending, default=math.inf) - reach
        return self.version, s_m, until, v_q if until > s_m else -math.inf

    def arrived(self, gone: list[str]) -> None:
        """Trains that left the network."""
        self.gone.update(gone)
        if gone:
            self.version += 1
        self.single.arrived(gone)
        for tid in gone:
            for ap in self.approaches.get(tid, ()):
                if tid not in self.junctions[ap.node].order:
                    self.junctions[ap.node].cleared.add(tid)

    def _lock(self, j: _Junction, tid: str, new: list) -> None:
        # in front of the trains that must pass after it, else last
        k = next((i for i, x in enumerate(j.order) if tid in j.first.get(x, ())), len(j.order))
        j.order.insert(k, tid)
        self.version += 1
        self._constrain(j, tid, new)

    def ahead(self, node: str, tid: str) -> list[str]:
        """Trains that pass junction ``node`` before ``tid`` and have not cleared it yet."""
        j = self.junctions[node]
        before = j.order[: j.order.index(tid)] if tid in j.order else list(j.order)  # not locked yet: every train that has locked it goes first
        before = [x for x in before if tid not in j.first.get(x, ())]  # never one that must pass after it
        before += [x for x in sorted(j.first.get(tid, ())) if x not in j.cleared and x not in before]
        return before

    def _constrain(self, j: _Junction, tid: str, new: list) -> None:
        """SUMO's rail signal lets ``tid`` pass only after every train ahead of it from another track
        — added while that train's front has not reached the signal (SUMO counts passages from then)."""
        track = self.track_of[(j.node, tid)]
        for foe in self.ahead(j.node, tid):
            if self.track_of[(j.node, foe)] == track or (j.node, tid, foe) in self.constraints:
                continue
            if self.s_m.get(foe, -math.inf) > self.position[(j.node, foe)]:
                continue  # already through the signal
            self.constraints.add((j.node, tid, foe))
            new.append((j.node, tid, foe))

    def authority_distance(self, tid: str, s_m: float, coupled_to: str | None = None) -> float:
        """Distance to the end of authority a junction ahead sets (inf: none), m.

        ``coupled_to``: the train's convoy predecessor when vcsumo drives it virtually coupled; the
        junction is released behind it once its front has passed it (module doc)."""
        best = self.single.authority_distance(tid, s_m) if self.single.active else math.inf
        if s_m > self._last_approach.get(tid, -math.inf):
            return best
        for ap in self.approaches.get(tid, ()):
            if ap.s_m < s_m:
                continue
            j = self.junctions[ap.node]
            if not j.order and tid not in j.first:
                continue  # nobody has locked it and no order fixes trains before this one
            if self._waits_for_foe(j, tid, ap.track, coupled_to):
                best = min(best, self.behind_rear(tid, s_m, ap.s_m))  # the train ahead may stand with its rear at the fouling point
        return best

    def _waits_for_foe(self, j: _Junction, tid: str, track: str, coupled_to: str | None) -> bool:
        """Some train of :meth:`ahead` comes from another track than ``track`` (not ``coupled_to`` once
        its front has passed the junction)."""
        return any(self._foe(j.node, x, track, coupled_to) for x in self.ahead(j.node, tid))

    def _foe(self, node: str, x: str, track: str, coupled_to: str | None) -> bool:
        if self.track_of[(node, x)] == track:
            return False
        return not (x == coupled_to and self.s_m.get(x, -math.inf) >= self.position[(node, x)])

    def behind_rear(self, tid: str, s_m: float, rear_m: float) -> float:
        """Distance to the end of authority behind a rear standing at route position ``rear_m``, m:
        FBS — the last signal whose overlap (+ the position error of the rear) ends before it, less the
        train's own position error (as the supervision's FBS rule); otherwise margin and position errors."""
        sig = self.signals.get(tid)
        if sig is None:
            return rear_m - s_m - self.model.margin_m
        a = self.model.assumptions
        clear = rear_m - a.overlap_m - a.position_error_m
        k = bisect_right(sig, clear) - 1
        if k < 0 or sig[k] < s_m - 2 * a.position_error_m - 1.0:  # no signal between: on sight behind it
            return clear - s_m - a.position_error_m
        return sig[k] - s_m - a.position_error_m

    def authority_floor(self, tid: str, s_m: float) -> float:
        """A route position p such that :meth:`authority_distance` of the train (not coupled) is at
        least p − x for every front position x ≥ ``s_m`` while the orders at the junctions and on
        single track stay as they are (:attr:`version` unchanged), m; inf: nothing ahead holds the
        train.  A bound for skipping the supervision where nothing here can be within reach: passing
        a junction or a stretch only removes it from those ahead."""
        best = math.inf
        single = self.single
        if single.active:
            for run in single.runs.get(tid, ()):
                key = (tid, run.first)
                if run.exit_s < s_m or key in single.given or key in single.done:
                    continue
                if any(x == tid and r.first == run.first for x, r in single.order.get(run.stretch, ())):
                    best = min(best, self.rear_floor(tid, run.entry_s))
        for ap in self.approaches.get(tid, ()):
            if ap.s_m < s_m:
                continue
            j = self.junctions[ap.node]
            if (j.order or tid in j.first) and self._waits_for_foe(j, tid, ap.track, None):
                best = min(best, self.rear_floor(tid, ap.s_m))
        return best

    def _changed(self) -> None:
        self.version += 1

    def rear_floor(self, tid: str, rear_m: float) -> float:
        """The route position where :meth:`behind_rear` ends the authority behind a rear at ``rear_m``,
        at its lowest over the train's front positions (FBS: the signal it ends at, or the on-sight
        point, less the position error; otherwise the margin and position errors behind it), m."""
        sig = self.signals.get(tid)
        if sig is None:
            return rear_m - self.model.margin_m
        a = self.model.assumptions
        clear = rear_m - a.overlap_m - a.position_error_m
        k = bisect_right(sig, clear) - 1
        return (sig[k] if k >= 0 else clear) - a.position_error_m

    def fouling_gap(self, tid: str, s_m: float, leader: str, leader_s_m: float) -> float | None:
        """While a train crossing into this train's route at a merge still has its rear on the other
        track, the gap that matters runs to the junction (the fouling point), not to where SUMO
        projects that rear: the distance from the front to the junction, m (None: no such merge)."""
        if s_m > self._last_approach.get(tid, -math.inf):
            return None
        length = self.plans[leader].stock.length_m if leader in self.plans else 0.0
        signals_l = self._approach_s.get(leader)
        if signals_l is not None:  # no junction signal of the train ahead between its rear and its front: none fouled
            k = bisect_right(signals_l, leader_s_m - length)
            if k == len(signals_l) or signals_l[k] > leader_s_m:
                return None
        for ap in self.approaches.get(tid, ()):
            if ap.s_m < s_m:
                continue
            pos_l = self.position.get((ap.node, leader))
            if pos_l is None or self.track_of[(ap.node, leader)] == ap.track:
                continue
            if leader_s_m >= pos_l and leader_s_m - length < pos_l:
                return ap.s_m - s_m
        return None
