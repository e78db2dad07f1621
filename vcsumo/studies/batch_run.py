"""One run of a batch: plan the timetable, inject the seeded primary delays, simulate it in SUMO under
one regime (and controller), and reduce it to one row of ``batch.csv`` and its trains' rows of
``batch_trains.csv`` (:mod:`vcsumo.studies.batch` plans, runs and reports the whole batch).

Metrics of a run (``BATCH_COLUMNS``; times in s):

* arrival delay of a train = actual arrival at its destination − its *reference arrival*: the
  scheduled arrival, or, for a train without one, its scheduled departure + its unhindered
  running time (:func:`vcsumo.signalling.scheduled_run.reference_arrivals`: unhindered run on the
  supervision's guaranteed braking curves, as SUMO's trains run, scheduled stops honoured);
* ``punctuality_3min_share`` / ``punctuality_5min_share``: share of the run's trains that arrived
  with an arrival delay ≤ 180 s / 300 s (trains that never arrived count as late);
* ``mean_arrival_delay_s``, ``max_arrival_delay_s``: over the trains that arrived (signed: early
  arrivals are negative);
* ``primary_delay_s``: sum of the injected delays; ``knock_on_delay_s``: sum over arrived trains
  of max(0, arrival delay − the primary delay the train carried), the secondary delay;
* ``capacity_consumption_pct``: UIC 406 consumption of the timetable (no delays) under the run's
  regime, maximum over the line sections (:mod:`vcsumo.signalling.uic406`; ``..._cyclic_pct`` with the cycle
  closed);
* ``min_gap_m``, ``gap_violations``, ``collisions``, ``emergency_brakes``: from the simulation;
* the run's health (:mod:`vcsumo.sim.health`): ``healthy`` (every train arrived, every stop served,
  no overspeed, overrun, collision, braking beyond service or gap below the safe separation),
  ``min_margin_m`` (smallest gap minus the safe separation), ``stops_skipped``, ``overspeed_events``,
  ``beyond_service_brakings``, ``authority_overruns``.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from vcsumo.delays import DelayConfig, inject_delays
from vcsumo.engine.campaign import error_message
from vcsumo.errors import InputError
from vcsumo.network_file import load_line_or_network
from vcsumo.results import ResultsFolder, file_digest

BATCH_COLUMNS = [
    "timetable", "regime", "controller", "seed", "status", "error", "trains", "trains_arrived",
    "punctuality_3min_share", "punctuality_5min_share", "mean_arrival_delay_s", "max_arrival_delay_s",
    "primary_delay_s", "knock_on_delay_s", "capacity_consumption_pct", "capacity_consumption_cyclic_pct",
    "min_gap_m", "gap_violations", "collisions", "emergency_brakes",
    "healthy", "min_margin_m", "stops_skipped", "short_dwells", "overspeed_events", "beyond_service_brakings", "authority_overruns",
    "sumo_emergency_stops", "sumo_emergency_brakings", "sumo_stop_warnings", "teleports", "wall_time_s",
    "line", "timetable_sha256", "delay_config_sha256", "run_key", "run_dir",
]
TRAIN_COLUMNS = [
    "run_key", "timetable", "regime", "controller", "seed", "train", "service", "direction",
    "scheduled_departure_s", "departure_s", "reference_arrival_s", "arrival_s", "arrived", "arrival_delay_s",
    "origin_delay_s", "dwell_extension_s", "primary_delay_s", "knock_on_delay_s",
]
PUNCTUALITY_THRESHOLDS_S = (180.0, 300.0)
DEFAULT_CONTROLLER = "cbf-cbc"

_SUMO_LOCK = threading.Lock()
"""libsumo is one simulation per process: runs in threads of one process (a Dask worker with
several threads) take turns."""


# ---------------------------------------------------------------------------------------------
# Runs


@dataclass(frozen=True)
class RunSpec:
    """One run of a batch (picklable: sent to worker processes and Dask workers)."""

    line_path: str
    block_length_m: float | None
    timetable_path: str
    timetable: str
    timetable_sha256: str
    regime: str
    controller: str
    """VC controller; '' for fbs and mb."""
    seed: int
    delays: dict
    """The DelayConfig as a plain dict."""
    delay_config_sha256: str
    step_length_s: float
    run_dir: str
    key: str
    line: str
    command: str = ""
    assumptions: dict | None = None
    """The separation model's assumption set every run of the batch is supervised and judged with
    (:meth:`AssumptionSet.record`; None: the shipped default)."""
    assumptions_sha256: str = ""
    """Its digest (:func:`assumptions_digest`), part of the run's key."""

    def assumption_set(self):
        """The run's :class:`~vcsumo.signalling.assumptions.AssumptionSet`."""
        from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions

        return load_assumptions() if self.assumptions is None else AssumptionSet.model_validate(self.assumptions)

    @property
    def label(self) -> str:
        ctrl = f"/{self.controller}" if self.controller else ""
        return f"{self.timetable} {self.regime}{ctrl} seed {self.seed}"


