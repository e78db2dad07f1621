"""Headway study: identical trains released as close as the regime allows, headway measured.

For each direction, regime (fbs, mb) and train type:

1. the unhindered running profile of one train from the start of the direction's main track
   gives the speed at the release point (line file ``headway.release_km``; default: the track
   start, from standstill); trains are released there with that speed (a flying start);
2. identical trains are released at an interval h; the smallest h at which the follower is not
   hindered anywhere up to a measuring point (never slower than the unhindered leader at the same
   position, beyond 0.3 m/s or 0.5 %) is found by bisection (:mod:`vcsumo.studies.min_headway`);
   the follower's speed is compared up to 3 s past the point (a braking curve that binds at the
   point shows a deficit a moment later); the simulated minimum headway is the time between the
   two fronts passing the point in that
   run (``headway_sim_s``; the release interval is ``release_interval_s``).  By default a pair
   of trains is released (``n_trains=2``): blocking-time theory's headway is a property of two
   consecutive trains, and with longer sequences a bigger bottleneck *downstream* of the point
   spills back and shows up upstream (a flow effect of the downstream section, not of the point);
3. beside it, the regime's analytic headway from the separation model alone
   (:mod:`vcsumo.signalling.regimes`: blocking-time theory with the guaranteed braking curves the
   supervised trains keep), on the same unhindered profile: the largest blocking time met between
   the release point and the measuring point.

Writes ``headway.csv`` (one row per direction × regime × train × measuring point) and
``headway.png``; each probe's SUMO run is kept under ``runs/`` only for the final (minimum) h.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.regimes import REGIMES, HeadwayInputs
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.errors import InputError, VcsumoError
from vcsumo.line import Line
from vcsumo.results import write_csv
from vcsumo.sim.network import BuiltNetwork
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.running_time import speed_at, stall_problem, unhindered_run
from vcsumo.sim.loop import MeasuringPoint, Scenario, simulate
from vcsumo.studies.min_headway import Probe, search_min_headway
from vcsumo.timetable import PlannedTrain

SPEED_TOL_ABS_MPS = 0.03
SPEED_TOL_REL = 0.0
"""A follower counts as hindered where it runs slower than the leader at the same position by more
than 0.03 m/s: SUMO is deterministic, so identical unhindered trains agree to the interpolation
between their samples (well below that), and any braking curve that binds shows at once."""
DEFICIT_WINDOW_S = 1.0
"""Speeds are compared up to where the follower is this long after the measuring point, s: theory
counts every block whose approach point lies before the point, and a braking curve that starts to
bind there shows a deficit of 0.03 m/s one step later (the cap applies from the next step)."""

HEADWAY_COLUMNS = [
    "line", "direction", "regime", "train", "measuring_point_km", "headway_sim_s", "headway_analytic_s",
    "deviation_pct", "release_interval_s", "speed_at_point_mps", "critical_km", "block_length_m", "release_km", "release_speed_mps",
    "hindrance_delay_s", "min_gap_m", "gap_violations", "collisions", "emergency_brakes", "simulations", "healthy", "min_margin_m", "assumptions",
    "below_separation_time_s", "max_impact_kmh", "stops_skipped", "short_dwells", "overspeed_events", "beyond_service_brakings", "authority_overruns",
    "sumo_emergency_stops", "sumo_emergency_brakings", "sumo_stop_warnings", "teleports", "trains_arrived", "trains", "unhealthy_probes",
    "error",
]
HEALTH_COLUMNS = ("below_separation_time_s", "max_impact_kmh", "stops_skipped", "short_dwells", "overspeed_events", "beyond_service_brakings",
                  "authority_overruns", "sumo_emergency_stops", "sumo_emergency_brakings", "sumo_stop_warnings", "teleports", "trains_arrived", "trains")
"""The run summary's counters that its verdict (``healthy``) rests on, carried by every row as the
capacity study's rows carry them: a row that is not healthy says why (until unseen-studies a row
read ``healthy`` False with 0 gap violations and 0 collisions, and nothing else to go on)."""


@dataclass
class HeadwayCase:
    direction: str
    regime: str
    stock: RollingStock


def measuring_points(line: Line, points_km: list[float] | None) -> list[float]:
    if points_km:
        return list(points_km)
    if line.data.headway and line.data.headway.measuring_points_km:
        return list(line.data.headway.measuring_points_km)
    lo, hi = line.data.km_start, line.data.km_end
    return [lo + f * (hi - lo) for f in (0.25, 0.5, 0.75)]


def release_km(line: Line, direction: str) -> float:
    d = line.data
    if d.headway and direction in d.headway.release_km:
        return d.headway.release_km[direction]
    return d.km_start if direction == "up" else d.km_end


def prepare_case(line: Line, net: BuiltNetwork, stock: RollingStock, direction: str, step_s: float, n_trains: int, model: SeparationModel):
    """Route, release state, planned trains and the unhindered run from the release point."""
    topo = net.topology
    track = topo.track_for("main", direction)
    full = RouteProfile.from_edges(topo, track.edges)
    p = stock.params()
    rel_km = release_km(line, direction)
    s_rel_full = full.s_of("main", rel_km)
    start = min(stock.length_m + 1.0, full.length_m)
    stall = stall_problem(p, full, min(start, s_rel_full), full.length_m)
    if stall:  # it would stand there for ever: no probe could be healthy
        raise VcsumoError(f"infeasible: train {stock.name} {stall} ({direction})")
    if s_rel_full <= start + 1.0:
        v0 = 0.0
        s_rel_full = start
    else:
        run0 = unhindered_run(p, full, dt=step_s, s0=start, end_s=s_rel_full + 1.0, stop_at_end=False, curve=RouteBraking(model, stock, full).curve(1.5 * step_s))
        v0 = speed_at(run0, s_rel_full)
        if math.isnan(v0):  # pragma: no cover
            raise VcsumoError(f"train {stock.name} cannot reach the release point {rel_km} km")
    i0 = full.index_at(s_rel_full)
    edges = track.edges[i0:]
    prof = RouteProfile.from_edges(topo, edges)
    pos0 = s_rel_full - float(full.starts_m[i0])
    trains = [
        PlannedTrain(
            id=f"{direction}_{stock.name}_{k:02d}", service="headway", stock=stock, edges=edges, profile=prof, depart_s=0.0,
            depart_pos_m=pos0, depart_speed_mps=v0, direction=direction, end_pos_m=None, start_s_m=pos0,
        )
        for k in range(n_trains)
    ]
    run = unhindered_run(p, prof, dt=step_s, s0=pos0, v0=v0, stop_at_end=False, curve=RouteBraking(model, stock, prof).curve(1.5 * step_s))
    return trains, prof, run, rel_km, v0


def analytic_headways(net: BuiltNetwork, trains: list[PlannedTrain], prof: RouteProfile, run: pd.DataFrame, regime: str, stock: RollingStock, step_s: float,
                      model: SeparationModel, route_end_m: float | None = None) -> Callable[[float], tuple[float, float]]:
    """Function x_m -> (analytic headway s, critical position m) of the regime at measuring point x."""
    signals = prof.signal_positions(net.topology)

    def at(x: float) -> tuple[float, float]:
        res = REGIMES[regime].analytic_headway(HeadwayInputs(model, stock, prof, run, signals, step_s, x, route_end_m))
        return res.headway_s, res.critical_m

    return at


def run_headway_case(
    line: Line, net: BuiltNetwork, stock: RollingStock, direction: str, regime: str, out: Path, points_km: list[float],
    step_s: float = 0.5, n_trains: int = 2, tolerance_s: float = 2.0, resolution_s: float = 0.25,
    progress: Callable[[float, float], None] | None = None, assumptions: AssumptionSet | None = None,
) -> list[dict]:
    """Bisection on the release interval for one case; one row per measuring point."""
    assumptions = assumptions or load_assumptions()
    model = SeparationModel(assumptions)
    trains0, prof, run, rel_km, v0 = prepare_case(line, net, stock, direction, step_s, n_trains, model)
    pts = []
    for k in points_km:
        try:
            x = prof.s_of("main", k)
        except KeyError:  # not on this direction's route (it starts at the release point's edge)
            x = -math.inf
        if x > trains0[0].start_s_m + 1.0:
            pts.append((f"km{k:g}", k, x))
        else:  # the trains never pass it after their release: no headway there in this direction
            warnings.warn(f"{direction}: measuring point km {k:g} lies before the release point (km {rel_km:g}) in this direction: not measured {direction}",
                          stacklevel=2)
    if not pts:
        return []
    # shorten the simulated route: last measuring point + braking distance + train + 2 km
    vmax = prof.max_speed()
    s_end = min(prof.length_m, max(x for _, _, x in pts) + vmax * vmax / (2 * stock.service_brake_decel_mps2) + stock.length_m + 2000.0)
    i_end = prof.index_at(s_end)
    edges = trains0[0].edges[: i_end + 1]
    cut = RouteProfile.from_edges(net.topology, edges)
    end_pos = min(s_end - float(cut.starts_m[-1]), float(cut.lengths_m[-1]))
    # theory on the same (shortened) route the simulation runs: the last block ends where the trains leave
    # (the trains leave at speed, so the leader's run is recomputed on that route)
    run_cut = unhindered_run(stock.params(), cut, dt=step_s, s0=trains0[0].start_s_m, v0=v0, end_s=float(cut.starts_m[-1]) + end_pos, stop_at_end=False,
                             curve=RouteBraking(model, stock, cut).curve(1.5 * step_s))
    analytic = analytic_headways(net, trains0, cut, run_cut, regime, stock, step_s, model, route_end_m=float(cut.starts_m[-1]) + end_pos)
    guesses = {lab: analytic(x)[0] for lab, _, x in pts}
    mps = [MeasuringPoint(lab, "main", k) for lab, k, _ in pts]
    probes_run = [0]
    unhealthy = [0]

    def run_at(h: float) -> Probe:
        trains = [
            replace(t, depart_s=k * h, edges=edges, profile=cut, end_pos_m=end_pos, stop_at_end=False)
            for k, t in enumerate(trains0)
        ]
        probes_run[0] += 1
        sub = out / "probes" / f"h{h:08.3f}"
        sim = simulate(Scenario(line, net, trains, regime, step_length_s=step_s, measuring_points=mps, record_period_s=3600.0, full_outputs=False, trace_speeds=True,
                                assumptions=assumptions), sub)
        unhealthy[0] += int(not sim.summary["healthy"])
        pr = Probe(h, sim.passages, {t.id: t.depart_s for t in trains}, sim.summary)
        order = [t.id for t in trains]
        pr.compute_delays([m.label for m in mps], order)
        start_delays = dict(zip(sim.trains.train, sim.trains.departure_delay_s.fillna(0.0)))
        pr.compute_speed_deficits({lab: x + DEFICIT_WINDOW_S * speed_at(run, x) for lab, _, x in pts}, sim.speed_traces, order, start_delays,
                                  rel_tol=SPEED_TOL_REL, abs_tol_mps=SPEED_TOL_ABS_MPS, step_s=step_s)
        return pr

    found = search_min_headway(run_at, [lab for lab, _, _ in pts], guesses, tolerance_s=tolerance_s, resolution_s=resolution_s)
    rows = []
    for lab, k, x in pts:
        h_rel, pr = found[lab]
        times = np.sort(pr.passages[pr.passages.measuring_point == lab]["time_s"].to_numpy())
        h_sim = float(np.median(np.diff(times))) if len(times) >= 2 and not math.isnan(h_rel) else math.nan
        # not found: the last probe's passages are the largest interval tried, not a headway
        error = "" if not math.isnan(h_rel) else (f"no sustainable headway found: a later train was hindered at every release interval tried, up to "
                                                  f"{pr.h_s:.1f} s (there: {pr.hindrance(lab, tolerance_s)})")
        h_an, crit = analytic(x)
        rows.append({
            "line": line.name, "direction": direction, "regime": regime, "train": stock.name, "measuring_point_km": k,
            "headway_sim_s": round(h_sim, 2), "headway_analytic_s": round(h_an, 2), "release_interval_s": round(h_rel, 2),
            "deviation_pct": round(100.0 * (h_sim - h_an) / h_an, 2) if h_an and not math.isnan(h_sim) else math.nan,
            "speed_at_point_mps": round(speed_at(run, x), 2), "critical_km": round(prof.km_at(crit)[1], 3) if not math.isnan(crit) else math.nan,
            "block_length_m": net.topology.block_length_m if regime == "fbs" else math.nan,
            "release_km": rel_km, "release_speed_mps": round(v0, 2), "hindrance_delay_s": round(pr.delays.get(lab, math.nan), 2),
            "min_gap_m": pr.summary["min_gap_m"], "gap_violations": pr.summary["gap_violations"],
            "collisions": pr.summary["collisions"], "emergency_brakes": pr.summary["emergency_brakes"], "simulations": probes_run[0],
            "healthy": pr.summary["healthy"], "min_margin_m": pr.summary["min_margin_m"], "assumptions": assumptions.name,
            **{c: pr.summary.get(c, math.nan) for c in HEALTH_COLUMNS}, "unhealthy_probes": unhealthy[0], "error": error,
        })
        if progress:
            progress(len(rows), len(pts))
    # keep the SUMO outputs of the probes at the reported headways only
    keep = {f"h{found[lab][0]:08.3f}" for lab, _, _ in pts if not math.isnan(found[lab][0])}
    probes_dir = out / "probes"
    if probes_dir.is_dir():
        import shutil

        for d in probes_dir.iterdir():
            if d.name not in keep:
                shutil.rmtree(d, ignore_errors=True)
    return rows


def run_headway_study(
    line: Line, net: BuiltNetwork, stocks: list[RollingStock], regimes: list[str], out: Path, points_km: list[float] | None = None,
    step_s: float = 0.5, n_trains: int = 2, tolerance_s: float = 2.0, directions: tuple[str, ...] = ("up", "down"), progress_factory=None,
    assumptions: AssumptionSet | None = None,
) -> pd.DataFrame:
    """Every direction × regime × train; writes ``headway.csv`` and ``headway.png`` into ``out``."""
    for r in regimes:
        if r not in ("fbs", "mb"):
            raise InputError(None, "--regime", f"headway study supports fbs and mb, not '{r}'")
    pts = measuring_points(line, points_km)
    rows: list[dict] = []
    cases = [(d, r, st) for d in directions for r in regimes for st in stocks]
    for d, r, st in cases:
        sub = out / "runs" / f"{d}_{r}_{st.name}"
        prog = progress_factory(f"{d} {r} {st.name}") if progress_factory else None
        rows += run_headway_case(line, net, st, d, r, sub, pts, step_s=step_s, n_trains=n_trains, tolerance_s=tolerance_s, progress=prog, assumptions=assumptions)
    df = pd.DataFrame(rows, columns=HEADWAY_COLUMNS)
    write_csv(df, out / "headway.csv")
    from vcsumo.infrastructure import write_infrastructure
    from vcsumo.plots.charts import plot_headway

    infra = write_infrastructure(net.topology, out)  # the stations on the plot's distance axis
    plot_headway(df, out / "headway.png", infra, {d: line.direction_label(d) for d in directions})
    return df
