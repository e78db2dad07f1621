"""``vcsumo reproduce``: run a seed paper's shipped experiment files and write its tables and figures.

* :func:`reproduce_felez2019` — Felez, Kim & Borrelli (2019) §IV-A (``felez2019_{sh,np,mb}.yaml``):
  ``felez2019.csv`` (SH, NP, MB, each with one a^f for all — the files' run ``one_af`` — and the
  labelled fit ``fitted``: ``stop_distance_m`` = gap at the leader's brake onset, ``stop_delay_s``,
  ``gap_at_rest_m``, beside the paper's values), ``felez2019_convoy4.csv`` (Fig. 10, fitted:
  ``gap_at_brake_onset{i}_m``, ``gap_at_rest{i}_m``, ``stop_delay{i}_s`` per follower),
  ``felez2019_horizon.csv`` (Fig. 11, fitted), the time series, ``measurements.csv`` and PNG plots.
* :func:`reproduce_terlizzi2024` — Terlizzi, Liuzza & Glielmo (2024) OS1 (delays 3 s and 0.8 s),
  OS2 (delay estimator on and off) and the authors'-code OS1: ``terlizzi2024_<scenario>.csv``
  summary rows, ``terlizzi2024_comparison.csv`` (paper / authors' code / vcsumo with the paper's
  equations / vcsumo with the authors' conventions), the time series, ``measurements.csv`` and PNG
  plots (barrier, gap, speeds, force, controller mode).
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from vcsumo.plots.charts import plot_felez2019, plot_terlizzi2024

FELEZ_COLUMNS = ["strategy", "variant", "a_follower_mps2", "stop_distance_m", "paper_stop_distance_m", "stop_distance_deviation_pct", "stop_delay_s",
                 "paper_stop_delay_s", "gap_at_rest_m", "min_gap_m", "collisions", "infeasible_steps", "solve_time_median_ms", "wall_time_s"]


def reproduce_felez2019(out: Path, strategies: tuple[str, ...] = ("SH", "NP", "MB"), horizon: int = 40, sweep: bool = True, convoy: bool = True, progress=None) -> pd.DataFrame:
    """Write the §IV-A reproduction into ``out``; returns the strategy table (both variants)."""
    from vcsumo.reproduce import felez2019 as fz

    steps = len(strategies) + int(sweep) + int(convoy)
    done = 0
    rows, trajectories, measurements = [], {}, []
    for s in strategies:
        for variant in (None, "fitted"):
            df = fz.run_felez2019((s,), horizon, variant=variant)
            rows.append(df.iloc[0].to_dict())
            name = s if variant is None else f"{s} fitted"
            trajectories[name] = df.attrs["trajectories"][s]
        done += 1
        if progress:
            progress(done, steps)
    table = pd.DataFrame(rows)
    table["stop_distance_deviation_pct"] = 100.0 * (table["stop_distance_m"] - table["paper_stop_distance_m"]) / table["paper_stop_distance_m"]
    table = table[[c for c in FELEZ_COLUMNS if c in table.columns]]
    table.to_csv(out / "felez2019.csv", index=False)
    for name, tr in trajectories.items():
        tr.to_csv(out / f"felez2019_{name.replace(' ', '_')}_trajectory.csv", index=False)
    plot_felez2019(trajectories, out / "felez2019.png")
    if convoy:
        res = fz.convoy(4, horizon=horizon, variant="fitted")
        pd.DataFrame([res.metrics]).to_csv(out / "felez2019_convoy4.csv", index=False)
        res.trajectory.to_csv(out / "felez2019_convoy4_trajectory.csv", index=False)
        plot_felez2019({"4-train SH": res.trajectory}, out / "felez2019_convoy4.png")
        measurements.append(res.run.measurements.assign(run="convoy4-" + res.run.run))
        done += 1
        if progress:
            progress(done, steps)
    if sweep:
        fz.horizon_sweep(variant="fitted").to_csv(out / "felez2019_horizon.csv", index=False)
        done += 1
        if progress:
            progress(done, steps)
    if measurements:
        pd.concat(measurements, ignore_index=True).to_csv(out / "measurements.csv", index=False)
    return table


def comparison_table(summary: pd.DataFrame) -> pd.DataFrame:
    """Paper / authors' code / vcsumo with the paper's equations (OS1 0.8 s) / vcsumo with the authors' conventions, per quantity."""
    from vcsumo.reproduce.terlizzi2024 import AUTHORS_CODE, PAPER

    by = summary.set_index("run")

    def get(run: str, col: str) -> float:
        return float(by.loc[run, col]) if run in by.index and col in by.columns else math.nan

    rows = []
    for speed in (50, 60, 40):
        for conv, key in (("front_to_front", "interdistance"), ("front_to_rear", "gap")):
            col = f"{key}_at_{speed}_m"
            paper = PAPER["coupled_interdistance_50_m"] if (speed == 50 and key == "interdistance") else math.nan
            authors = AUTHORS_CODE.get(f"coupled_interdistance_{speed}_m", math.nan) if key == "interdistance" else math.nan
            rows.append({"quantity": f"OS1 coupled distance at {speed} m/s ({conv.replace('_', ' ')}) m", "paper": paper, "authors_code": authors,
                         "vcsumo_paper_equations": get("os1_delay_0.8s", col), "vcsumo_authors_conventions": get("os1_authors", col)})
    rows.append({"quantity": "OS1 both stopped (front to front) m", "paper": math.nan, "authors_code": AUTHORS_CODE["both_stopped_interdistance_m"],
                 "vcsumo_paper_equations": get("os1_delay_0.8s", "both_stopped_interdistance_m"), "vcsumo_authors_conventions": get("os1_authors", "both_stopped_interdistance_m")})
    rows.append({"quantity": "OS2 coupled at 50 m/s in 300-500 s (front to front) m", "paper": PAPER["os2_interdistance_m"], "authors_code": math.nan,
                 "vcsumo_paper_equations": get("os2_estimator_on", "interdistance_steady_m"), "vcsumo_authors_conventions": math.nan})
    for run, label in (("os2_estimator_on", "with"), ("os2_estimator_off", "without")):
        rows.append({"quantity": f"OS2 emergency activations {label} the delay estimator", "paper": math.nan, "authors_code": math.nan,
                     "vcsumo_paper_equations": get(run, "emergency_activations"), "vcsumo_authors_conventions": math.nan})
    return pd.DataFrame(rows)


