"""Capacity study: how many trains per hour FBS, MB and VC let through, on this line, with these trains.

For each direction, stopping pattern, regime and (VC) controller and convoy size:

* **units** — single trains (FBS, MB) or convoys of ``n`` virtually coupled trains (VC) — are released
  at an interval h on the direction's main track with a flying start at their unhindered speed
  (release point: the line file's ``headway.release_km``, default the track start), and run to the
  end of the line, stopping at the intermediate stations of the pattern (``all-stops``: every
  station strictly between the line's first and last station; ``non-stop``: none);
* the **minimum sustainable headway** is the smallest h at which the second unit's leader is
  nowhere slower than the first unit's leader at the same position (0.3 m/s or 0.5 % tolerance)
  and no gap violation or collision occurs: bisection on h (:mod:`vcsumo.studies.min_headway`, one
  SUMO run per probe).  Only leaders are compared: a VC follower can only be held back through
  its own leader, and its trajectory depends on its own (seeded, random) channel; how well it keeps
  up is reported as ``intra_convoy_gap_m``;
* ``headway_sim_s`` is the time between the unit leaders passing the critical section in that run;
  ``headway_analytic_s`` is the regime's minimum headway from the separation model alone
  (:meth:`vcsumo.signalling.regimes.base.Regime.analytic_headway` on the leader's unhindered,
  supervised profile: FBS blocks with their release and fixed times, MB the guaranteed braking
  distance + margin behind the rear, VC a convoy whose followers run at the spacing their stack
  keeps where each of them is on the route (:func:`vcsumo.studies.capacity_route.convoy_spacing`:
  the relative-braking rule over the grades ahead) and the next convoy at moving-block distance
  from its last train) — it is independent of the simulation;
* convoy followers start at that same route spacing where they start
  (:func:`vcsumo.studies.capacity_route.initial_convoy_gaps`): started closer, the separation
  guard brakes them at their release;
* a convoy is **formed** when its followers run within 10 % + 10 m of the spacing their stacks
  keep: ``intra_convoy_gap_m`` — the median simulated gap at the release speed ±3 % — against
  ``coupled_spacing_m``, the median over the same records of the spacing at each follower's speed
  and position on its route (the spacing the controller holds and the driver's formation account
  uses; :func:`cruise_records`); ``convoy_formed``.  Beside them ``coupled_gap_model_m``: the
  analytic headway's spacing of the first follower at the release point and speed (on the route),
  and ``coupled_gap_level_m``: the same on level track (a paper check), m.  A follower that enters the line at a
  lower permitted speed than its leader (a speed restriction before the release point) keeps the
  time gap of that restriction at line speed: equal trains at the same line speed cannot close
  it, and the simulated headway is then longer than the analytic one, which assumes a formed
  convoy;
* ``capacity_trains_per_h`` = 3600·n / headway (every train of a convoy counts);
  ``gain_vs_fbs`` = capacity / FBS capacity in the same direction and stopping pattern (1.0 = same),
  only when both rows are healthy (:mod:`vcsumo.studies.capacity_gain`).

VC with convoy size 1 has nothing to couple: it is moving block, and its rows repeat the MB result.

Writes ``capacity.csv``, ``capacity.png`` (capacity by regime and convoy size) and
``time_distance.png`` (one released sequence per regime with its blocking-time stairs).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from vcsumo.engine.campaign import Outcome, Runner, Task, run_campaign
from vcsumo.engine.store import ResultStore, Table, atomic_csv
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.separation import SeparationModel
from vcsumo.signalling.regimes.base import AnalyticHeadway
from vcsumo.errors import InputError, VcsumoError
from vcsumo.line import Line
from vcsumo.sim.network import BuiltNetwork
from vcsumo.rolling_stock import RollingStock
from vcsumo.results import ResultsFolder, file_digest, write_meta
from vcsumo.sim.convoy_formation import within_spacing
from vcsumo.sim.loop import MeasuringPoint, Scenario, simulate
from vcsumo.studies.capacity_route import (STANDSTILL_EXTRA_M, Case, RouteSetup, analytic_headway, check_position_m, convoy_spacing, initial_convoy_gaps, leader_run, route_setup,
                                           convoys_longer_than_platforms, unit_trains)
from vcsumo.studies.capacity_gain import gains_vs_fbs
from vcsumo.studies.min_headway import Probe, search_min_headway
from vcsumo.studies.time_distance import TIME_DISTANCE_COLUMNS, TIME_DISTANCE_FILE, time_distance_table
from vcsumo.timetable import PlannedTrain

PATTERNS = ("non-stop", "all-stops")
CAPACITY_COLUMNS = [
    "line", "direction", "regime", "controller", "convoy_size", "stopping_pattern", "critical_section_km", "headway_sim_s",
    "headway_analytic_s", "intra_convoy_gap_m", "coupled_gap_model_m", "coupled_gap_level_m", "coupled_spacing_m", "convoy_formed", "release_speed_kmh", "capacity_trains_per_h", "gain_vs_fbs",
    "healthy", "min_gap_m", "min_margin_m", "gap_violations", "below_separation_time_s", "collisions", "max_impact_kmh", "stops_skipped",
    "short_dwells", "overspeed_events", "beyond_service_brakings", "authority_overruns", "sumo_emergency_stops",
    "sumo_emergency_brakings", "sumo_stop_warnings", "teleports", "unhealthy_probes", "assumptions",
    "train", "release_interval_s", "deviation_pct", "block_length_m", "fixed_time_s", "emergency_brakes", "guard_interventions", "simulations",
    "wall_time_s", "sumo_time_s", "controller_time_s", "io_time_s", "error",
]


SPEED_TOL_ABS_MPS = 0.1
"""A unit counts as hindered where its leader runs slower than the first unit's leader at the same
position by more than max(0.1 m/s, 0.5 %); SUMO is deterministic, so identical unhindered trains
agree far better than that (a looser 0.3 m/s let MB followers creep towards a train dwelling at a
station and hid up to 12 % of the headway)."""
SPEED_TOL_REL = 0.005
LOST_TOL_S = 2.0
"""A unit is hindered when its leader lost more than this against the first unit's leader, s."""
SPEED_TOL_MIN_MPS = 1.0
"""Below 1 m/s (the last metres of a stop) speeds are not compared, only lost time."""
SEARCH_CENTRE = 0.993
"""Centre of the first bisection bracket relative to the analytic (VC: calibrated) headway.  The
simulated minimum lies a little below blocking-time theory (on Bologna–Firenze 0.4–1.9 % below in
20 of the 24 default cases, 4–8 % in the others)."""
SEARCH_BRACKET = 0.0
"""Half-width of the first bisection bracket, relative; 0: one resolution wide, so that a good
centre decides the case with two runs.  The bracket widens (doubling) until it holds the answer, so
centre and width only save simulations (Bologna–Firenze: about 4 runs per case instead of 7)."""


