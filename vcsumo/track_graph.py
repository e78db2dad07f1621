"""The directed track graph of a line: nodes, edges, tracks, platforms and open ends.

Built from a line by :func:`vcsumo.topology.build_topology` (a network of lines by
:func:`vcsumo.network_topology.build_network_topology`); read by the SUMO network writer, the route
profiles and the timetable planner.  Track naming and layout are described in :mod:`vcsumo.topology`.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections import deque
from dataclasses import dataclass, field, replace

from vcsumo.dynamics import curve_equivalent_gradient
from vcsumo.line import Line

EPS_KM = 1e-6
"""Tolerance when a chainage is compared with a range's ends, km."""


@dataclass(frozen=True)
class TopoNode:
    """A point on a track where something changes."""

    id: str
    x: float
    y: float
    z: float
    signal: bool
    section: str
    km: float


@dataclass(frozen=True)
class TopoEdge:
    """A piece of one track with uniform speed, gradient, curve and tunnel."""

    id: str
    track: str
    section: str
    direction: str
    from_node: str
    to_node: str
    km_from: float
    km_to: float
    length_m: float
    speed_ms: float
    gradient: float
    """Geometric gradient in the direction of travel (rise/run)."""
    curve_radius_m: float
    tunnel: str | None
    tunnel_factor: float
    bidi: str | None = None

    def km_at(self, pos_m: float) -> float:
        """Section chainage at a position along this edge."""
        sign = 1.0 if self.km_to >= self.km_from else -1.0
        return self.km_from + sign * pos_m / 1000.0

    @property
    def equivalent_gradient(self) -> float:
        """Gradient plus curve resistance as a gradient (rise/run, travel direction)."""
        return self.gradient + curve_equivalent_gradient(self.curve_radius_m)


@dataclass(frozen=True)
class Platform:
    """Where a train serving a station stops on one track (SUMO trainStop)."""

    id: str
    station_id: str
    station_name: str
    section: str
    track: str
    edge: str
    start_pos_m: float
    end_pos_m: float
    """Stopping position of the train front on the edge, m."""
    dwell_s: float
    km_stop: float
    """Section chainage of the train front when stopped, km."""
    length_m: float = 0.0
    """The station's platform length, m (the line file's). The SUMO stop (``start_pos_m`` to
    ``end_pos_m``) lies on the platform's last edge only and is shorter where a gradient, speed,
    curve or tunnel change cuts the platform into edges; a train stands in the whole platform."""


@dataclass
class Track:
    id: str
    section: str
    direction: str
    increasing: bool
    """True when travel on this track goes towards increasing section chainage."""
    edges: list[str] = field(default_factory=list)


@dataclass
class Topology:
    """The directed track graph of a line."""

    line: Line
    block_length_m: float | None
    nodes: dict[str, TopoNode] = field(default_factory=dict)
    edges: dict[str, TopoEdge] = field(default_factory=dict)
    tracks: dict[str, Track] = field(default_factory=dict)
    successors: dict[str, list[str]] = field(default_factory=dict)
    turnout_speed_ms: dict[tuple[str, str], float] = field(default_factory=dict)
    platforms: dict[str, Platform] = field(default_factory=dict)
    endpoints: dict[str, tuple[list[str], list[str]]] = field(default_factory=dict)
    """Open ends trains may start or end at: name ('start', 'end', 'branch:<id>'; in a network
    '<line>:start' ...) -> (edges leaving the end into the network, edges arriving at it)."""
    km_origin: dict[str, float] = field(default_factory=dict)
    """Section -> chainage (km) of SUMO's kilometrage origin (edge ``distance``): the line start."""
    named_nodes: dict[str, list[str]] = field(default_factory=dict)
    """Named places a route may be asked to pass (network joins) -> their node ids."""

    # ---------------------------------------------------------------------------------------
    def track_for(self, section: str, direction: str) -> Track:
        tid = f"{section}_{direction}"
        if tid not in self.tracks:
            raise KeyError(tid)
        return self.tracks[tid]

    def locate(self, section: str, km: float, direction: str) -> tuple[str, float]:
        """(edge id, position on the edge in m) of chainage ``km`` on a section's track."""
        tr = self.track_for(section, direction)
        for eid in tr.edges:
            e = self.edges[eid]
            lo, hi = sorted((e.km_from, e.km_to))
            if lo - EPS_KM <= km <= hi + EPS_KM:
                pos = abs(km - e.km_from) * 1000.0
                return eid, min(max(pos, 0.0), e.length_m)
        raise KeyError(f"{km} km is not on track {tr.id}")

    def entry_nodes(self) -> set[str]:
        """Nodes no edge leads into (track starts): SUMO would turn a signal there into a dead end."""
        targets = {e.to_node for e in self.edges.values()}
        return {e.from_node for e in self.edges.values() if e.from_node not in targets}

    def signal_nodes(self) -> set[str]:
        """Nodes that become SUMO rail signals."""
        entry = self.entry_nodes()
        return {n.id for n in self.nodes.values() if n.signal and n.id not in entry}

    def first_signal_ahead(self, edges: list[str], starts_m, front_s_m: float) -> str | None:
        """The first signal a train whose front stands at route position ``front_s_m`` has to pass
        (``edges``: its route; ``starts_m``: the route position of each edge's start, m): the signal
        at its front when it stands exactly at an edge's end (a platform's exit signal), not the one
        after it; None when its route ends before one."""
        k = max(0, bisect_right(starts_m, front_s_m - 0.01) - 1)
        signals = self.signal_nodes()
        return next((self.edges[e].to_node for e in edges[k:-1] if self.edges[e].to_node in signals), None)

    def platforms_of(self, station_id: str) -> list[Platform]:
        return [p for p in self.platforms.values() if p.station_id == station_id]

    def route_edges(self, start_edges: list[str], goal_edges: list[str]) -> list[str] | None:
        """Shortest (by length) edge sequence from any start edge to any goal edge (BFS over successors)."""
        import heapq

        goals = set(goal_edges)
        dist: dict[str, float] = {}
        prev: dict[str, str | None] = {}
        heap: list[tuple[float, str]] = []
        for s in start_edges:
            dist[s] = 0.0
            prev[s] = None
            heapq.heappush(heap, (0.0, s))
        while heap:
            d, e = heapq.heappop(heap)
            if d > dist.get(e, math.inf):
                continue
            if e in goals:
                path = [e]
                while prev[path[-1]] is not None:
                    path.append(prev[path[-1]])  # type: ignore[arg-type]
                return path[::-1]
            for n in self.successors.get(e, []):
                nd = d + self.edges[e].length_m
                if nd < dist.get(n, math.inf):
                    dist[n] = nd
                    prev[n] = e
                    heapq.heappush(heap, (nd, n))
        return None

    def end_edges(self, endpoint: str) -> tuple[list[str], list[str]]:
        """(start edges, goal edges) of an open end (see :attr:`endpoints`); KeyError if unknown."""
        return self.endpoints[endpoint]

    def tracks_first(self, section: str, direction: str) -> str:
        return self.track_for(section, direction).edges[0]

    def tracks_last(self, section: str, direction: str) -> str:
        return self.track_for(section, direction).edges[-1]