def reproduce_terlizzi2024(out: Path, scenarios: tuple[str, ...] = ("os1", "os2", "authors"), progress=None) -> pd.DataFrame:
    """Write the OS1/OS2 (and authors'-code OS1) reproduction into ``out``; returns the summary rows."""
    from vcsumo.reproduce import terlizzi2024 as tz

    rows, meas = [], []
    jobs = []
    if "os1" in scenarios:
        jobs += [("os1", lambda: tz.run_os1(3.0, full=True), 3.0), ("os1", lambda: tz.run_os1(0.8, full=True), 0.8)]
    if "os2" in scenarios:
        jobs += [("os2", lambda: tz.run_os2(True, full=True), True), ("os2", lambda: tz.run_os2(False, full=True), False)]
    if "authors" in scenarios:
        jobs += [("authors", lambda: tz.run_authors(full=True), None)]
    for k, (scen, fn, arg) in enumerate(jobs):
        res = fn()
        if scen == "os1":
            row = {"run": f"os1_delay_{arg:g}s", **tz.summary_row(res, "OS1"), "delay_s": float(arg)}
        elif scen == "os2":
            row = {"run": f"os2_{res.variant}", **tz.os2_row(res), "delay_s": math.nan}
        else:
            row = {"run": "os1_authors", **tz.summary_row(res, "OS1"), "delay_s": math.nan}
        row["file"] = res.experiment.name
        rows.append(row)
        traj = tz.wide_trajectory(res)
        traj.to_csv(out / f"terlizzi2024_{row['run']}_trajectory.csv", index=False)
        plot_terlizzi2024(traj, out / f"terlizzi2024_{row['run']}.png", f"{row['run']} ({res.experiment.name})")
        meas.append(res.measurements.assign(run=row["run"]))
        if progress:
            progress(k + 1, len(jobs))
    summary = pd.DataFrame(rows)
    summary = summary[["run", "file"] + [c for c in summary.columns if c not in ("run", "file")]]
    for sc in scenarios:
        part = summary[summary.run.str.startswith(sc if sc != "authors" else "os1_authors")]
        if sc == "os1":
            part = part[part.run != "os1_authors"]
        if len(part):
            part.to_csv(out / f"terlizzi2024_{sc}.csv", index=False)
    comparison_table(summary).to_csv(out / "terlizzi2024_comparison.csv", index=False)
    pd.concat(meas, ignore_index=True).to_csv(out / "measurements.csv", index=False)
    return summary
