"""Plots that read only results tables (CSV/DataFrames), so figures can be redrawn without SUMO."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402


def plot_headway(df: pd.DataFrame, path: Path) -> None:
    """Simulated vs analytic headway per measuring point, one panel per direction."""
    if df.empty:
        return
    dirs = list(dict.fromkeys(df["direction"]))
    fig, axes = plt.subplots(1, len(dirs), figsize=(6 * len(dirs), 4), squeeze=False)
    for ax, d in zip(axes[0], dirs):
        sub = df[df.direction == d]
        for (regime, train), g in sub.groupby(["regime", "train"]):
            g = g.sort_values("measuring_point_km")
            line, = ax.plot(g.measuring_point_km, g.headway_sim_s, "o-", label=f"{regime} {train} simulated")
            ax.plot(g.measuring_point_km, g.headway_analytic_s, "x--", color=line.get_color(), label=f"{regime} {train} analytic")
        ax.set_title(f"{df.line.iloc[0]} — {d}")
        ax.set_xlabel("measuring point [km]")
        ax.set_ylabel("minimum headway [s]")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_run(traj: pd.DataFrame, path: Path, title: str = "") -> None:
    """Time-distance (graphical timetable) and speed-distance of every train in a run."""
    if traj.empty:
        return
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 8))
    for train, g in traj.groupby("train"):
        main = g[g.section == "main"]
        a1.plot(main.time_s / 60.0, main.km, lw=1)
        a2.plot(main.km, main.speed_mps * 3.6, lw=1, label=train)
    a1.set_xlabel("time [min]")
    a1.set_ylabel("km")
    a1.set_title(title or "time–distance")
    a1.grid(alpha=0.3)
    a2.set_xlabel("km")
    a2.set_ylabel("speed [km/h]")
    a2.grid(alpha=0.3)
    if traj.train.nunique() <= 15:
        a2.legend(fontsize=6, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