def convoy_formed(gap_m: float, spacing_m: float | None) -> bool | float:
    """Whether a simulated intra-convoy gap at the release speed is the spacing the followers' stacks
    keep there (``coupled_spacing_m``), by the rule of :func:`vcsumo.sim.convoy_formation.within_spacing`
    (10 % + 10 m); NaN when either is unknown."""
    if spacing_m is None or math.isnan(gap_m) or math.isnan(spacing_m):
        return math.nan
    return bool(within_spacing(gap_m, spacing_m))


CRUISE_REL = 0.03
"""A follower record counts towards the convoy's gap at the release speed within ±3 % of it."""


def cruise_records(records: pd.DataFrame, setup: RouteSetup, followers: dict[str, PlannedTrain], spacing_m: Callable[..., float]) -> pd.DataFrame:
    """The followers' records at the release speed (±:data:`CRUISE_REL`), each with ``spacing_m``:
    the spacing its stack keeps at its speed where it is on its route
    (``spacing_m(train_id, v, s)``, :meth:`vcsumo.sim.vc_driver.VCDriver.coupled_spacing_m`,
    the spacing the driver's formation account and the controller use), m."""
    if not len(records):
        return records.assign(spacing_m=pd.Series(dtype=float))
    cruise = records[(records.speed_mps - setup.v0).abs() <= CRUISE_REL * max(setup.v0, 1.0)]
    cruise = cruise[cruise.train.isin(list(followers))]
    full = setup.full
    spacing = []
    for tid, km, v in zip(cruise.train, cruise.km, cruise.speed_mps):
        off = full.length_m - followers[tid].profile.length_m  # the follower's route is the full track's tail
        try:
            s_own = full.s_of("main", float(km)) - off
        except KeyError:  # not on the main track (cannot happen on the study's routes): no spacing
            spacing.append(math.nan)
            continue
        spacing.append(float(spacing_m(tid, float(v), s_own)))
    return cruise.assign(spacing_m=spacing)


