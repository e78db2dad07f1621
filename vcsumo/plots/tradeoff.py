"""The trade-off figure: line capacity of FBS, MB and VC against one assumption at a time.

Drawn from the study's CSVs only (``tradeoff.csv``, optionally ``tradeoff_check.csv`` and
``tradeoff_breakeven.csv``), so it can be redrawn without recomputing anything.  One panel per
swept assumption: capacity (trains/h) against its value, one line per regime (FBS, MB, VC for each
convoy size), the base assumption set's value marked; a regime whose rule does not use the
assumption is drawn dashed and named in the panel (it is computed under the same changed set, and
stays flat).  Simulated checks are crosses beside the VC n=2 line.  With the grid rows, a last
panel maps VC's gain over MB (smallest convoy) over T2T delay × braking uncertainty.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

AXES = {
    "t2t_delay_bound_s": ("T2T delay bound (message age VC relies on), s", 1.0, "{:g} s"),
    "braking_uncertainty": ("braking uncertainty, ± % of nominal deceleration", 100.0, "±{:g} %"),
    "position_error_m": ("position error per train, m", 1.0, "{:g} m"),
}
"""Swept assumption -> (axis label with units, scale from the CSV's SI value, base-value label)."""
GRID = "grid"
REGIME_NAMES = {"fbs": "FBS", "mb": "MB"}
STYLE = {"fbs": ("black", "s"), "mb": ("tab:blue", "o")}
VC_COLOURS = ["tab:orange", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan"]


def _label(regime: str, n: int) -> str:
    return REGIME_NAMES.get(regime, f"VC n={n}")


def _style(regime: str, n: int) -> tuple[str, str]:
    return STYLE.get(regime) or (VC_COLOURS[(n - 2) % len(VC_COLOURS)], "^")


def _read(path: Path | None) -> pd.DataFrame | None:
    if path is None or not Path(path).is_file():
        return None
    return pd.read_csv(path, dtype={"error": str}, keep_default_na=False, na_values=[""])


def plot_tradeoff(csv: Path, path: Path, check_csv: Path | None = None, breakeven_csv: Path | None = None):
    """Draw ``tradeoff.png`` (see the module) into ``path``; returns the figure (closed)."""
    df = _read(csv)
    check = _read(check_csv)
    be = _read(breakeven_csv)
    params = [p for p in AXES if p in set(df.parameter)]
    has_grid = GRID in set(df.parameter)
    n_panels = len(params) + int(has_grid)
    cols = max(n_panels, 1) if n_panels <= 3 else 2
    rows = math.ceil(max(n_panels, 1) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.6 * cols, 4.6 * rows + 0.8), squeeze=False)
    axes = axes.ravel()
    units = list(dict.fromkeys(zip(df.regime, df.convoy_size.astype(int))))
    handles = {}
    for ax, param in zip(axes, params):
        label, scale, fmt = AXES[param]
        g = df[df.parameter == param]
        not_used = []
        for regime, n in units:
            r = g[(g.regime == regime) & (g.convoy_size == n)].sort_values("value")
            if r.empty:
                continue
            colour, marker = _style(regime, n)
            used = bool(r.parameter_in_rule.astype(str).str.lower().eq("true").all())
            if not used:
                not_used.append(_label(regime, n))
            (h,) = ax.plot(r.value * scale, r.capacity_trains_per_h, color=colour, marker=marker, ms=4, lw=1.6, ls="-" if used else "--")
            handles.setdefault(_label(regime, n), h)
        base = float(g.base_value.iloc[0])
        ax.axvline(base * scale, color="0.45", lw=0.9, ls=":")
        ax.plot([base * scale], [0.0], marker="^", ms=9, color="0.3", transform=ax.get_xaxis_transform(), clip_on=False)
        for regime, n in units:  # the base point on every line
            b = g[(g.regime == regime) & (g.convoy_size == n) & (g.value == base)]
            if len(b):
                ax.plot(base * scale, float(b.capacity_trains_per_h.iloc[0]), marker="o", ms=8, mfc="none", mec="0.3", lw=0)
        if check is not None:
            c = check[(check.parameter == param) & (check.error.fillna("") == "")]
            if len(c):
                h = ax.scatter(c.value * scale, c.capacity_sim_trains_per_h, marker="x", s=60, color="black", zorder=5)
                handles.setdefault(f"VC n=2 simulated ({c.controller.iloc[0]})", h)
        notes = [f"dotted, ▲: base ({df.assumptions.iloc[0]}) {fmt.format(round(base * scale, 6))}"]
        if not_used:
            notes.append(f"dashed: {', '.join(not_used)} — rule does not use it (computed under the same changed set)")
        if param == "t2t_delay_bound_s" and be is not None:
            ahead = []
            for _, b in be.iterrows():
                v = b.breakeven_value
                if isinstance(v, float) and math.isfinite(v):
                    notes.append(f"VC n={int(b.convoy_size)} falls to MB's capacity at {v:g} s")
                else:
                    ahead.append(str(int(b.convoy_size)))
            if ahead:
                notes.append(f"VC n={', '.join(ahead)} beat{'s' if len(ahead) == 1 else ''} MB at every bound up to {float(be.searched_up_to.iloc[0]):g} s")
        ax.set_title("\n".join(notes), fontsize=7.5, loc="left", color="0.2")
        ax.set_xlabel(label)
        ax.set_ylabel("line capacity, trains/h")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    if has_grid:
        _grid_panel(axes[len(params)], df, fig)
    for ax in axes[n_panels:]:
        ax.set_visible(False)
    first = df.iloc[0]
    fig.suptitle(f"{first.line} ({first.direction}, {first.pattern}), {first.train}, assumption set {first.assumptions}:\nanalytic line capacity "
                 "as one assumption changes (the others at base), every regime under the same changed set", fontsize=10)
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=min(len(handles), 7), fontsize=8.5, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 0.93))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return fig


def _grid_panel(ax, df: pd.DataFrame, fig) -> None:
    """VC's gain over MB (smallest convoy) over T2T delay × braking uncertainty, with the 1.0 contour."""
    g = df[(df.parameter == GRID) & (df.regime == "vc")]
    n = int(g.convoy_size.min())
    g = g[g.convoy_size == n]
    piv = g.pivot_table(index="braking_uncertainty", columns="t2t_delay_bound_s", values="gain_vs_mb")
    x, y, z = piv.columns.to_numpy(float), piv.index.to_numpy(float) * 100.0, piv.to_numpy(float)
    im = ax.pcolormesh(np.arange(len(x) + 1), np.arange(len(y) + 1), z, cmap="RdYlGn", vmin=min(0.5, np.nanmin(z)), vmax=max(1.5, np.nanmax(z)))
    for i in range(len(y)):
        for j in range(len(x)):
            if np.isfinite(z[i, j]):
                ax.text(j + 0.5, i + 0.5, f"{z[i, j]:.2f}", ha="center", va="center", fontsize=7)
    if np.nanmin(z) < 1.0 < np.nanmax(z):
        ax.contour(np.arange(len(x)) + 0.5, np.arange(len(y)) + 0.5, z, levels=[1.0], colors="black", linewidths=1.5)
    ax.set_xticks(np.arange(len(x)) + 0.5, [f"{v:g}" for v in x])
    ax.set_yticks(np.arange(len(y)) + 0.5, [f"{v:g}" for v in y])
    ax.set_xlabel("T2T delay bound, s")
    ax.set_ylabel("braking uncertainty, ± %")
    ax.set_title(f"VC n={n} capacity / MB capacity (1.0: no gain)", fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.05, pad=0.02)
