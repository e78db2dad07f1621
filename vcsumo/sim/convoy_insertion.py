"""Convoy followers enter the network behind their predecessor, never in front of it.

A follower that does not stand behind its predecessor at the start (the platform does not hold them
both, or it starts at a station its predecessor runs through) departs from its own position once the
train ahead has cleared it by the standstill gap — planned with the predecessor's unhindered start
(:func:`~vcsumo.sim.convoy_plan.arrange_convoy_departures`).  SUMO inserts a train at its departure
time wherever its place is free, so a predecessor that starts later than planned (held by its own
controller or by a train ahead) was overtaken at the start: found by unseen8 (2026-11-28), a 4-train
convoy under ``cbf-cruise`` whose third member stood 62 s behind the second had its fourth member
inserted 219 m in front of it; neither coupled again and the run was reported healthy.

:class:`ConvoyInsertion` keeps every such follower out of the network (an insertion constraint at
the first signal ahead of its departure position, :meth:`~vcsumo.sim.sumo_backend.SumoBackend.hold_insertion`)
until its predecessor's rear has passed its front's position by the standstill gap, or the
predecessor has left the network.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from vcsumo.timetable import PlannedTrain
from vcsumo.topology import Topology


class ConvoyInsertion:
    """Followers held out of the network until their predecessor has passed where they enter."""

    def __init__(self, convoys: list[list[PlannedTrain]], standstill_gap_m: Mapping[str, float]):
        self.waiting: dict[str, tuple[str, float, float]] = {}
        """Follower -> (predecessor, the position its rear must pass on its own route, m; its length, m)."""
        self.plans: dict[str, PlannedTrain] = {}
        for members in convoys:
            for k in range(1, len(members)):
                ego, ahead = members[k], members[k - 1]
                if ego.edges[0] not in ahead.edges:
                    continue  # it joins the predecessor's route further on: the interlocking orders them at the merge
                s = float(ahead.profile.starts_m[ahead.edges.index(ego.edges[0])]) + ego.depart_pos_m
                if s <= ahead.start_s_m - ahead.stock.length_m + 1e-6:
                    continue  # it starts behind the predecessor (standing behind it in the platform)
                self.waiting[ego.id] = (ahead.id, s + standstill_gap_m.get(ego.id, 0.0), ahead.stock.length_m)
                self.plans[ego.id] = ego
        self.signal: dict[str, str] = {}
        self.seen: set[str] = set()
        self._hold: Callable[[str, str, bool], None] | None = None

    def attach(self, hold: Callable[[str, str, bool], None], topo: Topology) -> None:
        """Hold every waiting follower now (before the first step): ``hold(signal, train, True)``."""
        self._hold = hold
        for fid in list(self.waiting):
            plan = self.plans[fid]
            sig = topo.first_signal_ahead(plan.edges, plan.profile.starts_m, plan.start_s_m)
            if sig is None:
                del self.waiting[fid]  # no signal to hold it at (its route ends before one): SUMO inserts it as planned
                continue
            self.signal[fid] = sig
            hold(sig, fid, True)

    def update(self, states: Mapping[str, object]) -> None:
        """Release the followers whose predecessor (``states``: the running trains, each with ``s_m``
        on its own route) has cleared their departure position, or has left the network."""
        if self._hold is None:
            return
        self.seen.update(states.keys() & {p for p, _, _ in self.waiting.values()})
        for fid, (pid, s_clear, length) in list(self.waiting.items()):
            st = states.get(pid)
            cleared = (st.s_m - length >= s_clear) if st is not None else pid in self.seen
            if cleared or fid in states:
                del self.waiting[fid]
                self._hold(self.signal[fid], fid, False)
