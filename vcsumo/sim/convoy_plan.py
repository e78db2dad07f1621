"""Convoys as the timetable declares them, before the VC driver runs them: the channel settings,
the convoys' member trains, their departures together from a shared platform and their stops
aligned (a convoy leaves a station together).  :class:`vcsumo.sim.vc_driver.VCDriver` drives them."""

from __future__ import annotations

import math
from dataclasses import dataclass
import warnings
from pathlib import Path

from vcsumo.config import load_model
from vcsumo.control.channel import ChannelConfig
from vcsumo.control.params import resolve_params
from vcsumo.errors import InputError
from vcsumo.running_time import Stop, time_at, unhindered_run
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.timetable import PlannedTrain, TimetableFile
from vcsumo.units import format_clock


def load_channel(spec: str | Path | None, field: str | None = "--channel", base_dir: str | Path | None = None) -> ChannelConfig:
    """Channel settings: a YAML file, a name in controllers/ (default ``channel``)."""
    return load_model(ChannelConfig, resolve_params(spec, "channel", field, base_dir, kind="channel"))


# -------------------------------------------------------------------------------------------
# Convoys from the timetable


def convoys_from_timetable(tt: TimetableFile, tt_path: Path, trains: list[PlannedTrain]) -> list[list[PlannedTrain]]:
    """Convoys as lists of planned trains (leader first); repeated services pair up by index."""
    by_service: dict[str, list[PlannedTrain]] = {}
    for t in trains:
        by_service.setdefault(t.service, []).append(t)
    out: list[list[PlannedTrain]] = []
    used: set[str] = set()
    late_pairs: set[tuple[str, str]] = set()  # one warning per pair of services
    for c_i, cv in enumerate(tt.convoys):
        counts = {s: len(by_service.get(s, [])) for s in cv.services}
        for s_i, s in enumerate(cv.services):
            if counts[s] == 0:
                raise InputError(tt_path, f"convoys[{c_i}].services[{s_i}]", f"convoy '{cv.id}' names service '{s}', which does not exist")
            if s in used:
                raise InputError(tt_path, f"convoys[{c_i}].services[{s_i}]", f"service '{s}' is already in another convoy")
        if len(set(counts.values())) != 1:
            raise InputError(tt_path, f"convoys[{c_i}].services", f"services of convoy '{cv.id}' repeat a different number of times: {counts}")
        used |= set(cv.services)
        for k in range(next(iter(counts.values()))):
            members = [by_service[s][k] for s in cv.services]
            shared = set(members[0].edges)
            for m in members[1:]:
                if not shared & set(m.edges):
                    raise InputError(tt_path, f"convoys[{c_i}]", f"trains of convoy '{cv.id}' share no track ({members[0].id} / {m.id})")
            for j in range(1, len(members)):
                late = late_entry(members[j], members[j - 1])
                if late and (members[j - 1].service, members[j].service) not in late_pairs:
                    late_pairs.add((members[j - 1].service, members[j].service))
                    warnings.warn(f"{tt_path}: convoys[{c_i}] ({cv.id}): {late}", stacklevel=2)
            out.append(members)
    if not out:
        raise InputError(tt_path, "convoys", "the vc regime needs at least one convoy in the timetable (convoys: [{id, services: [leader, follower]}])")
    return out



def late_entry(ego: PlannedTrain, ahead: PlannedTrain) -> str:
    """Why a follower enters the network later than its departure time, or "" when it does not: it
    departs on its predecessor's route ahead of it, before the predecessor (running unhindered, with
    its stops) has got there.  Nothing overtakes on a track, so it enters behind its predecessor once
    that has passed (:mod:`~vcsumo.sim.convoy_insertion`) — until 2026-11-28 it ran in front, uncoupled."""
    if ego.edges[0] not in ahead.edges:
        return ""  # it joins the predecessor's route further on (a merge): the interlocking orders them
    s = float(ahead.profile.starts_m[ahead.edges.index(ego.edges[0])]) + ego.depart_pos_m
    if s <= ahead.start_s_m + 1.0:
        return ""
    end_s = ahead.final_stop.s_m if ahead.final_stop else float(ahead.profile.starts_m[-1] + (ahead.end_pos_m or 0.0))
    run = unhindered_run(ahead.stock.params(), ahead.profile, dt=0.5, s0=ahead.start_s_m, stops=[Stop(x.s_m, x.dwell_s) for x in ahead.stops],
                         end_s=end_s)
    reach = ahead.depart_s + float(time_at(run, min(s, end_s) - 1.0)[0])
    if reach <= ego.depart_s:  # (nan: it never gets there)
        return ""
    when = f"gets there at {format_clock(reach)} at the earliest" if reach == reach else "ends its run before"
    return (f"{ego.id} departs at {format_clock(ego.depart_s)} {s - ahead.start_s_m:.0f} m ahead of its predecessor {ahead.id}, which {when}: "
            f"{ego.id} enters the network only once {ahead.id} has passed (a late departure; schedule it after {ahead.id} has passed, or let it lead)")