def run_key(timetable_sha256: str, regime: str, controller: str, seed: int, delay_sha256: str, line_sha256: str,
            step_length_s: float, block_length_m: float | None, assumptions_sha256: str = "") -> str:
    """The resume key of a run (16 hex digits)."""
    text = f"{timetable_sha256}|{regime}|{controller}|{int(seed)}|{delay_sha256}|{line_sha256}|{step_length_s:g}|{block_length_m}|{assumptions_sha256}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def assumptions_digest(record: dict) -> str:
    """SHA-256 of an assumption set's record (every value, not only its name), 16 hex digits."""
    return hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()[:16]


def _one_line(msg: str) -> str:
    return " ".join(str(msg).split())


def _base_row(spec: RunSpec) -> dict:
    row = {c: None for c in BATCH_COLUMNS}
    row.update(timetable=spec.timetable, regime=spec.regime, controller=spec.controller, seed=spec.seed, line=spec.line,
               timetable_sha256=spec.timetable_sha256, delay_config_sha256=spec.delay_config_sha256, run_key=spec.key,
               run_dir=os.path.relpath(spec.run_dir, Path(spec.run_dir).parent.parent))
    return row


def failed_outcome(spec: RunSpec, error: str, wall_time_s: float = 0.0) -> dict:
    """The outcome of a run that did not complete."""
    row = _base_row(spec)
    row.update(status="failed", error=_one_line(error), wall_time_s=round(wall_time_s, 3))
    return {"row": row, "trains": []}


def run_one(spec: RunSpec) -> dict:
    """Run one batch run; never raises: a failure is an outcome with status 'failed'.

    Returns ``{"row": <batch.csv row>, "trains": [<batch_trains.csv rows>]}``.
    """
    t0 = time.perf_counter()
    try:
        with _SUMO_LOCK:
            out = _run(spec)
        out["row"]["wall_time_s"] = round(time.perf_counter() - t0, 3)
        return out
    except BaseException as exc:  # noqa: BLE001 - a batch never stops for one run
        if isinstance(exc, KeyboardInterrupt):
            raise
        return failed_outcome(spec, error_message(exc), time.perf_counter() - t0)


def _run(spec: RunSpec) -> dict:
    from vcsumo.sim.network import build_network
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.timetable import load_timetable, plan_trains
    from vcsumo.signalling.scheduled_run import reference_arrivals
    from vcsumo.signalling.separation import SeparationModel

    line = load_line_or_network(spec.line_path)
    tt_path = Path(spec.timetable_path)
    if not tt_path.is_file():
        raise InputError(tt_path, None, "timetable file not found")
    if file_digest(tt_path) != spec.timetable_sha256:
        raise InputError(tt_path, None, "timetable file changed since the batch started")
    tt, tt_path = load_timetable(tt_path, line)
    net = build_network(line, spec.block_length_m)
    planned = plan_trains(tt, tt_path, line, net.topology, dt=spec.step_length_s)
    cfg = DelayConfig.model_validate(spec.delays)
    trains, delays = inject_delays(planned, cfg, spec.seed, spec.timetable_sha256)
    aset = spec.assumption_set()
    driver = None
    if spec.regime == "vc":
        from vcsumo.sim.vc_driver import make_vc_driver

        driver = make_vc_driver(tt, tt_path, trains, spec.controller or DEFAULT_CONTROLLER, spec.step_length_s, spec.seed, assumptions=aset)
    # measured against the train's own supervised run (every train SUMO drives brakes on its guaranteed curves)
    ref = reference_arrivals(planned, spec.step_length_s, SeparationModel(aset))
    params = {"regime": spec.regime, "controller": spec.controller or None, "step_length_s": spec.step_length_s,
              "block_length_m": spec.block_length_m, "delays": spec.delays, "delay_config_sha256": spec.delay_config_sha256,
              "run_key": spec.key, "batch_command": spec.command, "assumptions": aset.record()}
    with ResultsFolder(Path(spec.run_dir), inputs={**line.input_files(), "timetable": tt_path}, seed=spec.seed, params=params, overwrite=True) as rf:
        scn = Scenario(line, net, trains, spec.regime, step_length_s=spec.step_length_s, seed=spec.seed, driver=driver, full_outputs=False,
                       assumptions=aset)
        res = simulate(scn, rf.path)
        if driver is not None:
            driver.write_report(rf.path)
            res.summary.update(driver.summary())
            (rf.path / "summary.json").write_text(json.dumps(res.summary, indent=2, default=str))
        pd.DataFrame([{"train": d.train, "origin_delay_s": d.origin_s, "dwell_extensions_s": " ".join(f"{x:g}" for x in d.dwell_s),
                       "primary_delay_s": round(d.total_s, 1)} for d in delays.values()]).to_csv(rf.path / "delays.csv", index=False)
        row, train_rows = _metrics(spec, planned, delays, ref, res)
        pd.DataFrame(train_rows, columns=TRAIN_COLUMNS).to_csv(rf.path / "trains.csv", index=False)
    return {"row": row, "trains": train_rows}