@dataclass
class CaseResult:
    row: dict
    probe: Probe | None
    units: list[list[PlannedTrain]]
    run: pd.DataFrame
    blocks: pd.DataFrame | None
    h: float
    theory: AnalyticHeadway | None = None
    """The regime's analytic headway of the case (its blocking times, reservation, convoy rear lag)."""


def run_case(line: Line, net: BuiltNetwork, stock: RollingStock, setup: RouteSetup, case: Case, out: Path, step_s: float, vc_step_s: float,
             resolution_s: float = 0.5, seed: int = 42, fixed_time_s: float | None = None, assumptions: AssumptionSet | None = None) -> CaseResult:
    """Bisection on the release interval for one case, started at the regime's analytic headway."""
    t_wall = time.perf_counter()
    topo = net.topology
    assumptions = assumptions or load_assumptions()
    if fixed_time_s is not None:
        assumptions = assumptions.model_copy(update={"fixed_time_s": fixed_time_s})
    fixed_time_s = assumptions.fixed_time_s
    model = SeparationModel(assumptions)
    dt = vc_step_s if case.regime == "vc" else step_s
    run = leader_run(setup, stock, case, dt, model)
    s_check = check_position_m(setup)
    # the spacing the followers' stacks keep on this route (the stack the loop builds, on the full track)
    from vcsumo.sim.vc_driver import load_channel

    channel = load_channel(None)  # the runs' channel: the stacks' spacing budgets its message age
    spacing_of = (convoy_spacing(case.controller, stock, dt, assumptions, setup.full, channel.age_budget_s())
                  if case.regime == "vc" and case.convoy_size > 1 else None)
    init_gap = initial_convoy_gaps(spacing_of, model, stock, setup, case.convoy_size) if case.convoy_size > 1 else []
    theory = analytic_headway(net, setup, run, stock, case, model, dt, s_check, spacing_of, on_route=True)
    guess = theory.headway_s
    probes = [0]
    unhealthy = [0]
    timing = {"sumo_step_time_s": 0.0, "controller_time_s": 0.0, "io_time_s": 0.0}
    mps = [MeasuringPoint("end", "main", setup.full.km_at(s_check)[1])]

    def run_at(h: float, n_units: int = 2) -> Probe:
        units = unit_trains(topo, setup, stock, case, n_units, h, init_gap)
        trains = [t for u in units for t in u]
        driver = None
        if case.regime == "vc":
            from vcsumo.sim.vc_driver import VCDriver

            driver = VCDriver(units, case.controller, dt, seed, channel, assumptions=assumptions)
        probes[0] += 1
        sim = simulate(Scenario(line, net, trains, case.regime, step_length_s=dt, measuring_points=mps, record_period_s=3600.0,
                                full_outputs=False, trace_speeds=True, driver=driver, seed=seed, assumptions=assumptions), out / "probes" / f"h{h:08.3f}")
        for k in timing:
            timing[k] += sim.summary.get(k, 0.0)
        unhealthy[0] += int(not sim.summary["healthy"])
        pr = Probe(h, sim.passages, {t.id: t.depart_s for t in trains}, sim.summary)
        pr.units = units  # type: ignore[attr-defined]
        pr.sim = sim  # type: ignore[attr-defined]
        if n_units == 1:
            return pr
        pairs = [(units[1][0].id, units[0][0].id)]
        order = [t.id for t in trains]
        pr.compute_delays(["end"], order, pairs)
        start_delays = dict(zip(sim.trains.train, sim.trains.departure_delay_s.fillna(0.0)))
        # every train's position in its own route frame: compare in the full-track frame
        traces = {}
        for t in trains:
            off = setup.full.length_m - t.profile.length_m
            sv = sim.speed_traces.get(t.id)
            if sv is not None:
                traces[t.id] = ([x + off for x in sv[0]], sv[1])
        pr.compute_speed_deficits({"end": s_check}, traces, order, start_delays, rel_tol=SPEED_TOL_REL, abs_tol_mps=SPEED_TOL_ABS_MPS, pairs=pairs,
                                   min_speed_mps=SPEED_TOL_MIN_MPS, step_s=dt)
        if driver is not None:
            pr.vc = driver.summary()  # type: ignore[attr-defined]
            pr.vc_records = cruise_records(pd.DataFrame(driver.records), setup, {t.id: t for u in units for t in u[1:]}, driver.coupled_spacing_m)  # type: ignore[attr-defined]
        return pr

    found = search_min_headway(run_at, ["end"], {"end": guess}, tolerance_s=LOST_TOL_S, resolution_s=resolution_s, bracket=SEARCH_BRACKET,
                                 centre=SEARCH_CENTRE)
    h, pr = found["end"]
    if math.isnan(h):
        raise VcsumoError(f"no sustainable headway found: the second unit was hindered at every release interval tried, up to {pr.h_s:.1f} s "
                          f"(there: {pr.hindrance('end', LOST_TOL_S)})")
    units = pr.units  # type: ignore[attr-defined]
    # coupled gap inside convoys at the release speed (±3 %), beside the separation model's gap there
    gap = spacing = math.nan
    if case.convoy_size > 1 and hasattr(pr, "vc_records") and len(pr.vc_records):
        gap, spacing = float(pr.vc_records.gap_m.median()), float(pr.vc_records.spacing_m.median())
    h_an, crit, blocks = theory.headway_s, theory.critical_m, theory.blocks
    # simulated headway: leaders passing the critical section in the run at the minimum interval
    tr0 = pr.sim.speed_traces  # type: ignore[attr-defined]
    h_sim = h
    lead0, lead1 = units[0][0], units[1][0]
    try:
        off0 = setup.full.length_m - lead0.profile.length_m
        off1 = setup.full.length_m - lead1.profile.length_m
        s0, _ = tr0[lead0.id]
        s1, _ = tr0[lead1.id]
        t0 = np.interp(crit - off0, s0, np.arange(len(s0)) * dt) + lead0.depart_s
        t1 = np.interp(crit - off1, s1, np.arange(len(s1)) * dt) + lead1.depart_s
        if s0[0] <= crit - off0 <= s0[-1] and s1[0] <= crit - off1 <= s1[-1]:
            h_sim = float(t1 - t0)
    except KeyError:
        pass
    summ = pr.summary
    row = {
        "line": line.name, "direction": case.direction, "regime": case.regime, "controller": case.controller or "", "convoy_size": case.convoy_size,
        "stopping_pattern": case.pattern, "critical_section_km": round(setup.full.km_at(crit)[1], 3), "headway_sim_s": round(h_sim, 2),
        "headway_analytic_s": round(h_an, 2), "intra_convoy_gap_m": round(gap, 1) if not math.isnan(gap) else math.nan,
        "coupled_gap_model_m": round(theory.coupled_gap_m, 1) if theory.coupled_gap_m is not None else math.nan,
        "coupled_gap_level_m": round(theory.coupled_gap_level_m, 1) if theory.coupled_gap_level_m is not None else math.nan,
        "coupled_spacing_m": round(spacing, 1), "convoy_formed": convoy_formed(gap, spacing) if case.convoy_size > 1 else math.nan,
        "release_speed_kmh": round(3.6 * setup.v0, 1),
        "capacity_trains_per_h": round(3600.0 * case.convoy_size / h_sim, 2), "gain_vs_fbs": math.nan,
        "min_gap_m": summ["min_gap_m"], "gap_violations": summ["gap_violations"], "collisions": summ["collisions"], "train": stock.name,
        "assumptions": assumptions.name, "healthy": bool(summ["healthy"]), "min_margin_m": summ["min_margin_m"],
        "below_separation_time_s": summ["below_separation_time_s"], "max_impact_kmh": summ["max_impact_kmh"],
        "stops_skipped": summ["stops_skipped"], "short_dwells": summ["short_dwells"], "overspeed_events": summ["overspeed_events"], "beyond_service_brakings": summ["beyond_service_brakings"],
        "authority_overruns": summ["authority_overruns"], "sumo_emergency_stops": summ["sumo_emergency_stops"],
        "sumo_emergency_brakings": summ["sumo_emergency_brakings"], "sumo_stop_warnings": summ["sumo_stop_warnings"], "teleports": summ["teleports"],
        "unhealthy_probes": unhealthy[0],
        "release_interval_s": round(h, 2), "deviation_pct": round(100.0 * (h_sim - h_an) / h_an, 2),
        "block_length_m": net.topology.block_length_m, "fixed_time_s": fixed_time_s, "emergency_brakes": summ["emergency_brakes"],
        "guard_interventions": getattr(pr, "vc", {}).get("guard_interventions", 0) if hasattr(pr, "vc") else 0,
        "simulations": probes[0], "wall_time_s": round(time.perf_counter() - t_wall, 1),
        "sumo_time_s": round(timing["sumo_step_time_s"], 1), "controller_time_s": round(timing["controller_time_s"], 1),
        "io_time_s": round(timing["io_time_s"], 1), "error": "",
    }
    _prune(out / "probes", f"h{h:08.3f}")
    return CaseResult(row, pr, units, run, blocks, h, theory)


