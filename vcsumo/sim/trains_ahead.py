"""The train ahead of every running train, from vcsumo's own index of the routes (:class:`TrainsAhead`).

Railway terms: each train occupies the track from its front back over its length; the *train ahead*
of a train is the nearest train whose body lies on the train's own route ahead of its front
(following it, or still clearing a junction where it turned off, or joined from another line),
and the *gap* is the distance along the route from the front to that train's rear.

This answers what SUMO's ``getLeader`` (look-ahead of 30 km) and, beyond SUMO's look-ahead, the
route walk with ``getDrivingDistance`` (:class:`vcsumo.sim.route_leaders.RouteLeaders`) answered,
without calling either: every route gets, once, the exact distance from its start to each of its
edges as SUMO drives it — the edges' lengths *and* the junctions' internal lanes between them (the
0.1–26 m that :attr:`RouteProfile.starts_m` leaves out) — so every train's front and rear are route
positions, and a gap is a difference of two of them (the same metres as SUMO's, to ~1e-9 m).

Per step the work is proportional to the running trains, and small:

* each train's front comes from its (edge, lane position, route index) read this step, its rear is
  its front less its length; the track index (which trains occupy each edge) changes only when a
  front enters or a rear leaves an edge;
* each train keeps its train ahead (however far: the look-ahead only filters the answer) and its
  gap is one subtraction, as long as that train's rear stays on the route (checked when the rear
  passes onto the next edge); it is searched again along the route only when that train turns off
  the route or leaves the network;
* a train can come between two trains only by entering the route from elsewhere: a departure, or a
  front entering an edge where lines join from another edge than the route's.  Such an entry is
  offered to the trains whose route it lies on, ahead of them and nearer than their train ahead.

A train never reverses and trains on one track never overtake, so nothing else changes the answer.
Opposing trains on a single track (an edge and its twin, bidirectional track) are on different
edges and are not trains ahead, as for ``getLeader``.  Routes that pass an edge twice are handled
(the occurrence ahead of the train is taken).
"""

from __future__ import annotations

import math
from bisect import bisect_right

from vcsumo.sim.sumo_backend import SumoBackend


class _Route:
    """A route as SUMO drives it: ``off[k]`` is the driving distance from the start of edge 0 to the
    start of edge k (edges and internal lanes), ``end[k]`` that of edge k's end; ``at`` the first
    index of each edge, ``again`` every index of the edges the route passes more than once."""

    __slots__ = ("edges", "off", "end", "at", "again", "n", "far")

    def __init__(self, sim: SumoBackend, edges: list[str], passages: dict[tuple[str, str], float], via: dict[str, float], lookahead_m: float):
        self.edges = list(edges)
        self.n = len(edges)
        self.off: list[float] = []
        self.end: list[float] = []
        x = 0.0
        for k, e in enumerate(edges):
            if k:
                key = (edges[k - 1], e)
                if key not in passages:
                    inner = 0.0
                    for iid, length in sim.junction_passage(*key):
                        via[iid] = inner  # where the internal lane starts within the passage
                        inner += length
                    passages[key] = inner
                x += passages[key]
            self.off.append(x)
            x += sim.edge_length(e)
            self.end.append(x)
        self.far = lookahead_m + max(b - a for a, b in zip([0.0] + self.end, self.end))
        """Gaps beyond this are beyond the look-ahead (:meth:`TrainsAhead._in_reach`)."""
        self.at: dict[str, int] = {}
        self.again: dict[str, list[int]] = {}
        for k, e in enumerate(edges):
            if e in self.at:
                self.again.setdefault(e, [self.at[e]]).append(k)
            else:
                self.at[e] = k

    def index_from(self, edge: str, k0: int) -> int:
        """Index of ``edge`` on the route at or after ``k0`` (-1: not there)."""
        k = self.at.get(edge, -1)
        if k < k0 and k >= 0 and edge in self.again:
            k = next((i for i in self.again[edge] if i >= k0), -1)
        return k if k >= k0 else -1


