"""The tables of a run: stop events, the per-train summary and the run summary from the loop's
records and SUMO's own outputs (:func:`collect_results`), and :class:`SimulationResult`."""

from __future__ import annotations

import math
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from vcsumo.errors import SumoError
from vcsumo.results import read_results_csv, write_csv
from vcsumo.sim.health import SUMO_BRAKING_COLUMNS, HealthMonitor
from vcsumo.sim.sumo_io import read_sumo_log

TRAJECTORY_COLUMNS = ["time_s", "train", "section", "km", "s_m", "speed_mps", "accel_mps2", "gap_m", "leader", "edge"]
"""Columns of trajectories.csv (one row per running train and record period)."""
TRAJECTORY_FLOATS = ["time_s", "km", "s_m", "speed_mps", "accel_mps2", "gap_m"]
DWELL_TOLERANCE_S = 0.5
"""A stop ended more than this before the train's own minimum dwell was served is a short dwell, s
(SUMO ends a stop at a step: up to one step early against the minimum)."""
STOP_PASSED_M = 10.0
"""A front more than this beyond a stop's position has passed the stop (an unserved stop it passed is
skipped; one still ahead of a train that had not arrived when the run ended was not reached), m."""


HEALTH_COUNTERS = ("stops_skipped", "short_dwells", "overspeed_events", "beyond_service_brakings", "authority_overruns", "sumo_emergency_stops",
                   "collisions", "gap_violations", "teleports", "sumo_stop_warnings", "sumo_emergency_brakings")
"""The counters of a run summary that must all be 0 for it to be healthy (with every train arrived);
every study row that carries a run's health carries each of them."""


@dataclass
class SimulationResult:
    trajectories_file: Path | None
    """trajectories.csv as written during the run (None: not written, Scenario.full_outputs off)."""
    passages: pd.DataFrame
    stop_events: pd.DataFrame
    trains: pd.DataFrame
    summary: dict
    speed_traces: dict[str, tuple[list[float], list[float]]] = field(default_factory=dict)
    """train -> (route positions m, speeds m/s) at every step, when Scenario.trace_speeds."""
    _trajectories: pd.DataFrame | None = field(default=None, repr=False)

    @property
    def trajectories(self) -> pd.DataFrame:
        """Every train's state once per record period (read from trajectories.csv when first asked
        for: the loop streams it to disk; empty when it was not written)."""
        if self._trajectories is None:
            if self.trajectories_file is not None and self.trajectories_file.is_file():
                self._trajectories = read_results_csv(self.trajectories_file)
            else:
                self._trajectories = pd.DataFrame(columns=TRAJECTORY_COLUMNS)
        return self._trajectories



def parse_xml_rows(path: Path, tag: str) -> list[dict]:
    if not path.is_file():
        return []
    try:
        return [el.attrib for el in ET.parse(path).getroot().iter(tag)]
    except ET.ParseError as exc:
        raise SumoError(f"{path}: SUMO output is not valid XML ({exc})") from None


def stop_counts(stops: list, served, arrived: bool, front_m: float) -> dict:
    """A train's scheduled stops (:class:`~vcsumo.timetable.PlannedStop`, the final one included) as
    ``stops_scheduled``, ``stops_served`` (``served(platform)``), ``stops_skipped`` (not served, and
    passed: the train arrived, or its front at the end of the run ``front_m`` lay more than
    :data:`STOP_PASSED_M` beyond the stop) and ``stops_not_reached`` (not served and still ahead of a
    train that had not arrived when the run ended — e.g. cut short by ``--end-time``; ``front_m`` NaN:
    it never departed), counts."""
    unserved = [x for x in stops if not served(x.platform)]
    passed = [x for x in unserved if arrived or (math.isfinite(front_m) and front_m > x.s_m + STOP_PASSED_M)]
    return {"stops_scheduled": len(stops), "stops_served": len(stops) - len(unserved), "stops_skipped": len(passed),
            "stops_not_reached": len(unserved) - len(passed)}


