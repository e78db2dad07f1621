"""Batch timetable experiments: timetables × regimes × controllers × seeds with primary delays.

Every run plans a timetable, injects seeded primary delays (:mod:`vcsumo.delays`), runs it in
SUMO under one regime (and, for ``vc``, one controller) and reduces it to one row of
``batch.csv``; the trains of every run go to ``batch_trains.csv``.  Runs execute in parallel
processes (one SUMO per process: libsumo is a per-process singleton) or on a Dask cluster.

Results folder (``--out``)::

    batch.csv            one row per run (appended as each run finishes)
    batch_trains.csv     one row per train and run (written before the run's row)
    uic406.csv           UIC 406 capacity consumption per timetable, regime and line section
    runs/<run>/          each run's own results folder (summary.csv, stop_events.csv, delays.csv,
                         trains.csv, SUMO outputs, meta.json: inputs, versions, seed, wall time)
    report/              batch_summary.csv, batch_delays.png, batch_punctuality.png, meta.json
    workers.log          what SUMO printed in the local worker processes

Resuming: a run is identified by its key, the hash of (timetable file SHA-256, regime,
controller, seed, delay-configuration hash, line file SHA-256, step length, block length).  A
run whose key is already in ``batch.csv`` is not run again, so re-running the same command
continues an interrupted batch, and adding seeds or timetables only runs the new combinations.
The two CSV files are the folder's result store (:mod:`vcsumo.engine.store`): appended one whole
line at a time, every run exactly once, locked — a second batch into the same folder while one
runs stops at once with one error line.  Failed runs count as finished unless ``retry_failed``.
A run that fails (bad input, SUMO stopping on an error mid-run) is a row with status ``failed``
and its ``error``; its results folder is removed (never left half-written).  Runs execute through
:mod:`vcsumo.engine.campaign`: a worker process that dies during a run (SIGKILL, SUMO aborting
the process) fails only that run, after one more try alone (error :data:`WORKER_DIED`).

Metrics of a run (``BATCH_COLUMNS``; times in s):

* arrival delay of a train = actual arrival at its destination − its *reference arrival*: the
  scheduled arrival, or, for a train without one, its scheduled departure + its unhindered
  running time (:func:`vcsumo.signalling.scheduled_run.reference_arrivals`: unhindered run, scheduled stops
  honoured);
* ``punctuality_3min_share`` / ``punctuality_5min_share``: share of the run's trains that arrived
  with an arrival delay ≤ 180 s / 300 s (trains that never arrived count as late);
* ``mean_arrival_delay_s``, ``max_arrival_delay_s``: over the trains that arrived (signed: early
  arrivals are negative);
* ``primary_delay_s``: sum of the injected delays; ``knock_on_delay_s``: sum over arrived trains
  of max(0, arrival delay − the primary delay the train carried), the secondary delay;
* ``capacity_consumption_pct``: UIC 406 consumption of the timetable (no delays) under the run's
  regime, maximum over the line sections (:mod:`vcsumo.signalling.uic406`; ``..._cyclic_pct`` with the cycle
  closed);
* ``min_gap_m``, ``gap_violations``, ``collisions``, ``emergency_brakes``: from the simulation.
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
from typing import Callable, Iterable

import pandas as pd

from vcsumo.delays import DelayConfig, config_digest, inject_delays
from vcsumo.engine.campaign import WORKER_DIED, Outcome, Runner, Task, error_message, run_campaign  # noqa: F401 - WORKER_DIED re-exported
from vcsumo.engine.store import ResultStore, Table, atomic_csv, read_table
from vcsumo.errors import InputError, VcsumoError
from vcsumo.line import Line
from vcsumo.network_file import load_line_or_network
from vcsumo.results import ResultsFolder, file_digest

BATCH_COLUMNS = [
    "timetable", "regime", "controller", "seed", "status", "error", "trains", "trains_arrived",
    "punctuality_3min_share", "punctuality_5min_share", "mean_arrival_delay_s", "max_arrival_delay_s",
    "primary_delay_s", "knock_on_delay_s", "capacity_consumption_pct", "capacity_consumption_cyclic_pct",
    "min_gap_m", "gap_violations", "collisions", "emergency_brakes", "wall_time_s",
    "line", "timetable_sha256", "delay_config_sha256", "run_key", "run_dir",
]
TRAIN_COLUMNS = [
    "run_key", "timetable", "regime", "controller", "seed", "train", "service", "direction",
    "scheduled_departure_s", "departure_s", "reference_arrival_s", "arrival_s", "arrived", "arrival_delay_s",
    "origin_delay_s", "dwell_extension_s", "primary_delay_s", "knock_on_delay_s",
]
UIC_COLUMNS = ["timetable", "timetable_sha256", "regime", "step_length_s", "window_s", "direction", "section", "from_km", "to_km",
               "length_m", "blocks", "trains", "scheduled_span_s", "occupation_s", "consumption_pct", "cycle_s", "cyclic_consumption_pct"]
PUNCTUALITY_THRESHOLDS_S = (180.0, 300.0)
REGIMES = ("fbs", "mb", "vc")
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

    @property
    def label(self) -> str:
        ctrl = f"/{self.controller}" if self.controller else ""
        return f"{self.timetable} {self.regime}{ctrl} seed {self.seed}"


def run_key(timetable_sha256: str, regime: str, controller: str, seed: int, delay_sha256: str, line_sha256: str,
            step_length_s: float, block_length_m: float | None) -> str:
    """The resume key of a run (16 hex digits)."""
    text = f"{timetable_sha256}|{regime}|{controller}|{int(seed)}|{delay_sha256}|{line_sha256}|{step_length_s:g}|{block_length_m}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]


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
    driver = None
    if spec.regime == "vc":
        from vcsumo.sim.vc_driver import make_vc_driver

        driver = make_vc_driver(tt, tt_path, trains, spec.controller or DEFAULT_CONTROLLER, spec.step_length_s, spec.seed)
    ref = reference_arrivals(planned, spec.step_length_s)
    params = {"regime": spec.regime, "controller": spec.controller or None, "step_length_s": spec.step_length_s,
              "block_length_m": spec.block_length_m, "delays": spec.delays, "delay_config_sha256": spec.delay_config_sha256,
              "run_key": spec.key, "batch_command": spec.command}
    with ResultsFolder(Path(spec.run_dir), inputs={**line.input_files(), "timetable": tt_path}, seed=spec.seed, params=params, overwrite=True) as rf:
        scn = Scenario(line, net, trains, spec.regime, step_length_s=spec.step_length_s, seed=spec.seed, driver=driver, full_outputs=False)
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
    )
    return row, train_rows


# ---------------------------------------------------------------------------------------------
# Store (vcsumo.engine.store): batch.csv + batch_trains.csv, keyed by run_key


BATCH_TABLE = Table("batch.csv", tuple(BATCH_COLUMNS), "run_key", text=("controller", "error", "timetable"))
TRAINS_TABLE = Table("batch_trains.csv", tuple(TRAIN_COLUMNS), "run_key", identity=("train",))


def read_batch(out: Path) -> pd.DataFrame:
    """``batch.csv`` of a batch folder (one row per run key), typed; empty frame if none."""
    df = read_table(Path(out), BATCH_TABLE)
    df = df[df["status"].isin(["ok", "failed"])]
    return df.reset_index(drop=True)


# ---------------------------------------------------------------------------------------------
# Planning a batch


def resolve_timetables(spec: str | Iterable[str | Path] | None, line: Line) -> list[Path]:
    """Timetable files from names, paths or glob patterns (comma-separated); default: all of the line's."""
    import glob

    from vcsumo.line import project_root
    from vcsumo.timetable import resolve_timetable_path

    if spec is None or (isinstance(spec, str) and not spec.strip()):
        files = sorted((project_root() / "routes" / line.name).glob("*.yaml"))
        if not files:
            raise InputError(None, "--timetables", f"no timetables in routes/{line.name}/ (give names or paths)")
        return [f.resolve() for f in files]
    items = [x.strip() for x in spec.split(",")] if isinstance(spec, str) else [str(x) for x in spec]
    out: list[Path] = []
    for item in (x for x in items if x):
        if any(ch in item for ch in "*?["):
            hits = sorted(glob.glob(item)) or sorted(glob.glob(str(project_root() / item)))
            hits = [h for h in hits if h.endswith((".yaml", ".yml"))]
            if not hits:
                raise InputError(None, "--timetables", f"no timetable file matches '{item}'")
            out += [Path(h).resolve() for h in hits]
        else:
            try:
                out.append(Path(resolve_timetable_path(item, line)).resolve())
            except InputError as exc:
                if exc.field == "--timetable":
                    raise InputError(exc.path, "--timetables", exc.message) from None
                raise
    seen: set[Path] = set()
    return [p for p in out if not (p in seen or seen.add(p))]


