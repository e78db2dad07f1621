"""Throughput of ``vcsumo batch``: runs per minute with 1 and 2 worker processes.

Runs the same batch (default: firenze_bologna peak + base, fbs and mb, 4 seeds = 16 runs) into a
fresh temporary folder for each worker count and prints runs/minute, the speed-up and the mean
SUMO wall time per run.  The wall time includes starting the worker processes, the UIC 406
computation and the report, i.e. what a user waits for.

    python bench/bench_batch.py [--line firenze_bologna] [--timetables peak,base] [--seeds 4] [--workers 1 2]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path


def main() -> None:
    from vcsumo.studies.batch import run_batch

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--line", default="firenze_bologna")
    ap.add_argument("--timetables", default="peak,base")
    ap.add_argument("--regimes", default="fbs,mb")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args()
    regimes = args.regimes.split(",")
    print(f"vcsumo batch throughput: {args.line} [{args.timetables}] x {args.regimes} x {args.seeds} seeds, default primary delays")
    print(f"python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} CPUs")
    print(f"{'workers':>7} {'runs':>5} {'wall s':>8} {'runs/min':>9} {'speed-up':>9} {'SUMO s/run':>11}")
    base = None
    for w in args.workers:
        with tempfile.TemporaryDirectory(prefix="vcsumo-bench-") as tmp:
            t0 = time.perf_counter()
            df = run_batch(args.line, args.timetables, regimes, list(range(1, args.seeds + 1)), out=Path(tmp) / "b", workers=w)
            wall = time.perf_counter() - t0
        n = len(df)
        rate = 60.0 * n / wall
        base = base or rate
        failed = int((df.status != "ok").sum())
        print(f"{w:>7} {n:>5} {wall:>8.1f} {rate:>9.1f} {rate / base:>9.2f} {df.wall_time_s.mean():>11.2f}" + (f"  ({failed} failed)" if failed else ""))


if __name__ == "__main__":
    main()
