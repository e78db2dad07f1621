"""The train ahead beyond SUMO's look-ahead, kept from step to step (:class:`RouteLeaders`, on
:class:`vcsumo.sim.sumo_backend.SumoBackend`'s route walk and driving distance).

The loop no longer asks this (nor getLeader): :class:`vcsumo.sim.trains_ahead.TrainsAhead` answers
from vcsumo's own route index.  It stays as the reference the tests compare that index with
(tests/train_ahead_check.py)."""

from __future__ import annotations

from vcsumo.errors import SumoError
from vcsumo.sim.sumo_backend import INVALID_DISTANCE, SumoBackend


class RouteLeaders:
    """The train ahead on each train's route beyond SUMO's look-ahead, kept from step to step.

    :meth:`SumoBackend.route_leader_indexed` walks a train's route ahead at every step.  Here the
    answer is kept: the nearest train found stays the nearest until a train comes onto the route
    between the two (a departure, a train coming off a junction: an edge it enters) or it leaves
    the route; a walk that found nobody at all goes on from where it stopped, over the route the
    train reaches since, unless a train entered the part already walked.  SUMO's driving distance
    gives the gap at every step.  A train's answer is kept only from one step to the next (a step
    without a query forgets it) and only on routes that pass no edge twice: the answers are those of
    walking at every step (tests/test_loop_cost.py compares them with a driving distance to every
    train)."""

    def __init__(self, sim: SumoBackend, max_length_m: float, lookahead_m: float):
        self.sim = sim
        self.max_length_m = max_length_m
        self.lookahead_m = lookahead_m
        self.on_edge: dict[str, list[tuple[str, float, float]]] = {}
        self._where: dict[str, tuple[str, float, float]] = {}
        self._entered: list[str] = []
        self._step = 0
        self._kept: dict[str, tuple] = {}
        self._index: dict[int, dict[str, int] | None] = {}
        self.kept_answers = 0
        """Answers given from the step before (the rest walked the route again)."""

    def begin_step(self, ids: list[str], observed: list[tuple], lengths: dict[str, float]) -> None:
        """This step's trains: ``observed`` as :meth:`SumoBackend.observe_all` gives them."""
        self._step += 1
        before = self._where
        on_edge: dict[str, list[tuple[str, float, float]]] = {}
        where: dict[str, tuple[str, float, float]] = {}
        entered = []
        for vid, o in zip(ids, observed):
            edge = o[0]
            if edge[:1] == ":":  # inside a junction: on the edge it is leaving (as in route_leader)
                edge, pos, length = self.sim.crossing(vid, o[1], lengths[vid])
                item = (vid, pos, length)
            else:
                item = (vid, o[1], lengths[vid])
            lst = on_edge.get(edge)
            if lst is None:
                on_edge[edge] = [item]
            else:
                lst.append(item)
            where[vid] = (edge, item[1], item[2])
            prev = before.get(vid)
            if prev is None or prev[0] != edge:
                entered.append(edge)
        self.on_edge, self._where, self._entered = on_edge, where, entered

    def _route_index(self, route: list[str]) -> dict[str, int] | None:
        key = id(route)
        if key not in self._index:
            idx = {e: k for k, e in enumerate(route)}
            self._index[key] = idx if len(idx) == len(route) else None
        return self._index[key]

    def leader(self, vid: str, s_m: float, route: list[str], starts_m: list[float], index: int) -> tuple[str, float] | None:
        """As :meth:`SumoBackend.route_leader_indexed` on this step's trains."""
        try:
            return self._leader(vid, s_m, route, starts_m, index)
        except SumoError:
            raise
        except Exception as exc:
            err = self.sim.translate_failure("route_leader", exc)
            if err is not None:
                raise err from None
            raise

    def _leader(self, vid: str, s_m: float, route: list[str], starts_m: list[float], index: int) -> tuple[str, float] | None:
        sim, look = self.sim, self.lookahead_m
        if index < 0:
            return None
        pos_of = self._route_index(route)
        kept = self._kept.get(vid)
        if pos_of is not None and kept is not None and kept[0] == self._step - 1 and kept[1] is route:
            if kept[2] == "train":  # the train found last step, if still the nearest on the route
                w = self._where.get(kept[3])
                k_l = pos_of.get(w[0], -1) if w is not None else -1
                if k_l >= index and not any(index <= pos_of.get(e, -1) <= k_l for e in self._entered):
                    d = sim.get_driving_distance(vid, w[0], w[1])
                    if not (d <= INVALID_DISTANCE + 1 or d < -1e8 or d <= 0.0) and d - w[2] <= look:
                        self._kept[vid] = (self._step, route, "train", kept[3])
                        self.kept_answers += 1
                        return kept[3], d - w[2]
            else:  # nobody on what was walked: walk on from where it stopped
                k_stop = kept[3]
                if k_stop >= index and not any(index <= pos_of.get(e, -1) < k_stop for e in self._entered):
                    self.kept_answers += 1
                    cands, k_end = sim.walk_route(vid, s_m, route, starts_m, k_stop, self.on_edge, self.max_length_m, look)
                    return self._keep(vid, route, cands, k_end, sim.nearest_candidate(vid, cands, look))
        cands, k_end = sim.walk_route(vid, s_m, route, starts_m, index, self.on_edge, self.max_length_m, look)
        return self._keep(vid, route, cands, k_end, sim.nearest_candidate(vid, cands, look))

    def _keep(self, vid: str, route: list[str], cands: list, k_end: int, found: tuple[str, float] | None) -> tuple[str, float] | None:
        if found is not None:
            self._kept[vid] = (self._step, route, "train", found[0])
        elif not cands:
            self._kept[vid] = (self._step, route, "none", k_end)
        else:
            self._kept.pop(vid, None)  # candidates, none within the look-ahead: walk again next step
        return found