def default_batch_out(line: Line, delay_sha256: str, step_length_s: float, block_length_m: float | None) -> Path:
    """``results/batch-<line>-<hash>``: the same for the same line and settings, so re-running resumes."""
    h = hashlib.sha256(f"{line.source_digest()}|{delay_sha256}|{step_length_s:g}|{block_length_m}".encode()).hexdigest()[:8]
    return Path("results") / f"batch-{line.name}-{h}"


def plan_runs(line: Line, timetables: list[Path], regimes: list[str], seeds: list[int], controllers: list[str], delays: DelayConfig,
              out: Path, step_length_s: float = 0.5, block_length_m: float | None = None, command: str = "") -> list[RunSpec]:
    """Every timetable × regime × controller (vc only) × seed, in that order."""
    from vcsumo.results import safe_component

    for r in regimes:
        if r not in REGIMES:
            raise InputError(None, "--regimes", f"unknown regime '{r}' (choose from {', '.join(REGIMES)})")
    if not seeds:
        raise InputError(None, "--seeds", "no seeds")
    d_sha = config_digest(delays)
    l_sha = line.source_digest()
    specs = []
    for tt in timetables:
        t_sha = file_digest(tt)
        for regime in regimes:
            for ctrl in (controllers or [DEFAULT_CONTROLLER]) if regime == "vc" else [""]:
                for seed in seeds:
                    key = run_key(t_sha, regime, ctrl, seed, d_sha, l_sha, step_length_s, block_length_m)
                    name = safe_component(f"{tt.stem}-{regime}{'-' + ctrl if ctrl else ''}-s{seed}-{key[:8]}")  # ctrl may hold a path
                    specs.append(RunSpec(
                        line_path=str(line.path), block_length_m=block_length_m, timetable_path=str(tt), timetable=tt.stem,
                        timetable_sha256=t_sha, regime=regime, controller=ctrl, seed=int(seed), delays=delays.model_dump(mode="json"),
                        delay_config_sha256=d_sha, step_length_s=step_length_s, run_dir=str((out / "runs" / name).resolve()), key=key,
                        line=line.name, command=command,
                    ))
    return specs


