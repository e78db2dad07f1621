"""A :class:`TrainsAhead` that also asks SUMO the old way at every step and records the differences.

The old way is what the loop asked before: SUMO's ``getLeader`` (30 km) with the train's minGap
added back, else the train ahead on the route from :class:`RouteLeaders` (driving distances).
``checked_trains_ahead(plans, logs)`` gives a subclass to put in place of
``vcsumo.sim.loop.TrainsAhead``; each run appends its :class:`CheckLog` to ``logs``.

Every differing answer gets the reason it may differ, from SUMO's own view of the two trains (None:
no reason, a defect):

* ``junction``: the same train ahead, the gaps within 1e-4 m, while that train crosses into the
  route from another line: SUMO's getLeader measures such a train at the junction's conflict point
  (a "link leader"), a few 1e-5 m off the driving distance along the lanes;
* ``turning off``: the train ahead has its front off the route already, its rear still on it: the
  route walk (beyond getLeader's reach) looks for fronts only and missed it;
* ``crossing in``: the train ahead is inside a junction, coming onto the route from another line:
  getLeader sees it there (a link leader), the route walk did not;
* ``look-ahead``: one of the two trains ahead is beyond the 30 km look-ahead: getLeader reaches
  beyond it lane by lane (which the new answer follows) except where a lower speed limit ahead
  shortens its reach, and there the route walk stops at 30 km.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from vcsumo.sim.route_leaders import RouteLeaders
from vcsumo.sim.trains_ahead import TrainsAhead

TOLERANCE_M = 1e-6
JUNCTION_TOLERANCE_M = 1e-4


@dataclass
class Differ:
    time_s: float
    train: str
    new: tuple[str, float] | None
    old: tuple[str, float] | None
    source: str
    """Where the old answer came from: 'getLeader' or 'route walk'."""
    edge: str
    lane_pos_m: float
    why: str | None


@dataclass
class CheckLog:
    compared: int = 0
    found: int = 0
    from_get_leader: int = 0
    from_walk: int = 0
    max_gap_error_m: float = 0.0
    """Largest gap difference of the answers naming the same train ahead (beside ``junction``)."""
    turning_off: int = 0
    """Agreeing answers whose train ahead has its front off the route (its rear still on it)."""
    differ: list[Differ] = field(default_factory=list)
    searches: int = 0
    train_steps: int = 0

    def why(self) -> dict[str | None, int]:
        out: dict[str | None, int] = {}
        for d in self.differ:
            out[d.why] = out.get(d.why, 0) + 1
        return out

    def __str__(self) -> str:
        return (f"compared {self.compared} answers ({self.found} trains ahead: {self.from_get_leader} by getLeader, {self.from_walk} "
                f"by the route walk; {self.turning_off} agreeing on a train turning off the route), largest gap difference "
                f"{self.max_gap_error_m:.3g} m, {len(self.differ)} differ {self.why()}, {self.searches} searches in {self.train_steps} train-steps")


def checked_trains_ahead(plans: dict, logs: list[CheckLog]):
    """A TrainsAhead class comparing every answer with the old way (``plans``: the PlannedTrains by id)."""
    routes = {vid: p.profile.edges for vid, p in plans.items()}
    on_route = {vid: set(edges) for vid, edges in routes.items()}

    class Checked(TrainsAhead):
        def __init__(self, sim, routes_of, lookahead_m):
            super().__init__(sim, routes_of, lookahead_m)
            self.log = CheckLog()
            logs.append(self.log)
            self.walk = RouteLeaders(sim, max(p.stock.length_m for p in plans.values()), lookahead_m)
            self.sync: dict[str, tuple[float, float]] = {}
            self.starts = {vid: [float(x) for x in p.profile.starts_m] for vid, p in plans.items()}
            self.lengths = {vid: p.stock.length_m for vid, p in plans.items()}

        def leaders(self, ids, observed):
            new = super().leaders(ids, observed)
            sim, log = self.sim, self.log
            old = sim.leaders(ids, self.lookahead_m)
            self.walk.begin_step(ids, observed, self.lengths)
            log.searches = self.searches
            log.train_steps += len(ids)
            where = {vid: (o[0], o[5]) for vid, o in zip(ids, observed)}
            for i, (vid, o) in enumerate(zip(ids, observed)):
                edge, pos, odo, ridx = o[0], o[1], o[4], o[5]
                if 0 <= ridx < len(routes[vid]) and routes[vid][ridx] == edge:
                    self.sync[vid] = (self.starts[vid][ridx] + pos, odo)
                if vid not in self.sync:
                    continue  # (the loop skips a train not yet on its route)
                source = "getLeader"
                if old[i] is None and len(ids) > 1:  # the loop's fallback, as it was
                    source = "route walk"
                    s = self.sync[vid][0] + odo - self.sync[vid][1]
                    old[i] = self.walk.leader(vid, s, routes[vid], self.starts[vid], ridx)
                log.compared += 1
                a, b = new[i], old[i]
                if b is not None:
                    log.found += 1
                    log.from_get_leader += source == "getLeader"
                    log.from_walk += source == "route walk"
                if a is not None and b is not None and a[0] == b[0] and abs(a[1] - b[1]) <= TOLERANCE_M:
                    log.max_gap_error_m = max(log.max_gap_error_m, abs(a[1] - b[1]))
                    log.turning_off += _front(where, a[0])[1] not in on_route[vid]
                elif a is not None or b is not None:
                    why = self.why(vid, a, b, source, where)
                    if why is None and a is not None and b is not None and a[0] == b[0]:
                        log.max_gap_error_m = max(log.max_gap_error_m, abs(a[1] - b[1]))
                    log.differ.append(Differ(sim.time, vid, a, b, source, edge, pos, why))
            return new

        def why(self, vid, a, b, source, where) -> str | None:
            mine = on_route[vid]
            if a is not None and b is not None and a[0] == b[0]:
                back, _ = _front(where, a[0], behind=True)
                return "junction" if abs(a[1] - b[1]) <= JUNCTION_TOLERANCE_M and back not in mine else None
            if max(a[1] if a else 0.0, b[1] if b else 0.0) > self.lookahead_m and (a is None or b is None):
                return "look-ahead"
            if a is None or source != "route walk" or (b is not None and b[1] <= a[1]):
                return None
            leaving, entering = _front(where, a[0])
            if entering not in mine:
                return "turning off"
            if where[a[0]][0][:1] == ":" and leaving not in mine:
                return "crossing in"
            return None

    def _front(where, vid, behind=False) -> tuple[str, str]:
        """(edge its front leaves or last left, edge its front is on or enters) on its route; with
        ``behind``: (the edge before its front's edge, its front's edge)."""
        edge, k = where[vid]
        r = routes[vid]
        if edge[:1] == ":":
            return r[k], r[k + 1] if k + 1 < len(r) else ""
        return (r[k - 1] if behind and k > 0 else edge), edge

    return Checked
