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


def plot_felez2019(trajectories: dict, path: Path) -> None:
    """Speed, gap and force over time for each strategy (Felez et al. Fig. 10-12)."""
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    for name, tr in trajectories.items():
        trains = sorted({c[1:-4] for c in tr.columns if c.startswith("v") and c.endswith("_mps")}, key=int)
        for i in trains:
            style = "-" if i == "0" else "--"
            label = f"{name} train {i}" if i != "0" else f"{name} leader"
            axes[0].plot(tr.time_s, tr[f"v{i}_mps"], style, lw=1, label=label)
            if f"gap{i}_m" in tr:
                axes[1].plot(tr.time_s, tr[f"gap{i}_m"], lw=1, label=f"{name} gap {int(i) - 1}-{i}")
            if f"F{i}_n" in tr:
                axes[2].plot(tr.time_s, tr[f"F{i}_n"] / 1000.0, style, lw=1, label=label)
    axes[0].set_ylabel("speed [m/s]")
    axes[1].set_ylabel("gap [m]")
    axes[2].set_ylabel("force [kN]")
    axes[2].set_xlabel("time [s]")
    for a in axes:
        a.grid(alpha=0.3)
        a.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_terlizzi2024(traj: pd.DataFrame, path: Path, title: str = "") -> None:
    """Barrier, gap, speeds, forces and active controller mode over time (Terlizzi et al. Fig. 5-6)."""
    fig, axes = plt.subplots(5, 1, figsize=(10, 12), sharex=True)
    t = traj.time_s
    if "true_barrier_m" in traj:
        axes[0].plot(t, traj.true_barrier_m, lw=1, label="true barrier b(x)")
    if "robust_barrier_m" in traj:
        axes[0].plot(t, traj.robust_barrier_m, lw=1, label="robust barrier")
    axes[0].axhline(0.0, color="k", lw=0.8)
    axes[0].set_ylabel("barrier [m]")
    axes[1].plot(t, traj.gap_m, lw=1, label="gap (front-to-rear)")
    axes[1].set_ylabel("gap [m]")
    axes[2].plot(t, traj.leader_speed_mps, lw=1, label="leader")
    axes[2].plot(t, traj.follower_speed_mps, lw=1, label="follower")
    axes[2].set_ylabel("speed [m/s]")
    axes[3].plot(t, traj.leader_force_n / 1000.0, lw=1, label="leader")
    axes[3].plot(t, traj.follower_force_n / 1000.0, lw=1, label="follower")
    axes[3].set_ylabel("force [kN]")
    modes = traj["mode"].astype(str)
    order = sorted(modes.unique())
    axes[4].step(t, modes.map({m: k for k, m in enumerate(order)}), where="post", lw=1)
    axes[4].set_yticks(range(len(order)), order)
    axes[4].set_ylabel("mode")
    axes[4].set_xlabel("time [s]")
    axes[0].set_title(title)
    for a in axes:
        a.grid(alpha=0.3)
    for a in axes[:4]:
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_capacity(df: pd.DataFrame, path: Path) -> None:
    """Capacity (trains/h per direction) by regime, controller and convoy size; one panel per direction × pattern."""
    if df.empty:
        return
    groups = list(df.groupby(["direction", "stopping_pattern"]))
    fig, axes = plt.subplots(1, len(groups), figsize=(6 * len(groups), 4.5), squeeze=False)
    for ax, ((d, pat), g) in zip(axes[0], groups):
        labels, values, colors = [], [], []
        palette = {"fbs": "#888888", "mb": "#4477aa"}
        vc_cols = ["#cc6677", "#ddcc77", "#117733", "#882255", "#44aa99", "#aa4499"]
        ctrls = [c for c in dict.fromkeys(g[g.regime == "vc"].controller)]
        for _, r in g.iterrows():
            if r.regime == "vc":
                labels.append(f"VC {r.controller}\nn={r.convoy_size}")
                colors.append(vc_cols[ctrls.index(r.controller) % len(vc_cols)])
            else:
                labels.append(r.regime.upper())
                colors.append(palette[r.regime])
            values.append(r.capacity_trains_per_h)
        ax.bar(range(len(values)), values, color=colors)
        ax.set_xticks(range(len(values)), labels, rotation=60, fontsize=7, ha="right")
        ax.set_ylabel("capacity [trains/h per direction]")
        ax.set_title(f"{df.line.iloc[0]} — {d}, {pat}")
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_time_distance_stairs(examples: dict, setups: dict, path: Path, line_name: str) -> None:
    """Time–distance diagram of one released sequence per regime with its blocking-time stairs.

    FBS: one rectangle per block (from the approach point's time to the tail clearing the next
    signal); MB / VC: the band reserved ahead of each unit (braking distance + 50 m) until its
    last train's tail has passed.  Stairs come from the leader's unhindered run, shifted by the
    release interval; the lines are the simulated trains.
    """
    import numpy as np

    if not examples:
        return
    fig, axes = plt.subplots(1, len(examples), figsize=(6 * len(examples), 6), squeeze=False)
    for ax, (regime, res) in zip(axes[0], examples.items()):
        setup = setups[res.units[0][0].direction]
        full = setup.full
        run = res.run
        t = run.time_s.to_numpy()
        s = run.s_m.to_numpy()
        v = run.speed_mps.to_numpy()
        km = np.array([full.km_at(x)[1] for x in s])
        stock = res.units[0][0].stock
        n = len(res.units[0])
        gap = res.row.get("intra_convoy_gap_m")
        L_u = n * stock.length_m + (n - 1) * (gap if gap == gap and gap is not None else 0.0)
        for j in range(len(res.units)):
            shift = j * res.h
            color = f"C{j}"
            if res.blocks is not None:
                for _, b in res.blocks.iterrows():
                    k0, k1 = full.km_at(b.block_start_m)[1], full.km_at(b.block_end_m)[1]
                    ax.fill_betweenx([k0, k1], (b.t_approach_s + shift) / 60, (b.t_clear_s + shift) / 60, color=color, alpha=0.25, lw=0)
            else:
                d = v * v / (2 * stock.service_brake_decel_mps2) + 50.0
                t_app = np.interp(s - d, s, t, left=t[0])
                t_clr = np.interp(s + L_u, s, t, right=np.nan)
                ax.fill_betweenx(km, (t_app + shift) / 60, (t_clr + shift) / 60, color=color, alpha=0.25, lw=0)
            ax.plot((t + shift) / 60, km, color=color, lw=0.8, ls="--")
        traces = res.probe.sim.speed_traces if res.probe is not None else {}
        for u in res.units:
            for tr in u:
                if tr.id in traces:
                    ts, _ = traces[tr.id]
                    off = full.length_m - tr.profile.length_m
                    kms = [full.km_at(x + off)[1] for x in ts[::10]]
                    tt = tr.depart_s + np.arange(len(ts))[::10] * (res.run.time_s.iloc[1] - res.run.time_s.iloc[0])
                    ax.plot(tt / 60, kms, color="k", lw=0.9)
        ax.set_xlabel("time [min]")
        ax.set_ylabel("km")
        title = regime.upper() if regime != "vc" else f"VC {res.row['controller']} n={n}"
        ax.set_title(f"{line_name} {setup.direction}: {title}, h = {res.h:.1f} s")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