class _Train:
    """A running train: its front ``x`` on its route (m; its rear is ``x - length``), the route
    indices of the edges holding its front (``kf``: a front inside a junction counts on the edge it
    enters) and its rear (``kr``; past every edge once it left the network), the edges it occupies in
    the index (``occ_r``..``occ_f``); ``edge``, ``x0``: the edge (or junction) of its front and where
    that begins on the route, ``rear_x``: the front position at which its rear leaves its edge.
    Its train ahead ``lead`` is seen through edge ``lead_k`` of the leader's route, edge ``lead_j``
    of this one: the leader's rear is at ``shift + lead.x`` on this route."""

    __slots__ = ("id", "route", "length", "x", "kf", "kr", "occ_r", "occ_f", "running", "stale",
                 "edge", "x0", "rear_x", "lead", "lead_k", "lead_j", "shift")

    def __init__(self, vid: str, route: _Route, length: float):
        self.id, self.route, self.length = vid, route, length
        self.x = math.nan
        self.kf = self.kr = self.occ_r = self.occ_f = -1
        self.running = True
        self.stale = True  # its train ahead is to be searched for
        self.edge, self.x0, self.rear_x = "", 0.0, math.inf
        self.lead: _Train | None = None
        self.lead_k = self.lead_j = -1
        self.shift = 0.0

    def see(self, lead: "_Train", k: int, j: int, base: float) -> None:
        """``lead`` is the train ahead, seen through edge k of its route, edge j of this one (``base``:
        where that edge begins on this route less where it begins on the leader's)."""
        self.lead, self.lead_k, self.lead_j, self.shift = lead, k, j, base - lead.length