def _prune(folder: Path, keep: str) -> None:
    import shutil

    if folder.is_dir():
        for d in folder.iterdir():
            if d.name != keep:
                shutil.rmtree(d, ignore_errors=True)


def cases_for(directions, patterns, controllers, sizes) -> list[Case]:
    out = []
    for d in directions:
        for pat in patterns:
            out.append(Case(d, "fbs", None, 1, pat))
            out.append(Case(d, "mb", None, 1, pat))
            for c in controllers:
                for n in sizes:
                    out.append(Case(d, "vc", c, n, pat))
    return out


def _case_dir(out: Path, case: Case) -> Path:
    from vcsumo.results import safe_component  # the controller spec may hold a path ('cbc:../p.yaml')

    return out / "runs" / safe_component(f"{case.direction}_{case.pattern}_{case.regime}_{case.controller or 'sumo'}_{case.convoy_size}".replace(":", "-"))


CASES_TABLE = Table("capacity_cases.csv", ("case_key", *CAPACITY_COLUMNS), "case_key",
                    text=("line", "direction", "regime", "controller", "stopping_pattern", "train", "error"))
"""The capacity study's result store: one row per finished case (the rows of ``capacity.csv``)."""
EXAMPLE_FILE = TIME_DISTANCE_FILE
"""A case shown in the time-distance plot keeps its rows of ``time_distance.csv`` in its run folder."""