def arrange_convoy_departures(convoys: list[list[PlannedTrain]], standstill_gap_m: dict[str, float], model: SeparationModel | None = None,
                              window_s: float = 300.0) -> None:
    """Members leaving the leader's platform within ``window_s`` depart with it, standing behind it,
    and so does every member timetabled *before* the train ahead of it there, however long before.

    The follower's front is placed ``standstill_gap_m`` behind the rear of the train ahead on the
    same departure edge.  If the convoy does not stand in that edge, the follower departs from its
    own position as soon as the train ahead has cleared it by the standstill gap (its unhindered
    start, with ``model``'s guaranteed braking; SUMO would otherwise insert it a few metres behind).
    A follower that leaves later than its timetable says this way (timetabled before the train ahead
    of it, or after it where the two do not stand on the departure track together) is warned of,
    naming both times and the reason.

    A follower timetabled before the train ahead cannot leave in front of it (nothing overtakes,
    :mod:`~vcsumo.sim.convoy_insertion` keeps it out until that train has passed), and it must not
    keep its earlier departure time either: SUMO tries one train per edge and step, in departure
    order, so the held follower kept it from ever trying the train ahead — neither departed (found
    2026-12-01: a batch's primary delay put a leader 7 min 44 s behind its follower; an open end let a
    75 m follower timetabled 90 s before its 202 m leader keep its time).
    """
    for members in convoys:
        for k in range(1, len(members)):
            ego, ahead = members[k], members[k - 1]
            if ego.edges[0] != ahead.edges[0] or ego.depart_s - ahead.depart_s > window_s or ahead.depart_speed_mps > 0:
                continue
            timetabled = ego.depart_s
            _depart_with(ego, ahead, standstill_gap_m.get(ego.id, 10.0), model)
            if ego.depart_s <= ahead.depart_s and timetabled < ahead.depart_s and not ego.depart_pos_m < ahead.depart_pos_m - ahead.stock.length_m:
                ego.depart_s = ahead.depart_s + 1.0  # (no model to plan its start with) after the train ahead, in SUMO's order too
            if ego.depart_s > timetabled + 0.5:
                late = f"({ego.depart_s - timetabled:.0f} s after its timetable; summary.csv's scheduled departure is that time)"
                if timetabled < ahead.depart_s:
                    warnings.warn(f"convoy follower {ego.id} is timetabled at {format_clock(timetabled)}, before {ahead.id} ahead of it in the convoy "
                                  f"({format_clock(ahead.depart_s)}): it leaves behind it at {format_clock(ego.depart_s)} {late}", stacklevel=2)
                else:  # after it, but the convoy does not stand on the departure track: it waits until the train ahead has cleared it
                    warnings.warn(f"convoy follower {ego.id} is timetabled at {format_clock(timetabled)}, after {ahead.id} ahead of it in the convoy "
                                  f"({format_clock(ahead.depart_s)}), but cannot stand behind it on its departure track: it leaves once {ahead.id} has "
                                  f"cleared it by the standstill gap, at {format_clock(ego.depart_s)} {late}", stacklevel=2)


