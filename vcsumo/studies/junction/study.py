"""The junction study: cases, the offset sweep and bisection of each case, and the tables and plots
(definitions and outputs: module doc of :mod:`vcsumo.studies.junction`).
"""

from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pandas as pd

from vcsumo.errors import InputError
from vcsumo.line import Line
from vcsumo.plots.junction import plot_junction_regimes, plot_junction_sweep
from vcsumo.rolling_stock import RollingStock
from vcsumo.sim.network import BuiltNetwork
from vcsumo.signalling.assumptions import AssumptionSet
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel
from vcsumo.control.registry import parse_controller
from vcsumo.studies.junction.metrics import actual_order, formation, run_metrics, signal_rows, speed_at_trace, trajectory_rows, unhindered
from vcsumo.studies.junction.model import (ROLES, SIGNAL_VARIANTS, Case, RunResult, Setup, build_setup, resolve_junctions, signal_links, simulate_pair,
                                           solo_runs)

DEFAULT_OFFSETS_S = (0.0, 10.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0)

JUNCTION_COLUMNS = [
    "line", "junction", "junction_name", "direction", "junction_kind", "junction_throughput_trains_per_h",
    "merge_junction", "merge_km", "split_junction", "split_km",
    "leader_service", "follower_service", "regime", "controller", "junction_signal", "train",
    "leader_speed_at_junction_mps", "follower_speed_at_junction_mps",
    "formation_start_m_before_merge", "vc_control_start_m_before_merge", "formed_m_after_merge", "formation_time_s",
    "formation_distance_m", "formed_gap_m", "formed_speed_mps", "formed_lost_time_s",
    "merge_junction_min_offset_s", "merge_junction_headway_s", "merge_junction_throughput_trains_per_h", "merge_trunk_lost_s",
    "merge_min_offset_s", "merge_headway_s", "merge_throughput_trains_per_h",
    "split_min_offset_s", "split_headway_s", "split_throughput_trains_per_h", "split_is_bottleneck",
    "first_through_junction", "order_kept", "merging_service_delay_s", "merging_service_delay_end_s", "first_service_delay_end_s",
    "min_gap_merge_m", "min_gap_split_m", "gap_violations_merge", "gap_violations_split", "gap_violations", "collisions",
    "sumo_emergency_brakes", "sumo_emergency_warnings", "red_signal_stops",
    "merge_red_max_required_decel_mps2", "merge_red_inside_braking_s", "split_red_max_required_decel_mps2", "split_red_inside_braking_s",
    "max_overspeed_mps", "vc_guard_interventions", "vc_emergency_activations", "vc_supervisor_interventions", "junction_signal_caps",
    "junction_signal_overruns", "speed_profile_caps",
    "healthy", "unhealthy_runs", "min_margin_m", "below_separation_time_s", "gap_violations_all_runs", "collisions_all_runs", "max_impact_kmh",
    "stops_skipped", "short_dwells", "overspeed_events", "overspeed_max_kmh", "beyond_service_brakings", "authority_overruns", "sumo_emergency_stops",
    "sumo_emergency_brakings", "sumo_stop_warnings", "teleports", "assumptions", "simulations", "wall_time_s",
]

HEALTH_SUMS = ("gap_violations", "collisions", "stops_skipped", "short_dwells", "overspeed_events", "beyond_service_brakings", "authority_overruns",
               "sumo_emergency_stops", "sumo_emergency_brakings", "sumo_stop_warnings", "teleports")
"""Run-health counters summed over every simulation of a case (``<name>_all_runs`` for the two the
row also gives for the Δ = 0 run)."""


def case_health(summaries: list[dict]) -> dict:
    """The run health of a case over all its simulations (sweep probes and analysis runs): healthy
    only if every run was (:mod:`vcsumo.sim.health`), the smallest margin to the safe separation,
    the counters summed and the largest excesses."""
    out: dict = {"healthy": bool(summaries) and all(bool(x["healthy"]) for x in summaries),
                 "unhealthy_runs": sum(int(not x["healthy"]) for x in summaries)}
    margins = [x["min_margin_m"] for x in summaries if x.get("min_margin_m") is not None]
    out["min_margin_m"] = round(min(margins), 2) if margins else math.nan
    out["below_separation_time_s"] = round(sum(x["below_separation_time_s"] for x in summaries), 2)
    for k in HEALTH_SUMS:
        out[f"{k}_all_runs" if k in ("gap_violations", "collisions") else k] = int(sum(x[k] for x in summaries))
    out["max_impact_kmh"] = max((x["max_impact_kmh"] for x in summaries), default=0.0)
    out["overspeed_max_kmh"] = max((x["overspeed_max_kmh"] for x in summaries), default=0.0)
    out["assumptions"] = summaries[0].get("assumptions", "") if summaries else ""
    return out


