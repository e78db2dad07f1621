"""Throughput of ``vcsumo batch``: runs per minute against workers, local processes and Dask.

Runs the same batch (default: firenze_bologna peak + base, fbs and mb, 4 seeds = 16 runs) into a
fresh temporary folder for each back-end and worker count and prints runs/minute, the speed-up
over one worker, the mean SUMO wall time per run and the CPU time of the whole machine's
processes (this one and its children) — the wall time includes starting the workers, the UIC 406
computation and the report, i.e. what a user waits for.

Back-ends (``--backends``): ``processes`` (``--workers K``: local worker processes, the default
of ``vcsumo batch``) and ``dask`` (a ``distributed.LocalCluster`` of K single-threaded worker
processes on this machine, reached the way a real cluster is, ``--scheduler tcp://…``).

It also prints what limits the scaling, measured:

* the fixed cost of a batch — the wall time of a batch of one run less that run's own SUMO wall
  time (loading the line, planning, the result store, UIC 406, the report);
* the import cost paid in every fresh worker — a new Python process importing vcsumo's batch run
  and libsumo;
* the load average before and after each batch (the machine is shared: compare paired figures).

    python bench/bench_batch.py [--line firenze_bologna] [--timetables peak,base] [--seeds 4] [--workers 1 2]
                                [--backends processes dask]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _cpu_s() -> float:
    """CPU time of this process and its waited-for children, s."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def import_cost_s(repeats: int = 3) -> float:
    """Median wall time of a fresh Python process importing what a batch worker imports, s."""
    code = "import vcsumo.studies.batch_run, vcsumo.sim.loop, libsumo"
    env = dict(os.environ)
    from vcsumo.sim.sumo_paths import sumo_home

    env["SUMO_HOME"] = str(sumo_home())
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True, env=env)
        times.append(time.perf_counter() - t0)
    bare = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        bare.append(time.perf_counter() - t0)
    return sorted(times)[len(times) // 2] - sorted(bare)[len(bare) // 2]


def one_batch(args, regimes: list[str], seeds: list[int], workers: int, backend: str):
    """(rows, wall s, CPU s, load before, load after) of one batch into a fresh folder."""
    from vcsumo.studies.batch import run_batch

    cluster = None
    scheduler = None
    if backend == "dask":
        from distributed import LocalCluster

        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
        scheduler = cluster.scheduler_address
    load0 = os.getloadavg()[0]
    try:
        with tempfile.TemporaryDirectory(prefix="vcsumo-bench-") as tmp:
            c0, t0 = _cpu_s(), time.perf_counter()
            df = run_batch(args.line, args.timetables, regimes, seeds, out=Path(tmp) / "b",
                           workers=None if scheduler else workers, scheduler=scheduler)
            wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
    finally:
        if cluster is not None:
            cluster.close()
    return df, wall, cpu, load0, os.getloadavg()[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--line", default="firenze_bologna")
    ap.add_argument("--timetables", default="peak,base")
    ap.add_argument("--regimes", default="fbs,mb")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--backends", nargs="+", default=["processes", "dask"], choices=["processes", "dask"])
    args = ap.parse_args()
    regimes = args.regimes.split(",")
    seeds = list(range(1, args.seeds + 1))
    print(f"vcsumo batch throughput: {args.line} [{args.timetables}] x {args.regimes} x {args.seeds} seeds, default primary delays")
    print(f"python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} CPUs, load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")

    # what limits the scaling: the fixed cost of a batch and the imports of a fresh worker
    df1, wall1, _, l0, l1 = one_batch(args, regimes[:1], [1], 1, "processes")
    run_s = float(df1.wall_time_s.iloc[0]) if len(df1) else float("nan")
    print(f"fixed cost of a batch (a 1-run batch {wall1:.1f} s wall less its run's SUMO wall time {run_s:.1f} s): "
          f"{wall1 - run_s:.1f} s   load {l0:.2f}->{l1:.2f}")
    print(f"imports of a fresh worker process (vcsumo batch run, loop, libsumo; python start-up apart): {import_cost_s():.2f} s")

    print(f"{'backend':>9} {'workers':>7} {'runs':>5} {'wall s':>8} {'runs/min':>9} {'speed-up':>9} {'SUMO s/run':>11} {'CPU s':>7} {'load':>11}")
    for backend in args.backends:
        base = None
        for w in args.workers:
            df, wall, cpu, l0, l1 = one_batch(args, regimes, seeds, w, backend)
            n = len(df)
            rate = 60.0 * n / wall
            base = base or rate
            failed = int((df.status != "ok").sum())
            cpu_txt = f"{cpu:7.1f}" if backend == "processes" else f"{'n/a':>7}"  # dask workers are not this process's children
            print(f"{backend:>9} {w:>7} {n:>5} {wall:>8.1f} {rate:>9.1f} {rate / base:>9.2f} {df.wall_time_s.mean():>11.2f} {cpu_txt} "
                  f"{l0:5.2f}->{l1:5.2f}" + (f"  ({failed} failed)" if failed else ""))


if __name__ == "__main__":
    main()
