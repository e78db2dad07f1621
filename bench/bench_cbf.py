"""Per-step computation time of the Terlizzi et al. (2024) follower control system.

Runs the OS1 and OS2 reproductions (compressed timelines by default, ``--full`` for the paper's)
and times every call of the CBF supervisor (Algorithms 1–2 + T^max rule) and of the switched cruise
controller (Algorithms 3–5 with the QP).  Seed Table I: mean 0.16 ms (OS1), 0.07 ms (OS2) for the
whole follower control system on an i7-10710U (Rust/PANOC); max 5.5 / 6.9 ms.

    python bench/bench_cbf.py [--full]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vcsumo.control.cbf import CBFSupervisor
from vcsumo.control.cruise import SwitchedCruiseController
from vcsumo.reproduce.terlizzi2024 import OS1Spec, OS2Spec, line_profile, run_os1, run_os2

COMPACT_OS1 = OS1Spec(duration_s=800.0, dt_s=0.1, speed_schedule=((0.0, 45.0), (300.0, 35.0)), brake_time_s=500.0)
COMPACT_OS2 = OS2Spec(
    duration_s=600.0, dt_s=0.1, leader_start_m=40000.0,
    degradations=((150.0, 250.0, 1.0, 0.5, 0.02), (250.0, 330.0, 2.0, 1.0, 0.05), (330.0, 400.0, 3.5, 1.5, 0.10)),
    outage=(400.0, 430.0), steady_window=(100.0, 150.0), degraded_window=(330.0, 400.0),
)


class _Timer:
    def __init__(self) -> None:
        self.samples: list[float] = []

    def wrap(self, fn):
        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            out = fn(*args, **kwargs)
            self.samples.append(time.perf_counter() - t0)
            return out

        return timed


def _stats(name: str, xs: list[float]) -> str:
    a = np.asarray(xs) * 1e3
    return f"{name:<28s} n={len(a):6d}  mean={a.mean():7.3f} ms  p99={np.percentile(a, 99):7.3f} ms  max={a.max():7.3f} ms  var={a.var():8.4f} ms²"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="the paper-length OS1/OS2 timelines (about a minute)")
    args = ap.parse_args()
    prof = line_profile()
    sup_timer, cruise_timer = _Timer(), _Timer()
    orig_filter, orig_step = CBFSupervisor.filter, SwitchedCruiseController.make_step
    CBFSupervisor.filter = sup_timer.wrap(orig_filter)
    SwitchedCruiseController.make_step = cruise_timer.wrap(orig_step)
    try:
        cases = [("OS1 (delay 0.8 s)", lambda: run_os1(0.8, spec=None if args.full else COMPACT_OS1, profile=prof)),
                 ("OS2 (delay estimator)", lambda: run_os2(True, spec=None if args.full else COMPACT_OS2, profile=prof))]
        print(f"Terlizzi et al. (2024) follower control system, {'full' if args.full else 'compressed'} scenarios, Δt = 0.1 s")
        for name, run in cases:
            sup_timer.samples.clear()
            cruise_timer.samples.clear()
            run()
            total = [a + b for a, b in zip(sup_timer.samples, cruise_timer.samples)]
            print(name)
            print("  " + _stats("CBF supervisor (Alg. 1-2)", sup_timer.samples))
            print("  " + _stats("cruise control (Alg. 3-5)", cruise_timer.samples))
            print("  " + _stats("follower system (total)", total))
        print("seed Table I (whole follower system): OS1 mean 0.16 ms, max 5.53 ms; OS2 mean 0.07 ms, max 6.88 ms")
    finally:
        CBFSupervisor.filter, SwitchedCruiseController.make_step = orig_filter, orig_step


if __name__ == "__main__":
    main()
