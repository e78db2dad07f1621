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

Modules: :mod:`vcsumo.studies.batch_run` runs one run and defines its metrics (``BATCH_COLUMNS``,
``TRAIN_COLUMNS``); :mod:`vcsumo.studies.batch_uic406` computes the UIC 406 table; this module plans,
executes, stores and reports the batch.
"""

from __future__ import annotations

import hashlib
import time
import warnings
from pathlib import Path
from typing import Callable, Iterable

import pandas as pd

from vcsumo.delays import DelayConfig, config_digest
from vcsumo.engine.campaign import WORKER_DIED, Outcome, Runner, Task, run_campaign
from vcsumo.engine.store import ResultStore, Table, read_table
from vcsumo.errors import InputError, VcsumoError
from vcsumo.line import Line
from vcsumo.network_file import load_line_or_network
from vcsumo.results import ResultsFolder, file_digest
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.studies.batch_run import (
    BATCH_COLUMNS,
    DEFAULT_CONTROLLER,
    PUNCTUALITY_THRESHOLDS_S,
    TRAIN_COLUMNS,
    RunSpec,
    assumptions_digest,
    failed_outcome,
    run_key,
    run_one,
)
from vcsumo.studies.batch_uic406 import UIC_COLUMNS, run_capacity, uic_table

REGIMES = ("fbs", "mb", "vc")


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


def default_batch_out(line: Line, delay_sha256: str, step_length_s: float, block_length_m: float | None, assumptions_sha256: str = "") -> Path:
    """``results/batch-<line>-<hash>``: the same for the same line and settings, so re-running resumes."""
    h = hashlib.sha256(f"{line.source_digest()}|{delay_sha256}|{step_length_s:g}|{block_length_m}|{assumptions_sha256}".encode()).hexdigest()[:8]
    return Path("results") / f"batch-{line.name}-{h}"


def plan_runs(line: Line, timetables: list[Path], regimes: list[str], seeds: list[int], controllers: list[str], delays: DelayConfig,
              out: Path, step_length_s: float = 0.5, block_length_m: float | None = None, command: str = "",
              assumptions: AssumptionSet | None = None) -> list[RunSpec]:
    """Every timetable × regime × controller (vc only) × seed, in that order, supervised and judged
    under ``assumptions`` (None: the shipped default set)."""
    from vcsumo.results import safe_component

    for r in regimes:
        if r not in REGIMES:
            raise InputError(None, "--regimes", f"unknown regime '{r}' (choose from {', '.join(REGIMES)})")
    if not seeds:
        raise InputError(None, "--seeds", "no seeds")
    d_sha = config_digest(delays)
    l_sha = line.source_digest()
    a_rec = (assumptions or load_assumptions()).record()
    a_sha = assumptions_digest(a_rec)
    specs = []
    no_convoys: list[Path] = []  # the vc regime runs a timetable's convoys: without any it is not run there
    for tt in timetables:
        t_sha = file_digest(tt)
        if "vc" in regimes and not _has_convoys(tt):
            no_convoys.append(tt)
        for regime in regimes:
            if regime == "vc" and no_convoys and no_convoys[-1] == tt:
                continue
            for ctrl in (controllers or [DEFAULT_CONTROLLER]) if regime == "vc" else [""]:
                for seed in seeds:
                    key = run_key(t_sha, regime, ctrl, seed, d_sha, l_sha, step_length_s, block_length_m, a_sha)
                    name = safe_component(f"{tt.stem}-{regime}{'-' + ctrl if ctrl else ''}-s{seed}-{key[:8]}")  # ctrl may hold a path
                    specs.append(RunSpec(
                        line_path=str(line.path), block_length_m=block_length_m, timetable_path=str(tt), timetable=tt.stem,
                        timetable_sha256=t_sha, regime=regime, controller=ctrl, seed=int(seed), delays=delays.model_dump(mode="json"),
                        delay_config_sha256=d_sha, step_length_s=step_length_s, run_dir=str((out / "runs" / name).resolve()), key=key,
                        line=line.name, command=command, assumptions=a_rec, assumptions_sha256=a_sha,
                    ))
    if no_convoys:
        names = ", ".join(p.name for p in no_convoys)
        if not specs:
            raise InputError(no_convoys[0], "convoys", f"the vc regime needs at least one convoy in the timetable, and no timetable of the batch has one ({names})")
        warnings.warn(f"vc is not run for {names}: no convoys in the timetable (the vc regime couples a timetable's convoys; "
                      f"declare them with convoys: [{{id, services: [leader, follower]}}])", stacklevel=2)
    return specs


def _has_convoys(path: Path) -> bool:
    """Whether a timetable file declares convoys (a file that cannot be read: True, its runs give the error)."""
    from vcsumo.config import load_model
    from vcsumo.timetable import TimetableFile

    try:
        return bool(load_model(TimetableFile, path).convoys)
    except InputError:
        return True


# ---------------------------------------------------------------------------------------------
# Execution (vcsumo.engine.campaign)


def _to_rows(uic: pd.DataFrame, window_s: float):
    def to_rows(task: Task, out: Outcome) -> tuple[list[dict], dict[str, list[dict]]]:
        spec: RunSpec = task.arg
        outcome = out.value if out.ok else failed_outcome(spec, out.error, out.wall_time_s)
        row = outcome["row"]
        row["capacity_consumption_pct"], row["capacity_consumption_cyclic_pct"] = run_capacity(uic, spec, window_s)
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
    assumptions: AssumptionSet | None = None,
) -> pd.DataFrame:
    """Run (or resume) a batch; returns its rows (``BATCH_COLUMNS``) in plan order.

    ``controllers`` (vc only; default ``cbf-cbc``) must not be given without the vc regime.
    ``workers``: parallel processes (default: the number of CPUs; 1 runs in this process; 0 or
    less is an input error); ``scheduler``: ``tcp://host:port`` of a Dask scheduler instead.
    ``df.attrs`` holds ``out`` (the folder), ``new_runs`` (runs executed now), ``resumed_runs``
    (found finished in ``batch.csv``), ``failed_runs`` and ``new_failed``.
    ``progress(done, total, row)`` is called before the first new run and after every one.
    ``assumptions``: the separation model's set every run is supervised and judged with and UIC 406
    computed under (None: the shipped default); part of every run's resume key.
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
    assumptions = assumptions or load_assumptions()
    out = Path(out) if out is not None else default_batch_out(line, config_digest(delays), step_length_s, block_length_m,
                                                              assumptions_digest(assumptions.record()))
    t_wall = time.perf_counter()
    from vcsumo.sim.network import build_network

    build_network(line, block_length_m)  # once, before the workers need it
    specs = plan_runs(line, tts, regimes, seeds, controllers, delays, out, step_length_s, block_length_m, command, assumptions)
    requested = {s.key for s in specs}
    runner.log_path, runner.partial_roots = out / "workers.log", [out / "runs"]
    with runner, ResultStore(out, BATCH_TABLE, [TRAINS_TABLE], kind="batch") as store:
        (out / "runs").mkdir(exist_ok=True)
        if retry_failed:
            existing = read_batch(out)
            store.forget(existing.loc[(existing["status"] == "failed") & existing["run_key"].isin(requested), "run_key"])
        uic = uic_table(out, line, specs, window_s, step_length_s, block_length_m, assumptions)

        tasks = [Task(s.key, run_one, s, s.label) for s in specs]
        res = run_campaign(store, tasks, runner, _to_rows(uic, window_s),
                           (lambda done, total, rows: progress(done, total, rows[0] if rows else None)) if progress else None)
        df = read_batch(out)
        df = df[df["run_key"].isin(requested)]
        order = {s.key: i for i, s in enumerate(specs)}
        df = df.sort_values("run_key", key=lambda k: k.map(order)).reset_index(drop=True)[BATCH_COLUMNS]
        # capacity consumption of this invocation's window (rows resumed from an earlier window are refreshed)
        by_key = {s.key: s for s in specs}
        caps = [run_capacity(uic, by_key[k], window_s) for k in df["run_key"]]
        df["capacity_consumption_pct"] = [c[0] for c in caps]
        df["capacity_consumption_cyclic_pct"] = [c[1] for c in caps]
        write_report(out, df, line, tts, delays, delay_config_path, seeds, regimes, controllers, step_length_s, block_length_m, window_s,
                     time.perf_counter() - t_wall, res.new, res.resumed, assumptions)
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
    "unhealthy_runs": ("unhealthy", "sum"), "min_margin_m": ("min_margin_m", "min"),
}