# -------------------------------------------------------------------------------------------
# A case: sweep, bisection, analysis runs


def release_offset(setup: Setup, dt: float, model: SeparationModel, regime: str) -> float:
    """Smallest release interval of two trains at the common release point (both at the release
    speed) that keeps the regime's safe separation there from the first step, s: under VC the
    relative-braking gap of the guard (dead time + the messages' age bound + 1.5 steps), under FBS
    and MB the absolute one (stopping distance after the dead time + 1.5 steps; MB: a report period
    of running more), each + margin and position errors + 10 m."""
    stock, v = setup.stock, setup.start_v["main"]
    if v <= 0.5:
        return 0.0
    s0 = setup.start_s["main"]
    prof = setup.profiles["main"]
    a = model.assumptions
    if regime == "vc":
        rule = RelativeBraking(model, stock, stock, prof)
        dead = model.dead_time_s + a.t2t_delay_bound_s + 1.5 * dt
        gap = model.vc_gap(stock, stock, v)
        for _ in range(2):  # the leader's front where the gap puts it (its grades)
            gap = rule.required_gap(s0, v, s0 + gap + stock.length_m, v, dead)
    else:
        gap = model.margin_m + RouteBraking(model, stock, prof).stopping_distance(s0, v, model.dead_time_s + 1.5 * dt)
        if regime == "mb":
            gap += v * a.position_report_period_s
    return (gap + 10.0 + stock.length_m) / v


@dataclass
class CaseOutcome:
    row: dict
    sweep: list[dict]
    runs: dict[str, RunResult]
    """'simultaneous', 'merge_min', 'split_min' analysis runs."""


