"""Plots that read only results tables (CSV/DataFrames), so figures can be redrawn without SUMO."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from matplotlib.lines import Line2D  # noqa: E402

from vcsumo.plots.common import distance_axis, read_table, set_clock_axis, train_styles  # noqa: E402

LEGEND_MAX = 60
"""At most this many legend entries in the run plot (the first trains, then "… and k more")."""


def plot_headway(df: pd.DataFrame, path: Path, infrastructure: pd.DataFrame | Path | None = None, titles: dict[str, str] | None = None):
    """Simulated vs analytic headway per measuring point, one panel per direction: the line's km on
    the x axis with the station names above it (``infrastructure.csv``), FBS / MB in capitals, a
    measuring point without a sustainable headway left out of its line.  ``titles``: direction ->
    its label (the line file's ``directions``).  One legend for all panels, below them, outside every
    axes (until unseen-studies each panel had its own inside it, where matplotlib found room: on a line
    of our own with two trains it lay over the FBS line of the down panel).  Returns the figure (closed)."""
    if df.empty:
        return None
    infra = read_table(infrastructure)
    dirs = list(dict.fromkeys(df["direction"]))
    fig, axes = plt.subplots(1, len(dirs), figsize=(6.5 * len(dirs), 4.4), squeeze=False, layout="constrained")
    for ax, d in zip(axes[0], dirs):
        sub = df[df.direction == d]
        for (regime, train), g in sub.groupby(["regime", "train"]):
            g = g.sort_values("measuring_point_km")
            line, = ax.plot(g.measuring_point_km, g.headway_sim_s, "o-", label=f"{str(regime).upper()} {train} simulated")
            ax.plot(g.measuring_point_km, g.headway_analytic_s, "x--", color=line.get_color(), label=f"{str(regime).upper()} {train} analytic")
        label = (titles or {}).get(d, d)
        ax.set_title(f"{df.line.iloc[0]} — {label}" if label == d else f"{df.line.iloc[0]} — {d}: {label}", fontsize=10)
        ax.set_xlabel("measuring point [km]")
        ax.set_ylabel("minimum headway [s]")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        distance_axis(ax, infra, (d,), axis="x", signals=False)
    entries: dict[str, object] = {}  # every (regime, train, kind) once, in drawing order, over all panels
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(lab, h)
    fig.legend(list(entries.values()), list(entries), loc="outside lower center", ncol=min(len(entries), 4), fontsize=7, frameon=False)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return fig


def plot_run(traj: pd.DataFrame | Path, path: Path, title: str = "", infrastructure: pd.DataFrame | Path | None = None):
    """Graphical timetable (time–distance, clock time) and speed–distance of every train of a run.

    Reads ``trajectories.csv`` and, for station names and signals on the distance axis,
    ``infrastructure.csv`` (:mod:`vcsumo.infrastructure`).  Only the main line is drawn.  Styles
    stay distinct for many trains (:func:`vcsumo.plots.common.train_styles`); the legend sits
    outside the axes, at most :data:`LEGEND_MAX` entries.  Returns the figure (closed).
    """
    traj = read_table(traj)
    infra = read_table(infrastructure)
    if traj is None or traj.empty:
        return None
    traj = traj.sort_values("time_s", kind="stable")  # trains in order of departure
    trains = list(dict.fromkeys(traj["train"].astype(str)))
    styles, labels = train_styles(trains)
    fig = plt.figure(figsize=(13, 9), layout="constrained")
    a1, a2 = fig.subplots(2, 1, height_ratios=[3, 1.25])
    directions = set()
    # a network of lines (sections '<line>.main'): the main line with the most train-seconds
    sec = "main" if (traj["section"] == "main").any() else str(traj.loc[traj["section"].str.endswith(".main"), "section"].mode().iat[0])
    for train, g in traj.groupby(traj["train"].astype(str), sort=False):
        km = g["km"].where(g["section"] == sec)
        if km.notna().sum() < 1:
            continue
        k = km.dropna()
        directions.add("up" if k.iloc[-1] >= k.iloc[0] else "down")
        st = styles[train]
        a1.plot(g["time_s"], km, lw=1.0, color=st["color"], ls=st["ls"], label=labels.get(train, "_nolegend_"))
        a2.plot(km, g["speed_mps"] * 3.6, lw=0.7, color=st["color"], ls=st["ls"], alpha=0.8)
    t0, t1 = float(traj["time_s"].min()), float(traj["time_s"].max())
    a1.set_xlim(t0 - 0.01 * (t1 - t0), t1 + 0.01 * (t1 - t0))
    set_clock_axis(a1.xaxis, t0, t1)
    a1.set_xlabel("clock time [HH:MM]")
    main = traj.loc[traj["section"] == sec, "km"]
    if len(main):
        lo, hi = float(main.min()), float(main.max())
        if infra is not None and len(infra):  # the stations just beyond the trains' ends too
            near = max(0.05 * (hi - lo), 0.5)
            st = infra.loc[(infra["kind"] == "station") & (infra["section"] == sec), "km"].astype(float)
            st = st[(st >= lo - near) & (st <= hi + near)]
            lo, hi = min([lo, *st]), max([hi, *st])
        pad = max(0.02 * (hi - lo), 0.05)
        a1.set_ylim(lo - pad, hi + pad)
        a2.set_xlim(lo - pad, hi + pad)
    a1.grid(axis="x", alpha=0.3)
    a1.grid(axis="x", which="minor", alpha=0.12)
    a1.set_title(f"{title or 'time–distance'} — {len(trains)} train{'s' if len(trains) != 1 else ''}" + ("" if sec == "main" else f" — {sec[:-5]}"))
    distance_axis(a1, infra, sorted(directions) or ("up", "down"), section=sec)
    a2.set_xlabel("km")
    a2.set_ylabel("speed [km/h]")
    a2.set_ylim(bottom=0)
    a2.grid(alpha=0.3)
    distance_axis(a2, infra, axis="x", signals=False, section=sec)
    handles, names = a1.get_legend_handles_labels()
    if len(handles) > LEGEND_MAX:  # the first trains, the signals, and how many more
        keep = [k for k, n in enumerate(names) if n.startswith("signal")]
        first = [k for k in range(len(handles)) if k not in keep][: LEGEND_MAX - len(keep) - 1]
        more = len(handles) - len(first) - len(keep)
        handles = [handles[k] for k in first] + [Line2D([], [], ls="none")] + [handles[k] for k in keep]
        names = [names[k] for k in first] + [f"… and {more} more trains"] + [names[k] for k in keep]
    if handles:
        ncol = max(1, -(-len(handles) // 40))
        grouped = len(trains) > 20 and any("trains)" in n for n in names)
        fig.legend(handles, names, loc="outside right upper", fontsize=7 if len(handles) <= 40 else 6, ncol=ncol,
                   title="services" if grouped else "trains", title_fontsize=8, frameon=False)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return fig


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
