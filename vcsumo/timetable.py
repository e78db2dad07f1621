"""Timetables: services on a line or a network of lines, resolved into SUMO trains with routes and stops.

A timetable file (``routes/<line>/<name>.yaml``) lists services: train type, origin and
destination (a station id, ``start``/``end`` of the main line, or ``branch:<id>`` for the far end of
a branch; on a network of lines, a station of any line or an open end ``<line>:start``,
``<line>:end``, ``<line>:branch:<id>``), places the route must pass (``via``: network nodes or
stations, when the shortest route is not the one meant), departure time, intermediate stops
(dwell and optional scheduled times) and an optional repeat pattern (``count`` trains, or every
``every_s`` until a time); and convoys (services that run virtually coupled).  Everything is
checked against the line before a run starts: unknown stations or trains, stops not on the route,
times out of order and schedules faster than the train can run are errors naming the field.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

from pydantic import Field, field_validator, model_validator

from vcsumo.config import InputProblems, StrictModel, is_dir, is_file, load_model, unique_ids
from vcsumo.errors import InputError, VcsumoError
from vcsumo.line import Line, project_root
from vcsumo.rolling_stock import RollingStock, load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.running_time import Stop, stall_problem, time_at, unhindered_run
from vcsumo.single_track import single_track_meetings
from vcsumo.timetable_convoys import check_convoy_times
from vcsumo.timetable_gaps import idle_gaps
from vcsumo.topology import Topology
from vcsumo.track_graph import reachable
from vcsumo.units import format_clock, parse_clock

Clock = str | float | int


MAX_CLOCK_S = 7 * 86400.0
"""Latest time a timetable may name, s after midnight of its first day (a week)."""


def _check_clock(v: Clock | None) -> Clock | None:
    """A time of day (``HH:MM[:SS]``) or seconds: finite, not negative, within a week."""
    if v is None:
        return v
    if isinstance(v, bool):
        raise ValueError(f"{v} is not a time: write HH:MM, HH:MM:SS or seconds")
    t = parse_clock(v)
    if not math.isfinite(t) or not 0 <= t <= MAX_CLOCK_S:
        raise ValueError(f"{v} is not a time between 0 s and {MAX_CLOCK_S:.0f} s (one week)")
    return v


class StopCall(StrictModel):
    """A stop of a service at a station."""

    station: str = Field(description="Station id")
    dwell_s: float | None = Field(default=None, ge=0, le=86400, description="Minimum dwell, s, 0–86,400 (default: the station's)")
    arrival: Clock | None = Field(default=None, description="Scheduled arrival, HH:MM[:SS] or s")
    departure: Clock | None = Field(default=None, description="Scheduled (earliest) departure, HH:MM[:SS] or s")

    @field_validator("arrival", "departure")
    @classmethod
    def _clock(cls, v: Clock | None) -> Clock | None:
        return _check_clock(v)


MAX_REPEAT = 1000
"""Most trains one repeated service may expand to."""


class Repeat(StrictModel):
    """Repeat a service at a fixed interval (ids get a suffix .1, .2, ...): ``count`` trains, or
    every ``every_s`` until the last departure at or before ``until``."""

    count: int | None = Field(default=None, ge=1, le=MAX_REPEAT, description="Number of trains (1–1,000)")
    every_s: float = Field(ge=1, le=86400, description="Interval between departures, s (1 s–1 day)")
    until: Clock | None = Field(default=None, description="Latest departure of a repetition, HH:MM[:SS] or s (instead of count)")

    @field_validator("until")
    @classmethod
    def _clock(cls, v: Clock | None) -> Clock | None:
        return _check_clock(v)

    @model_validator(mode="after")
    def _count_or_until(self) -> "Repeat":
        if (self.count is None) == (self.until is None):
            raise ValueError("give count or until (one of them)")
        return self

    def trains(self, departure_s: float) -> int:
        """Number of trains when the first departs at ``departure_s`` (0 if ``until`` is before it)."""
        if self.count is not None:
            return self.count
        return max(0, int(math.floor((parse_clock(self.until) - departure_s) / self.every_s + 1e-9)) + 1)


class Service(StrictModel):
    """One train (or a repeated pattern of identical trains)."""

    id: str = Field(pattern=r"^[A-Za-z0-9_\-]+$", description="Service id")
    train: str = Field(description="Rolling stock name or path")
    origin: str = Field(description="Station id, or an open end: 'start', 'end' or 'branch:<id>' (a network: '<line>:start', '<line>:end', '<line>:branch:<id>')")
    destination: str = Field(description="Station id or an open end, as origin")
    via: list[str] = Field(default_factory=list, description="Places the route must pass, in order: network nodes (join ids) or station ids (passing without a stop unless also in stops)")
    departure: Clock = Field(description="Departure from the origin, HH:MM[:SS] or s")
    arrival: Clock | None = Field(default=None, description="Scheduled arrival at the destination")
    stops: list[StopCall] = Field(default_factory=list, description="Intermediate stops in running order")
    repeat: Repeat | None = None

    @field_validator("departure", "arrival")
    @classmethod
    def _clock(cls, v: Clock | None) -> Clock | None:
        return _check_clock(v)


class Convoy(StrictModel):
    """Services that run virtually coupled (the first is the convoy leader)."""

    id: str = Field(pattern=r"^[A-Za-z0-9_\-]+$")
    services: list[str] = Field(min_length=2, description="Service ids, leader first")
    couple_at: str | None = Field(default=None, description="Not supported (an error when given): a convoy couples as soon as its members run together")
    decouple_at: str | None = Field(default=None, description="Not supported (an error when given): a convoy splits where its members' routes part")

    @field_validator("couple_at", "decouple_at")
    @classmethod
    def _not_supported(cls, v: str | None, info) -> str | None:  # (accepted and ignored until 2026-11-28: a run reported clean that did not do it)
        if v is not None:
            where = "couples as soon as its members run on the same track" if info.field_name == "couple_at" else "splits where its members' routes part"
            raise ValueError(f"'{v}': not supported — a convoy {where}; remove the field (to couple later, let the "
                             "follower's service start there; to split earlier, end or route the services so)")
        return v

    @field_validator("services")
    @classmethod
    def _each_once(cls, v: list[str]) -> list[str]:
        twice = next((s for i, s in enumerate(v) if s in v[:i]), None)
        if twice is not None:
            raise ValueError(f"service '{twice}' is named twice: a train cannot be its own predecessor in a convoy")
        return v


class TimetableFile(StrictModel):
    """A timetable file."""

    name: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_\-]*$", max_length=64,
                      description="Timetable name: letters, digits, '_' and '-' (it names results folders, so no '/' or '..')")
    line: str = Field(description="Line the timetable runs on")
    description: str = ""
    sources: dict[str, str] = Field(default_factory=dict)
    services: list[Service] = Field(min_length=1)
    convoys: list[Convoy] = Field(default_factory=list)

    @model_validator(mode="after")
    def _ids_once(self) -> "TimetableFile":
        return unique_ids(self, "services", "convoys")


@dataclass
class PlannedStop:
    platform: str
    station: str
    s_m: float
    """Route position of the front when stopped (the platform's departure end), m."""
    dwell_s: float
    arrival_s: float | None
    departure_s: float | None
    platform_length_m: float = 0.0


@dataclass
class PlannedTrain:
    """A train ready to be written into SUMO routes and followed by the loop."""

    id: str
    service: str
    stock: RollingStock
    edges: list[str]
    profile: RouteProfile
    depart_s: float
    depart_pos_m: float
    depart_speed_mps: float
    direction: str
    stops: list[PlannedStop] = field(default_factory=list)
    final_stop: PlannedStop | None = None
    end_pos_m: float | None = None
    scheduled_arrival_s: float | None = None
    start_s_m: float = 0.0
    """Route position of the front at departure, m."""
    stop_at_end: bool = True
    """Brake to a stop at the end of the route (False: run off the end at speed)."""
    shares_platforms: bool = False
    """May berth behind another train standing in the same platform track (a virtually coupled
    follower, standing in the platform with its convoy as one train).  Other trains stop at the
    platform's departure end and wait until the platform track is clear."""
    insertion_checks: str | None = None
    """SUMO's ``insertionChecks`` for this train (None: all of them)."""


def resolve_timetable_path(spec: str | Path, line: Line) -> Path:
    p = Path(spec)
    if p.suffix in (".yaml", ".yml"):
        if not is_file(p):  # named by an option or a study file's field: that is blamed (the file does not exist)
            raise InputError(None, "--timetable", f"timetable file '{p}' " + ("is a folder" if is_dir(p) else "not found"))
        return p.resolve()
    for base in (project_root() / "routes" / line.name, line.path.parent):
        cand = base / f"{spec}.yaml"
        if is_file(cand):
            return cand
    avail = sorted(x.stem for x in (project_root() / "routes" / line.name).glob("*.yaml"))
    raise InputError(None, "--timetable", f"unknown timetable '{spec}' for line '{line.name}' (available: {', '.join(avail) or 'none'}; or give a path)")


def load_timetable(spec: str | Path, line: Line) -> tuple[TimetableFile, Path]:
    path = resolve_timetable_path(spec, line)
    tt = load_model(TimetableFile, path)
    if tt.line != line.name:
        raise InputError(path, "line", f"timetable is for line '{tt.line}', not '{line.name}'")
    return tt, path


def _endpoint_edges(topo: Topology, name: str, line: Line, path: Path, field_name: str) -> tuple[list[tuple[str, float]], list[tuple[str, float]]]:
    """(start candidates, goal candidates) as (edge, position of the train front)."""
    if name in topo.endpoints:
        starts, goals = topo.end_edges(name)
        return [(e, -1.0) for e in starts], [(e, topo.edges[e].length_m) for e in goals]
    if name in ("start", "end") or re.fullmatch(r"([A-Za-z0-9_\-]+:)?(start|end|branch:\w+)", name):
        kind = "unknown branch in" if "branch:" in name else "no open end"
        raise InputError(path, field_name, f"{kind} '{name}' (open ends of {line.name}: {', '.join(topo.endpoints) or 'none'}; "
                         "an end where lines are joined is not open)")
    if not line.all_station_ids():
        raise InputError(line.path, "stations", f"the line has no stations, so '{name}' ({path.name}: {field_name}) is not on it "
                         f"(a timetable runs between stations or open ends: {', '.join(topo.endpoints) or 'none'})")
    try:
        line.station(name)
    except KeyError:
        raise InputError(path, field_name, f"unknown station '{name}' (stations of {line.name}: {', '.join(line.all_station_ids())}; "
                         f"open ends: {', '.join(topo.endpoints)})") from None
    plats = topo.platforms_of(name)
    return [(p.edge, p.end_pos_m) for p in plats], [(p.edge, p.end_pos_m) for p in plats]


def _via_edges(topo: Topology, name: str, line: Line, path: Path, field_name: str) -> list[str]:
    """Edges a route passing ``name`` (a network node or a station) must run over."""
    if name in topo.named_nodes:
        nodes = set(topo.named_nodes[name])
        return [e.id for e in topo.edges.values() if e.to_node in nodes]
    try:
        line.station(name)
    except KeyError:
        raise InputError(path, field_name, f"unknown node or station '{name}' (nodes: {', '.join(topo.named_nodes) or 'none'}; "
                         f"stations: {', '.join(line.all_station_ids())})") from None
    return [p.edge for p in topo.platforms_of(name)]


def _route(topo: Topology, starts: list[str], legs: list[list[str]]) -> list[str] | None:
    """Shortest route from any start edge through an edge of every leg in turn (each leg from the
    edge the previous one ended on)."""
    route: list[str] = []
    current = starts
    for goals in legs:
        part = topo.route_edges(current, goals)
        if part is None:
            return None
        route += part[1:] if route else part
        current = [part[-1]]
    return route


def _reach_hint(topo: Topology, starts: list[tuple[str, float]], line: Line, origin: str) -> str:
    """What a train from these start edges can reach (trains do not reverse), for a no-route error."""
    seen: set[str] = set()
    for e, _ in starts:
        seen |= reachable(topo, e)
    stations = [s for s in line.all_station_ids() if s != origin and any(p.edge in seen for p in topo.platforms_of(s))]
    ends = [k for k in topo.endpoints if any(e in seen for e in topo.end_edges(k)[1])]
    return (f": trains do not reverse, and a junction is passed only the way its line leaves (a join's towards, a branch's "
            f"leaves_towards); from there a train reaches {', '.join(stations + ends) or 'nothing'}")


def _stock_spec(train: str, timetable_path: Path) -> str | Path:
    """A service's rolling stock: a shipped name, or a file path; a relative path is taken next to the timetable file when there is such a file there (as a network file's line files), else as given."""
    p = Path(train)
    if p.suffix in (".yaml", ".yml") and not p.is_absolute() and is_file(timetable_path.parent / p):
        return timetable_path.parent / p
    return train


def plan_trains(tt: TimetableFile, path: Path, line: Line, topo: Topology, dt: float = 0.5, check_feasible: bool = True) -> list[PlannedTrain]:
    """Resolve every service into planned trains (repeats expanded), checking it against the line."""
    trains: list[PlannedTrain] = []
    stocks: dict[str, RollingStock] = {}
    runtime_cache: dict[tuple, float] = {}
    for i, svc in enumerate(tt.services):
        f = f"services[{i}]"
        if svc.train not in stocks:
            try:
                stocks[svc.train] = load_rolling_stock(_stock_spec(svc.train, path))
            except InputError as exc:
                if exc.path is None:
                    where = f" (a relative path is looked for next to the timetable, in {path.parent}, then in the current folder)" \
                        if Path(svc.train).suffix in (".yaml", ".yml") and not Path(svc.train).is_absolute() else ""
                    raise InputError(path, f"{f}.train", exc.message + where) from None
                raise
        stock = stocks[svc.train]
        starts, _ = _endpoint_edges(topo, svc.origin, line, path, f"{f}.origin")
        _, goals = _endpoint_edges(topo, svc.destination, line, path, f"{f}.destination")
        if svc.origin == svc.destination:
            raise InputError(path, f"{f}.destination", "destination equals origin")
        legs = [_via_edges(topo, v, line, path, f"{f}.via[{k}]") for k, v in enumerate(svc.via)] + [[e for e, _ in goals]]
        route = _route(topo, [e for e, _ in starts], legs)
        if route is None:
            via = f" via {', '.join(svc.via)}" if svc.via else ""
            raise InputError(path, f"{f}.destination", f"no route from '{svc.origin}' to '{svc.destination}'{via} on {line.name} (infeasible){_reach_hint(topo, starts, line, svc.origin)}")
        start_pos = dict(starts)[route[0]]
        if start_pos < 0:
            start_pos = min(stock.length_m + 1.0, topo.edges[route[0]].length_m)
        end_pos = dict(goals)[route[-1]]
        prof = RouteProfile.from_edges(topo, route)
        direction = topo.edges[route[0]].direction
        # stops
        planned_stops: list[PlannedStop] = []
        last_s = start_pos
        for j, call in enumerate(svc.stops):
            fs = f"{f}.stops[{j}]"
            try:
                _, st = line.station(call.station)
            except KeyError:
                raise InputError(path, f"{fs}.station", f"unknown station '{call.station}' (stations of {line.name}: {', '.join(line.all_station_ids())})") from None
            if call.station in (svc.origin, svc.destination):
                raise InputError(path, f"{fs}.station", f"'{call.station}' is the service's {'origin' if call.station == svc.origin else 'destination'}: stops lists the stops in between")
            plat = next((p for p in topo.platforms_of(call.station) if p.edge in route), None)
            if plat is None:
                raise InputError(path, f"{fs}.station", f"station '{call.station}' is not on the route from '{svc.origin}' to '{svc.destination}'")
            s_stop = float(prof.starts_m[route.index(plat.edge)] + plat.end_pos_m)
            if s_stop <= last_s + 1.0:
                raise InputError(path, f"{fs}.station", f"stop at '{call.station}' is not after the previous stop in running order")
            last_s = s_stop
            arr = parse_clock(call.arrival) if call.arrival is not None else None
            dep = parse_clock(call.departure) if call.departure is not None else None
            dwell = call.dwell_s if call.dwell_s is not None else st.dwell_s
            planned_stops.append(PlannedStop(plat.id, call.station, s_stop, dwell, arr, dep, plat.length_m))
        end_s = float(prof.starts_m[-1] + end_pos)
        final = None
        if svc.destination not in topo.endpoints:
            plat = next(p for p in topo.platforms_of(svc.destination) if p.edge == route[-1])
            final = PlannedStop(plat.id, svc.destination, end_s, 0.0, None, None, plat.length_m)
        platforms = [(f"{f}.stops[{j}].station", s) for j, s in enumerate(planned_stops)] + ([(f"{f}.destination", final)] if final else [])
        first = next((p for p in topo.platforms_of(svc.origin) if p.edge == route[0]), None) if svc.origin not in topo.endpoints else None
        if first is not None:
            platforms.insert(0, (f"{f}.origin", PlannedStop(first.id, svc.origin, start_pos, 0.0, None, None, first.length_m)))
        short = [InputError(path, where, f"train {stock.name} is {stock.length_m:g} m long, longer than the {stop.platform_length_m:g} m platform of '{stop.station}' (stations of {line.path})")
                 for where, stop in platforms if stop.platform_length_m + 1e-6 < stock.length_m]
        if short:  # every platform it does not fit, one line each
            raise short[0] if len(short) == 1 else InputProblems(short)
        dep0 = parse_clock(svc.departure)
        arr_sched = parse_clock(svc.arrival) if svc.arrival is not None else None
        times = [(f"{f}.departure", dep0)] + [(f"{f}.stops[{j}].{k}", x) for j, s in enumerate(planned_stops) for k, x in (("arrival", s.arrival_s),
                 ("departure", s.departure_s)) if x is not None] + ([(f"{f}.arrival", arr_sched)] if arr_sched is not None else [])
        for (fa, ta), (fb, tb) in ((a, b) for a, b in zip(times, times[1:]) if b[1] < a[1]):  # the first time earlier than the one before
            raise InputError(path, fb, f"{format_clock(tb)} is before {fa} ({format_clock(ta)}): scheduled times are not in running order")
        if stall := stall_problem(stock.params(), prof, start_pos, end_s):  # it would stand there for ever (or never depart): no run of it can be healthy
            raise InputError(path, f"{f}.train", f"infeasible: train {stock.name} {stall}")
        if check_feasible and (arr_sched is not None or any(s.arrival_s is not None for s in planned_stops)):
            key = (tuple(route), stock.name, tuple((s.s_m, s.dwell_s) for s in planned_stops), start_pos, end_s)
            if key not in runtime_cache:
                run = unhindered_run(stock.params(), prof, dt=dt, s0=start_pos, stops=[Stop(s.s_m, s.dwell_s) for s in planned_stops], end_s=end_s)
                runtime_cache[key] = run
            run = runtime_cache[key]
            # every leg: from the previous scheduled departure (or the origin) to a scheduled arrival
            t_arr = [float(time_at(run, s.s_m - 0.5)[0]) for s in planned_stops]
            prev_dep_sched, prev_dep_run = dep0, 0.0
            for j, s in enumerate(planned_stops):
                if s.arrival_s is not None:
                    need = t_arr[j] - prev_dep_run
                    if prev_dep_sched + need > s.arrival_s + 1.0:
                        raise InputError(path, f"{f}.stops[{j}].arrival", f"infeasible: scheduled {format_clock(s.arrival_s)} but the train needs {need:.0f} s from its previous departure (earliest {format_clock(prev_dep_sched + need)})")
                dep_sched = s.departure_s if s.departure_s is not None else (s.arrival_s + s.dwell_s if s.arrival_s is not None else None)
                if dep_sched is not None:
                    prev_dep_sched, prev_dep_run = dep_sched, t_arr[j] + s.dwell_s
                else:
                    prev_dep_sched, prev_dep_run = prev_dep_sched + (t_arr[j] + s.dwell_s - prev_dep_run), t_arr[j] + s.dwell_s
            if arr_sched is not None:
                need = float(run["time_s"].iloc[-1]) - prev_dep_run
                if prev_dep_sched + need > arr_sched + 1.0:
                    raise InputError(path, f"{f}.arrival", f"infeasible: scheduled {format_clock(arr_sched)} but the train needs {need:.0f} s from its previous departure (earliest {format_clock(prev_dep_sched + need)})")
        count = svc.repeat.trains(dep0) if svc.repeat else 1
        every = svc.repeat.every_s if svc.repeat else 0.0
        if count == 0:
            raise InputError(path, f"{f}.repeat.until", f"until is before the departure ({format_clock(dep0)})")
        if count > MAX_REPEAT:
            raise InputError(path, f"{f}.repeat", f"{count} trains: at most {MAX_REPEAT} per service")
        if dep0 + (count - 1) * every > MAX_CLOCK_S:
            raise InputError(path, f"{f}.repeat", f"the last repetition departs after {MAX_CLOCK_S:.0f} s (one week)")
        for k in range(count):
            off = k * every
            tid = svc.id if count == 1 else f"{svc.id}.{k + 1}"
            trains.append(PlannedTrain(
                id=tid, service=svc.id, stock=stock, edges=route, profile=prof, depart_s=dep0 + off,
                depart_pos_m=start_pos, depart_speed_mps=0.0, direction=direction,
                stops=[PlannedStop(s.platform, s.station, s.s_m, s.dwell_s, None if s.arrival_s is None else s.arrival_s + off,
                                   None if s.departure_s is None else s.departure_s + off, s.platform_length_m) for s in planned_stops],
                final_stop=final, end_pos_m=end_pos, scheduled_arrival_s=None if arr_sched is None else arr_sched + off,
                start_s_m=start_pos,
            ))
    ids = [t.id for t in trains]
    if len(set(ids)) != len(ids):
        dup = next(x for x in ids if ids.count(x) > 1)
        raise InputError(path, "services", f"train id '{dup}' occurs twice after expanding repeats")
    for c_i, cv in enumerate(tt.convoys):
        for s_i, sid in enumerate(cv.services):
            if sid not in {s.id for s in tt.services}:
                raise InputError(path, f"convoys[{c_i}].services[{s_i}]", f"convoy '{cv.id}' names service '{sid}', which does not exist")
        check_convoy_times(trains, cv.services, path, f"convoys[{c_i}]", dt)
    for msg in single_track_meetings(trains, topo, dt) + idle_gaps(trains):  # opposing trains waiting; a day of nothing
        warnings.warn(f"{path}: {msg}", stacklevel=2)
    return trains


END_OF_TRACK_WINDOW_M, END_OF_TRACK_SHORT_M = 100.0, 90.0
"""A train whose route ends at an open end of track arrives when it stands within 100 m (or its own
length, or its position error + 90 m, if longer) of the end, m: braking-curve supervision stops it its
position error (``routes_xml``'s ``position_error_m``) short of the end, so SUMO's stop spans this window."""


def routes_xml(trains: list[PlannedTrain], topo: Topology, min_gap_m: float = 5.0, position_error_m: float = 0.0) -> str:
    """SUMO route file: vTypes (open-air and tunnel variants) and vehicles sorted by departure."""
    factors = sorted({e.tunnel_factor for e in topo.edges.values()})
    stocks = {t.stock.name: t.stock for t in trains}
    out = ["<routes>"]
    for st in stocks.values():
        for tf in factors:
            out.append("  " + st.vtype_xml(tf, min_gap_m=min_gap_m))
    for t in sorted(trains, key=lambda x: x.depart_s):  # stable: equal times keep planning order (convoy leader first)
        first_tf = topo.edges[t.edges[0]].tunnel_factor
        speed = "0" if t.depart_speed_mps <= 0 else f"{t.depart_speed_mps:.4f}"
        arrival_pos = t.end_pos_m or topo.edges[t.edges[-1]].length_m
        end_stop = t.final_stop is None and t.end_pos_m is not None and t.stop_at_end
        if end_stop:  # stopped short of the end of track (by its position error, under supervision), the train has arrived
            arrival_pos = max(0.0, t.end_pos_m - max(t.stock.length_m, END_OF_TRACK_WINDOW_M, position_error_m + END_OF_TRACK_SHORT_M))
        out.append(
            f'  <vehicle id={quoteattr(t.id)} type="{t.stock.vtype_id(first_tf)}" depart="{t.depart_s:.2f}" '
            f'departPos="{t.depart_pos_m:.3f}" departSpeed="{speed}" arrivalPos="{arrival_pos:.3f}" line={quoteattr(t.service)}'
            + (f' insertionChecks={quoteattr(t.insertion_checks)}>' if t.insertion_checks is not None else '>')
        )
        out.append(f'    <route edges="{" ".join(t.edges)}"/>')
        for s in t.stops:
            extra = ""
            if s.arrival_s is not None:
                extra += f' arrival="{s.arrival_s:.1f}"'
            if s.departure_s is not None and s.departure_s >= t.depart_s:
                # A train that departs after a stop's scheduled departure (a primary delay at the
                # origin, vcsumo batch) has no 'until' to wait for: SUMO ends the stop after its
                # duration either way, but warned "stop ... set to end at ... earlier than departure"
                # — a stop warning that made a healthy delayed run "not healthy".
                extra += f' until="{s.departure_s:.1f}"'
            out.append(f"    {_stop_element(topo, s.platform, t.shares_platforms)} duration=\"{s.dwell_s:.1f}\"{extra}/>")
        if t.final_stop is not None:
            extra = f' arrival="{t.scheduled_arrival_s:.1f}"' if t.scheduled_arrival_s is not None else ""
            out.append(f"    {_stop_element(topo, t.final_stop.platform, t.shares_platforms)} duration=\"1\"{extra}/>")
        elif end_stop:
            out.append(f'    <stop lane="{t.edges[-1]}_0" startPos="{arrival_pos:.3f}" endPos="{t.end_pos_m:.3f}" duration="1"/>')
        out.append("  </vehicle>")
    out.append("</routes>")
    return "\n".join(out) + "\n"


def _stop_element(topo: Topology, platform_id: str, shared: bool) -> str:
    """The opening of a SUMO stop element for a platform.

    SUMO lets any train berth behind one already standing at a trainStop; independent trains must
    not share a platform track, so they get an exact stopping position on the platform's lane (and
    wait until it is free).  Virtually coupled followers use the trainStop and stand behind their
    convoy's leader.
    """
    if shared:
        return f'<stop trainStop="{platform_id}"'
    p = topo.platforms[platform_id]
    return f'<stop lane="{p.edge}_0" startPos="{p.start_pos_m:.3f}" endPos="{p.end_pos_m:.3f}"'


def check_within(trains: list[PlannedTrain]) -> None:
    if not trains:
        raise VcsumoError("no trains to simulate")
    if any(math.isnan(t.depart_s) for t in trains):  # pragma: no cover
        raise VcsumoError("a train has no departure time")
