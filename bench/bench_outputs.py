"""Same outputs before and after a change: run a fixed set of small scenarios and compare result files.

Runs felez_test (12-train convoy timetable under vc with cbc and cbf-cbc, 20-train ``dense`` under
fbs and mb) and regional_graded (``all_stations`` under fbs and mb, ``convoy`` under vc with cbc
and cbf-cbc) through ``vcsumo run`` into ``--out``, prints the CPU time of each run and, with
``--against REF`` (the folder of an earlier run of this script, e.g. made on ``main``), whether
summary.csv, stop_events.csv, violations.csv (and the other tidy CSVs) are byte-identical.

    python bench/bench_outputs.py --out /tmp/before            # on main
    python bench/bench_outputs.py --out /tmp/after --against /tmp/before
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

SCENARIOS = {
    "felez_convoy_cbc": ["--line", "felez_test", "--timetable", "convoy", "--regime", "vc", "--controller", "cbc"],
    "felez_convoy_cbf-cbc": ["--line", "felez_test", "--timetable", "convoy", "--regime", "vc", "--controller", "cbf-cbc"],
    "felez_dense_fbs": ["--line", "felez_test", "--timetable", "dense", "--regime", "fbs"],
    "felez_dense_mb": ["--line", "felez_test", "--timetable", "dense", "--regime", "mb"],
    "regional_all_fbs": ["--line", "regional_graded", "--timetable", "all_stations", "--regime", "fbs"],
    "regional_all_mb": ["--line", "regional_graded", "--timetable", "all_stations", "--regime", "mb"],
    "regional_convoy_cbc": ["--line", "regional_graded", "--timetable", "convoy", "--regime", "vc", "--controller", "cbc"],
    "regional_convoy_cbf-cbc": ["--line", "regional_graded", "--timetable", "convoy", "--regime", "vc", "--controller", "cbf-cbc"],
}
REQUIRED = ("summary.csv", "stop_events.csv", "violations.csv")
ALSO = ("passages.csv", "collisions.csv", "trajectories.csv", "vc_followers.csv", "faults.csv")


def digest(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16] if path.is_file() else None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for the runs (one sub-folder per scenario)")
    ap.add_argument("--against", type=Path, help="an earlier --out folder to compare with")
    ap.add_argument("--only", nargs="*", help="scenario names (default: all)")
    args = ap.parse_args()
    names = args.only or list(SCENARIOS)
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")
    differ = 0
    for name in names:
        out = args.out / name
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        rc = subprocess.run([sys.executable, "-m", "vcsumo.cli.main", "run", *SCENARIOS[name], "--out", str(out), "-q"],
                            stdout=subprocess.DEVNULL).returncode
        if rc not in (0, 1):  # 1: the run finished and is not healthy (its results are written all the same)
            raise SystemExit(f"{name}: vcsumo run failed (exit status {rc})")
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        healthy = json.loads((out / "summary.json").read_text()).get("healthy")
        line = f"{name:26s} CPU {cpu:6.2f} s  wall {time.perf_counter() - w0:6.2f} s  {'healthy' if healthy else 'NOT HEALTHY'}"
        if args.against is not None:
            same, diff = [], []
            for f in REQUIRED + ALSO:
                a, b = digest(out / f), digest(args.against / name / f)
                if a is None and b is None:
                    continue
                (same if a == b else diff).append(f)
            bad = [f for f in diff if f in REQUIRED]
            differ += bool(bad)
            line += "  identical" if not diff else f"  DIFFERENT: {', '.join(diff)}"
        print(line, flush=True)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
