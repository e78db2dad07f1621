"""Planned meetings on single track: opposing trains timetabled onto the same single track at once.

vcsumo models no crossing loops: a single-track line or branch (``tracks: single``) is one track used
both ways from end to end, so two trains timetabled onto it in opposite directions at overlapping
times cannot pass: the interlocking gives the single track to one direction at a time
(:mod:`vcsumo.sim.single_track_lock`), and the train that asks for it later waits in front of it
until the other has left it — a delay the timetable did not plan.  :func:`single_track_meetings` finds them from every train's unhindered run (its own
timetabled stops and dwells, departure as planned): the time its front enters a stretch of
single track and the time its rear leaves it.  Trains delayed on the way can still meet; trains
reported here meet unless another one holds them back first.
"""

from __future__ import annotations

import math

from vcsumo.running_time import Stop, time_at, unhindered_run
from vcsumo.topology import Topology
from vcsumo.units import format_clock


def _stretches(topo: Topology, edges: list[str]) -> list[tuple[int, int]]:
    """(first, last) route indices of every run of single-track (bidirectional) edges."""
    out, start = [], None
    for i, e in enumerate(edges):
        if topo.edges[e].bidi is not None:
            start = i if start is None else start
        elif start is not None:
            out.append((start, i - 1))
            start = None
    if start is not None:
        out.append((start, len(edges) - 1))
    return out


def single_track_meetings(trains: list, topo: Topology, dt: float = 0.5) -> list[str]:
    """One sentence per pair of planned trains (``timetable.PlannedTrain``) that run in opposite
    directions over a common single-track edge at overlapping times (unhindered runs)."""
    occupied: list[tuple[str, set[str], set[str], float, float, str]] = []  # train, edges, their twins, enter, leave, where
    runs: dict[tuple, object] = {}
    for t in trains:
        parts = _stretches(topo, t.edges)
        if not parts:
            continue
        end_s = t.final_stop.s_m if t.final_stop else float(t.profile.starts_m[-1] + (t.end_pos_m or topo.edges[t.edges[-1]].length_m))
        key = (tuple(t.edges), t.stock.name, t.start_s_m, end_s, tuple((s.s_m, s.dwell_s) for s in t.stops))
        if key not in runs:
            runs[key] = unhindered_run(t.stock.params(), t.profile, dt=dt, s0=t.start_s_m, stops=[Stop(s.s_m, s.dwell_s) for s in t.stops], end_s=end_s)
        run = runs[key]
        t_end = float(run["time_s"].iloc[-1])
        for i, j in parts:
            s_in = max(float(t.profile.starts_m[i]), t.start_s_m)
            s_out = min(float(t.profile.starts_m[j] + t.profile.lengths_m[j]) + t.stock.length_m, end_s)
            enter = 0.0 if s_in <= t.start_s_m + 1e-6 else float(time_at(run, s_in)[0])
            leave = t_end if s_out >= end_s - 1e-6 else float(time_at(run, s_out)[0])
            if math.isnan(enter) or math.isnan(leave):
                continue
            e0, e1 = topo.edges[t.edges[i]], topo.edges[t.edges[j]]
            where = f"{e0.section} km {min(e0.km_from, e1.km_to):g}–{max(e0.km_from, e1.km_to):g}"
            mine = set(t.edges[i:j + 1])
            occupied.append((t.id, mine, {topo.edges[e].bidi for e in mine}, t.depart_s + enter, t.depart_s + leave, where))
    out = []
    for k, (a, ea, ta, a0, a1, wa) in enumerate(occupied):
        for b, eb, tb, b0, b1, wb in occupied[k + 1:]:
            if a != b and ea & tb and a0 < b1 and b0 < a1:
                out.append(f"trains {a} and {b} are timetabled onto the same single track in opposite directions at the same time "
                           f"({a} on {wa} {format_clock(a0)}–{format_clock(a1)}, {b} on {wb} {format_clock(b0)}–{format_clock(b1)}, "
                           "unhindered): no crossing loop is modelled, so the one that asks for the single track later waits in front of "
                           "it until the other has left it (a delay)")
    return out