def run_case(setup: Setup, case: Case, solo: dict[str, RunResult], out: Path, dt: float, offsets: list[float], tolerance_s: float, resolution_s: float,
             window_m: float, seed: int, links, link_warmup: bool = True) -> CaseOutcome:
    t_wall = time.perf_counter()
    leader = case.first
    follower = "main" if leader == "branch" else "branch"
    solo_times = {r: solo[r].passages[setup.key[0].upper()][r] - solo[r].departures[r] for r in ROLES}
    d0 = 0.0
    if setup.merge is None:  # both start at the same point: the follower must fit behind the leader
        d0 = math.ceil(release_offset(setup, dt, setup.model, case.regime))
    cache: dict[float, tuple[dict, RunResult]] = {}
    count = [0]

    def probe(off: float) -> dict:
        key = round(off, 2)
        if key not in cache:
            count[0] += 1
            sub = out / "probes" / f"o{key:08.2f}"
            rr = simulate_pair(setup, case, key, solo_times, sub, dt, seed, full=False, link_warmup=link_warmup)
            m = run_metrics(setup, case, rr, solo, links, window_m)
            cache[key] = (m, rr)
        return cache[key][0]

    grid = sorted({round(d0 + o, 2) for o in offsets})
    for o in grid:
        probe(o)
    labels = ["junction", "merge"] if setup.merge is not None else []
    if setup.split is not None:
        labels.append("split")
    mins: dict[str, float] = {}
    for lab in labels:
        # extend the grid until the largest offset is unhindered
        hi_o = max(cache)
        tries = 0
        while not unhindered(cache[hi_o][0], lab, tolerance_s, setup) and tries < 4:
            hi_o = round(hi_o * 1.5 + 30.0, 2)
            probe(hi_o)
            tries += 1
        if not unhindered(cache[hi_o][0], lab, tolerance_s, setup):
            mins[lab] = math.nan
            continue
        keys = sorted(k for k in cache if k >= d0 - 1e-9)
        # smallest offset from which every probed offset above is unhindered
        hi = keys[-1]
        for k in reversed(keys):
            if unhindered(cache[k][0], lab, tolerance_s, setup):
                hi = k
            else:
                break
        lower = [k for k in keys if k < hi]
        if not lower:
            mins[lab] = hi
            continue
        lo = lower[-1]
        while hi - lo > resolution_s:
            mid = round(0.5 * (lo + hi), 2)
            if unhindered(probe(mid), lab, tolerance_s, setup):
                hi = mid
            else:
                lo = mid
        mins[lab] = hi
    # analysis runs with full outputs: simultaneous arrival and the minimum offsets
    runs: dict[str, RunResult] = {}
    analysis = {"simultaneous": grid[0]}
    for lab, v in mins.items():
        if not math.isnan(v) and lab != "junction":  # the junction's own offset: its probe is enough
            analysis[f"{lab}_min"] = v
    done: dict[float, RunResult] = {}
    for name, off in analysis.items():
        if off not in done:
            count[0] += 1
            done[off] = simulate_pair(setup, case, off, solo_times, out / f"{name}_o{off:07.2f}", dt, seed, full=True, link_warmup=link_warmup)
            (done[off].folder / "fcd.xml").unlink(missing_ok=True)  # its content is in trajectories.csv; keeps the folder small
        runs[name] = done[off]
    shutil.rmtree(out / "probes", ignore_errors=True)
    sim = runs["simultaneous"]
    m0 = run_metrics(setup, case, sim, solo, links, window_m)
    row = {
        "line": setup.line.name, "junction": setup.junction.id, "junction_name": setup.junction.junction_name or setup.junction.name,
        "direction": setup.direction, "merge_junction": setup.merge.id if setup.merge else "", "merge_km": setup.merge.junction_km if setup.merge else math.nan,
        "split_junction": setup.split.id if setup.split else "", "split_km": setup.split.junction_km if setup.split else math.nan,
        "leader_service": leader, "follower_service": follower, "regime": case.regime, "controller": case.controller or "",
        "junction_signal": case.variant or "", "train": setup.stock.name,
        "leader_speed_at_junction_mps": round(speed_at_trace(solo[leader], leader, setup.s_key(leader)), 2),
        "follower_speed_at_junction_mps": round(speed_at_trace(solo[follower], follower, setup.s_key(follower)), 2),
    }
    row["junction_kind"] = "merge" if (setup.merge is not None and setup.merge.id == setup.junction.id) else "split"
    first, second = actual_order(setup, sim, leader)
    row.update(formation(setup, sim, solo, first, second))
    fc = sim.driver_counts.get("first_command", {}).get(follower) if sim.driver_counts else None
    row["vc_control_start_m_before_merge"] = round(setup.s_merge[follower] - fc[1], 1) if (fc and setup.merge is not None) else math.nan
    for lab, col in (("merge", "merge"), ("split", "split")):
        v = mins.get(lab, math.nan)
        row[f"{col}_min_offset_s"] = round(v, 2) if not math.isnan(v) else math.nan
        h = math.nan
        if f"{lab}_min" in runs:
            p = runs[f"{lab}_min"].passages.get("M" if lab == "merge" else "S", {})
            if leader in p and follower in p:
                h = p[follower] - p[leader]
        row[f"{col}_headway_s"] = round(h, 2) if not math.isnan(h) else math.nan
        row[f"{col}_throughput_trains_per_h"] = round(3600.0 / h, 1) if h and not math.isnan(h) and h > 0 else math.nan
    # the merge junction alone: the headway of the fronts at the junction node at the smallest offset
    # from which both pass the junction unhindered; what the follower loses after it, forming up
    # behind its leader on the trunk, is reported apart (merge_trunk_lost_s)
    v = mins.get("junction", math.nan)
    row["merge_junction_min_offset_s"] = round(v, 2) if not math.isnan(v) else math.nan
    h = trunk = math.nan
    if not math.isnan(v):
        m_j, rr_j = cache[round(v, 2)]
        p = rr_j.passages.get("M", {})
        if leader in p and follower in p:
            h = p[follower] - p[leader]
        trunk = m_j["follower_lost_PM_s"] - m_j["follower_lost_M_s"]
    row["merge_junction_headway_s"] = round(h, 2) if not math.isnan(h) else math.nan
    row["merge_junction_throughput_trains_per_h"] = round(3600.0 / h, 1) if not math.isnan(h) and h > 0 else math.nan
    row["merge_trunk_lost_s"] = round(trunk, 2) if math.isfinite(trunk) else math.nan
    kind = row["junction_kind"]
    row["junction_throughput_trains_per_h"] = row["merge_junction_throughput_trains_per_h" if kind == "merge" else "split_throughput_trains_per_h"]
    if setup.split is None:
        row["split_is_bottleneck"] = None
    elif setup.merge is None:
        row["split_is_bottleneck"] = True
    else:
        a, b = row["split_min_offset_s"], row["merge_min_offset_s"]
        row["split_is_bottleneck"] = bool(a > b + resolution_s) if not (math.isnan(a) or math.isnan(b)) else None
    row["first_through_junction"] = first
    row["merging_service_delay_s"] = _r(m0["merging_service_delay_s"])
    row["merging_service_delay_end_s"] = _r(m0["merging_service_delay_end_s"])
    row["first_service_delay_end_s"] = _r(m0["first_service_delay_end_s"])
    row["order_kept"] = m0["order_kept"]
    for k in ("min_gap_merge_m", "min_gap_split_m", "gap_violations_merge", "gap_violations_split", "gap_violations", "collisions", "sumo_emergency_brakes",
              "sumo_emergency_warnings", "red_signal_stops", "merge_red_max_required_decel_mps2", "merge_red_inside_braking_s",
              "split_red_max_required_decel_mps2", "split_red_inside_braking_s", "vc_guard_interventions", "vc_emergency_activations",
              "vc_supervisor_interventions", "junction_signal_caps", "junction_signal_overruns", "speed_profile_caps", "max_overspeed_mps"):
        row[k] = m0.get(k)
    row.update(case_health([rr.summary for _, rr in cache.values()] + [rr.summary for rr in done.values()]))
    row["simulations"] = count[0]
    row["wall_time_s"] = round(time.perf_counter() - t_wall, 1)
    sweep = []
    for off in sorted(cache):
        m, _ = cache[off]
        r = {"line": setup.line.name, "junction": setup.junction.id, "direction": setup.direction, "leader_service": leader, "regime": case.regime,
             "controller": case.controller or "", "junction_signal": case.variant or ""}
        r.update({k: (_r(v) if isinstance(v, float) else v) for k, v in m.items()})
        r["healthy"] = bool(cache[off][1].summary["healthy"])
        r["min_margin_m"] = cache[off][1].summary["min_margin_m"]
        r["unhindered_junction"] = unhindered(m, "junction", tolerance_s, setup) if setup.merge is not None else None
        r["unhindered_merge"] = unhindered(m, "merge", tolerance_s, setup) if setup.merge is not None else None
        r["unhindered_split"] = unhindered(m, "split", tolerance_s, setup) if setup.split is not None else None
        sweep.append(r)
    return CaseOutcome(row, sweep, runs)