def case_key(params: dict, case: Case) -> str:
    """The resume key of a case: the study's parameters and the case (16 hex digits)."""
    text = json.dumps(params, sort_keys=True, default=str) + f"|{case.direction}|{case.regime}|{case.controller or ''}|{case.convoy_size}|{case.pattern}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _case_task(args: tuple) -> dict:
    """One case, in a worker process or in this one: its row of ``capacity.csv`` (an error raises).

    The case's folder ``runs/<case>/`` is written whole or not at all; an example case also
    leaves its result there (:data:`EXAMPLE_FILE`) for the time-distance plot."""
    line, net, stock, setup, case, out, step_s, vc_step_s, seed, assumptions, keep_example, key = args
    params = {"case": {"direction": case.direction, "regime": case.regime, "controller": case.controller, "convoy_size": case.convoy_size,
                       "pattern": case.pattern}, "case_key": key, "step_length_s": step_s, "vc_step_length_s": vc_step_s,
              "assumptions": assumptions.record()}
    with ResultsFolder(_case_dir(out, case), inputs={"line": line.path}, seed=seed, params=params, overwrite=True) as rf:
        res = run_case(line, net, stock, setup, case, rf.path, step_s, vc_step_s, seed=seed,
                       resolution_s=1.0 if case.regime == "vc" else 0.5, assumptions=assumptions)
        if keep_example:
            time_distance_table({case.regime: res}, {case.direction: setup}).to_csv(rf.path / EXAMPLE_FILE, index=False)
    return dict(res.row, case_key=key)


