"""Figures of a timetable batch (``vcsumo batch``), drawn from its CSVs only: arrival-delay
distributions and punctuality per timetable, regime and controller."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

DELAY_LINES_S = (180.0, 300.0)
"""Reference lines of the delay plot: the batch's punctuality thresholds, 3 and 5 min
(:data:`vcsumo.studies.batch.PUNCTUALITY_THRESHOLDS_S`; plots do not import studies)."""


def regime_label(regime: str, controller) -> str:
    """``fbs``, or ``vc`` and its controller on a second line."""
    return regime if not isinstance(controller, str) or not controller else f"{regime}\n{controller}"


def plot_delays(trains_csv: Path, runs_csv: Path, path: Path):
    """Arrival-delay distributions per regime (box plots, one panel per timetable), from the CSVs.
    Returns the figure (closed)."""
    runs = pd.read_csv(runs_csv, dtype={"run_key": str, "controller": str}, keep_default_na=False)
    tr = pd.read_csv(trains_csv, dtype={"run_key": str, "controller": str}, keep_default_na=False)
    tr = tr[tr["run_key"].isin(set(runs["run_key"]))]
    tr = tr[tr["arrived"].astype(str) == "True"].copy()
    tr["arrival_delay_s"] = pd.to_numeric(tr["arrival_delay_s"], errors="coerce")
    tts = list(dict.fromkeys(runs["timetable"])) or ["(none)"]
    fig, axes = plt.subplots(1, len(tts), figsize=(max(4.0, 3.2 * len(tts)), 4.2), squeeze=False, sharey=True)
    for ax, tt in zip(axes[0], tts):
        sub = tr[tr["timetable"] == tt]
        groups = list(dict.fromkeys(zip(runs.loc[runs["timetable"] == tt, "regime"], runs.loc[runs["timetable"] == tt, "controller"])))
        data, labels = [], []
        for regime, ctrl in groups:
            vals = sub[(sub["regime"] == regime) & (sub["controller"] == ctrl)]["arrival_delay_s"].dropna().to_numpy() / 60.0
            data.append(vals if len(vals) else [float("nan")])
            labels.append(regime_label(regime, ctrl))
        if data:
            ax.boxplot(data, showfliers=True, widths=0.6)
            ax.set_xticks(range(1, len(labels) + 1), labels)
            for k, vals in enumerate(data, start=1):  # a group without any arrival: every run failed (or no train arrived)
                if not np.isfinite(np.asarray(vals, dtype=float)).any():
                    ax.text(k, 0.5, "no arrivals\n(runs failed)", transform=ax.get_xaxis_transform(), ha="center", va="center", fontsize=8,
                            color="0.35", bbox=dict(facecolor="#f0f0f0", edgecolor="0.7", boxstyle="round,pad=0.3"))
        for thr, ls in zip(DELAY_LINES_S, ("--", ":")):
            ax.axhline(thr / 60.0, color="grey", ls=ls, lw=0.8)
        ax.set_title(tt)
        ax.grid(alpha=0.3, axis="y")
    axes[0][0].set_ylabel("arrival delay [min]  (lines: 3 and 5 min)")
    fig.suptitle(f"{runs['line'].iloc[0] if len(runs) else ''} — arrival delay per regime (all seeds)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return fig


def zoomed_percent_range(values: np.ndarray, step: float = 5.0) -> tuple[float, float]:
    """The lower limit of a percentage axis that shows differences: a multiple of ``step`` at least
    one step below the smallest value (0 if the values spread over more than half the scale), and
    the upper limit just above 100 % for the labels."""
    v = values[np.isfinite(values)]
    if not len(v):
        return 0.0, 105.0
    lo = math.floor((float(v.min()) - 0.5 * step) / step) * step
    if lo < 50.0:
        lo = 0.0
    return max(lo, 0.0), 100.0 + 0.12 * (100.0 - max(lo, 0.0))


def plot_punctuality(runs_csv: Path, path: Path):
    """Mean 3-min / 5-min punctuality per timetable and regime over the seeds (bars with their values;
    whiskers: lowest and highest seed), from batch_runs.csv.  The axis is zoomed onto the values
    (it starts at a multiple of 5 %, noted on the axis); the legend sits above the bars; a group
    whose runs all failed keeps its place, marked "failed".  Returns the figure (closed)."""
    keys = ["timetable", "regime", "controller"]
    every = pd.read_csv(runs_csv, dtype={"controller": str}, keep_default_na=False)
    groups = list(dict.fromkeys(zip(*(every[k] for k in keys)))) if len(every) else []
    runs = every[every["status"] == "ok"].copy()
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * max(len(groups), 1) + 2.0), 4.4), layout="constrained")
    lo, hi = 0.0, 105.0
    if groups:
        cols = ["punctuality_3min_share", "punctuality_5min_share"]
        for c in cols:
            runs[c] = 100.0 * pd.to_numeric(runs[c], errors="coerce")
        index = pd.MultiIndex.from_tuples(groups, names=keys)
        grouped = runs.groupby(keys, sort=False)[cols]
        mean, low, high = (x.reindex(index) for x in (grouped.mean(), grouped.min(), grouped.max()))
        count = grouped.count().reindex(index).fillna(0)
        lo, hi = zoomed_percent_range(np.concatenate([low[cols].to_numpy().ravel(), mean[cols].to_numpy().ravel()]))
        x = np.arange(len(groups))
        for k, (c, name, colour) in enumerate(zip(cols, ("≤ 3 min", "≤ 5 min"), ("#4477aa", "#ee7733"))):
            xs = x + (k - 0.5) * 0.38
            m = mean[c].to_numpy()
            yerr = np.vstack([m - low[c].to_numpy(), high[c].to_numpy() - m])
            ax.bar(xs, m - lo, 0.38, bottom=lo, color=colour, label=f"punctual {name}")
            ax.errorbar(xs, m, yerr=yerr, fmt="none", ecolor="0.25", elinewidth=0.8, capsize=2)
            for xi, mi, top in zip(xs, m, high[c].to_numpy()):
                if np.isfinite(mi):
                    ax.text(xi, top + 0.01 * (hi - lo), f"{mi:.1f}", ha="center", va="bottom", fontsize=7, color="0.15")
        for xi, n in zip(x, count[cols[0]].to_numpy()):
            if n == 0:  # every run of the group failed
                ax.bar(xi, 0.2 * (hi - lo), 0.76, bottom=lo, color="none", edgecolor="#bbbbbb", hatch="///", lw=0.8)
                ax.text(xi, lo + 0.1 * (hi - lo), "failed", ha="center", va="center", fontsize=8, color="0.3",
                        bbox=dict(facecolor="white", edgecolor="none", pad=0.5))
        runs_per = every.groupby(keys, sort=False).size().reindex(index).to_numpy()
        labels = [f"{t}\n{regime_label(r, c)}\n({int(n)} of {int(a)} run{'s' if a != 1 else ''})"
                  for (t, r, c), n, a in zip(groups, count[cols[0]].to_numpy(), runs_per)]
        ax.set_xticks(x, labels, fontsize=7)
        fig.legend(loc="outside upper center", ncol=2, fontsize=8, frameon=False)
    ax.set_ylim(lo, hi)
    step = next(st for st in (1, 2, 5, 10, 20, 25) if (100.0 - lo) / st <= 8)
    ax.set_yticks(np.arange(lo, 100.0 + 1e-9, step))  # no tick above 100 %
    ax.set_ylabel("punctual trains [%]" + (f"  (axis from {lo:.0f} %)" if lo > 0 else ""))
    ax.set_title("punctuality: mean over the runs that finished, whiskers lowest–highest seed", fontsize=9)
    ax.grid(alpha=0.3, axis="y")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return fig