def _depart_with(ego: PlannedTrain, ahead: PlannedTrain, gap: float, model: SeparationModel | None) -> None:
    """Place ``ego`` to depart behind ``ahead`` (:func:`arrange_convoy_departures`)."""
    pos = ahead.depart_pos_m - ahead.stock.length_m - gap
    if pos >= ego.stock.length_m:
        ego.depart_s = ahead.depart_s
        ego.depart_pos_m = pos
        ego.start_s_m = pos
        return
    if model is None:
        return
    # the rear of the train ahead must pass the follower's front by the standstill gap, as the convoy
    # insertion holds it (both fronts on the same first edge: an open end puts each its own length in)
    clear_s = ego.depart_pos_m + gap + ahead.stock.length_m
    run = unhindered_run(ahead.stock.params(), ahead.profile, dt=0.5, s0=ahead.start_s_m, end_s=clear_s + 1.0,
                         stop_at_end=False, curve=RouteBraking(model, ahead.stock, ahead.profile).curve(0.75))
    clear = float(time_at(run, clear_s)[0])
    ego.depart_s = max(ego.depart_s, ahead.depart_s + math.ceil(clear))


def stop_window_m(ego: PlannedTrain, stop) -> float:
    """How much of a stop's platform SUMO counts as the stop: it holds a train there only with its
    front on the platform's last edge, which a change of gradient, speed, curve or tunnel inside the
    platform makes shorter than the platform, m."""
    return float(ego.profile.lengths_m[ego.profile.index_at(stop.s_m - 0.01)])  # every platform's start is a node


def stands_behind(ego: PlannedTrain, ahead: PlannedTrain, stop, standstill_gap_m: float, queued_m: float = 0.0) -> bool:
    """A convoy follower ``ego`` can stand at its stop behind ``ahead`` standing in the same platform,
    ``standstill_gap_m`` apart, with ``ahead``'s front ``queued_m`` short of the stopping point (it
    stands behind members of the convoy further ahead, :func:`platform_queues`): the platform holds
    them all, and SUMO's stop window reaches back far enough (:func:`stop_window_m`)."""
    behind = queued_m + ahead.stock.length_m + standstill_gap_m  # from the stopping point back to ego's front
    window = stop_window_m(ego, stop)
    cut = 0.0 < window < min(stop.platform_length_m, behind) - 1e-6
    return not (0.0 < stop.platform_length_m < behind + ego.stock.length_m - 1e-6 or cut)


def platform_queues(members: list[PlannedTrain], standstill_gap_m: dict[str, float]) -> dict[str, dict[str, float]]:
    """Per member of a convoy (leader first), per platform it stops at: how far short of the stopping
    point its front stands when it stands behind the members ahead of it that stop there too (each its
    standstill gap behind the one ahead), m; 0 where it stands at the stopping point (it leads, or the
    platform cannot hold it behind them: it waits outside until they have left).  A platform that holds
    two of a convoy's trains does not hold three."""
    out: dict[str, dict[str, float]] = {members[0].id: {}}
    for k in range(1, len(members)):
        ego, ahead = members[k], members[k - 1]
        ahead_at = {x.platform for x in ahead.stops}  # (a final stop ends the train's run: it does not stand there)
        gap = standstill_gap_m.get(ego.id, 0.0)
        mine = out[ego.id] = {}
        for x in ego.stops + ([ego.final_stop] if ego.final_stop else []):
            q = out[ahead.id].get(x.platform, 0.0)
            if x.platform in ahead_at and stands_behind(ego, ahead, x, gap, q):
                mine[x.platform] = q + ahead.stock.length_m + gap
    return out


