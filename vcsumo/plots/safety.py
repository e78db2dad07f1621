"""Figures of a safety campaign, drawn from its CSVs only (no simulation needed to redraw them)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402


def plot_safety(runs_csv: Path, path: Path):
    """Left: the smallest margin of every run (true gap − the safe separation of the run-health
    monitor's relative-braking rule), per controller and loop (symmetric-log axis; below zero is a
    violation). Right: share of scenarios with a separation violation and with a collision, per
    controller and loop, each labelled (a zero share as "0" with a mark on the axis, so that "none"
    is seen, not missed).  Returns the figure (closed)."""
    df = pd.read_csv(runs_csv, dtype={"error": str, "loop": str}, keep_default_na=False)
    df = df[df["error"] == ""].copy()
    if "loop" in df and df["loop"].nunique() > 1:  # both loops in one table: one group per loop and controller
        df["controller"] = df["controller"] + " (" + df["loop"] + ")"
    ctrls = list(dict.fromkeys(df["controller"]))
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [3, 2]})
    data = [pd.to_numeric(df.loc[df["controller"] == c, "min_margin_m"]).to_numpy() for c in ctrls]
    if ctrls:
        ax1.boxplot(data, tick_labels=ctrls, whis=(0, 100), showfliers=False)
        rng = np.random.default_rng(0)
        for k, d in enumerate(data, start=1):
            ax1.scatter(k + rng.uniform(-0.18, 0.18, d.size), d, s=4, alpha=0.35, color="tab:red" if np.any(d < 0) else "tab:blue")
    ax1.axhline(0.0, color="k", lw=0.8)
    ax1.set_yscale("symlog", linthresh=10.0)
    ax1.set_ylabel("min (gap − safe separation), m")
    ax1.set_title(f"gap margin per run ({len(df)} runs)")
    viol = [float((pd.to_numeric(df.loc[df["controller"] == c, "separation_violations"]) > 0).mean()) for c in ctrls]
    coll = [float((pd.to_numeric(df.loc[df["controller"] == c, "collisions"]) > 0).mean()) for c in ctrls]
    x = np.arange(len(ctrls))
    for shares, dx, name, colour in ((viol, -0.2, "with a separation violation", "tab:orange"), (coll, 0.2, "with a collision", "tab:red")):
        ax2.bar(x + dx, shares, 0.4, label=name, color=colour)
        for xi, v in zip(x + dx, shares):  # every share labelled; a zero share gets a mark on the axis
            if v == 0:
                ax2.plot(xi, 0.0, marker="o", ms=5, mfc="white", mec=colour, mew=1.2, clip_on=False, zorder=3)
            ax2.text(xi, v + 0.015, share_text(v), ha="center", va="bottom", fontsize=8, color="0.15")
    ax2.set_xticks(x, ctrls)
    ax2.set_ylim(0, 1.08)
    ax2.set_ylabel("share of scenarios")
    ax2.legend(fontsize=8, loc="upper left", bbox_to_anchor=(0.0, -0.12), ncol=2, frameon=False)
    ax2.set_title("violations and collisions")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return fig


def share_text(v: float) -> str:
    """A share as a label: ``0`` for none, else a percentage (one decimal below 1 %)."""
    if not np.isfinite(v):
        return "–"
    if v == 0:
        return "0"
    return f"{100 * v:.1f} %" if v < 0.01 else f"{100 * v:.0f} %"
