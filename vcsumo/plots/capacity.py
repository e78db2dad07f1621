"""Figures of the capacity study, drawn from its tables only: ``capacity.csv`` (bars) and
``time_distance.csv`` + ``infrastructure.csv`` (blocking-time stairs)."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FuncFormatter, MultipleLocator  # noqa: E402

from vcsumo.plots.common import FAILED_COLOUR, UNHEALTHY_COLOUR, distance_axis, read_table  # noqa: E402

REGIME_COLOURS = {"fbs": "#888888", "mb": "#4477aa"}
VC_COLOURS = ["#cc6677", "#117733", "#ddcc77", "#882255", "#44aa99", "#aa4499", "#999933", "#332288"]


def _text(v) -> str:
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v).strip()


def is_failed(row: pd.Series) -> bool:
    """A case that ended in an error (non-empty ``error``) or has no capacity."""
    cap = row.get("capacity_trains_per_h")
    return bool(_text(row.get("error"))) or cap is None or not np.isfinite(float(cap))


def is_unhealthy(row: pd.Series) -> bool:
    """``healthy`` is false (when the table has run-health columns), or a gap violation or collision was counted."""
    if "healthy" in row.index and _text(row["healthy"]).lower() in ("false", "0", "no"):
        return True
    return any(float(row.get(c, 0) or 0) > 0 for c in ("gap_violations", "collisions") if _text(row.get(c)) != "")


def plot_capacity(table: pd.DataFrame | Path, path: Path):
    """Capacity (trains/h per direction) by regime, VC controller and convoy size; one panel per
    direction (rows) and stopping pattern (columns).  Every bar carries its value and its gain over
    FBS; failed cases are hatched placeholders marked "failed", unhealthy cases (``healthy`` false,
    or any gap violation or collision) are outlined in red and marked.  VC with one train repeats MB
    and is not drawn.  Returns the figure (closed)."""
    df = read_table(table, dtype={"controller": str, "error": str})
    if df is None or df.empty:
        return None
    df = df[~((df["regime"] == "vc") & (df["convoy_size"] == 1))]
    dirs = list(dict.fromkeys(df["direction"]))
    pats = list(dict.fromkeys(df["stopping_pattern"]))
    ctrls = list(dict.fromkeys(df.loc[df["regime"] == "vc", "controller"].fillna("")))
    top = float(pd.to_numeric(df["capacity_trains_per_h"], errors="coerce").max())
    top = top if np.isfinite(top) and top > 0 else 1.0
    n_bars = max(len(g) for _, g in df.groupby(["direction", "stopping_pattern"]))
    fig, axes = plt.subplots(len(dirs), len(pats), figsize=(max(9.0 / len(pats), 0.62 * n_bars + 1.5) * len(pats), 4.3 * len(dirs) + 0.8),
                             squeeze=False, sharey=True, layout="constrained")
    any_failed = any_unhealthy = False
    for i, d in enumerate(dirs):
        for j, pat in enumerate(pats):
            ax = axes[i][j]
            g = df[(df["direction"] == d) & (df["stopping_pattern"] == pat)]
            order = [("fbs", ""), ("mb", "")] + [("vc", c) for c in ctrls]
            x, pos, ticks, labels = 0.0, [], [], []
            for regime, ctrl in order:
                sub = g[(g["regime"] == regime) & ((g["controller"].fillna("") == ctrl) if regime == "vc" else True)]
                if sub.empty:
                    continue
                x0 = x
                for _, r in sub.sort_values("convoy_size").iterrows():
                    pos.append((x, r, regime, ctrl))
                    ticks.append(x)
                    labels.append(regime.upper() if regime != "vc" else f"n={int(r['convoy_size'])}")
                    x += 1.0
                if regime == "vc":  # the controller under its group of convoy sizes
                    ax.annotate(f"VC {ctrl}", xy=((x0 + x - 1.0) / 2, 0), xycoords=("data", "axes fraction"), xytext=(0, -16),
                                textcoords="offset points", ha="center", va="top", fontsize=8)
                x += 0.5
            fbs = g.loc[(g["regime"] == "fbs"), "capacity_trains_per_h"].dropna()
            if len(fbs):
                ax.axhline(float(fbs.iloc[0]), color=REGIME_COLOURS["fbs"], ls="--", lw=0.8, zorder=0)
            for xb, r, regime, ctrl in pos:
                colour = REGIME_COLOURS.get(regime) or VC_COLOURS[ctrls.index(ctrl) % len(VC_COLOURS)]
                if is_failed(r):
                    any_failed = True
                    h = 0.15 * top
                    ax.bar(xb, h, 0.8, color="none", edgecolor=FAILED_COLOUR, hatch="///", lw=0.8)
                    ax.text(xb, h / 2, "failed", rotation=90, ha="center", va="center", fontsize=7, color="0.3",
                            bbox=dict(facecolor="white", edgecolor="none", pad=0.5))
                    continue
                cap = float(r["capacity_trains_per_h"])
                bad = is_unhealthy(r)
                any_unhealthy |= bad
                ax.bar(xb, cap, 0.8, color=colour, edgecolor=UNHEALTHY_COLOUR if bad else "none", lw=2.0 if bad else 0, hatch="xx" if bad else None)
                gain = r.get("gain_vs_fbs")
                text = f"{cap:.0f}"
                if regime != "fbs" and gain is not None and np.isfinite(float(gain)):
                    text += f"\n×{float(gain):.2f}"
                if bad:
                    text = "unhealthy\n" + text
                ax.text(xb, cap + 0.01 * top, text, ha="center", va="bottom", fontsize=7, color=UNHEALTHY_COLOUR if bad else "0.15",
                        bbox=dict(facecolor="white", edgecolor="none", pad=0.3, alpha=0.8))
            ax.set_xticks(ticks, labels, fontsize=8)
            ax.set_xlim(-0.7, max(x - 0.8, 0.7))
            ax.set_ylim(0, top * 1.25)
            ax.set_title(f"{d}, {pat}", fontsize=10)
            ax.grid(axis="y", alpha=0.3)
            if j == 0:
                ax.set_ylabel("capacity [trains/h per direction]")
    handles = [Patch(color=REGIME_COLOURS["fbs"], label="FBS"), Patch(color=REGIME_COLOURS["mb"], label="MB")]
    handles += [Patch(color=VC_COLOURS[k % len(VC_COLOURS)], label=f"VC {c} (n = convoy size)") for k, c in enumerate(ctrls)]
    handles.append(Line2D([], [], color=REGIME_COLOURS["fbs"], ls="--", lw=0.8, label="FBS capacity (×1.00)"))
    if any_failed:
        handles.append(Patch(facecolor="none", edgecolor=FAILED_COLOUR, hatch="///", label="failed (no result)"))
    if any_unhealthy:
        handles.append(Patch(facecolor="white", edgecolor=UNHEALTHY_COLOUR, hatch="xx", label="unhealthy (not clean)"))
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 3), fontsize=8, frameon=False)
    first = df.iloc[0]
    extra = []
    if "train" in df and _text(first.get("train")):
        extra.append(str(first["train"]))
    if "block_length_m" in df and np.isfinite(float(first.get("block_length_m", np.nan))):
        extra.append(f"blocks {float(first['block_length_m']):.0f} m")
    if "fixed_time_s" in df and float(first.get("fixed_time_s", 0) or 0) > 0:
        extra.append(f"fixed times {float(first['fixed_time_s']):g} s")
    fig.suptitle(f"{first['line']} — capacity per direction" + (f" ({', '.join(extra)})" if extra else "") +
                 "; labels: trains/h and gain over FBS", fontsize=11)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return fig


def _release_time_axis(axis, span_s: float) -> None:
    """Ticks every 30 s … 30 min after the release, as ``m:ss``."""
    step = next((s for s in (15, 30, 60, 120, 300, 600, 900, 1800) if span_s / s <= 8), 3600)
    axis.set_major_locator(MultipleLocator(step))
    axis.set_major_formatter(FuncFormatter(lambda x, _pos: f"{'-' if x < 0 else ''}{int(abs(round(x))) // 60}:{int(abs(round(x))) % 60:02d}"))


def _panel_title(p: pd.Series) -> str:
    name = p["regime"].upper() if p["regime"] != "vc" else f"VC {p['controller']} n={int(p['convoy_size'])}"
    return name


def plot_time_distance_stairs(table: pd.DataFrame | Path, path: Path, line_name: str, infrastructure: pd.DataFrame | Path | None = None):
    """Time–distance diagram of one released sequence per regime with its blocking-time stairs
    (from ``time_distance.csv``, see :mod:`vcsumo.studies.time_distance`), station names and the
    signals of the direction on the distance axis.  A regime whose example case failed keeps its
    panel, with the error.  Returns the figure (closed)."""
    df = read_table(table, dtype={"controller": str, "train": str, "note": str}, keep_default_na=False, na_values={"t_from_s": [""]})
    infra = read_table(infrastructure, dtype={"name": str, "track": str, "direction": str}, keep_default_na=False)
    if df is None or df.empty:
        return None
    for c in ("t_from_s", "t_to_s", "km_from", "km_to", "headway_s", "panel", "unit", "convoy_size"):
        df[c] = pd.to_numeric(df[c], errors="coerce")
    panels = [g for _, g in df.groupby("panel", sort=True)]
    ok_km = df.loc[df["kind"] != "failed", ["km_from", "km_to"]].stack()
    fig, axes = plt.subplots(1, len(panels), figsize=(5.6 * len(panels) + 1.0, 6.2), squeeze=False, layout="constrained")
    for ax, g in zip(axes[0], panels):
        p = g.iloc[0]
        if p["kind"] == "failed":
            ax.set_facecolor("#f4f4f4")
            msg = "\n".join(textwrap.wrap(str(p["note"]) or "no result", 48)[:12])
            ax.text(0.5, 0.5, f"{_panel_title(p)} failed\n(the largest convoy, {p['direction']}, {p['stopping_pattern']})\n\n{msg}",
                    transform=ax.transAxes, ha="center", va="center", fontsize=8, color="0.2", wrap=True)
            ax.set_xticks([])
            if len(ok_km):
                ax.set_ylim(float(ok_km.min()), float(ok_km.max()))
            ax.set_title(f"{line_name} {p['direction']}: {_panel_title(p)} — failed", fontsize=10)
            distance_axis(ax, infra, [p["direction"]])
            continue
        for unit, u in g.groupby("unit", sort=True):
            colour = f"C{int(unit)}"
            for _, b in u[u["kind"] == "block"].iterrows():
                ax.fill_betweenx([b["km_from"], b["km_to"]], b["t_from_s"], b["t_to_s"], color=colour, alpha=0.25, lw=0)
            band = u[u["kind"] == "band"]
            if len(band):
                ax.fill_betweenx(band["km_from"], band["t_from_s"], band["t_to_s"], color=colour, alpha=0.25, lw=0)
            sch = u[u["kind"] == "schedule"]
            ax.plot(sch["t_from_s"], sch["km_from"], color=colour, lw=0.9, ls="--")
            for _, tr in u[u["kind"] == "train"].groupby("train", sort=False):
                ax.plot(tr["t_from_s"], tr["km_from"], color="k", lw=0.9)
        ts = g[["t_from_s", "t_to_s"]].stack()
        _release_time_axis(ax.xaxis, float(ts.max() - ts.min()) if len(ts) else 60.0)
        ax.set_xlabel("time after the first release [min:s]")
        ax.set_ylim(float(ok_km.min()), float(ok_km.max()))
        ax.grid(axis="x", alpha=0.3)
        ax.set_title(f"{line_name} {p['direction']}: {_panel_title(p)}, h = {p['headway_s']:.1f} s", fontsize=10)
        distance_axis(ax, infra, [p["direction"]])
    kinds = set(df["kind"])
    handles = [Patch(color="C0", alpha=0.25, label="blocking time, unit 1"), Patch(color="C1", alpha=0.25, label="blocking time, unit 2 (released h later)")]
    handles.append(Line2D([], [], color="0.4", ls="--", lw=0.9, label="leader's unhindered run (shifted by h)"))
    if "train" in kinds:
        handles.append(Line2D([], [], color="k", lw=0.9, label="simulated trains"))
    if infra is not None and len(infra[infra["kind"] == "signal"]):
        handles.append(Line2D([], [], ls="none", marker="^", ms=4, color="0.3", label="signals (▲ up, ▼ down)"))
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 5), fontsize=8, frameon=False, title_fontsize=8,
               title="blocking time — FBS: each block, from the approach point's time until the tail clears the next signal; "
                     "MB / VC: from the time the unit's reservation (supervised braking distance + margin) reaches a point until its last train has passed")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return fig