# ---------------------------------------------------------------------------------------------
# UIC 406 per timetable (cached in uic406.csv)


def _uic_table(out: Path, line: Line, specs: list[RunSpec], window_s: float, step_length_s: float, block_length_m: float | None) -> pd.DataFrame:
    path = out / "uic406.csv"
    have = pd.read_csv(path, dtype={"timetable_sha256": str, "timetable": str}) if path.is_file() else pd.DataFrame(columns=UIC_COLUMNS)
    if list(have.columns) != UIC_COLUMNS:
        have = pd.DataFrame(columns=UIC_COLUMNS)

    def cached(sha: str, regime: str) -> bool:
        m = (have["timetable_sha256"] == sha) & (have["regime"] == regime) & (have["window_s"] == window_s) & (have["step_length_s"] == step_length_s)
        return bool(m.any())

    need: dict[str, tuple[RunSpec, set[str]]] = {}
    for s in specs:
        if not cached(s.timetable_sha256, s.regime):
            need.setdefault(s.timetable_sha256, (s, set()))[1].add(s.regime)
    if not need:
        return have
    from vcsumo.sim.network import build_network
    from vcsumo.timetable import load_timetable, plan_trains
    from vcsumo.signalling.uic406 import capacity_consumption, convoy_pairs

    net = build_network(line, block_length_m)
    new = []
    for sha, (spec, regimes) in need.items():
        try:
            tt, p = load_timetable(Path(spec.timetable_path), line)
            trains = plan_trains(tt, p, line, net.topology, dt=step_length_s)
            pairs = convoy_pairs(tt, trains)
        except VcsumoError:
            continue  # the runs fail with the same error
        cache: dict = {}
        for regime in sorted(regimes):
            df = capacity_consumption(line, net.topology, trains, regime, pairs, window_s=window_s, step_s=step_length_s, cache=cache)
            df.insert(0, "timetable", spec.timetable)
            df.insert(1, "timetable_sha256", sha)
            df.insert(3, "step_length_s", step_length_s)
            new.append(df[UIC_COLUMNS])
    if new:
        have = pd.concat([have] + new, ignore_index=True) if len(have) else pd.concat(new, ignore_index=True)
        atomic_csv(have, path)
    return have


def _capacity(uic: pd.DataFrame, spec: RunSpec, window_s: float) -> tuple[float, float]:
    m = (uic["timetable_sha256"] == spec.timetable_sha256) & (uic["regime"] == spec.regime) & (uic["window_s"] == window_s) & (uic["step_length_s"] == spec.step_length_s)
    sel = uic[m]
    if sel.empty:
        return math.nan, math.nan
    return float(sel["consumption_pct"].max()), float(sel["cyclic_consumption_pct"].max())


