"""The capacity study's cases on one direction's route: where units are released, how fast, with
which stops; the planned trains of a probe; the leader's unhindered run and the regime's analytic
headway on it (:mod:`vcsumo.studies.capacity` runs the cases)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import pandas as pd

from vcsumo.errors import VcsumoError
from vcsumo.line import Line
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.running_time import Stop, speed_at, stall_problem, unhindered_run
from vcsumo.signalling.regimes import REGIMES, HeadwayInputs
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel
from vcsumo.sim.network import BuiltNetwork
from vcsumo.studies.headway import release_km
from vcsumo.timetable import PlannedStop, PlannedTrain


@dataclass(frozen=True)
class Case:
    direction: str
    regime: str
    controller: str | None
    convoy_size: int
    pattern: str


@dataclass
class RouteSetup:
    """One direction's route, release state, stops and the leader's unhindered run."""

    direction: str
    track_edges: list[str]
    full: RouteProfile
    release_s: float
    v0: float
    stops_full: list[tuple[str, str, float, float, float]]
    """(station, platform, route position of the stop, dwell, platform length) on the full track."""
    rel_km: float
    approach: pd.DataFrame | None = None
    """A supervised run over the track before the release point entered at the permitted speed (a
    train already running when the track begins; None: standing start at the release point)."""

    def depart_speed(self, s_m: float) -> float:
        """Release speed of a train whose front is at route position ``s_m`` (≤ the release point):
        the release speed, at most what the flying approach run has there — a convoy follower
        starting in a lower limit (or on the braking curve to one) keeps to it, m/s."""
        if self.approach is None or s_m >= self.release_s - 1e-6:
            return self.v0
        return min(self.v0, speed_at(self.approach, s_m))


def intermediate_stops(line: Line, net: BuiltNetwork, direction: str, full: RouteProfile, release_s: float) -> list[tuple[str, str, float, float, float]]:
    topo = net.topology
    stations = sorted(line.data.stations, key=lambda s: s.km)
    inner = {s.id for s in stations[1:-1]}
    out = []
    for pid, p in topo.platforms.items():
        if p.section != "main" or p.track != f"main_{direction}" or p.station_id not in inner:
            continue
        s_stop = float(full.starts_m[full.edges.index(p.edge)] + p.end_pos_m)
        if s_stop > release_s + 1.0:
            out.append((p.station_id, pid, s_stop, p.dwell_s, p.length_m))
    return sorted(out, key=lambda x: x[2])


def route_setup(line: Line, net: BuiltNetwork, stock: RollingStock, direction: str, step_s: float, model: SeparationModel | None = None) -> RouteSetup:
    topo = net.topology
    track = topo.track_for("main", direction)
    full = RouteProfile.from_edges(topo, track.edges)
    rel = release_km(line, direction)
    s_rel = full.s_of("main", rel)
    start = min(stock.length_m + 1.0, full.length_m)
    run0 = None
    if s_rel <= start + 1.0:
        s_rel, v0 = start, 0.0
    else:
        curve = RouteBraking(model, stock, full).curve(1.5 * step_s) if model is not None else None
        # the release speed: what a train starting at the track's beginning reaches at the release point
        v0 = speed_at(unhindered_run(stock.params(), full, dt=step_s, s0=start, end_s=s_rel + 1.0, stop_at_end=False, curve=curve), s_rel)
        v_enter = min(full.speed_limit_train(start, stock.length_m), stock.params().max_speed_ms)
        run0 = unhindered_run(stock.params(), full, dt=step_s, s0=start, v0=v_enter, end_s=s_rel + 1.0, stop_at_end=False, curve=curve)
    return RouteSetup(direction, list(track.edges), full, s_rel, v0, intermediate_stops(line, net, direction, full, s_rel), rel, run0)


def train_at(topo, setup: RouteSetup, stock: RollingStock, tid: str, s_depart: float, stops: list, depart_s: float, service: str) -> PlannedTrain:
    """A planned train departing at route position ``s_depart`` of the full track (flying start)."""
    full = setup.full
    i0 = full.index_at(s_depart)
    edges = setup.track_edges[i0:]
    prof = RouteProfile.from_edges(topo, edges)
    off = float(full.starts_m[i0])
    pstops = [PlannedStop(pid, st, s - off, dwell, None, None, plen) for st, pid, s, dwell, plen in stops]
    return PlannedTrain(
        id=tid, service=service, stock=stock, edges=edges, profile=prof, depart_s=depart_s, depart_pos_m=s_depart - off,
        depart_speed_mps=setup.depart_speed(s_depart), direction=setup.direction, stops=pstops, end_pos_m=None, start_s_m=s_depart - off, stop_at_end=False,
    )


def unit_trains(topo, setup: RouteSetup, stock: RollingStock, case: Case, n_units: int, h: float, initial_gap_m: float | list[float]) -> list[list[PlannedTrain]]:
    """``n_units`` units released ``h`` apart; convoy member k starts ``initial_gap_m`` (one gap for
    all, or member k's gap behind member k − 1 at index k − 1: :func:`initial_convoy_gaps`) behind
    the train ahead."""
    gaps = list(initial_gap_m) if isinstance(initial_gap_m, (list, tuple)) else [float(initial_gap_m)] * max(case.convoy_size - 1, 0)
    stops = setup.stops_full if case.pattern == "all-stops" else []
    units = []
    for j in range(n_units):
        members = []
        s_dep = setup.release_s
        for k in range(case.convoy_size):
            if k:
                s_dep -= stock.length_m + (gaps[k - 1] if k - 1 < len(gaps) else gaps[-1])
            if s_dep < stock.length_m + 1.0:
                raise VcsumoError(f"convoy of {case.convoy_size} does not fit before the release point {setup.rel_km} km; move headway.release_km")
            members.append(train_at(topo, setup, stock, f"{case.direction}_u{j}_m{k}", s_dep, stops, j * h, f"unit{j}"))
        units.append(members)
    return units


def leader_run(setup: RouteSetup, stock: RollingStock, case: Case, step_s: float, model: SeparationModel) -> pd.DataFrame:
    """The unit leader's run alone, as the supervised SUMO driver runs it (guaranteed braking)."""
    stops = setup.stops_full if case.pattern == "all-stops" else []
    short = [f"'{st}' ({length:g} m)" for st, _, _, _, length in stops if length + 1e-6 < stock.length_m]
    if short:  # as a timetable's stop there is refused (vcsumo.timetable)
        raise VcsumoError(f"{case.pattern}: train {stock.name} is {stock.length_m:g} m long, longer than the platform of {', '.join(short)}")
    stall = stall_problem(stock.params(), setup.full, min(stock.length_m + 1.0, setup.release_s), setup.full.length_m)
    if stall:  # it would stand there for ever: no probe could be healthy
        raise VcsumoError(f"infeasible: train {stock.name} {stall} ({setup.direction})")
    return unhindered_run(stock.params(), setup.full, dt=step_s, s0=setup.release_s, v0=setup.v0, stops=[Stop(s, d) for _, _, s, d, _ in stops],
                          stop_at_end=False, curve=RouteBraking(model, stock, setup.full).curve(1.5 * step_s))


def check_position_m(setup: RouteSetup) -> float:
    """Where a case's headway is checked (measuring point of the runs, end of the analytic maximum), m."""
    return setup.full.length_m - 100.0


def convoy_spacing(controller: str, stock: RollingStock, step_s: float, assumptions, profile: RouteProfile | None = None,
                   message_age_s: float | None = None) -> Callable[..., float]:
    """The front-to-rear gap a follower of ``controller``'s stack keeps behind a train of its own type
    at a common speed v, m: ``spacing(v)`` on level track, ``spacing(v, s)`` with the follower's
    front at route position s of ``profile`` (on the gradients there: the relative-braking rule
    over the grades ahead within the braking distance).  It is the stack the SUMO loop builds
    (:func:`vcsumo.control.registry.build_follower_stack` on the route), read as
    :meth:`vcsumo.sim.vc_driver.VCDriver.coupled_spacing_m` reads it (the stack's coupled gap, at
    least its minimum safe gap) — a formula of the separation model, the guard's brake build-up and
    the controller's parameters, not a measurement.  ``message_age_s``: the message age the stack's
    spacing budgets, as the loop gives it (:meth:`vcsumo.control.channel.ChannelConfig.age_budget_s`
    of the run's channel; None: the assumption set's bound)."""
    from vcsumo.control.registry import StackContext, build_follower_stack

    stack = build_follower_stack(controller, StackContext(ego=stock, predecessor=stock, step_s=step_s, profile=profile, assumptions=assumptions,
                                                          message_age_s=message_age_s))

    def spacing(v: float, position_m: float | None = None) -> float:
        return max(stack.coupled_gap_m(v, position_m if profile is not None else None), stack.d_min_m)

    return spacing


START_ITERATIONS = 8
"""Fixed-point steps for a start gap that depends on where the follower starts (the gradients there)."""


def initial_convoy_gaps(spacing: Callable[..., float] | None, model: SeparationModel, stock: RollingStock, setup: RouteSetup, members: int) -> list[float]:
    """Starting gap of each convoy follower behind the train ahead (member k = 1 … ``members`` − 1), m.

    Each follower starts at the spacing its stack keeps where it starts (``spacing(v, s)`` of
    :func:`convoy_spacing` on the full track, at its release speed and its front's route position:
    on a grade the relative-braking rule over the grades ahead, which is what the controller holds
    and the separation guard enforces 10 m inside — started closer, the follower brakes at its
    release), and never inside the health monitor's relative-braking rule with the two trains' own
    release speeds (+ 20 m; it decides where the train ahead is slower).  The follower's position
    depends on its gap: solved by a fixed point (the largest of the last two steps if it has not
    settled to 0.1 m)."""
    rule = RelativeBraking(model, stock, stock, setup.full)
    dead = model.dead_time_s + model.assumptions.t2t_delay_bound_s  # as vc_gap: the leader's newest message at its oldest
    gaps: list[float] = []
    s_l = setup.release_s
    for _ in range(1, members):
        v_l = setup.depart_speed(s_l)

        def need(gap: float) -> float:
            s_f = s_l - stock.length_m - gap
            v_f = setup.depart_speed(s_f)
            held = spacing(v_f, s_f) if spacing is not None else model.vc_gap(stock, stock, v_f) + 20.0
            return max(held, rule.required_gap(s_f, v_f, s_l, v_l, dead) + 20.0)

        gap = prev = need(model.vc_gap(stock, stock, v_l) + 20.0)
        for _ in range(START_ITERATIONS):
            prev, gap = gap, need(gap)
            if abs(gap - prev) < 0.1:
                break
        gap = max(gap, prev)
        gaps.append(gap)
        s_l = s_l - stock.length_m - gap
        if s_l < stock.length_m:
            break
    return gaps


def analytic_headway(net: BuiltNetwork, setup: RouteSetup, run: pd.DataFrame, stock: RollingStock, case: Case, model: SeparationModel, step_s: float,
                     s_check: float, coupled_gap: Callable[..., float] | None = None, on_route: bool = False):
    """The regime's minimum headway between two units from the separation model alone
    (:meth:`vcsumo.signalling.regimes.base.Regime.analytic_headway`; VC convoys at ``coupled_gap``,
    e.g. :func:`convoy_spacing`: with ``on_route`` its ``spacing(v, s)`` on the full track, each
    follower at the spacing where it is as the convoy runs; else ``spacing(v)``, level track)."""
    route_gap = coupled_gap if on_route else None
    inp = HeadwayInputs(model, stock, setup.full, run, setup.full.signal_positions(net.topology), step_s, s_check, coupled_gap=coupled_gap,
                        coupled_gap_at=route_gap)
    return REGIMES[case.regime].analytic_headway(inp, case.convoy_size)


def initial_convoy_gap(model: SeparationModel, stock: RollingStock, v0: float, setup: RouteSetup | None = None, members: int = 2) -> float:
    """Starting gap inside a convoy: the separation model's coupled gap at the release speed + 20 m,
    and (``setup``) at least that relative-braking gap where the ``members`` start on the route (a
    grade under them changes it) + 20 m: no follower starts inside its safe separation."""
    gap = model.vc_gap(stock, stock, v0) + 20.0
    if setup is None:
        return gap
    rule = RelativeBraking(model, stock, stock, setup.full)
    dead = model.dead_time_s + model.assumptions.t2t_delay_bound_s  # as vc_gap: the leader's newest message at its oldest
    for _ in range(3):  # where the members start depends on the gap
        need = 0.0
        for k in range(1, members):
            s_l = setup.release_s - (k - 1) * (stock.length_m + gap)
            s_f = s_l - stock.length_m - gap
            if s_f < stock.length_m:
                break
            need = max(need, rule.required_gap(s_f, setup.depart_speed(s_f), s_l, setup.depart_speed(s_l), dead))
        gap = max(gap, need + 20.0)
    return gap


STANDSTILL_EXTRA_M = 2.0
"""A convoy's members stand the separation model's margin + this apart in a platform (the VC driver's
standstill gap), m."""


def convoys_longer_than_platforms(stops: list[tuple[str, str, float, float, float]], stock: RollingStock, convoy_sizes: list[int],
                                  standstill_gap_m: float) -> list[str]:
    """All-stops: one warning per VC convoy size whose members, standing ``standstill_gap_m`` apart,
    are longer than a platform it stops at (``stops``: :attr:`RouteSetup.stops_full`).  The analytic
    VC headway stands the convoy in the platform as one train; such a convoy's followers stop one
    after another, so its figure is a bound the line cannot run (the capacity study simulates it)."""
    out = []
    for n in sorted(set(convoy_sizes)):
        length = n * stock.length_m + (n - 1) * standstill_gap_m
        short = sorted({(st, plen) for st, _, _, _, plen in stops if plen + 1e-6 < length})
        if short:
            names = ", ".join(f"{st} ({plen:g} m)" for st, plen in short)
            out.append(f"all-stops: a VC convoy of {n} ({n} × {stock.length_m:g} m + {n - 1} × {standstill_gap_m:g} m standstill gap = "
                       f"{length:g} m) does not fit the platform of {names}; its members stop there one after another, so VC n={n}'s "
                       "analytic headway (the convoy as one train in the platform) is shorter than the line can run")
    return out
