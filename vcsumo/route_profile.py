"""A train's route as a one-dimensional profile: speed limits, gradients, tunnels along distance.

Positions ``s`` are metres from the start of the route (the start of its first edge), exactly the
same metres SUMO uses (edge lengths are written explicitly into the network).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field

import numpy as np

from vcsumo.topology import Topology


@dataclass
class RouteProfile:
    """Speed limit, gradient and tunnel factor along a route of topology edges."""

    edges: list[str]
    starts_m: np.ndarray
    lengths_m: np.ndarray
    speeds_ms: np.ndarray
    gradients: np.ndarray
    """Equivalent gradient (gradient + curve resistance), rise/run in the direction of travel."""
    tunnel_factors: np.ndarray
    sections: list[str]
    km_from: np.ndarray
    km_to: np.ndarray
    point_limits: list[tuple[float, float]]
    """(position m, speed m/s) of turnouts: held until the whole train has passed."""
    _starts: list[float] = field(default_factory=list, repr=False, compare=False)
    _speeds: list[float] = field(default_factory=list, repr=False, compare=False)
    _grads: list[float] = field(default_factory=list, repr=False, compare=False)
    _tfs: list[float] = field(default_factory=list, repr=False, compare=False)
    _ends: list[float] = field(default_factory=list, repr=False, compare=False)
    _km_from: list[float] = field(default_factory=list, repr=False, compare=False)
    _km_sign: list[float] = field(default_factory=list, repr=False, compare=False)
    _last_i: int = field(default=0, repr=False, compare=False)
    _mg_key: tuple = field(default=(), repr=False, compare=False)
    _mg_val: float = field(default=0.0, repr=False, compare=False)
    _slt_key: tuple = field(default=(), repr=False, compare=False)
    _slt_val: float = field(default=0.0, repr=False, compare=False)

    def __post_init__(self) -> None:
        # plain lists for fast scalar look-ups (bisect) in the per-step loops
        self._starts = [float(x) for x in self.starts_m]
        self._speeds = [float(x) for x in self.speeds_ms]
        self._grads = [float(x) for x in self.gradients]
        self._tfs = [float(x) for x in self.tunnel_factors]
        self._ends = [float(a + b) for a, b in zip(self.starts_m, self.lengths_m)]
        self._km_from = [float(x) for x in self.km_from]
        self._km_sign = [1.0 if b >= a else -1.0 for a, b in zip(self.km_from, self.km_to)]
        # the edge found last (a train's look-ups walk along the route) and the last values of the
        # train-length look-ups: the loop, the controller and the guard ask for the same position
        # several times per step
        self._last_i = 0
        self._mg_key = ()
        self._slt_key = ()

    @property
    def length_m(self) -> float:
        return float(self.starts_m[-1] + self.lengths_m[-1])

    @classmethod
    def from_edges(cls, topo: Topology, edges: list[str]) -> "RouteProfile":
        starts, lengths, speeds, grads, tfs, secs, k0, k1 = [], [], [], [], [], [], [], []
        points: list[tuple[float, float]] = []
        s = 0.0
        for i, eid in enumerate(edges):
            e = topo.edges[eid]
            starts.append(s)
            lengths.append(e.length_m)
            speeds.append(e.speed_ms)
            grads.append(e.equivalent_gradient)
            tfs.append(e.tunnel_factor)
            secs.append(e.section)
            k0.append(e.km_from)
            k1.append(e.km_to)
            if i > 0 and (edges[i - 1], eid) in topo.turnout_speed_ms:
                points.append((s, topo.turnout_speed_ms[(edges[i - 1], eid)]))
            s += e.length_m
        return cls(
            edges=list(edges), starts_m=np.array(starts), lengths_m=np.array(lengths), speeds_ms=np.array(speeds),
            gradients=np.array(grads), tunnel_factors=np.array(tfs), sections=secs, km_from=np.array(k0),
            km_to=np.array(k1), point_limits=points,
        )

    # ---------------------------------------------------------------------------------------
    def signal_positions(self, topo: Topology) -> list[float]:
        """Route positions (m) of the rail signals at the ends of the route's edges (not the last)."""
        signals = topo.signal_nodes()
        return [float(self.starts_m[i] + self.lengths_m[i]) for i, eid in enumerate(self.edges[:-1]) if topo.edges[eid].to_node in signals]

    def index_at(self, s: float) -> int:
        """Index of the edge containing position s (the later edge at a boundary)."""
        starts = self._starts
        i = self._last_i
        # fast path: still on the edge found last (same answer as the bisection)
        if starts[i] <= s and (i + 1 == len(starts) or s < starts[i + 1]):
            return i
        i = bisect_right(starts, s) - 1
        i = min(max(i, 0), len(starts) - 1)
        self._last_i = i
        return i

    def km_at(self, s: float) -> tuple[str, float]:
        """(section, chainage km) of route position s."""
        i = self.index_at(s)
        pos = s - self._starts[i]
        km0 = self._km_from[i]
        return self.sections[i], float(km0 + self._km_sign[i] * pos / 1000.0)

    def s_of(self, section: str, km: float) -> float:
        """Route position of a section chainage (first pass), m; raises KeyError if not on the route."""
        for i in range(len(self.edges)):
            if self.sections[i] != section:
                continue
            lo, hi = sorted((self.km_from[i], self.km_to[i]))
            if lo - 1e-6 <= km <= hi + 1e-6:
                return float(self.starts_m[i] + abs(km - self.km_from[i]) * 1000.0)
        raise KeyError(f"{section} km {km} is not on this route")

    def edge_position(self, s: float) -> tuple[str, float]:
        """(edge id, position on the edge) of route position s."""
        i = self.index_at(s)
        return self.edges[i], float(min(max(s - self.starts_m[i], 0.0), self.lengths_m[i]))

    def speed_limit_at(self, s: float) -> float:
        """Speed limit at the train front, m/s."""
        return self._speeds[self.index_at(s)]

    def speed_limit_train(self, s: float, length_m: float) -> float:
        """Lowest limit over the whole train [s − L, s] including turnouts (SUMO's rule), m/s."""
        key = (s, length_m)
        if key == self._slt_key:
            return self._slt_val
        i0 = self.index_at(max(s - length_m, 0.0))
        i1 = self.index_at(s)
        v = min(self._speeds[i0 : i1 + 1])
        for ps, pv in self.point_limits:
            if s - length_m - 1e-9 <= ps <= s + 1e-9 and pv < v:
                v = pv
        self._slt_key, self._slt_val = key, v
        return v

    def mean_gradient(self, s: float, length_m: float) -> float:
        """Equivalent gradient averaged over the train [s − L, s] (SUMO's getSlope)."""
        key = (s, length_m)
        if key == self._mg_key:
            return self._mg_val
        val = self._mean_gradient(s, length_m)
        self._mg_key, self._mg_val = key, val
        return val

    def _mean_gradient(self, s: float, length_m: float) -> float:
        lo = s - length_m
        g = self._grads
        if length_m <= 0:
            return g[self.index_at(s)]
        i0, i1 = self.index_at(max(lo, 0.0)), self.index_at(s)
        if i0 == i1 and lo >= 0:
            return g[i1]
        total = 0.0
        if lo < 0:  # train tail before the route start: extend the first edge's gradient
            total += g[0] * (-lo)
            lo = 0.0
        starts, ends = self._starts, self._ends
        for i in range(i0, i1 + 1):
            a = lo if lo > starts[i] else starts[i]
            b = s if s < ends[i] else ends[i]
            if b > a:
                total += g[i] * (b - a)
        return total / length_m

    def gradient_range(self, s0: float, s1: float) -> tuple[float, float]:
        """(lowest, highest) equivalent gradient of the edges touching [s0, s1]."""
        i0, i1 = self.index_at(max(s0, 0.0)), self.index_at(max(s1, s0))
        seg = self._grads[i0 : i1 + 1]
        return min(seg), max(seg)

    def tunnel_factor_at(self, s: float) -> float:
        """Tunnel factor at the train front (SUMO switches the vType when the front passes a portal)."""
        return self._tfs[self.index_at(s)]

    def restriction_targets(self) -> list[tuple[float, float]]:
        """(position, speed) of every place where the limit drops, sorted by position."""
        out = []
        for i in range(1, len(self.edges)):
            if self.speeds_ms[i] < self.speeds_ms[i - 1] - 1e-9:
                out.append((float(self.starts_m[i]), float(self.speeds_ms[i])))
        out += [(s, v) for s, v in self.point_limits]
        return sorted(out)

    def max_speed(self) -> float:
        return float(max(self.speeds_ms.max(), max((v for _, v in self.point_limits), default=0.0)))

    def min_speed_over(self, s0: float, s1: float) -> float:
        i0, i1 = self.index_at(s0), self.index_at(s1)
        return float(self.speeds_ms[i0 : i1 + 1].min()) if i1 >= i0 else math.inf
