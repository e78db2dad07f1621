"""Single track without crossing loops: one direction at a time on each stretch (a token rule).

A *stretch* is a run of single track used both ways (edges with a ``bidi`` twin, from the point
where a train leaves its own track to the point where it gets back onto one: a single-track line,
a single-track branch from its junction, a single-track line joined into a network).  vcsumo
models no crossing loops, so two trains may be on a stretch together only when they run the same
way; the rule a signalling engineer applies (electric token/tablet block, or the direction lock of
a single-line block) is:

* a train *asks* for the stretch when it comes within its guaranteed stopping distance (plus
  ``lock_time_s`` of running) of the point where its authority would end in front of the stretch
  (:meth:`SingleTrackLocking.hold_distance`); the requests are served first come, first served;
* it is *given* the stretch when no train running the other way holds it or asked for it before;
  trains running the same way share it (they keep their regime's own separation behind each
  other: fixed block, moving block or virtual coupling);
* a train that has not been given the stretch has its movement authority end in front of it, on
  its own track, under the regime's rule for a point that must stay clear (as behind a train
  standing at a merging junction, :meth:`vcsumo.sim.interlocking.MergeLocking.behind_rear`: FBS —
  the last signal whose overlap ends before the stretch; MB/VC — the margin and the position errors
  before it), so the supervision stops it there on its guaranteed braking curve; SUMO is told the
  same (a rail-signal constraint: it may pass its entry signal only after the train it waits for
  has passed the signal where it leaves the stretch), so SUMO never sets the stretch for it first
  (its rail signals would then hold the other train inside: both would wait for ever);
* the stretch is released behind a train once its rear has cleared the far end by the regime's
  clearance (overlap or margin, position errors, the age of a report), or the train has left
  the network (a train whose journey ends on the stretch).

A train that enters the network on a stretch (its origin lies on single track) asks for it at its
departure time, like any other, and SUMO does not insert it before it is given the stretch (an
insertion constraint at the first signal ahead of it, :meth:`SingleTrackLocking.attach`): SUMO's own
insertion checks only the track at the insertion place, so it put a train into its platform on a
single-track branch as soon as the platform was free, with an opposing train already running towards
it on the stretch (seen: a head-on collision at 120 km/h).  A train inserted without such a signal
holds the stretch from its departure.

:class:`OpposingTrains` is the check that the rule held: two trains running opposite ways whose
occupied (and, over the step, swept) lengths of the same single track overlap have met head on.
The loop counts it as a collision, whether or not SUMO saw it (SUMO sees no collision where a
single track leaves a junction as two one-way edges); a train that enters a stretch where an opposing
train left it, before that train's rear has cleared the point by :func:`clearance`, or while an
opposing train is still on it, is a gap violation (:attr:`OpposingTrains.too_close`).
"""

from __future__ import annotations

from typing import Callable

import math
from bisect import bisect_right
from dataclasses import dataclass

from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.timetable import PlannedTrain
from vcsumo.topology import Topology

LOCK_TIME_S = 20.0
"""A train asks for a stretch this long before it would have to start braking for it, s."""


@dataclass(frozen=True)
class Run:
    """One train's passage over one stretch of single track."""

    stretch: int
    first: int
    """Route index of the first edge on the stretch."""
    last: int
    """Route index of the last edge on the stretch."""
    entry_s: float
    """Route position where the train leaves its own track for the stretch, m."""
    exit_s: float
    """Route position where it leaves the stretch, m."""
    entry_node: str
    exit_node: str
    edges: frozenset[str]
    twins: frozenset[str]
    """The same pieces of track run the other way."""
    starts_inside: bool
    ends_inside: bool

    def opposes(self, other: "Run") -> bool:
        """The two runs use a common piece of single track in opposite directions."""
        return self.stretch == other.stretch and not self.twins.isdisjoint(other.edges)


