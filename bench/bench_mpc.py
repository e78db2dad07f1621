"""Benchmark of the follower NMPC (Felez et al. 2019, eq. 12) and of one felez2019 strategy.

Prints the CPU time per follower solve (``make_step``: prediction of the leader, warm start, real-
time iterations) over a few hundred closed-loop steps — start from rest behind a leader,
acceleration with the power limit active, cruising on the terminal set 12m — for each horizon,
``--repeats`` times, each repeat with the load average of the machine: mean, median and p99, and
the wall time of ``run_felez2019(("SH",))``.

Targets on the 2-core machine: median ≤ 1 ms, p99 ≤ 5 ms (N_p = 40), one strategy ≤ 10 s; issue
14: mean ≤ 0.24 ms CPU at N_p = 17.  Wall-clock times include whatever else the machine does (on a
shared or virtual machine the p99 of the wall time is dominated by preemption and CPU steal), so
the figures to compare are CPU times, in paired runs (before/after alternately) at a similar load.

Run: ``python bench/bench_mpc.py [--steps 600] [--horizons 40 17] [--repeats 3] [--no-felez]``
"""

from __future__ import annotations

import argparse
import gc
import os
import time

import numpy as np

from vcsumo.control.base import Message, Observation, TrainStateMsg
from vcsumo.control.route_lookup import straight_route_profile
from vcsumo.control.mpc import FollowerMPC, LeaderMPC
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.reproduce.felez2019 import load_scenario, run_felez2019
from vcsumo.rolling_stock import load_rolling_stock


def follower_solve_times(steps: int, horizon: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """(wall s, CPU s) per follower solve over ``steps`` closed-loop steps and the infeasible count
    (``horizon``: N_p of both controllers, default the parameter file's 40)."""
    sc = load_scenario()
    cfg = sc.settings.model_copy(update={"a_follower_mps2": 0.75, **({"horizon_steps": horizon} if horizon else {})})
    p = load_rolling_stock("felez2019").params()
    route = straight_route_profile(1200.0, 27.78)
    leader, follower = LeaderMPC(p, cfg), FollowerMPC(p, cfg, predictor="SH")
    lp = TrainPlant(p, PlantState(100.0, 0.0, 0.0), route)
    fp = TrainPlant(p, PlantState(100.0 - p.length_m - cfg.d_min_m, 0.0, 0.0), route)
    wall, cpu, last = [], [], None
    dt = cfg.step_s
    for k in range(steps):
        t = k * dt
        xl, xf = lp.x, fp.x
        obs_l = Observation(time_s=t, step_s=dt, ego_id="L", ego=TrainStateMsg(t, xl.s_m, xl.v_mps, xl.accel_mps2, xl.force_n), params=p, profile=route,
                            target_speed_mps=20.0)
        cl = leader.make_step(obs_l)
        kw = {}
        if last is not None:
            kw = dict(plan_times_s=last.plan_times_s, plan_positions_m=last.plan_positions_m, plan_speeds_mps=last.plan_speeds_mps, plan_forces_n=last.plan_forces_n)
        msg = Message("L", t, TrainStateMsg(t, xl.s_m, xl.v_mps), p.length_m, **kw)
        obs_f = Observation(time_s=t, step_s=dt, ego_id="F", ego=TrainStateMsg(t, xf.s_m, xf.v_mps, xf.accel_mps2, xf.force_n), params=p, profile=route,
                            received={"L": msg}, predecessor="L", sensed_gap_m=xl.s_m - p.length_m - xf.s_m, sensed_speed_mps=xl.v_mps, target_speed_mps=20.0)
        c0, w0 = time.process_time(), time.perf_counter()
        cf = follower.make_step(obs_f)
        w1, c1 = time.perf_counter(), time.process_time()
        if k > 0:  # the first call builds the route data (DP) once
            wall.append(w1 - w0)
            cpu.append(c1 - c0)
        lp.step(cl.force_n, dt)
        fp.step(cf.force_n, dt)
        last = cl
    return np.array(wall), np.array(cpu), follower.stats.infeasible


def load() -> str:
    return "load " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=600, help="closed-loop steps (solves) of the follower")
    ap.add_argument("--horizons", type=int, nargs="+", default=[40, 17], help="prediction horizons N_p to time (issue 14: N = 17, mean <= 0.24 ms)")
    ap.add_argument("--repeats", type=int, default=3, help="closed loops timed per horizon")
    ap.add_argument("--no-felez", action="store_true", help="skip the felez2019 strategy run")
    args = ap.parse_args()
    print(f"{load()} (1, 5, 15 min)")
    for n in args.horizons:
        follower_solve_times(20, n)  # build and warm up (CasADi functions, DP cache)
        cpus = []
        for r in range(args.repeats):
            gc.collect()
            wall, cpu, infeasible = follower_solve_times(args.steps, n)
            cpus.append(cpu)
            print(f"follower NMPC N_p = {n:3d} run {r + 1}: {len(cpu)} solves, {infeasible} infeasible, CPU per solve mean {np.mean(cpu) * 1e3:6.3f} ms  "
                  f"median {np.median(cpu) * 1e3:6.3f} ms  p99 {np.percentile(cpu, 99) * 1e3:6.3f} ms  (wall median {np.median(wall) * 1e3:6.3f} ms, "
                  f"p99 {np.percentile(wall, 99) * 1e3:6.3f} ms)  {load()}")
        cpu = np.concatenate(cpus)
        means = [np.mean(c) * 1e3 for c in cpus]
        print(f"follower NMPC N_p = {n:3d} all : CPU per solve mean {np.mean(cpu) * 1e3:6.3f} ms (runs {min(means):.3f}-{max(means):.3f})  median "
              f"{np.median(cpu) * 1e3:6.3f} ms  p99 {np.percentile(cpu, 99) * 1e3:6.3f} ms")
    if not args.no_felez:
        t0 = time.perf_counter()
        df = run_felez2019(("SH",))
        wall_one = time.perf_counter() - t0
        row = df.iloc[0]
        print(f"felez2019 one strategy (SH, 2 trains, {row['leader_stop_time_s']:.0f} s simulated): wall time {wall_one:.2f} s "
              f"(distance {row['stop_distance_m']:.1f} m, paper {row['paper_stop_distance_m']:.1f} m)  {load()}")


if __name__ == "__main__":
    main()