class TrainsAhead:
    """The train ahead on each running train's route within ``lookahead_m``: (id, gap m) or None.

    ``routes``: each train's route edges (e.g. ``PlannedTrain.profile.edges``), by train id.
    Call :meth:`leaders` once per step with the running trains and what
    :meth:`SumoBackend.observe_all` read for them."""

    def __init__(self, sim: SumoBackend, routes: dict[str, list[str]], lookahead_m: float):
        self.sim = sim
        self.lookahead_m = lookahead_m
        self.routes_of = routes
        self.trains: dict[str, _Train] = {}
        self.order: list[_Train] = []
        self._ids: list[str] = []
        self._mine: list[_Train] = []
        self._routes: dict[int, _Route] = {}
        self._passages: dict[tuple[str, str], float] = {}
        self._via: dict[str, float] = {}
        self.on_edge: dict[str, list[tuple[_Train, int]]] = {}
        """The trains occupying each edge: (train, index of the edge on its route)."""
        self.max_length = 0.0
        before: dict[str, set[str]] = {}
        for edges in routes.values():
            for a, b in zip(edges, edges[1:]):
                before.setdefault(b, set()).add(a)
        self.joins = {e for e, prev in before.items() if len(prev) > 1}
        """Edges where routes come in from different edges (lines joining)."""
        self.searches = 0
        """Times a train's train ahead was searched for along its route (the rest were kept)."""

    # ----------------------------------------------------------------------------- per step
    def leaders(self, ids: list[str], observed: list[tuple]) -> list[tuple[str, float] | None]:
        """(id of the train ahead, gap from the front to its rear in m) of each train in ``ids``,
        None where nobody is within the look-ahead; ``observed``: (edge, lane position, speed,
        acceleration, odometer, route index) of each, as :meth:`SumoBackend.observe_all` reads."""
        arrived = False
        for vid in self.sim.arrived():
            tr = self.trains.pop(vid, None)
            if tr is not None:
                tr.running, tr.kr, arrived = False, 1 << 40, True
                self._occupy(tr, -1, -1)
        if arrived:
            self.order = [tr for tr in self.order if tr.running]
        entries: list[tuple[_Train, int, bool]] = []
        if ids != self._ids:  # trains departed or arrived: the list of this step's trains anew
            trains, mine = self.trains, []
            for vid in ids:
                tr = trains.get(vid)
                if tr is None:
                    tr = self._depart(vid)
                    entries.append((tr, -1, True))
                mine.append(tr)
            self._ids, self._mine = list(ids), mine
        for tr, o in zip(self._mine, observed):
            if o[0] == tr.edge:  # on the edge it was on (most steps): one position
                x = tr.x = tr.x0 + o[1]
                if x >= tr.rear_x:
                    self._place(tr, o[0], o[1], o[5], entries)  # its rear passed onto the next edge
            else:
                self._place(tr, o[0], o[1], o[5], entries)
        for tr, k, departed in entries:
            self._entered(tr, tr.kf if departed else k, departed)
        look = self.lookahead_m
        out: list[tuple[str, float] | None] = []
        append = out.append
        for tr in self._mine:
            lead = tr.lead
            if lead is None:  # nobody ahead on its route
                append(self._answer(tr) if tr.stale else None)
                continue
            if lead.kr <= tr.lead_k:  # its train ahead as at the last step (running: else its kr is past every edge)
                gap = tr.shift + lead.x - tr.x
                if gap <= look:
                    append((lead.id, gap))
                    continue
                if gap > tr.route.far:  # far beyond the look-ahead
                    append(None)
                    continue
            append(self._answer(tr))
        return out

    def _place(self, tr: _Train, edge: str, pos: float, k: int, entries: list[tuple[_Train, int, bool]]) -> None:
        """Put ``tr``'s front at ``pos`` on ``edge`` (route index ``k``): its front and rear on the
        route, the edges it occupies, and the edges where lines join that it entered."""
        r = tr.route
        if 0 <= k < r.n and r.edges[k] == edge:
            x0 = r.off[k]
        elif edge[:1] == ":" and 0 <= k < r.n - 1 and edge in self._via:  # inside a junction, from edge k onto edge k + 1
            x0 = r.end[k] + self._via[edge]
            k += 1
        else:  # not where its route index says (not expected): found on the route from where it was, else kept there
            k = r.index_from(edge, max(tr.kf, 0))
            if k < 0:
                return
            x0 = r.off[k]
        x = x0 + pos
        xr = x - tr.length
        kr = tr.kr
        if kr < 0:  # (departed)
            kr = k
            while kr > 0 and r.end[kr - 1] > xr:
                kr -= 1
        else:
            while kr < k and r.end[kr] <= xr:
                kr += 1
            if k > tr.kf >= 0:
                joins = self.joins
                entries += [(tr, j, False) for j in range(tr.kf + 1, k + 1) if r.edges[j] in joins]
        tr.x, tr.kf, tr.kr = x, k, kr
        tr.edge, tr.x0, tr.rear_x = edge, x0, (r.end[kr] + tr.length if kr < k else math.inf)
        if kr != tr.occ_r or k != tr.occ_f:
            self._occupy(tr, kr, k)

    def _answer(self, tr: _Train) -> tuple[str, float] | None:
        """The answer where the train ahead is not simply the one of the last step within the look-ahead."""
        lead = tr.lead
        if lead is not None:
            if not lead.running or (lead.kr > tr.lead_k and not self._follow(tr, lead)):
                self._search(tr)  # it left the network or turned off the route
                lead = tr.lead
        elif tr.stale:
            self._search(tr)
            lead = tr.lead
        if lead is None:
            return None
        gap = tr.shift + lead.x - tr.x
        return (lead.id, gap) if gap <= self.lookahead_m or self._in_reach(tr, gap) else None

    def _in_reach(self, tr: _Train, gap: float) -> bool:
        """A train ahead beyond the look-ahead counts as SUMO's lane-by-lane look-ahead counts it: the
        track (edge or junction) holding its rear begins within the look-ahead; an edge counts from
        the junction before it, which the look-ahead enters before the edge."""
        r, rear = tr.route, tr.x + gap
        j = bisect_right(r.off, rear) - 1
        if j < 0:
            return False
        if rear >= r.end[j]:  # its rear inside the junction after edge j
            begins = r.end[j]
        elif j <= tr.kf:
            return True
        else:
            begins = r.end[j - 1]
        return begins - tr.x <= self.lookahead_m

    # ----------------------------------------------------------------------------- the index
    def _depart(self, vid: str) -> _Train:
        edges = self.routes_of[vid]
        key = id(edges)
        route = self._routes.get(key)
        if route is None:
            route = self._routes[key] = _Route(self.sim, edges, self._passages, self._via, self.lookahead_m)
        tr = self.trains[vid] = _Train(vid, route, self.sim.train_length(vid))
        self.order.append(tr)
        self.max_length = max(self.max_length, tr.length)
        return tr

    def _occupy(self, tr: _Train, kr: int, kf: int) -> None:
        """Put ``tr`` on the edges kr..kf of its route in the index (none: -1, -1)."""
        edges, on_edge = tr.route.edges, self.on_edge
        for k in range(max(tr.occ_r, 0), tr.occ_f + 1):
            if not kr <= k <= kf:
                lst = on_edge.get(edges[k])
                if lst is not None:
                    lst[:] = [item for item in lst if item[0] is not tr]
        for k in range(max(kr, 0), kf + 1):
            if not tr.occ_r <= k <= tr.occ_f:
                on_edge.setdefault(edges[k], []).append((tr, k))
        tr.occ_r, tr.occ_f = kr, kf

    def _entered(self, new: _Train, k: int, departed: bool) -> None:
        """``new`` came onto edge k of its route by departing there or from another line: it becomes
        the train ahead of the trains behind it on that edge's routes, where nearer than theirs."""
        if k < 0 or math.isnan(new.x):
            return
        edge = new.route.edges[k]
        came_from = None if departed or k == 0 else new.route.edges[k - 1]
        off_new = new.route.off[k]
        for tr in self.order:
            if tr is new or not tr.running or math.isnan(tr.x):
                continue
            r = tr.route
            j = r.index_from(edge, max(tr.kf, 0))
            if j < 0 or (came_from is not None and j > 0 and r.edges[j - 1] == came_from):
                continue  # not on this route ahead, or it was on this route already
            base = r.off[j] - off_new
            if base + new.x <= tr.x:
                continue  # behind this train's front
            lead = tr.lead
            if lead is not None and lead.running and (lead.kr <= tr.lead_k or self._follow(tr, lead)):
                if tr.shift + lead.x <= base - new.length + new.x:
                    continue  # its train ahead is nearer
            elif lead is not None or tr.stale:
                tr.lead, tr.stale = None, True  # its train ahead is lost: searched for anew (``new`` is in the index)
                continue
            tr.see(new, k, j, base)

    def _follow(self, tr: _Train, lead: _Train) -> bool:
        """The rear of ``lead`` passed onto further edges: still on ``tr``'s route (the two routes run
        on together), the projection moves with it; else it turned off."""
        a, b = lead.route, tr.route
        d = lead.kr - tr.lead_k
        j = tr.lead_j + d
        if j >= b.n or any(b.edges[tr.lead_j + i] != a.edges[tr.lead_k + i] for i in range(1, d + 1)):
            return False
        tr.see(lead, lead.kr, j, b.off[j] - a.off[lead.kr])
        return True

    def _search(self, tr: _Train) -> None:
        """The nearest train whose body lies on ``tr``'s route ahead of its front (however far)."""
        self.searches += 1
        tr.lead, tr.stale = None, False
        r, x = tr.route, tr.x
        if math.isnan(x) or tr.kf < 0:
            return
        best = math.inf
        on_edge, max_length = self.on_edge, self.max_length
        for j in range(tr.kf, r.n):
            if r.off[j] - x - max_length > best:
                break
            for other, k in on_edge.get(r.edges[j], ()):
                if other is tr:
                    continue
                base = r.off[j] - other.route.off[k]
                if base + other.x <= x:
                    continue  # its front is behind this train's front
                gap = base + other.x - other.length - x
                if gap < best - 1e-9:  # (the same train on a further edge of its body: kept where first seen)
                    best = gap
                    tr.see(other, k, j, base)