def _load_example(out: Path, case: Case) -> pd.DataFrame | None:
    """An example case's time-distance rows, as written (text), or None if they cannot be read."""
    try:
        df = pd.read_csv(_case_dir(out, case) / EXAMPLE_FILE, dtype=str, keep_default_na=False)
    except (OSError, ValueError):  # missing or cut off: the case runs again
        return None
    return df if list(df.columns) == TIME_DISTANCE_COLUMNS else None


def _time_distance(out: Path, example_of: dict, results: dict, setups: dict) -> pd.DataFrame:
    """``time_distance.csv``: the example cases' rows (one panel per regime, FBS, MB, VC), a failed
    example as its error (:func:`vcsumo.studies.time_distance.time_distance_table`)."""
    parts = []
    for regime in (r for r in ("fbs", "mb", "vc") if r in example_of):
        case = example_of[regime]
        rows = _load_example(out, case) if not results[case]["error"] else None
        if rows is None:
            rows = time_distance_table({}, setups, {regime: (case, results[case]["error"] or "no result")})
        parts.append(rows.assign(panel=len(parts)))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=TIME_DISTANCE_COLUMNS)


def _failed_row(line: Line, stock: RollingStock, net: BuiltNetwork, case: Case, error: str, fixed_time_s: float) -> dict:
    row = {c: math.nan for c in CAPACITY_COLUMNS}
    row.update(line=line.name, direction=case.direction, regime=case.regime, controller=case.controller or "", convoy_size=case.convoy_size,
               stopping_pattern=case.pattern, train=stock.name, block_length_m=net.topology.block_length_m, fixed_time_s=fixed_time_s, error=error)
    return row


def study_params(line: Line, net: BuiltNetwork, stock: RollingStock, step_s: float, vc_step_s: float, seed: int, assumptions: AssumptionSet) -> dict:
    """The parameters every case of a study depends on: a study folder holds cases of one set only."""
    return {"line": line.name, "line_sha256": file_digest(line.path), "block_length_m": net.topology.block_length_m, "train": stock.name,
            "train_sha256": hashlib.sha256(json.dumps(stock.model_dump(mode="json"), sort_keys=True).encode()).hexdigest(),
            "step_length_s": step_s, "vc_step_length_s": vc_step_s, "seed": seed, "fixed_time_s": assumptions.fixed_time_s,
            "assumptions": assumptions.record()}