# ---------------------------------------------------------------------------------------------
# Execution (vcsumo.engine.campaign)


def _to_rows(uic: pd.DataFrame, window_s: float):
    def to_rows(task: Task, out: Outcome) -> tuple[list[dict], dict[str, list[dict]]]:
        spec: RunSpec = task.arg
        outcome = out.value if out.ok else failed_outcome(spec, out.error, out.wall_time_s)
        row = outcome["row"]
        row["capacity_consumption_pct"], row["capacity_consumption_cyclic_pct"] = _capacity(uic, spec, window_s)
        return [row], {TRAINS_TABLE.name: outcome["trains"]}

    return to_rows


def run_batch(
    line: Line | str | Path,
    timetables: str | Iterable[str | Path] | None,
    regimes: Iterable[str] = ("fbs", "mb", "vc"),
    seeds: Iterable[int] = (1, 2, 3),
    controllers: Iterable[str] | None = None,
    delays: DelayConfig | None = None,
    delay_config_path: Path | None = None,
    out: Path | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    step_length_s: float = 0.5,
    block_length_m: float | None = None,
    window_s: float = 3600.0,
    retry_failed: bool = False,
    progress: Callable[[int, int, dict | None], None] | None = None,
    command: str = "",
) -> pd.DataFrame:
    """Run (or resume) a batch; returns its rows (``BATCH_COLUMNS``) in plan order.

    ``controllers`` (vc only; default ``cbf-cbc``) must not be given without the vc regime.
    ``workers``: parallel processes (default: the number of CPUs; 1 runs in this process; 0 or
    less is an input error); ``scheduler``: ``tcp://host:port`` of a Dask scheduler instead.
    ``df.attrs`` holds ``out`` (the folder), ``new_runs`` (runs executed now), ``resumed_runs``
    (found finished in ``batch.csv``), ``failed_runs`` and ``new_failed``.
    ``progress(done, total, row)`` is called before the first new run and after every one.
    """
    if not isinstance(line, Line):
        line = load_line_or_network(line)
    if step_length_s <= 0 or step_length_s > 2:
        raise VcsumoError(f"--step-length: {step_length_s} s is outside (0, 2] s")
    regimes = [r.strip() for r in regimes if r.strip()]
    if controllers is not None and "vc" not in regimes:
        raise InputError(None, "--controllers", f"only the vc regime takes a controller (regimes are {', '.join(regimes)})")
    controllers = [c.strip() for c in (controllers or [DEFAULT_CONTROLLER]) if c.strip()] or [DEFAULT_CONTROLLER]
    seeds = [int(s) for s in seeds]
    if len(set(seeds)) != len(seeds):
        raise InputError(None, "--seeds", "a seed is repeated")
    delays = delays or DelayConfig()
    if window_s <= 0:
        raise InputError(None, "--window-s", "the observation window must be positive")
    tts = resolve_timetables(timetables, line)
    runner = Runner(workers, scheduler)  # --workers and --scheduler checked before anything is built or written
    out = Path(out) if out is not None else default_batch_out(line, config_digest(delays), step_length_s, block_length_m)
    t_wall = time.perf_counter()
    from vcsumo.sim.network import build_network

    build_network(line, block_length_m)  # once, before the workers need it
    specs = plan_runs(line, tts, regimes, seeds, controllers, delays, out, step_length_s, block_length_m, command)
    requested = {s.key for s in specs}
    runner.log_path, runner.partial_roots = out / "workers.log", [out / "runs"]
    with runner, ResultStore(out, BATCH_TABLE, [TRAINS_TABLE], kind="batch") as store:
        (out / "runs").mkdir(exist_ok=True)
        if retry_failed:
            existing = read_batch(out)
            store.forget(existing.loc[(existing["status"] == "failed") & existing["run_key"].isin(requested), "run_key"])
        uic = _uic_table(out, line, specs, window_s, step_length_s, block_length_m)

        tasks = [Task(s.key, run_one, s, s.label) for s in specs]
        res = run_campaign(store, tasks, runner, _to_rows(uic, window_s),
                           (lambda done, total, rows: progress(done, total, rows[0] if rows else None)) if progress else None)
        df = read_batch(out)
        df = df[df["run_key"].isin(requested)]
        order = {s.key: i for i, s in enumerate(specs)}
        df = df.sort_values("run_key", key=lambda k: k.map(order)).reset_index(drop=True)[BATCH_COLUMNS]
        # capacity consumption of this invocation's window (rows resumed from an earlier window are refreshed)
        by_key = {s.key: s for s in specs}
        caps = [_capacity(uic, by_key[k], window_s) for k in df["run_key"]]
        df["capacity_consumption_pct"] = [c[0] for c in caps]
        df["capacity_consumption_cyclic_pct"] = [c[1] for c in caps]
        write_report(out, df, line, tts, delays, delay_config_path, seeds, regimes, controllers, step_length_s, block_length_m, window_s,
                     time.perf_counter() - t_wall, res.new, res.resumed)
    df.attrs.update(out=out, new_runs=res.new, resumed_runs=res.resumed, failed_runs=int((df["status"] != "ok").sum()), new_failed=res.failed)
    return df