def warn_short_platforms(convoys: list[list[PlannedTrain]], standstill_gap_m: dict[str, float]) -> list[str]:
    """Warn where a follower stops with the train ahead of it but the platform cannot hold both
    ``standstill_gap_m`` apart: the follower waits outside it until the train ahead has left, so the
    convoy falls apart there (a timetable matter, not a failure).  One warning per pair of services
    (their runs together; pairs within one service together by rolling stock), naming the platforms.  Returns the warnings."""
    short: dict[tuple, dict] = {}
    for members in convoys:
        queues = platform_queues(members, standstill_gap_m)
        for k in range(1, len(members)):
            ego, ahead = members[k], members[k - 1]
            ahead_at = {x.platform for x in ahead.stops + ([ahead.final_stop] if ahead.final_stop else [])}
            gap = standstill_gap_m.get(ego.id, 0.0)
            # a pair of services (their runs together); members of one service (a unit of the capacity
            # study) by their trains, one warning for all such pairs of the same stock
            pair = (ahead.service, ego.service) if ahead.service != ego.service else ("", ahead.stock.name, ego.stock.name, gap)
            for x in ego.stops + ([ego.final_stop] if ego.final_stop else []):
                if x.platform not in ahead_at:
                    continue
                q = queues[ahead.id].get(x.platform, 0.0)  # the members standing ahead of ``ahead`` in the platform
                window = stop_window_m(ego, x)
                cut = 0.0 < window < min(x.platform_length_m, q + ahead.stock.length_m + gap) - 1e-6
                if not stands_behind(ego, ahead, x, gap, q):
                    need = q + ahead.stock.length_m + gap + ego.stock.length_m
                    w = short.setdefault(pair, {"ego": ego, "ahead": ahead, "need": need, "gap": gap, "at": {}, "n": set()})
                    w["need"] = max(w["need"], need)
                    w["at"].setdefault(x.station, f"{x.platform_length_m:g} m, cut by a gradient, speed, curve or tunnel change: SUMO's stop "
                                                   f"is its last {window:.0f} m" if cut else f"{x.platform_length_m:g} m")
                    w["n"].add(ego.id)
    out = []
    for pair, w in short.items():
        ego, ahead = w["ego"], w["ahead"]
        by_train = pair[0] == ""
        lead, follow = (ahead.id, ego.id) if by_train else pair
        at = ", ".join(f"{st} ({length})" for st, length in w["at"].items())
        n = len(w["n"])
        more = (f" (and {n - 1} more such pair{'s' if n > 2 else ''})" if by_train else f" ({n} runs)") if n > 1 else ""
        out.append(f"convoy {lead}+{follow}{more}: {follow} ({ego.stock.name}, {ego.stock.length_m:g} m) cannot stand "
                   f"behind {lead} ({ahead.stock.name}, {ahead.stock.length_m:g} m) in the platform of {at}: {w['need']:.0f} m needed with the "
                   f"{w['gap']:.0f} m standstill gap; it waits outside until {lead} has left (the convoy re-forms after, where both run on)")
    for msg in out:
        warnings.warn(msg, stacklevel=2)
    return out


MIN_CONVOY_DWELL_S = 5.0
"""A follower released from a shared stop with its leader has stood there at least this long, s."""


def align_convoy_stops(convoys: list[list[PlannedTrain]], window_s: float = 300.0) -> dict[str, int]:
    """A convoy leaves a station it stops at together: a follower's scheduled departure from a station
    its predecessor also stops at is brought forward to the predecessor's when it is at most
    ``window_s`` later (a timetable written "follower 30 s behind" would otherwise keep it 30 s
    behind for ever: it cannot run faster than its leader at the line speed).  Returns the number
    of departures moved per follower."""
    moved: dict[str, int] = {}
    for members in convoys:
        for k in range(1, len(members)):
            ego, ahead = members[k], members[k - 1]
            dep = {x.station: x.departure_s for x in ahead.stops if x.departure_s is not None}
            n = 0
            for x in ego.stops:
                d = dep.get(x.station)
                if d is not None and x.departure_s is not None and 0.0 < x.departure_s - d <= window_s:
                    x.departure_s = d
                    n += 1
            moved[ego.id] = n
    return moved


def follower_stops(ego: PlannedTrain, pred: PlannedTrain, offset_m: float | None) -> tuple[list[float], list[float], list[float | None]]:
    """A convoy follower's stops for the driver: (stopping points, platform lengths, where its
    predecessor's front will stand in the same platform — in the follower's route frame, ``offset_m``
    added to the predecessor's positions; None where the predecessor does not stop or the routes
    share no stretch), m; the end of the route last where the train stops there without a final stop."""
    own = list(ego.stops) + ([ego.final_stop] if ego.final_stop is not None else [])
    pred_at = {x.platform: x.s_m for x in list(pred.stops) + ([pred.final_stop] if pred.final_stop is not None else [])}
    stops = [x.s_m for x in own]
    plats = [x.platform_length_m for x in own]
    stands: list[float | None] = [pred_at[x.platform] + offset_m if offset_m is not None and x.platform in pred_at else None for x in own]
    if ego.final_stop is None and ego.end_pos_m is not None and ego.stop_at_end:
        stops.append(float(ego.profile.starts_m[-1] + ego.end_pos_m))
        plats.append(0.0)
        stands.append(None)
    return stops, plats, stands