def unhealthy(df: pd.DataFrame) -> pd.Series:
    """Finished runs (status ok) whose ``healthy`` is not true (read back from batch.csv as text or bool)."""
    return (df["status"] == "ok") & ~df["healthy"].astype(str).str.lower().isin(("true", "1", "1.0"))


def summarize(df: pd.DataFrame) -> pd.DataFrame:
    """Per timetable × regime × controller: runs, failures and the means over seeds of the ok runs."""
    if df.empty:
        return pd.DataFrame(columns=["timetable", "regime", "controller", *SUMMARY_AGG])
    d = df.copy()
    d["failed"] = d["status"] != "ok"
    d["unhealthy"] = unhealthy(d)
    ok = d[~d["failed"]]
    counts = d.groupby(["timetable", "regime", "controller"], sort=False).agg(runs=("seed", "size"), failed=("failed", "sum"))
    agg = {k: v for k, v in SUMMARY_AGG.items() if k not in ("runs", "failed")}
    means = (ok.groupby(["timetable", "regime", "controller"], sort=False).agg(**agg) if len(ok)
             else pd.DataFrame(index=counts.index, columns=list(agg), dtype=float))  # every run failed: no means
    out = counts.join(means, how="left").reset_index()
    return out.round(4)


def write_report(out: Path, df: pd.DataFrame, line: Line, timetables: list[Path], delays: DelayConfig, delay_config_path: Path | None,
                 seeds: list[int], regimes: list[str], controllers: list[str], step_length_s: float, block_length_m: float | None,
                 window_s: float, wall_time_s: float, new_runs: int, resumed_runs: int, assumptions: AssumptionSet | None = None) -> None:
    """``report/``: batch_summary.csv, the plots (from the CSVs only) and meta.json."""
    inputs: dict[str, Path] = {"line": line.path}
    for i, p in enumerate(timetables):
        inputs[f"timetable_{i}_{p.stem}"] = p
    if delay_config_path is not None:
        inputs["delay_config"] = Path(delay_config_path)
    a_rec = (assumptions or load_assumptions()).record()
    params = {"seeds": seeds, "regimes": regimes, "controllers": controllers, "step_length_s": step_length_s,
              "block_length_m": block_length_m, "uic406_window_s": window_s, "delays": delays.model_dump(mode="json"),
              "delay_config_sha256": config_digest(delays), "runs": len(df), "new_runs": new_runs, "resumed_runs": resumed_runs,
              "batch_wall_time_s": round(wall_time_s, 3), "assumptions": a_rec}
    with ResultsFolder(out / "report", inputs=inputs, seed=None, params=params, overwrite=True) as rf:
        df.to_csv(rf.path / "batch_runs.csv", index=False)
        summarize(df).to_csv(rf.path / "batch_summary.csv", index=False)
        uic = out / "uic406.csv"
        if uic.is_file():
            u = pd.read_csv(uic, dtype={"timetable_sha256": str, "assumptions_sha256": str})
            shas = set(df["timetable_sha256"])
            u[u["timetable_sha256"].isin(shas) & u["regime"].isin(regimes) & (u["window_s"] == window_s)
              & (u["assumptions_sha256"] == assumptions_digest(a_rec))].to_csv(rf.path / "uic406.csv", index=False)
        from vcsumo.plots.batch import plot_delays, plot_punctuality

        plot_delays(out / "batch_trains.csv", rf.path / "batch_runs.csv", rf.path / "batch_delays.png")
        plot_punctuality(rf.path / "batch_runs.csv", rf.path / "batch_punctuality.png")


__all__ = [
    "BATCH_COLUMNS", "BATCH_TABLE", "DEFAULT_CONTROLLER", "PUNCTUALITY_THRESHOLDS_S", "REGIMES", "SUMMARY_AGG", "TRAIN_COLUMNS", "TRAINS_TABLE",
    "UIC_COLUMNS", "WORKER_DIED", "RunSpec", "default_batch_out", "failed_outcome", "plan_runs", "read_batch", "resolve_timetables", "run_batch",
    "run_key", "run_one", "summarize", "unhealthy", "write_report",
]
