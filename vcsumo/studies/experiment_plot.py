"""The figure of one experiment run: speed, gap, force and active mode over time (and the CBF's barrier).

Drawn from the run's recorded trajectories only (the rows of ``trajectories.csv``), so it can be
redrawn from a results folder: ``plot_trajectories(pd.read_csv("x/trajectories.csv").query("run == 'default-seed1'"), "x.png")``.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402


def plot_trajectories(traj: pd.DataFrame, path: Path, title: str = "") -> None:
    """Speed [m/s], gap [m] (front to rear solid, front to front dashed), applied force [kN], the
    followers' active mode, and the robust and true barrier [m] when a CBF recorded it."""
    has_barrier = traj["robust_barrier_m"].notna().any() or traj["true_barrier_m"].notna().any()
    rows = 5 if has_barrier else 4
    fig, axes = plt.subplots(rows, 1, figsize=(10, 2.3 * rows + 0.6), sharex=True)
    trains = list(dict.fromkeys(traj["train"]))
    colours = plt.get_cmap("tab10").colors
    followers = trains[1:]
    for k, tid in enumerate(trains):
        d = traj[traj["train"] == tid]
        c = colours[k % len(colours)]
        axes[0].plot(d.time_s, d.speed_mps, lw=1, color=c, label=tid + (" (leader)" if k == 0 and "leader" not in tid.lower() else ""))
        axes[2].plot(d.time_s, d.force_n / 1000.0, lw=0.8, color=c, label=tid)
        if k == 0:
            continue
        axes[1].plot(d.time_s, d.gap_front_to_rear_m, lw=1, color=c, label=f"{tid}: front to rear")
        axes[1].plot(d.time_s, d.gap_front_to_front_m, lw=0.8, ls="--", color=c, label=f"{tid}: front to front")
    modes = sorted(set(traj.loc[traj["train"].isin(followers), "mode"].astype(str)))
    code = {m: j for j, m in enumerate(modes)}
    for k, tid in enumerate(followers, start=1):
        d = traj[traj["train"] == tid]
        axes[3].step(d.time_s, d["mode"].astype(str).map(code) + 0.08 * (k - 1), where="post", lw=1, color=colours[k % len(colours)], label=tid)
    axes[3].set_yticks(range(len(modes)), modes)
    if has_barrier:
        for k, tid in enumerate(followers, start=1):
            d = traj[traj["train"] == tid]
            c = colours[k % len(colours)]
            axes[4].plot(d.time_s, d.robust_barrier_m, lw=0.8, color=c, alpha=0.6, label=f"{tid}: robust b(x̲^L, x^F)")
            axes[4].plot(d.time_s, d.true_barrier_m, lw=1, color=c, ls=":", label=f"{tid}: true b(x)")
        axes[4].axhline(0.0, color="k", lw=0.8)
        axes[4].set_ylabel("barrier [m]")
        lo = np.nanpercentile(traj["robust_barrier_m"].to_numpy(dtype=float), 1) if traj["robust_barrier_m"].notna().any() else -1.0
        axes[4].set_ylim(max(lo, -5000.0), None)
    axes[0].set_ylabel("speed [m/s]")
    axes[1].set_ylabel("gap [m]")
    axes[2].set_ylabel("force [kN]")
    axes[3].set_ylabel("active mode")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(title)
    for a in axes:
        a.grid(alpha=0.3)
        a.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_run(result, path: Path) -> None:
    """:func:`plot_trajectories` of a :class:`~vcsumo.studies.experiment.RunResult`."""
    exp = result.experiment
    plot_trajectories(result.trajectories, path, f"{exp.name}: {result.run}" + (f" — {exp.title}" if exp.title else ""))


__all__ = ["plot_trajectories", "plot_run"]