def reachable(topo: Topology, start: str) -> set[str]:
    """Edges reachable from ``start`` (used by checks and tests)."""
    seen = {start}
    q = deque([start])
    while q:
        e = q.popleft()
        for n in topo.successors.get(e, []):
            if n not in seen:
                seen.add(n)
                q.append(n)
    return seen


def converge_onto_single_track(topo: Topology, nodes: set[str] | None = None) -> list[str]:
    """Where a double track meets a single track at a junction *inside* it (a double-track branch
    of a single-track line, a double-track line of a network joined inside a single-track one),
    make the double track's last edges one track used both ways (a ``bidi`` pair: its two tracks
    converge one edge before the junction, at a signal).  Without it SUMO drew the train leaving
    the single track and the train joining it as two crossing one-way links of the junction: a train
    held off the single track (it waits for an opposing one on it) stood at the junction signal
    and SUMO's signal then kept the opposing train from leaving the single track there — both
    waited for ever.  ``nodes``: only these junctions (default: every one).  Returns the edges made
    single track."""
    changed: list[str] = []
    by_from: dict[str, list[TopoEdge]] = {}
    by_to: dict[str, list[TopoEdge]] = {}
    for e in topo.edges.values():
        by_from.setdefault(e.from_node, []).append(e)
        by_to.setdefault(e.to_node, []).append(e)
    for node in list(topo.nodes) if nodes is None else sorted(nodes):
        if sum(e.bidi is not None for e in by_from.get(node, [])) < 2:
            continue  # not a node inside a single track (an end of one joined to a double track stays as it is)
        for out in [e for e in by_from.get(node, []) if e.bidi is None]:
            into = next((e for e in by_to.get(node, []) if e.bidi is None and e.section == out.section and e.track != out.track
                         and abs(e.length_m - out.length_m) < 1e-6 and abs(e.km_from - out.km_to) < 1e-9), None)
            if into is None:
                continue
            x, y = out.to_node, into.from_node
            if x == y or by_from.get(y, []) != [into] or len(by_from.get(x, [])) != 1:
                continue  # the double track forks or ends there: left as it is
            for p in by_to.get(y, []):
                topo.edges[p.id] = p = replace(p, to_node=x)
                by_to.setdefault(x, []).append(p)
            by_to[y] = []
            topo.edges[into.id] = replace(into, from_node=x, bidi=out.id)
            topo.edges[out.id] = replace(out, bidi=into.id)
            by_from[x] = by_from.get(x, []) + [topo.edges[into.id]]
            by_from[y] = []
            xn, yn = topo.nodes[x], topo.nodes[y]
            topo.nodes[x] = replace(xn, signal=xn.signal or yn.signal)
            del topo.nodes[y]
            changed += [into.id, out.id]
    return changed
