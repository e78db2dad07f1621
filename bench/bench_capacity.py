"""Wall time of ``vcsumo study capacity`` and where it goes.

Runs the capacity study (default: firenze_bologna with the command's default options) into a
temporary folder, or reads a finished study's ``capacity.csv`` (``--from DIR``), and prints the
total wall time, the time per case, and the split of the summed case time into SUMO stepping
(libsumo ``simulationStep``), vcsumo's VC controllers (``VCDriver.make_step``: channel,
controllers, supervisor, guard), result I/O, and the rest of the loop (observing trains, gap and
violation checks, speed traces, tunnel vType switches, fixed-time caps).

    python bench/bench_capacity.py [--line firenze_bologna] [--workers 2] [--directions up,down] [--from DIR] [--out DIR]

Target (issue 4): the default study on firenze_bologna in at most 3 minutes on a 2-core machine.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import pandas as pd


def report(df: pd.DataFrame, wall_s: float | None, cpu_s: float | None = None, workers: int | None = None, load: tuple[float, float] | None = None) -> None:
    ok = df[df.error.isna() | (df.error.astype(str) == "")] if "error" in df else df
    fresh = ok.drop_duplicates(subset=["direction", "stopping_pattern", "regime", "controller", "convoy_size"])
    fresh = fresh[~((fresh.regime == "vc") & (fresh.convoy_size == 1))]
    case_s = float(fresh.wall_time_s.sum())
    sumo = float(fresh.sumo_time_s.sum())
    ctrl = float(fresh.controller_time_s.sum())
    io = float(fresh.io_time_s.sum())
    if wall_s is not None:
        print(f"total wall time            {wall_s:8.1f} s   ({wall_s / 60:.1f} min)")
    if cpu_s is not None:
        print(f"CPU time, all processes    {cpu_s:8.1f} s")
    if load is not None:
        print(f"load average (1 min)       {load[0]:8.2f} at start, {load[1]:.2f} at end (other work inflates every time here)")
    print(f"cases simulated            {len(fresh):8d}     ({int(fresh.simulations.sum())} SUMO runs)")
    print(f"summed case time           {case_s:8.1f} s   (over all worker processes)")
    for name, x in (("SUMO stepping", sumo), ("VC controllers", ctrl), ("result I/O", io), ("loop, search, analysis", case_s - sumo - ctrl - io)):
        print(f"  {name:<24} {x:8.1f} s   {100 * x / max(case_s, 1e-9):5.1f} %")
    n = workers or os.cpu_count() or 1
    longest = float(fresh.wall_time_s.max()) if len(fresh) else 0.0
    print(f"idle-machine estimate      {case_s / n:8.1f} s   (summed case time / {n} workers) to {case_s / n + longest:.1f} s (+ the longest case, {longest:.1f} s)")
    print("\nslowest cases:")
    cols = ["direction", "stopping_pattern", "regime", "controller", "convoy_size", "simulations", "wall_time_s", "sumo_time_s", "controller_time_s"]
    print(fresh.sort_values("wall_time_s", ascending=False)[cols].head(8).to_string(index=False))
    by = fresh.groupby("regime").wall_time_s.sum()
    print("\ncase time by regime: " + ", ".join(f"{k} {v:.1f} s" for k, v in by.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--line", default="firenze_bologna")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--directions", default="up,down")
    ap.add_argument("--from", dest="from_dir", type=Path, default=None, help="Report on a finished study folder instead of running one")
    ap.add_argument("--out", type=Path, default=None, help="Keep the study's results in this folder (default: a temporary one, removed)")
    args = ap.parse_args()
    print(f"python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} CPUs")
    if args.from_dir is not None:
        report(pd.read_csv(args.from_dir / "capacity.csv"), None)
        return
    from vcsumo.cli.main import main as cli

    with tempfile.TemporaryDirectory(prefix="vcsumo-bench-") as tmp:
        out = args.out if args.out is not None else Path(tmp) / "cap"
        argv = ["study", "capacity", "--line", args.line, "--directions", args.directions, "--out", str(out)]
        if args.workers:
            argv += ["--workers", str(args.workers)]
        load0 = os.getloadavg()[0]
        cpu0 = _cpu_s()
        t0 = time.perf_counter()
        rc = cli(argv)
        wall = time.perf_counter() - t0
        cpu = _cpu_s() - cpu0
        if rc != 0:
            raise SystemExit(rc)
        print(f"\nvcsumo study capacity --line {args.line} --directions {args.directions}")
        report(pd.read_csv(out / "capacity.csv"), wall, cpu, args.workers, (load0, os.getloadavg()[0]))


def _cpu_s() -> float:
    """CPU time of this process and of its finished children (the worker processes, SUMO included: libsumo), s."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


if __name__ == "__main__":
    main()
