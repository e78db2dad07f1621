"""``vcsumo reproduce``: run a seed paper's experiment and write its tables and figures.

* :func:`reproduce_felez2019` — Felez, Kim & Borrelli (2019) §IV-A: ``felez2019.csv`` (SH, NP, MB:
  ``strategy, stop_distance_m, stop_delay_s, min_gap_m, collisions`` beside the paper's values),
  ``felez2019_convoy4.csv`` (Fig. 10), ``felez2019_horizon.csv`` (Fig. 11), the time series and
  PNG plots (speed, gap, force, active mode).
* :func:`reproduce_terlizzi2024` — Terlizzi, Liuzza & Glielmo (2024) OS1 (channel delay 3 s and
  0.8 s) and OS2 (with and without the delay estimator): ``terlizzi2024_<scenario>.csv`` summary
  rows, the time series and PNG plots (barrier, gap, speeds, force, controller mode).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from vcsumo.plots.charts import plot_felez2019, plot_terlizzi2024

FELEZ_COLUMNS = ["strategy", "stop_distance_m", "paper_stop_distance_m", "stop_distance_deviation_pct", "stop_delay_s", "paper_stop_delay_s",
                 "gap_at_rest_m", "min_gap_m", "collisions", "infeasible_steps", "a_follower_mps2", "solve_time_median_ms", "wall_time_s"]


def reproduce_felez2019(out: Path, strategies: tuple[str, ...] = ("SH", "NP", "MB"), horizon: int = 40, sweep: bool = True, convoy: bool = True, progress=None) -> pd.DataFrame:
    """Write the §IV-A reproduction into ``out``; returns the strategy table."""
    from vcsumo.reproduce import felez2019 as fz

    steps = len(strategies) + int(sweep) + int(convoy)
    done = 0
    rows = []
    trajectories = {}
    for s in strategies:
        df = fz.run_felez2019((s,), horizon)
        rows.append(df)
        trajectories.update(df.attrs["trajectories"])
        done += 1
        if progress:
            progress(done, steps)
    table = pd.concat(rows, ignore_index=True)
    table["stop_distance_deviation_pct"] = 100.0 * (table["stop_distance_m"] - table["paper_stop_distance_m"]) / table["paper_stop_distance_m"]
    table = table[[c for c in FELEZ_COLUMNS if c in table.columns]]
    table.to_csv(out / "felez2019.csv", index=False)
    for s, tr in trajectories.items():
        tr.to_csv(out / f"felez2019_{s}_trajectory.csv", index=False)
    plot_felez2019(trajectories, out / "felez2019.png")
    if convoy:
        res = fz.convoy(4, horizon=horizon)
        pd.DataFrame([res.metrics]).to_csv(out / "felez2019_convoy4.csv", index=False)
        res.trajectory.to_csv(out / "felez2019_convoy4_trajectory.csv", index=False)
        plot_felez2019({"4-train SH": res.trajectory}, out / "felez2019_convoy4.png")
        done += 1
        if progress:
            progress(done, steps)
    if sweep:
        fz.horizon_sweep().to_csv(out / "felez2019_horizon.csv", index=False)
        done += 1
        if progress:
            progress(done, steps)
    return table


def reproduce_terlizzi2024(out: Path, scenarios: tuple[str, ...] = ("os1", "os2"), progress=None) -> pd.DataFrame:
    """Write the OS1/OS2 reproduction into ``out``; returns the summary rows."""
    from vcsumo.reproduce import terlizzi2024 as tz

    runs = []
    if "os1" in scenarios:
        runs += [("os1_delay_3s", lambda: tz.run_os1(3.0)), ("os1_delay_0.8s", lambda: tz.run_os1(0.8))]
    if "os2" in scenarios:
        runs += [("os2_estimator_on", lambda: tz.run_os2(True)), ("os2_estimator_off", lambda: tz.run_os2(False))]
    rows = []
    for k, (name, fn) in enumerate(runs):
        row, traj = fn()
        row = dict(row)
        row["run"] = name
        rows.append(row)
        traj.to_csv(out / f"terlizzi2024_{name}_trajectory.csv", index=False)
        plot_terlizzi2024(traj, out / f"terlizzi2024_{name}.png", name)
        if progress:
            progress(k + 1, len(runs))
    summary = pd.DataFrame(rows)
    cols = ["run"] + [c for c in summary.columns if c != "run"]
    summary = summary[cols]
    for sc in scenarios:
        part = summary[summary.run.str.startswith(sc)]
        if len(part):
            part.to_csv(out / f"terlizzi2024_{sc}.csv", index=False)
    return summary
