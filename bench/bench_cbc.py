"""Per-step computing time of the consensus-based controller (survey §IV.A; §V.A: CBC is cheap).

Runs the offline convoy simulator for each topology/law and convoy size, timing every
``ConsensusController.make_step`` call on the observations the simulator really produces (messages
through a lossy, delayed channel).  Prints mean / median / 95th percentile / max in microseconds.

    python bench/bench_cbc.py [--duration 120] [--trains 4 8]
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from vcsumo.control.base import Command, Observation
from vcsumo.control.channel import ChannelConfig
from vcsumo.control.consensus import ConsensusController, cbc_params_for, load_cbc_params
from vcsumo.control.consensus_stability import delay_margin_s
from vcsumo.sim.offline import SpeedProfile, simulate_convoy


class Timed:
    """Wraps a controller and records the wall time of each make_step (ns)."""

    def __init__(self, inner: ConsensusController, sink: list[int]):
        self.inner = inner
        self.sink = sink

    def make_step(self, obs: Observation) -> Command:
        t0 = time.perf_counter_ns()
        cmd = self.inner.make_step(obs)
        self.sink.append(time.perf_counter_ns() - t0)
        return cmd


def bench(name: str, prm, n_trains: int, duration_s: float) -> tuple[str, int, np.ndarray]:
    samples: list[int] = []
    ch = ChannelConfig(model="exponential", period_s=0.2, delay_s=0.1, mean_extra_s=0.2, loss_probability=0.05, seed=1)
    v = 40.0
    gap = prm.gap.d_min_m + prm.gap.headway_s * v
    simulate_convoy(
        ["etr1000"] * n_trains, lambda tid: Timed(ConsensusController(prm), samples), SpeedProfile((0.0, 60.0, 90.0, 1e4), (v, v, 35.0, 35.0)),
        duration_s, 0.1, ch, [gap + 20.0 * ((k % 3) - 1) for k in range(n_trains - 1)],
    )
    return name, n_trains, np.array(samples[10:], dtype=float) / 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds per case")
    ap.add_argument("--trains", type=int, nargs="+", default=[4, 8], help="convoy sizes (leader included)")
    args = ap.parse_args()
    base = load_cbc_params("cbc")
    cases = [(t, cbc_params_for(t, base)) for t in ("PF", "PLF", "BD", "BDL", "TPF")]
    cases += [("PF eq.4.4 (Δ=0.2)", cbc_params_for("PF", base, link_bound_mps2=0.2))]
    cases += [("PF eq.4.10 (liu)", load_cbc_params("cbc_liu")), ("PF eq.4.11 (zhou)", load_cbc_params("cbc_zhou"))]
    print(f"ConsensusController.make_step per-step time, dt = 0.1 s, {args.duration:g} s simulated per case")
    print(f"python {platform.python_version()} on {platform.machine()}")
    print(f"{'case':<20} {'trains':>6} {'steps':>7} {'mean µs':>9} {'p50 µs':>8} {'p95 µs':>8} {'max µs':>8}")
    for n in args.trains:
        for name, prm in cases:
            _, _, us = bench(name, prm, n, args.duration)
            print(f"{name:<20} {n:>6} {len(us):>7} {us.mean():>9.1f} {np.median(us):>8.1f} {np.percentile(us, 95):>8.1f} {us.max():>8.1f}")
    t0 = time.perf_counter()
    dm = delay_margin_s(cbc_params_for("BD", base, k_pos_per_s2=0.1, k_vel_per_s=0.3, delay_compensation="sender", gap={"d_min_m": 50.0, "headway_s": 0.0}), 4, 0.5)
    print(f"\nanalysis: delay_margin_s (BD, 4 trains) = {dm:.3f} s computed in {1e3 * (time.perf_counter() - t0):.0f} ms")


if __name__ == "__main__":
    main()