def stretches(topo: Topology) -> dict[str, int]:
    """Edge id -> stretch number: the connected pieces of single track (edges with a twin)."""
    parent: dict[str, str] = {}

    def find(x: str) -> str:
        while parent.setdefault(x, x) != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    single = [e for e in topo.edges.values() if e.bidi is not None]
    by_node: dict[str, list[str]] = {}
    for e in single:
        parent[find(e.id)] = find(e.bidi)
        for n in (e.from_node, e.to_node):
            by_node.setdefault(n, []).append(e.id)
    for e in single:  # consecutive single-track edges of a route are one stretch
        for n in topo.successors.get(e.id, ()):
            if topo.edges[n].bidi is not None:
                parent[find(e.id)] = find(n)
    roots = sorted({find(e.id) for e in single})
    number = {r: k for k, r in enumerate(roots)}
    return {e.id: number[find(e.id)] for e in single}


def route_runs(topo: Topology, plan: PlannedTrain, stretch_of: dict[str, int]) -> list[Run]:
    """The train's runs over single track, in route order."""
    edges, prof = plan.edges, plan.profile
    out, i = [], 0
    end_s = float(prof.starts_m[-1] + prof.lengths_m[-1])
    while i < len(edges):
        k = stretch_of.get(edges[i])
        if k is None:
            i += 1
            continue
        j = i
        while j + 1 < len(edges) and stretch_of.get(edges[j + 1]) == k:
            j += 1
        mine = frozenset(edges[i:j + 1])
        entry_s, exit_s = float(prof.starts_m[i]), float(prof.starts_m[j] + prof.lengths_m[j])
        out.append(Run(k, i, j, entry_s, exit_s, topo.edges[edges[i]].from_node, topo.edges[edges[j]].to_node, mine,
                       frozenset(topo.edges[e].bidi for e in mine), plan.start_s_m > entry_s + 1e-6, exit_s >= end_s - 1e-6))
        i = j + 1
    return out


def clearance(assumptions) -> float:
    """The least distance a train's rear must have cleared a stretch by, where it left it, before an
    opposing train enters there (the overlap or the margin, and the position error), m."""
    return max(assumptions.overlap_m, assumptions.safety_margin_m) + assumptions.position_error_m