def _metrics(spec: RunSpec, planned, delays, ref: dict[str, float], res) -> tuple[dict, list[dict]]:
    sim = res.trains.set_index("train")
    train_rows = []
    for t in planned:
        d = delays[t.id]
        r = sim.loc[t.id] if t.id in sim.index else None
        arrived = bool(r is not None and bool(r["arrived"]))
        arrival = float(r["arrival_s"]) if arrived else math.nan
        delay = arrival - ref[t.id] if arrived else math.nan
        primary = d.total_s
        train_rows.append({
            "run_key": spec.key, "timetable": spec.timetable, "regime": spec.regime, "controller": spec.controller, "seed": spec.seed,
            "train": t.id, "service": t.service, "direction": t.direction, "scheduled_departure_s": t.depart_s,
            "departure_s": float(r["departure_s"]) if r is not None and r["departure_s"] == r["departure_s"] else math.nan,
            "reference_arrival_s": round(ref[t.id], 2), "arrival_s": arrival, "arrived": arrived,
            "arrival_delay_s": round(delay, 2) if arrived else math.nan, "origin_delay_s": d.origin_s,
            "dwell_extension_s": round(sum(d.dwell_s), 1), "primary_delay_s": round(primary, 1),
            "knock_on_delay_s": round(max(0.0, delay - primary), 2) if arrived else math.nan,
        })
    tr = pd.DataFrame(train_rows)
    arr = tr[tr["arrived"]]
    n = len(tr)
    s = res.summary
    row = _base_row(spec)
    row.update(
        status="ok", error="", trains=n, trains_arrived=int(len(arr)),
        punctuality_3min_share=round(float((arr["arrival_delay_s"] <= PUNCTUALITY_THRESHOLDS_S[0]).sum()) / n, 4) if n else math.nan,
        punctuality_5min_share=round(float((arr["arrival_delay_s"] <= PUNCTUALITY_THRESHOLDS_S[1]).sum()) / n, 4) if n else math.nan,
        mean_arrival_delay_s=round(float(arr["arrival_delay_s"].mean()), 2) if len(arr) else math.nan,
        max_arrival_delay_s=round(float(arr["arrival_delay_s"].max()), 2) if len(arr) else math.nan,
        primary_delay_s=round(float(tr["primary_delay_s"].sum()), 1),
        knock_on_delay_s=round(float(arr["knock_on_delay_s"].sum()), 2),
        min_gap_m=round(float(s["min_gap_m"]), 3) if s.get("min_gap_m") is not None else math.nan,
        gap_violations=int(s["gap_violations"]), collisions=int(s["collisions"]), emergency_brakes=int(s["emergency_brakes"]),
        # the run's health (vcsumo.sim.health): a run that is not healthy is never a clean row
        healthy=bool(s["healthy"]), min_margin_m=s["min_margin_m"] if s.get("min_margin_m") is not None else math.nan,
        stops_skipped=int(s["stops_skipped"]), short_dwells=int(s.get("short_dwells", 0)), overspeed_events=int(s["overspeed_events"]),
        beyond_service_brakings=int(s["beyond_service_brakings"]), authority_overruns=int(s["authority_overruns"]),
        sumo_emergency_stops=int(s["sumo_emergency_stops"]), sumo_emergency_brakings=int(s["sumo_emergency_brakings"]),
        sumo_stop_warnings=int(s["sumo_stop_warnings"]), teleports=int(s["teleports"]),
    )
    return row, train_rows
