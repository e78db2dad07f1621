"""Convoy members of a timetable run at the same time: checked before a run (an InputError naming
the convoy), with each member's unhindered running time when no arrival is scheduled."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vcsumo.errors import InputError
from vcsumo.running_time import Stop, unhindered_run
from vcsumo.units import format_clock

PlannedTrain = Any
"""A :class:`vcsumo.timetable.PlannedTrain` (not imported: that module imports this one)."""


def running_time_s(t: PlannedTrain, dt: float) -> float:
    """Unhindered running time of a train from its departure to its destination (with its dwells), s."""
    end_s = t.final_stop.s_m if t.final_stop else float(t.profile.starts_m[-1] + (t.end_pos_m or 0.0))
    run = unhindered_run(t.stock.params(), t.profile, dt=dt, s0=t.start_s_m, stops=[Stop(s.s_m, s.dwell_s) for s in t.stops], end_s=end_s)
    return float(run["time_s"].iloc[-1])


def check_convoy_times(trains: list[PlannedTrain], services: list[str], path: Path, field_name: str, dt: float) -> None:
    """The k-th trains of a convoy's services run at the same time: a member that departs only after
    another has arrived (as scheduled, else unhindered) never couples (an InputError naming the convoy)."""
    by_service = {s: [t for t in trains if t.service == s] for s in services}
    running: dict[str, float] = {}

    def arrival(t: PlannedTrain) -> float:
        if t.scheduled_arrival_s is not None:
            return t.scheduled_arrival_s
        if t.service not in running:  # repeats of a service share its route and stops
            running[t.service] = running_time_s(t, dt)
        return t.depart_s + running[t.service]

    for k in range(min(len(v) for v in by_service.values())):
        members = [by_service[s][k] for s in services]
        last = max(members, key=lambda t: t.depart_s)
        first = min(members, key=arrival)
        if last.depart_s >= arrival(first):
            raise InputError(path, f"{field_name}.services", f"train {last.id} departs at {format_clock(last.depart_s)}, when {first.id} of the same "
                             f"convoy is already at its destination ({format_clock(arrival(first))}): they never run together, so they never couple")