def collect_results(scn, out: Path, state: dict, health: HealthMonitor, traj_file: Path | None, pass_rows: list[tuple], collisions: list, teleports: list,
                    sim_end: float, wall: float, extra: dict | None = None) -> SimulationResult:
    """The run's tables from the loop's records and SUMO's outputs in ``out``: stop events
    (stops.xml), the per-train summary (tripinfo.xml, the health counters, ``state``: per train
    ``min_gap``, ``departed_at``, ``emergencies``), passages; writes passages.csv,
    stop_events.csv and summary.csv; the summary dict (with ``extra``) is the caller's to write."""
    t_io = time.perf_counter()
    passages = pd.DataFrame(pass_rows, columns=["measuring_point", "train", "time_s", "speed_mps"])
    # stop events from SUMO's stop output
    plat_station = {p.id: p.station_id for p in scn.network.topology.platforms.values()}
    plat_of_lane = {f"{p.edge}_0": p.id for p in scn.network.topology.platforms.values()}
    sched = {(t.id, s.platform): s for t in scn.trains for s in t.stops}
    stop_rows = []
    for r in parse_xml_rows(out / "stops.xml", "stopinfo"):
        tid = r.get("id")
        plat = r.get("busStop") or r.get("trainStop") or plat_of_lane.get(r.get("lane", ""), "")
        if not plat:
            continue  # a stop at the end of a route, not at a platform
        s = sched.get((tid, plat))
        arr, dep = float(r.get("started", "nan")), float(r.get("ended", "nan"))
        stop_rows.append({
            "train": tid, "station": plat_station.get(plat, plat), "platform": plat, "arrival_s": arr, "departure_s": dep,
            "dwell_s": dep - arr, "scheduled_arrival_s": s.arrival_s if s else None, "scheduled_departure_s": s.departure_s if s else None,
            "arrival_delay_s": (arr - s.arrival_s) if s and s.arrival_s is not None else None,
            "departure_delay_s": (dep - s.departure_s) if s and s.departure_s is not None else None,
        })
    stops = pd.DataFrame(stop_rows, columns=["train", "station", "platform", "arrival_s", "departure_s", "dwell_s", "scheduled_arrival_s", "scheduled_departure_s", "arrival_delay_s", "departure_delay_s"])
    trip = {r["id"]: r for r in parse_xml_rows(out / "tripinfo.xml", "tripinfo")}
    scheduled = {t.id: list(t.stops) + ([t.final_stop] if t.final_stop is not None else []) for t in scn.trains}
    served = stops.groupby(["train", "platform"]).size().to_dict() if len(stops) else {}
    # a stop (not the last) that ended before the train's own minimum dwell was served: its passengers were not
    dwell_min = {(t.id, s.platform): s.dwell_s for t in scn.trains for s in t.stops}
    short: dict[str, int] = {}
    for r in stop_rows:
        need = dwell_min.get((r["train"], r["platform"]))
        if need is not None and r["dwell_s"] < need - DWELL_TOLERANCE_S:
            short[r["train"]] = short.get(r["train"], 0) + 1
    warnings = read_sumo_log(out / "sumo_errors.log")
    braking = health.judge_sumo_emergency_brakings(warnings, scn.step_length_s)  # each SUMO emergency braking: real or grade-assisted
    rows = []
    for t in scn.trains:
        tr = state.get(t.id)
        ti = trip.get(t.id, {})
        arrival = float(ti["arrival"]) if ti.get("arrival") not in (None, "-1", "-1.00") else math.nan
        if ti and not math.isnan(arrival) and t.final_stop is not None:
            # the train arrives at the platform when it stops there (SUMO removes it after the 1 s stop)
            st = stops[(stops.train == t.id) & (stops.platform == t.final_stop.platform)]
            if len(st):
                arrival = float(st.arrival_s.iloc[0])
        rows.append({
            "train": t.id, "service": t.service, "rolling_stock": t.stock.name, "direction": t.direction,
            "scheduled_departure_s": t.depart_s, "departure_s": float(ti["depart"]) if ti else (tr.departed_at if tr else math.nan),
            "departure_delay_s": float(ti["departDelay"]) if ti else math.nan, "arrival_s": arrival,
            "scheduled_arrival_s": t.scheduled_arrival_s,
            "arrival_delay_s": (arrival - t.scheduled_arrival_s) if t.scheduled_arrival_s is not None and not math.isnan(arrival) else None,
            "running_time_s": (arrival - float(ti["depart"])) if ti and not math.isnan(arrival) else math.nan,
            "route_length_m": float(ti["routeLength"]) if ti else math.nan,
            "time_loss_s": float(ti["timeLoss"]) if ti else math.nan,
            "min_gap_m": (tr.min_gap if tr and not math.isinf(tr.min_gap) else None),
            **stop_counts(scheduled[t.id], lambda pl, tid=t.id: served.get((tid, pl), 0) > 0, bool(ti) and not math.isnan(arrival), tr.s if tr else math.nan),
            "short_dwells": short.get(t.id, 0),
            **health.train_row(t.id),
            "gap_violations": health.trains[t.id].separation_violations,
            "emergency_brakes": tr.emergencies if tr else 0,
            "arrived": bool(ti) and not math.isnan(arrival),
        })
    trains_df = pd.DataFrame(rows)
    gaps = [tr.min_gap for tr in state.values() if not math.isinf(tr.min_gap)]
    margins = trains_df["min_margin_m"].dropna()
    summary = {
        "line": scn.line.name, "regime": scn.regime, "step_length_s": scn.step_length_s, "seed": scn.seed,
        "trains": len(scn.trains), "trains_arrived": int(trains_df["arrived"].sum()),
        "min_gap_m": min(gaps) if gaps else None,
        "min_margin_m": float(margins.min()) if len(margins) else None,
        "gap_violations": int(trains_df["gap_violations"].sum()),
        "below_separation_time_s": round(float(trains_df["below_separation_time_s"].sum()), 2),
        "collisions": len(collisions), "max_impact_kmh": float(trains_df["max_impact_kmh"].max()) if len(trains_df) else 0.0,
        "stops_scheduled": int(trains_df["stops_scheduled"].sum()), "stops_served": int(trains_df["stops_served"].sum()),
        "stops_skipped": int(trains_df["stops_skipped"].sum()), "stops_not_reached": int(trains_df["stops_not_reached"].sum()),
        "short_dwells": int(trains_df["short_dwells"].sum()),
        "overspeed_events": int(trains_df["overspeed_events"].sum()), "overspeed_max_kmh": float(trains_df["overspeed_max_kmh"].max()) if len(trains_df) else 0.0,
        "beyond_service_brakings": int(trains_df["beyond_service_brakings"].sum()),
        "max_decel_mps2": float(trains_df["max_decel_mps2"].max()) if len(trains_df) else 0.0,
        "authority_overruns": int(trains_df["authority_overruns"].sum()),
        "sumo_emergency_stops": warnings.emergency_stops, "sumo_stop_warnings": warnings.stop_warnings,
        "sumo_emergency_brakings": braking.real, "sumo_emergency_warnings": braking.warnings,
        "sumo_emergency_warnings_explained": braking.explained, "sumo_collision_warnings": warnings.collisions,
        "emergency_brakes": int(trains_df["emergency_brakes"].sum()), "teleports": len(teleports),
        "simulated_until_s": sim_end, **(extra or {}),
    }
    summary["healthy"] = bool(summary["trains_arrived"] == summary["trains"] and all(summary[k] == 0 for k in HEALTH_COUNTERS))
    passages.to_csv(out / "passages.csv", index=False)
    if braking.rows:
        write_csv(pd.DataFrame(braking.rows, columns=SUMO_BRAKING_COLUMNS), out / "sumo_emergency_brakings.csv")
    write_csv(stops, out / "stop_events.csv")
    write_csv(trains_df, out / "summary.csv")
    io = time.perf_counter() - t_io
    summary["io_time_s"] = round(io, 3)
    summary["wall_time_s"] = round(wall + io, 3)
    return SimulationResult(traj_file, passages, stops, trains_df, summary)