def _r(x, nd: int = 2):
    if x is None:
        return math.nan
    if isinstance(x, float) and (math.isinf(x) or math.isnan(x)):
        return x
    return round(float(x), nd)


# -------------------------------------------------------------------------------------------
# The study


def cases_for(junctions: list[str], line: Line, directions: tuple[str, ...], firsts: tuple[str, ...], controllers: list[str], variants: tuple[str, ...]) -> list[Case]:
    out = []
    for j in junctions:
        for d in directions:
            for f in firsts:
                out.append(Case(j, d, f, "fbs"))
                out.append(Case(j, d, f, "mb"))
                for c in controllers:
                    for v in variants:
                        out.append(Case(j, d, f, "vc", c, v))
    return out


def run_junction_study(
    line: Line, net: BuiltNetwork, stock: RollingStock, out: Path, controllers: list[str] | None = None, junctions: list[str] | str | None = None,
    directions: tuple[str, ...] = ("up", "down"), firsts: tuple[str, ...] = ("main", "branch"), variants: tuple[str, ...] = ("braking-curve",),
    offsets_s: tuple[float, ...] = DEFAULT_OFFSETS_S, tolerance_s: float = 2.0, resolution_s: float = 1.0, window_m: float = 5000.0,
    approach_m: float = 12000.0, post_m: float = 20000.0, step_s: float = 0.5, vc_step_s: float = 0.2, seed: int = 42,
    link_warmup: bool = True, progress: Callable[[int, int, str], None] | None = None, assumptions: AssumptionSet | None = None,
) -> pd.DataFrame:
    """Every junction × direction × leader service × regime (× VC controller × variant), under the
    separation model's set ``assumptions`` (None: the shipped default).

    Writes ``junction.csv``, ``junction_sweep.csv``, ``junction_trajectories.csv``,
    ``junction_signals.csv``, ``junction_<regime>.png`` and ``junction_sweep.png`` into ``out``.
    """
    controllers = ["cbc", "cbf-cbc"] if controllers is None else list(controllers)
    for c in controllers:
        parse_controller(c)
    for d in directions:
        if d not in ("up", "down"):
            raise InputError(None, "--directions", f"unknown direction '{d}' (choose up, down)")
    for f in firsts:
        if f not in ROLES:
            raise InputError(None, "--first", f"unknown service '{f}' (choose main, branch)")
    for v in variants:
        if v not in SIGNAL_VARIANTS:
            raise InputError(None, "--junction-signal", f"unknown variant '{v}' (choose {', '.join(SIGNAL_VARIANTS)})")
    if not offsets_s or any(o < 0 for o in offsets_s):
        raise InputError(None, "--offsets", "offsets must be a non-empty list of times ≥ 0 s")
    if tolerance_s <= 0 or resolution_s <= 0 or window_m <= 0 or approach_m <= 0 or post_m <= 0:
        raise InputError(None, "--tolerance-s/--resolution-s/--window-m/--approach-m/--post-m", "must be positive")
    jids = resolve_junctions(line, junctions)
    if line.data.tracks == "single":
        raise InputError(line.path, "tracks", "the junction study needs a double-track line (merging and splitting trains run in one direction)")
    out.mkdir(parents=True, exist_ok=True)
    cases = cases_for(jids, line, directions, firsts, controllers, variants)
    setups: dict[tuple[str, str], Setup] = {}
    solos: dict[tuple[str, str, str, float], dict[str, RunResult]] = {}
    rows, sweep, traj, sigs = [], [], [], []
    links_cache: dict[tuple[str, str], dict] = {}
    for k, case in enumerate(cases):
        if progress:
            progress(k, len(cases), f"{case.junction} {case.direction} {case.first}-first {case.label}")
        skey = (case.junction, case.direction)
        if skey not in setups:
            setups[skey] = build_setup(line, net, stock, case.junction, case.direction, approach_m, post_m, assumptions=assumptions)
            setups[skey].window_m = window_m
            links_cache[skey] = signal_links(setups[skey])
        setup = setups[skey]
        links = links_cache[skey]
        dt = vc_step_s if case.regime == "vc" else step_s
        solo_regime = "mb" if case.regime == "vc" else case.regime
        okey = (case.junction, case.direction, solo_regime, dt)
        base = out / "runs" / f"{case.junction}_{case.direction}"
        if okey not in solos:
            solos[okey] = solo_runs(setup, solo_regime, dt, base / f"solo_{solo_regime}_dt{dt:g}", seed)
            for r, rr in solos[okey].items():
                c_solo = Case(case.junction, case.direction, r, solo_regime)
                t = trajectory_rows(setup, c_solo, "solo", rr)
                if not t.empty:
                    t["step_s"] = dt
                    traj.append(t)
        solo = solos[okey]
        res = run_case(setup, case, solo, base / case.slug, dt, list(offsets_s), tolerance_s, resolution_s, window_m, seed, links, link_warmup)
        rows.append(res.row)
        sweep += res.sweep
        for name, rr in res.runs.items():
            t = trajectory_rows(setup, case, name, rr)
            if not t.empty:
                t["step_s"] = dt
                traj.append(t)
            s = signal_rows(setup, case, name, rr, links)
            if not s.empty:
                sigs.append(s)
    if progress:
        progress(len(cases), len(cases), "plots")
    df = pd.DataFrame(rows, columns=JUNCTION_COLUMNS)
    df.to_csv(out / "junction.csv", index=False)
    pd.DataFrame(sweep).to_csv(out / "junction_sweep.csv", index=False)
    tdf = pd.concat(traj, ignore_index=True) if traj else pd.DataFrame()
    tdf.to_csv(out / "junction_trajectories.csv", index=False)
    (pd.concat(sigs, ignore_index=True) if sigs else pd.DataFrame()).to_csv(out / "junction_signals.csv", index=False)
    plot_junction_regimes(out / "junction_trajectories.csv", out)
    plot_junction_sweep(out / "junction_sweep.csv", out / "junction_sweep.png")
    return df