def follower_dwells(ego: PlannedTrain, pred: PlannedTrain, n_stops: int, standstill_gap_m: float, queued_m: dict[str, float] | None = None) -> list[float | None]:
    """A convoy follower's own minimum dwell at each of its stops (:func:`follower_stops`' order)
    where its predecessor waits for it: where both stop in one platform that holds them
    (:func:`stands_behind`; ``queued_m``: per platform, how far short of the stopping point the
    predecessor's front stands behind the members ahead of it, :func:`platform_queues`); None where the
    follower ends its run, or waits outside the platform until its predecessor has left (it serves
    its stop on its own there), s."""
    pred_at = {x.platform for x in pred.stops}
    q = queued_m or {}
    out = [x.dwell_s if x.platform in pred_at and stands_behind(ego, pred, x, standstill_gap_m, q.get(x.platform, 0.0)) else None for x in ego.stops]
    return (out + [None] * n_stops)[:n_stops]


def stops_outside(ego: PlannedTrain, pred: PlannedTrain, dwells_s: list[float | None]) -> tuple[str | None, ...]:
    """Per stop (:func:`follower_stops`' order, ``dwells_s`` of :func:`follower_dwells`): "station
    (platform length)" where the follower waits outside the platform until its predecessor, stopping
    there too, has left (the platform cannot hold both), else None."""
    pred_at = {x.platform for x in pred.stops}
    return tuple(f"{x.station} ({x.platform_length_m:g} m)" if k < len(ego.stops) and x.platform in pred_at and dwells_s[k] is None else None
                 for k, x in enumerate(ego.stops[:len(dwells_s)])) + (None,) * max(0, len(dwells_s) - len(ego.stops))


def convoy_stop_holds(waiting: list[tuple[str, str, int, float]], now_s: float, step_s: float) -> dict[str, float]:
    """How long each train must stay at a platform its convoy shares: train -> the earliest time its
    stop may end, s.  ``waiting``: the followers standing (or stopping) behind their predecessor in a
    shared platform, as (follower, predecessor, place in the convoy, when the follower's own minimum
    dwell is served — nan while it has not come to a stand: held a step at a time).  A predecessor
    waits for every follower behind it, and for what they wait for (the convoy leaves together, and
    every member serves its dwell)."""
    need: dict[str, float] = {}
    for fid, pred, _, ready in sorted(waiting, key=lambda w: -w[2]):  # from the tail of the convoy
        until = max(ready if ready == ready else now_s + 2.0 * step_s, need.get(fid, -math.inf))
        need[pred] = max(need.get(pred, -math.inf), until)
    return need


# -------------------------------------------------------------------------------------------
# Route frames


@dataclass(frozen=True)
class Frame:
    """Maps positions of train ``a`` into the route frame of train ``b`` through their shared track."""

    offset_m: float
    """pos_b = pos_a + offset."""
    shared_end_a_m: float
    """End of the shared stretch in a's frame (after it the routes part)."""
    shared_end_b_m: float
    shared_start_a_m: float = 0.0
    """Start of the shared stretch in a's frame (where the routes meet: a merge, or a's start)."""


def frame(a: PlannedTrain, b: PlannedTrain) -> Frame | None:
    pos_b = {e: i for i, e in enumerate(b.edges)}
    first = next((i for i, e in enumerate(a.edges) if e in pos_b), None)
    if first is None:
        return None
    j = pos_b[a.edges[first]]
    i = first
    while i + 1 < len(a.edges) and j + 1 < len(b.edges) and a.edges[i + 1] == b.edges[j + 1]:
        i += 1
        j += 1
    pa, pb = a.profile, b.profile
    offset = float(pb.starts_m[pos_b[a.edges[first]]] - pa.starts_m[first])
    return Frame(offset, float(pa.starts_m[i] + pa.lengths_m[i]), float(pb.starts_m[j] + pb.lengths_m[j]), float(pa.starts_m[first]))
