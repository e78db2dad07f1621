"""Plots of the junction study; they read only the study's CSV tables (``junction_trajectories.csv``,
``junction_sweep.csv``), so figures can be redrawn without SUMO."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

_VC_COLORS = ["#cc6677", "#117733", "#882255", "#44aa99", "#ddcc77", "#aa4499", "#332288", "#999933"]


def _str_columns(df: pd.DataFrame) -> None:
    """Controller and variant columns as strings ('' for FBS/MB, which CSV reads back as NaN)."""
    for c in ("controller", "junction_signal"):
        df[c] = ["" if (isinstance(x, float) and np.isnan(x)) else str(x) for x in df[c]]


def _variant_label(r) -> str:
    if r.regime != "vc":
        return r.regime.upper()
    lab = f"VC {r.controller}"
    if isinstance(r.junction_signal, str) and r.junction_signal and r.junction_signal != "sumo":
        lab += f" ({r.junction_signal})"
    return lab


def identical_variants(groups: dict, columns: list[str]) -> dict:
    """Variants whose rows (``columns``) equal an earlier variant's: ``{variant: [variants drawn
    with it]}`` for the first of each set, ``{variant: None}`` for the others (drawn once, labelled
    together: two identical runs, e.g. cbc and a CBF that never intervened, would hide one another)."""
    out: dict = {}
    seen: dict = {}
    for key, g in groups.items():
        data = g[[c for c in columns if c in g]].reset_index(drop=True)
        first = next((k for k, d in seen.items() if d.shape == data.shape and d.equals(data)), None)
        if first is None:
            seen[key] = data
            out[key] = [key]
        else:
            out[first].append(key)
            out[key] = None
    return out


def _joined_label(rows: list) -> str:
    labels = [_variant_label(r) for r in rows]
    return labels[0] if len(labels) == 1 else " = ".join(labels) + " (identical runs)"


def plot_junction_regimes(traj_csv: Path, out_dir: Path, before_km: float = 12.0, after_km: float = 15.0) -> list[Path]:
    """``junction_<regime>.png`` for every regime: virtual gap and speeds around each junction.

    One row of panels per (junction, direction, leader service); for the merge and for the split
    junction of the scenario: the follower's virtual gap to the leader against the follower's
    distance to that junction, and the speeds of leader (thin) and follower (thick) against their
    own distance, with the follower running alone (dotted).  Solid: the simultaneous-arrival run
    (Δ = 0); dashed: the run at the merge's minimum offset (split-only scenarios: at the split's).
    """
    traj_csv = Path(traj_csv)
    if not traj_csv.is_file() or traj_csv.stat().st_size < 10:
        return []
    text = {c: str for c in ("merge_junction", "split_junction", "controller", "junction_signal", "sensed_leader")}
    df = pd.read_csv(traj_csv, dtype=text, low_memory=False)
    if df.empty:
        return []
    _str_columns(df)
    for c in ("merge_junction", "split_junction"):
        if c in df:
            df[c] = ["" if (isinstance(x, float) and np.isnan(x)) else str(x) for x in df[c]]
    written = []
    solo = df[df.run == "solo"]
    pairs = df[df.run != "solo"]
    for regime, rg in pairs.groupby("regime"):
        scen = list(rg.groupby(["junction", "direction", "leader_service"]).groups.keys())
        kinds_of = {}
        for j, d, lead in scen:
            sc = rg[(rg.junction == j) & (rg.direction == d) & (rg.leader_service == lead)]
            kinds_of[(j, d, lead)] = [k for k in ("merge", "split") if sc[f"distance_to_{k}_m"].notna().any()]
        ncol = 2 * max((len(k) for k in kinds_of.values()), default=1) or 2
        fig, axes = plt.subplots(len(scen), ncol, figsize=(5.6 * ncol, 4.2 * len(scen)), squeeze=False)
        variants = list(dict.fromkeys(zip(rg.controller, rg.junction_signal)))
        for ax_row, (j, d, lead) in zip(axes, scen):
            sc = rg[(rg.junction == j) & (rg.direction == d) & (rg.leader_service == lead)]
            follower = "main" if lead == "branch" else "branch"
            alone = solo[(solo.junction == j) & (solo.direction == d) & (solo.service == follower) & (solo.regime == ("mb" if regime == "vc" else regime))]
            kinds = kinds_of[(j, d, lead)]
            for ax in ax_row[2 * len(kinds):]:
                ax.set_axis_off()
            for col, kind in zip(range(0, ncol, 2), kinds):
                ax_g, ax_v = ax_row[col], ax_row[col + 1]
                dist = f"distance_to_{kind}_m"
                name = sc[f"{kind}_junction"].iloc[0] if f"{kind}_junction" in sc else ""
                lo, hi = (-before_km, after_km) if kind == "merge" else (-after_km, before_km / 2)
                min_run = "merge_min" if sc.distance_to_merge_m.notna().any() else "split_min"
                drawn = identical_variants({v: sc[(sc.controller == v[0]) & (sc.junction_signal == v[1])] for v in variants},
                                           ["run", "role", "time_s", "virtual_gap_m", "speed_mps"])
                for vi, (ctrl, var) in enumerate(variants):
                    color = _VC_COLORS[vi % len(_VC_COLORS)] if regime == "vc" else ("#888888" if regime == "fbs" else "#4477aa")
                    if drawn.get((ctrl, var)) is None:
                        continue
                    lab = _joined_label([sc[(sc.controller == c) & (sc.junction_signal == v)].iloc[0] for c, v in drawn[(ctrl, var)]])
                    for run, g in sc[(sc.controller == ctrl) & (sc.junction_signal == var)].groupby("run"):
                        if run not in ("simultaneous", min_run):
                            continue
                        ls = "-" if run == "simultaneous" else "--"
                        off = "Δ=0" if run == "simultaneous" else f"Δ*={g.offset_s.iloc[0]:.0f} s"
                        fol = g[g.role == "follower"].sort_values("time_s")
                        led = g[g.role == "leader"].sort_values("time_s")
                        xf = fol[dist] / 1000.0
                        win = (xf >= lo) & (xf <= hi)
                        ax_g.plot(xf[win], fol.virtual_gap_m[win], ls, color=color, lw=1.3, label=f"{lab}, {off}")
                        if run == "simultaneous":
                            xl = led[dist] / 1000.0
                            wl = (xl >= lo) & (xl <= hi)
                            ax_v.plot(xl[wl], led.speed_mps[wl] * 3.6, ls, color=color, lw=0.8, alpha=0.6, label=f"{lab} leader")
                            ax_v.plot(xf[win], fol.speed_mps[win] * 3.6, ls, color=color, lw=1.7, label=f"{lab} follower")
                if len(alone):
                    a = alone.sort_values("time_s")
                    xa = a[dist] / 1000.0
                    wa = (xa >= lo) & (xa <= hi)
                    ax_v.plot(xa[wa], a.speed_mps[wa] * 3.6, ":", color="k", lw=1.0, label="follower alone")
                for ax in (ax_g, ax_v):
                    ax.axvline(0.0, color="k", lw=0.8)
                    ax.grid(alpha=0.3)
                    ax.set_xlim(lo, hi)
                    ax.set_xlabel(f"distance of the train front to the {kind} junction [km]")
                ax_g.axhline(0.0, color="k", lw=0.5)
                ax_g.set_ylabel("virtual gap follower→leader [m]")
                ax_v.set_ylabel("speed [km/h]")
                ax_g.set_title(f"{sc.line.iloc[0]} {d}, {lead} service leads: {kind} {name} — gap", fontsize=9)
                ax_v.set_title(f"{kind} {name} — speed", fontsize=9)
                ax_g.legend(fontsize=6)
                ax_v.legend(fontsize=6, ncol=2)
        fig.tight_layout()
        path = Path(out_dir) / f"junction_{regime}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    return written


def plot_junction_sweep(sweep_csv: Path, path: Path) -> Path | None:
    """Follower's lost time vs arrival offset (solid: at the end of its route; dashed: at the merge check
    point; dotted: at the merge junction), one panel per scenario; offsets whose run was not healthy
    are marked with a red cross."""
    sweep_csv = Path(sweep_csv)
    if not sweep_csv.is_file() or sweep_csv.stat().st_size < 10:
        return None
    df = pd.read_csv(sweep_csv)
    if df.empty:
        return None
    _str_columns(df)
    scen = list(df.groupby(["junction", "direction", "leader_service"]).groups.keys())
    fig, axes = plt.subplots(1, len(scen), figsize=(5.5 * len(scen), 4.2), squeeze=False)
    for ax, (j, d, lead) in zip(axes[0], scen):
        sc = df[(df.junction == j) & (df.direction == d) & (df.leader_service == lead)]
        vi = 0
        cases = {k: g.sort_values("offset_s") for k, g in sc.groupby(["regime", "controller", "junction_signal"], sort=False)}
        drawn = identical_variants(cases, ["offset_s", "follower_lost_END_s", "follower_lost_PM_s", "follower_lost_M_s", "healthy"])
        for (regime, ctrl, var), g in cases.items():
            if drawn[(regime, ctrl, var)] is None:
                continue
            name = _joined_label([cases[k].iloc[0] for k in drawn[(regime, ctrl, var)]])
            if regime == "vc":
                color = _VC_COLORS[vi % len(_VC_COLORS)]
                vi += 1
            else:
                color = "#888888" if regime == "fbs" else "#4477aa"
            lost = g.follower_lost_END_s.replace([np.inf, -np.inf], np.nan)
            ax.plot(g.offset_s, lost, "o-", ms=3, color=color, label=name + " (route end)")
            if "follower_lost_PM_s" in g and g.follower_lost_PM_s.notna().any():
                pm = g.follower_lost_PM_s.replace([np.inf, -np.inf], np.nan)
                ax.plot(g.offset_s, pm, "--", lw=1.0, color=color, label=name + " (after the merge)")
            if "follower_lost_M_s" in g and g.follower_lost_M_s.notna().any():
                at_j = g.follower_lost_M_s.replace([np.inf, -np.inf], np.nan)
                ax.plot(g.offset_s, at_j, ":", lw=1.0, color=color, label=name + " (at the junction)")
            if "healthy" in g:
                bad = g[g.healthy.astype(str) == "False"]
                if len(bad):
                    ax.plot(bad.offset_s, bad.follower_lost_END_s.replace([np.inf, -np.inf], np.nan).fillna(0.0), "x", color="red", ms=8, mew=2,
                            label=name + " not healthy")
        ax.axhline(0.0, color="k", lw=0.6)
        merges = "follower_lost_PM_s" in sc and sc.follower_lost_PM_s.replace([np.inf, -np.inf], np.nan).notna().any()
        ax.set_xlabel("arrival offset at the merge, alone [s]" if merges else "release interval at the common release point [s]")
        ax.set_ylabel("follower's lost time [s]")
        ax.set_title(f"{sc.line.iloc[0]} {j} {d}: {lead} leads")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