class SingleTrackLocking:
    """Gives the stretches of single track to one direction at a time (module doc)."""

    def __init__(self, model: SeparationModel, topo: Topology, trains: list[PlannedTrain], braking: dict[str, RouteBraking],
                 behind_rear, lock_time_s: float = LOCK_TIME_S, on_change: Callable[[], None] | None = None):
        self.model = model
        self.on_change = on_change or (lambda: None)
        """Called whenever a request is made, granted or released (a bound built on the state is then stale)."""
        self.braking = braking
        self.behind_rear = behind_rear
        """(train, route position, point to keep clear) -> distance to the end of authority in front of it, m."""
        self.lock_time_s = lock_time_s
        self.plans = {t.id: t for t in trains}
        stretch_of = stretches(topo)
        self.signals = topo.signal_nodes()
        self.runs: dict[str, list[Run]] = {}
        if stretch_of:
            for t in trains:
                runs = route_runs(topo, t, stretch_of)
                if runs:
                    self.runs[t.id] = runs
        self.active = bool(self.runs)
        """Some train runs over single track (else nothing here does anything)."""
        self.order: dict[int, list[tuple[str, Run]]] = {}
        """Stretch -> the runs that asked for it and have not released it, first first."""
        self.given: set[tuple[str, int]] = set()
        """(train, route index of the run's first edge) that hold their stretch."""
        self.done: set[tuple[str, int]] = set()
        """Runs that released their stretch."""
        self.constraints: set[tuple[str, str, str, str]] = set()
        self.s_m: dict[str, float] = {}
        self.gone: set[str] = set()
        self.inserting: dict[str, tuple[float, Run, str]] = {}
        """Trains whose origin lies on a stretch: (departure time, their first run, the first signal
        ahead of them), by departure; kept out of the network until given the stretch (:meth:`attach`)."""
        self.departing: list[tuple[float, str, Run]] = []
        """Trains that depart in front of a stretch: (departure time, train, its first run), by
        departure; one standing within reach of where it would wait asks for it before SUMO inserts
        it (:meth:`_insertions`), so that its first step is already supervised to that point."""
        self._hold: Callable[[str, str, bool], None] | None = None
        for t in sorted(trains, key=lambda x: x.depart_s):
            runs = self.runs.get(t.id)
            if runs and runs[0].starts_inside:
                sig = topo.first_signal_ahead(t.edges, t.profile.starts_m, t.start_s_m)
                if sig is not None:
                    self.inserting[t.id] = (t.depart_s, runs[0], sig)
            elif runs:
                self.departing.append((t.depart_s, t.id, runs[0]))

    def attach(self, hold: Callable[[str, str, bool], None], now_s: float) -> None:
        """Keep every train whose origin lies on a stretch out of the network until it is given the
        stretch: ``hold(signal, train, True)`` now (before the first step), ``hold(signal, train,
        False)`` once given (:meth:`update`); ``now_s``: the time of the next step."""
        self._hold = hold
        for tid, (_, _, sig) in self.inserting.items():
            hold(sig, tid, True)
        self._insertions(now_s)

    def _insertions(self, now_s: float) -> None:
        """Trains due to enter the network on a stretch by ``now_s`` ask for it; each one given it may
        enter.  Then so does a train due to depart in front of one that stands within reach of where
        it would wait (the request :meth:`update` would make at its first step, after the supervision
        of that step had let SUMO start it towards a signal it must not pass)."""
        for tid, (dep, run, sig) in list(self.inserting.items()):
            if dep > now_s + 1e-9:
                break
            key = (tid, run.first)
            queue = self.order.setdefault(run.stretch, [])
            if not any(x == tid and r.first == run.first for x, r in queue):
                queue.append((tid, run))
                self.on_change()
            if self._may_have(tid, run):
                self.given.add(key)
                self.on_change()
                del self.inserting[tid]
                self._hold(sig, tid, False)
        while self.departing and self.departing[0][0] <= now_s + 1e-9:
            _, tid, run = self.departing.pop(0)
            if tid not in self.s_m and not self._far(tid, run, self.plans[tid].start_s_m, 0.0):
                self.order.setdefault(run.stretch, []).append((tid, run))
                if self._may_have(tid, run):
                    self.given.add((tid, run.first))
                self.on_change()

    # ------------------------------------------------------------------------------------------
    def _may_have(self, tid: str, run: Run) -> bool:
        """No train the other way holds the stretch or asked for it before this one."""
        for other, r in self.order.get(run.stretch, ()):
            if other == tid and r.first == run.first:
                return True
            if r.opposes(run):
                return False
        return True

    def update(self, states: dict[str, tuple[float, float]], now_s: float | None = None) -> list[tuple[str, str, str, str]]:
        """Advance the requests with this step's (route position, speed) of the running trains
        (``now_s``: the time of the next step, when trains entering on a stretch are held,
        :meth:`attach`); returns the new SUMO constraints (signal, train, foe's signal, foe)."""
        new: list[tuple[str, str, str, str]] = []
        if not self.active:
            return new
        for tid in states.keys() & self.inserting.keys():  # entered although held (SUMO did not check the signal): holds it as before
            del self.inserting[tid]
        a = self.model.assumptions
        self.s_m.update({tid: st[0] for tid, st in states.items()})
        for tid, (s_m, v) in states.items():
            for run in self.runs.get(tid, ()):
                key = (tid, run.first)
                if key in self.done or key in self.given:
                    continue
                queue = self.order.setdefault(run.stretch, [])
                asked = any(x == tid and r.first == run.first for x, r in queue)
                if not asked:
                    if run.starts_inside or s_m > run.entry_s + 1e-6:  # already on it (departed there): holds it from now
                        queue.insert(0, (tid, run))
                        self.given.add(key)
                        self.on_change()
                        continue
                    if self._far(tid, run, s_m, v):
                        break  # not yet (nor any later stretch of its route)
                    queue.append((tid, run))
                    self.on_change()
                if self._may_have(tid, run):
                    self.given.add(key)
                    self.on_change()
                else:
                    self._constrain(tid, run, new)
                break  # one stretch at a time: the next one is asked for once this one is held
        # release behind the trains that cleared their stretch (or left the network)
        for k, queue in self.order.items():
            keep = []
            for tid, run in queue:
                st = states.get(tid)
                length = self.plans[tid].stock.length_m
                clear = clearance(a) + (st[1] if st else 0.0) * (a.position_report_period_s + a.fixed_time_s) + 1.0
                if tid in self.gone or (st is not None and not run.ends_inside and st[0] - length > run.exit_s + clear):
                    self.done.add((tid, run.first))
                    self.given.discard((tid, run.first))
                    self.on_change()
                else:
                    keep.append((tid, run))
            self.order[k] = keep
        if self._hold is not None and now_s is not None and (self.inserting or self.departing):
            self._insertions(now_s)
        return new

    def _far(self, tid: str, run: Run, s_m: float, v: float) -> bool:
        """The train (front at ``s_m``, speed ``v``) is not yet within its stopping distance (+ the
        lock time's running and the position error) of where it would wait for the stretch."""
        a = self.model.assumptions
        d = self.hold_distance(tid, run, s_m)
        br, ahead = self.braking[tid], v * self.lock_time_s + a.position_error_m
        return d > br.stopping_bound(v, a.dead_time_s) + ahead or d > br.stopping_distance(s_m, v, a.dead_time_s) + ahead

    def _constrain(self, tid: str, run: Run, new: list) -> None:
        """SUMO may set the route onto the stretch for ``tid`` only after each train it waits for has
        passed the signal where that train leaves the stretch (while that train has not yet got there)."""
        if run.entry_node not in self.signals or self.s_m.get(tid, -math.inf) >= run.entry_s:
            return
        for foe, r in self.order.get(run.stretch, ()):
            if foe == tid:
                break
            if not r.opposes(run) or r.ends_inside or r.exit_node not in self.signals:
                continue
            if self.s_m.get(foe, -math.inf) >= r.exit_s:
                continue  # its front is already off the stretch
            c = (run.entry_node, tid, r.exit_node, foe)
            if c not in self.constraints:
                self.constraints.add(c)
                new.append(c)

    def arrived(self, gone: list[str]) -> None:
        """Trains that left the network."""
        self.gone.update(gone)
        if gone:
            self.on_change()

    def hold_distance(self, tid: str, run: Run, s_m: float) -> float:
        """Distance from the front to where the train's authority ends in front of the stretch, m."""
        return self.behind_rear(tid, s_m, run.entry_s)

    def authority_distance(self, tid: str, s_m: float) -> float:
        """Distance to the end of authority in front of a stretch the train has asked for and not
        been given (inf: none), m."""
        for run in self.runs.get(tid, ()):
            if s_m > run.exit_s:
                continue
            key = (tid, run.first)
            if key in self.given or key in self.done:
                continue
            if any(x == tid and r.first == run.first for x, r in self.order.get(run.stretch, ())):
                return self.hold_distance(tid, run, s_m)
            return math.inf  # not asked for yet (nor any later one)
        return math.inf