# ---------------------------------------------------------------------------------------------
# Report


SUMMARY_AGG = {
    "runs": ("seed", "size"), "failed": ("failed", "sum"), "trains": ("trains", "mean"),
    "punctuality_3min_share": ("punctuality_3min_share", "mean"), "punctuality_5min_share": ("punctuality_5min_share", "mean"),
    "mean_arrival_delay_s": ("mean_arrival_delay_s", "mean"), "max_arrival_delay_s": ("max_arrival_delay_s", "max"),
    "primary_delay_s": ("primary_delay_s", "mean"), "knock_on_delay_s": ("knock_on_delay_s", "mean"),
    "capacity_consumption_pct": ("capacity_consumption_pct", "first"), "capacity_consumption_cyclic_pct": ("capacity_consumption_cyclic_pct", "first"),
    "gap_violations": ("gap_violations", "sum"), "collisions": ("collisions", "sum"), "emergency_brakes": ("emergency_brakes", "sum"),
}


def summarize(df: pd.DataFrame) -> pd.DataFrame:
    """Per timetable × regime × controller: runs, failures and the means over seeds of the ok runs."""
    if df.empty:
        return pd.DataFrame(columns=["timetable", "regime", "controller", *SUMMARY_AGG])
    d = df.copy()
    d["failed"] = d["status"] != "ok"
    ok = d[~d["failed"]]
    counts = d.groupby(["timetable", "regime", "controller"], sort=False).agg(runs=("seed", "size"), failed=("failed", "sum"))
    agg = {k: v for k, v in SUMMARY_AGG.items() if k not in ("runs", "failed")}
    means = (ok.groupby(["timetable", "regime", "controller"], sort=False).agg(**agg) if len(ok)
             else pd.DataFrame(index=counts.index, columns=list(agg), dtype=float))  # every run failed: no means
    out = counts.join(means, how="left").reset_index()
    return out.round(4)


def write_report(out: Path, df: pd.DataFrame, line: Line, timetables: list[Path], delays: DelayConfig, delay_config_path: Path | None,
                 seeds: list[int], regimes: list[str], controllers: list[str], step_length_s: float, block_length_m: float | None,
                 window_s: float, wall_time_s: float, new_runs: int, resumed_runs: int) -> None:
    """``report/``: batch_summary.csv, the plots (from the CSVs only) and meta.json."""
    inputs: dict[str, Path] = {"line": line.path}
    for i, p in enumerate(timetables):
        inputs[f"timetable_{i}_{p.stem}"] = p
    if delay_config_path is not None:
        inputs["delay_config"] = Path(delay_config_path)
    params = {"seeds": seeds, "regimes": regimes, "controllers": controllers, "step_length_s": step_length_s,
              "block_length_m": block_length_m, "uic406_window_s": window_s, "delays": delays.model_dump(mode="json"),
              "delay_config_sha256": config_digest(delays), "runs": len(df), "new_runs": new_runs, "resumed_runs": resumed_runs,
              "batch_wall_time_s": round(wall_time_s, 3)}
    with ResultsFolder(out / "report", inputs=inputs, seed=None, params=params, overwrite=True) as rf:
        df.to_csv(rf.path / "batch_runs.csv", index=False)
        summarize(df).to_csv(rf.path / "batch_summary.csv", index=False)
        uic = out / "uic406.csv"
        if uic.is_file():
            u = pd.read_csv(uic, dtype={"timetable_sha256": str})
            shas = set(df["timetable_sha256"])
            u[u["timetable_sha256"].isin(shas) & u["regime"].isin(regimes) & (u["window_s"] == window_s)].to_csv(rf.path / "uic406.csv", index=False)
        from vcsumo.plots.batch import plot_delays, plot_punctuality

        plot_delays(out / "batch_trains.csv", rf.path / "batch_runs.csv", rf.path / "batch_delays.png")
        plot_punctuality(rf.path / "batch_runs.csv", rf.path / "batch_punctuality.png")
