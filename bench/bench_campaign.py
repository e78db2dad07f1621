"""Throughput of the campaign engine (issue 14 item 5): runs/min against workers for a small batch.

Runs the same small batch (default: felez_test ``dense`` + ``base``, fbs and mb, 3 seeds = 12 SUMO
runs) into a fresh temporary folder with 1 worker (this process) and with 2 worker processes,
``--rounds`` times in alternating order, and prints per run of the batch: wall time, runs/min,
CPU time of this process and its workers, the 1-minute load average before and after, and the
*fixed cost* (wall time until the first run is recorded, minus that run's own time: network
check, UIC 406 table, starting workers).  Then the **paired ratio** runs/min(2) / runs/min(1)
of each round (back to back, so both see the same machine load) and their median.  A second
table measures the engine alone with trivial tasks (no SUMO): tasks/s and the time to the first
result, i.e. what spawning a worker and importing vcsumo in it costs.

What limits scaling:

* **cores** — one SUMO per process is CPU-bound: beyond the number of *free* cores more workers
  only share them.  Measured on the shared 2-core machine at a load average of 6: 2 workers ran
  at 0.40–0.61 × the runs/min of 1 (felez_test, 0.15 s runs) and 0.86 × (firenze_bologna, 2 s
  runs): no core was free, and the per-run time rose from 0.15 to 0.4 s and from 2.0 to 4.3 s;
* **fixed cost per batch** — network check, the UIC 406 table of every timetable and the report
  run once in the main process whatever the worker count (0.1 s on felez_test, 5.8 s on
  firenze_bologna, where it is a quarter of a 23 s batch);
* **imports per worker** — each spawned worker imports vcsumo, pandas, numpy and libsumo before
  its first run (the "fixed s" column grows by 1.3–1.9 s with 2 workers; the engine-alone table
  shows 0.13–0.26 s to the first trivial result against 0.01 s in this process), paid again by
  every replacement worker after a crash;
* **the store** — one fsync per recorded task: about 4 ms, which caps trivial tasks at roughly
  200–260 per second and is nothing next to a SUMO run.

    python bench/bench_campaign.py [--line felez_test] [--timetables dense,base] [--seeds 3] [--rounds 2] [--tasks 200]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import tempfile
import time
from pathlib import Path


def cpu_s() -> float:
    """CPU time (user + system) of this process and its finished children."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def one_batch(args, workers: int) -> dict:
    from vcsumo.studies.batch import run_batch

    first: list[float] = []
    load0 = os.getloadavg()[0]
    c0 = cpu_s()
    with tempfile.TemporaryDirectory(prefix="vcsumo-bench-") as tmp:
        t0 = time.perf_counter()

        def progress(done: int, total: int, row: dict | None) -> None:
            if row is not None and not first:
                first.append(time.perf_counter() - t0 - float(row.get("wall_time_s") or 0.0))

        df = run_batch(args.line, args.timetables, args.regimes.split(","), list(range(1, args.seeds + 1)), out=Path(tmp) / "b",
                       workers=workers, progress=progress)
        wall = time.perf_counter() - t0
    return {"workers": workers, "runs": len(df), "failed": int((df.status != "ok").sum()), "wall": wall, "rate": 60.0 * len(df) / wall,
            "cpu": cpu_s() - c0, "fixed": first[0] if first else float("nan"), "load0": load0, "load1": os.getloadavg()[0],
            "run_s": float(df.wall_time_s.mean())}


def square(x: int) -> int:
    return x * x


def engine_alone(n_tasks: int, workers: int) -> dict:
    from vcsumo.engine.campaign import Runner, Task, run_campaign
    from vcsumo.engine.store import ResultStore, Table

    table = Table("t.csv", ("key", "value", "error"), "key")
    first: list[float] = []
    with tempfile.TemporaryDirectory(prefix="vcsumo-bench-") as tmp:
        t0 = time.perf_counter()
        with Runner(workers) as runner, ResultStore(Path(tmp) / "s", table, kind="bench") as store:
            run_campaign(store, [Task(f"k{i}", square, i) for i in range(n_tasks)], runner,
                         lambda t, o: ([{"key": t.key, "value": o.value, "error": o.error}], {}),
                         lambda d, n, rows: first.append(time.perf_counter() - t0) if rows and not first else None)
        wall = time.perf_counter() - t0
    return {"workers": workers, "tasks": n_tasks, "wall": wall, "per_s": n_tasks / wall, "first": first[0] if first else float("nan")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--line", default="felez_test")
    ap.add_argument("--timetables", default="dense,base")
    ap.add_argument("--regimes", default="fbs,mb")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--tasks", type=int, default=200, help="trivial tasks for the engine-alone table")
    args = ap.parse_args()
    from vcsumo.line import load_line
    from vcsumo.sim.network import build_network

    build_network(load_line(args.line), None)  # cached before timing
    print(f"campaign engine: {args.line} [{args.timetables}] x {args.regimes} x {args.seeds} seeds, {args.rounds} rounds")
    print(f"python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} CPUs")
    print(f"{'round':>5} {'workers':>7} {'runs':>5} {'wall s':>7} {'runs/min':>9} {'CPU s':>7} {'fixed s':>8} {'s/run':>6} {'load':>11}")
    ratios = []
    for r in range(args.rounds):
        order = (1, 2) if r % 2 == 0 else (2, 1)
        res = {w: one_batch(args, w) for w in order}
        for w in (1, 2):
            x = res[w]
            print(f"{r + 1:>5} {w:>7} {x['runs']:>5} {x['wall']:>7.1f} {x['rate']:>9.1f} {x['cpu']:>7.1f} {x['fixed']:>8.2f} {x['run_s']:>6.2f} "
                  f"{x['load0']:>5.2f}>{x['load1']:<5.2f}" + (f" ({x['failed']} failed)" if x["failed"] else ""))
        ratios.append(res[2]["rate"] / res[1]["rate"])
    print("paired ratio runs/min(2 workers) / runs/min(1 worker): " + ", ".join(f"{q:.2f}" for q in ratios)
          + f"; median {statistics.median(ratios):.2f}")
    print()
    print(f"engine alone, {args.tasks} trivial tasks (no SUMO):")
    print(f"{'workers':>7} {'wall s':>7} {'tasks/s':>8} {'first result s':>15}")
    for w in (1, 2):
        e = engine_alone(args.tasks, w)
        print(f"{w:>7} {e['wall']:>7.2f} {e['per_s']:>8.0f} {e['first']:>15.2f}")


if __name__ == "__main__":
    main()