class OpposingTrains:
    """Counts trains that met head on on single track (module doc)."""

    def __init__(self, topo: Topology, trains: list[PlannedTrain], clearance_m: float = 0.0):
        self.clearance_m = clearance_m
        """How far past the point where a train leaves a stretch its rear must be before an opposing
        train enters there (:func:`clearance`), m."""
        self.too_close: list[tuple[str, str, float, tuple[str, float]]] = []
        """This step's trains that entered a stretch too close to an opposing train: (train, the
        other, the other's rear past where it left the stretch (m, negative: still on it), (section,
        km) of the entering train's front)."""
        stretch_of = stretches(topo)
        self.plans = {t.id: t for t in trains}
        self.runs = {t.id: runs for t in trains if stretch_of and (runs := route_runs(topo, t, stretch_of))}
        self.active = bool(self.runs)
        """Some train runs over single track (else :meth:`step` finds nothing)."""
        self._key: dict[str, tuple[str, float, bool]] = {}
        """Edge -> (the twin pair's name, its length, whether the edge runs along the pair's direction)."""
        for e in topo.edges.values():
            if e.bidi is not None:
                name = min(e.id, e.bidi)
                self._key[e.id] = (name, e.length_m, e.id == name)
        self._prev: dict[str, float] = {}
        self.meeting: set[frozenset[str]] = set()
        """Pairs overlapping now (one collision per episode)."""

    def _entering(self, positions: dict[str, float]) -> list[tuple[str, str, float, tuple[str, float]]]:
        """Trains whose front has just passed the entry of a stretch while a train running the other
        way had not cleared it (where that train left it at the point this one enters it, its rear
        must be :attr:`clearance_m` past it; elsewhere, off the stretch)."""
        out = []
        for tid, s in positions.items():
            prev = self._prev.get(tid)
            if tid not in self.runs or prev is None or s != s:
                continue
            for run in self.runs[tid]:
                if not prev <= run.entry_s < s:
                    continue
                for other, so in positions.items():
                    for r in self.runs.get(other, ()) if other != tid else ():
                        if not r.opposes(run) or so < r.entry_s:
                            continue  # (not on it yet: the head-on check's)
                        past = so - self.plans[other].stock.length_m - r.exit_s
                        if past < (self.clearance_m if r.exit_node == run.entry_node else 0.0):
                            out.append((tid, other, past, self.plans[tid].profile.km_at(s)))
        return out

    def _pieces(self, tid: str, lo: float, hi: float) -> list[tuple[str, float, float, bool]]:
        """The single-track pieces a train covers between route positions lo and hi: (pair, from, to, along)."""
        plan = self.plans[tid]
        starts, lengths, edges = plan.profile.starts_m, plan.profile.lengths_m, plan.edges
        out = []
        for run in self.runs[tid]:
            if hi < run.entry_s or lo > run.exit_s:
                continue
            i = max(run.first, bisect_right(starts, lo) - 1)
            while i <= run.last and starts[i] < hi:
                a, b = max(lo, float(starts[i])) - float(starts[i]), min(hi, float(starts[i] + lengths[i])) - float(starts[i])
                if b > a:
                    name, length, along = self._key[edges[i]]
                    x0, x1 = (a, b) if along else (length - b, length - a)
                    out.append((name, x0, x1, along))
                i += 1
        return out

    def step(self, positions: dict[str, float]) -> list[tuple[str, str]]:
        """This step's route positions of the running trains -> pairs that have just met head on
        (and :attr:`too_close`)."""
        if not self.active:
            return []
        self.too_close = self._entering(positions)
        occupied: dict[str, list[tuple[float, float, bool, str]]] = {}
        for tid, s in positions.items():
            if tid not in self.runs or s != s:
                continue
            prev = self._prev.get(tid, s)
            self._prev[tid] = s
            length = self.plans[tid].stock.length_m
            for name, x0, x1, along in self._pieces(tid, min(prev, s) - length, max(prev, s)):
                occupied.setdefault(name, []).append((x0, x1, along, tid))
        now: set[frozenset[str]] = set()
        for pieces in occupied.values():
            for k, (a0, a1, along_a, ta) in enumerate(pieces):
                for b0, b1, along_b, tb in pieces[k + 1:]:
                    if ta != tb and along_a != along_b and a0 < b1 and b0 < a1:
                        now.add(frozenset((ta, tb)))
        new = [tuple(sorted(p)) for p in now - self.meeting]
        self.meeting = now
        return sorted(new)