def run_capacity_study(
    line: Line, net: BuiltNetwork, stock: RollingStock, out: Path, controllers: list[str], convoy_sizes: list[int],
    directions: tuple[str, ...] = ("up", "down"), patterns: tuple[str, ...] | None = None, step_s: float = 0.5, vc_step_s: float = 0.2,
    seed: int = 42, progress: Callable[[int, int, str], None] | None = None, fixed_time_s: float | None = None, workers: int | None = 1,
    scheduler: str | None = None, assumptions: AssumptionSet | None = None,
) -> pd.DataFrame:
    """Every case; writes ``capacity.csv``, ``capacity.png``, ``time_distance.png`` and ``meta.json`` into ``out``.

    Cases run through :mod:`vcsumo.engine.campaign`: ``workers`` processes (1: in this process;
    ``None``: the number of CPUs) or a Dask ``scheduler``; a case that fails becomes a row with its
    ``error`` and the study goes on.  Every finished case is recorded in ``capacity_cases.csv``
    (the folder's store) as it finishes, so a study that was stopped (killed, interrupted)
    resumes when run again into the same ``out``: only the missing cases run.  A folder holding
    a study with other parameters (line, network, train, steps, seed, fixed time) is refused;
    other cases (controllers, convoy sizes, directions, patterns) may be added.
    ``df.attrs``: ``new_cases``, ``resumed_cases``, ``failed_cases``.
    """
    from vcsumo.control.registry import parse_controller

    t_wall = time.perf_counter()
    for c in controllers:
        parse_controller(c)
    for n in convoy_sizes:
        if not 1 <= n <= 8:
            raise InputError(None, "--convoy-sizes", f"convoy size {n} is outside 1-8")
    if fixed_time_s is not None and fixed_time_s < 0:
        raise InputError(None, "--fixed-time-s", f"fixed time {fixed_time_s} s is negative")
    assumptions = assumptions or load_assumptions()
    if fixed_time_s is not None:
        assumptions = assumptions.model_copy(update={"fixed_time_s": fixed_time_s})
    fixed_time_s = assumptions.fixed_time_s
    model = SeparationModel(assumptions)
    out = Path(out)
    runner = Runner(workers, scheduler, log_path=out / "workers.log", partial_roots=[out / "runs"])
    setups = {d: route_setup(line, net, stock, d, step_s, model) for d in directions}
    if patterns is None:
        patterns = tuple(p for p in PATTERNS if p == "non-stop" or any(setups[d].stops_full for d in directions))
    # all-stops only where the direction has a station to stop at after its release point
    cases = [c for c in cases_for(directions, patterns, controllers, convoy_sizes) if c.pattern == "non-stop" or setups[c.direction].stops_full]
    if not cases:
        raise InputError(None, "--patterns", "no case to run (no stopping pattern with a station to stop at in these directions)")
    for d in directions:  # all-stops convoys longer than a platform: their members stop one after another, the analytic figure is short
        sizes = sorted({c.convoy_size for c in cases if c.direction == d and c.pattern == "all-stops" and c.regime == "vc" and c.convoy_size > 1})
        for msg in convoys_longer_than_platforms(setups[d].stops_full, stock, sizes, model.margin_m + STANDSTILL_EXTRA_M):
            warnings.warn(f"{d}: {msg}", stacklevel=2)
    # VC with one train is moving block: its rows repeat MB's
    todo = [c for c in cases if not (c.regime == "vc" and c.convoy_size == 1)]
    example_of = {}
    for c in todo:  # the time-distance plot shows the first direction and pattern, the largest convoy
        if c.direction == directions[0] and c.pattern == patterns[0]:
            if c.regime not in example_of or c.convoy_size > example_of[c.regime].convoy_size:
                example_of[c.regime] = c
    examples_wanted = set(example_of.values())
    # longest first: VC convoys (largest first), then FBS/MB
    todo.sort(key=lambda c: (c.regime != "vc", -c.convoy_size))
    params = study_params(line, net, stock, step_s, vc_step_s, seed, assumptions)
    keys = {c: case_key(params, c) for c in todo}
    by_key = {k: c for c, k in keys.items()}

    def label(case: Case) -> str:
        return f"{case.direction} {case.pattern} {case.regime} {case.controller or ''} n={case.convoy_size}"

    def to_rows(task: Task, outcome: Outcome) -> tuple[list[dict], dict]:
        case = by_key[task.key]
        row = outcome.value if outcome.ok else dict(_failed_row(line, stock, net, case, outcome.error, fixed_time_s), case_key=task.key)
        return [row], {}

    with runner, ResultStore(out, CASES_TABLE, kind="capacity", params=params, exclusive=True) as store:
        # an example case whose result cannot be read back runs again
        have = store.read().set_index("case_key")["error"]
        store.forget([keys[c] for c in examples_wanted if keys[c] in store and not have.get(keys[c]) and _load_example(out, c) is None])
        tasks = [Task(keys[c], _case_task, (line, net, stock, setups[c.direction], c, out, step_s, vc_step_s, seed, assumptions, c in examples_wanted, keys[c]),
                      label(c)) for c in todo]

        def on_progress(done: int, total: int, rows: list[dict] | None) -> None:
            if rows is None:
                progress(0, total, f"{total} cases" + (f" ({len(todo) - total} already done)" if total < len(todo) else ""))
            else:
                progress(done, total, label(by_key[rows[0]["case_key"]]) + (" FAILED" if rows[0].get("error") else ""))

        res = run_campaign(store, tasks, runner, to_rows, on_progress if progress else None)
        stored = store.read().set_index("case_key")
        results = {c: stored.loc[keys[c]].to_dict() for c in todo}
        rows: list[dict] = []
        for case in cases:
            if case.regime == "vc" and case.convoy_size == 1:
                base = results[Case(case.direction, "mb", None, 1, case.pattern)]
                rows.append(dict(base, regime="vc", controller=case.controller, convoy_size=1) if not base["error"]
                            else _failed_row(line, stock, net, case, base["error"], fixed_time_s))
                continue
            rows.append(results[case])
        df = pd.DataFrame(rows, columns=CAPACITY_COLUMNS)
        df["controller"] = df["controller"].fillna("")
        df["gain_vs_fbs"] = gains_vs_fbs(df)  # only between rows shown safe
        # capacity.csv goes first and comes back last: a folder without it is a stopped study (before, a
        # SIGTERM while the plots were drawn left it beside no meta.json: a stopped study that looked finished)
        (out / "capacity.csv").unlink(missing_ok=True)
        from vcsumo.infrastructure import write_infrastructure
        from vcsumo.plots.capacity import plot_capacity, plot_time_distance_stairs

        infra = write_infrastructure(net.topology, out)
        td = out / TIME_DISTANCE_FILE
        atomic_csv(_time_distance(out, example_of, results, setups), td)
        table = out / f".tmp-{os.getpid()}-capacity.csv"
        atomic_csv(df, table)
        _atomic_plot(lambda p: plot_capacity(table, p), out / "capacity.png")
        table.unlink()
        _atomic_plot(lambda p: plot_time_distance_stairs(td, p, line.name, infrastructure=infra), out / "time_distance.png")
        failed = int((df.error.astype(str) != "").sum())
        write_meta(out, {"line": line.path}, seed, {**params, "controllers": controllers, "convoy_sizes": convoy_sizes,
                   "directions": list(directions), "patterns": list(patterns), "workers": runner.where},
                   time.perf_counter() - t_wall, {"cases": len(df), "new_cases": res.new, "resumed_cases": res.resumed, "failed_cases": failed})
        atomic_csv(df, out / "capacity.csv")
    df.attrs.update(new_cases=res.new, resumed_cases=res.resumed, failed_cases=failed)
    return df


def _atomic_plot(draw: Callable[[Path], None], path: Path) -> None:
    """Draw into a temporary file and rename it (a plot is whole or absent; no plot: the old one goes)."""
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    draw(tmp)
    if tmp.is_file():
        os.replace(tmp, path)
    else:
        path.unlink(missing_ok=True)
