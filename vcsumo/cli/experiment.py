"""``vcsumo experiment FILE.yaml``: an offline convoy experiment from a file (:mod:`vcsumo.studies.experiment`).

A thin command: validate the file (every problem one ``error: <file>: <field>: <problem>`` line,
exit status 2, nothing written), run its runs (its own and its variants', for each seed) with a
progress bar, write the results folder atomically and print the headline measurements.
:mod:`vcsumo.cli.main` registers it.
"""

from __future__ import annotations

from pathlib import Path

import click
import pandas as pd

from vcsumo.cli.ui import out_console, print_table, progress_bar, progress_task
from vcsumo.cli.verdict import require_clean
from vcsumo.errors import InputError

HEADLINE = ["min_gap_front_to_rear_m", "collisions", "emergency_activations", "true_barrier_max_m", "gap_front_to_rear_mean_m", "gap_front_to_front_mean_m",
            "gap_at_brake_onset_m", "gap_at_rest_m", "stop_delay_s", "step_time_mean_ms"]


def _csv(value: str | None, kind=str) -> list | None:
    if value is None:
        return None
    items = [x.strip() for x in value.split(",") if x.strip()]
    try:
        return [kind(x) for x in items]
    except ValueError:
        raise InputError(None, "--seeds", f"'{value}' is not a comma-separated list of integers") from None


def headline(table: pd.DataFrame) -> pd.DataFrame:
    """One row per run and follower (and window): the headline quantities side by side."""
    m = table[(table.train != "") & table.quantity.isin(HEADLINE)].copy()
    m["where"] = m.train + m.window.map(lambda w: f" @ {w}" if w else "")
    wide = m.pivot_table(index=["run", "where"], columns="quantity", values="value", aggfunc="first", sort=False).reset_index()
    runs = table[table.quantity.isin(["wall_time_s", "cpu_time_s"])].pivot_table(index="run", columns="quantity", values="value", aggfunc="first").reset_index()
    return wide.merge(runs, on="run", how="left")[["run", "where"] + [c for c in HEADLINE + ["wall_time_s", "cpu_time_s"] if c in wide.columns or c in runs.columns]]


@click.command("experiment")
@click.argument("file")
@click.option("--variants", default=None, help="Only these runs of the file (its label and variant names), comma-separated")
@click.option("--seeds", default=None, help="Seeds in place of the file's, comma-separated integers")
@click.option("--no-plots", is_flag=True, help="Skip the PNG of every run")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (default: new folder under results/)")
def experiment_cmd(file: str, variants: str | None, seeds: str | None, no_plots: bool, out: Path | None) -> None:
    """Run an offline convoy experiment file (a path, or a shipped name such as terlizzi2024_os1_authors).

    Writes trajectories.csv, measurements.csv (tidy: run, variant, seed, train, window, quantity,
    value, unit), one PNG per run (speed, gap, force, active mode) and meta.json.
    """
    from vcsumo.results import ResultsFolder, default_out
    from vcsumo.studies.experiment import input_files, plan_runs, run_file, write_results
    from vcsumo.studies.experiment_model import load_experiment

    path, _, runs = load_experiment(file)
    seed_list = _csv(seeds, int)
    if seed_list is not None and (not seed_list or any(not 0 <= s < 2**32 for s in seed_list)):
        raise InputError(None, "--seeds", "give one or more seeds, 0–2³²−1")
    names = _csv(variants)
    plan_runs(path, names, seed_list, check=True)  # every run's set-up is built once: problems before anything is written
    out = out or default_out("experiment", runs[0][1].name)
    with ResultsFolder(out, seed=seed_list[0] if seed_list else runs[0][1].seeds[0], params={"variants": names, "seeds": seed_list}) as rf:
        with progress_bar() as prog, progress_task(prog, runs[0][1].name) as upd:
            results = run_file(path, names, seed_list, progress=upd)
        table = write_results(results, rf.path, plots=not no_plots)
        rf.inputs = input_files(path, results)
        rf.extra_meta = {"experiment": runs[0][1].name, "runs": [{"run": r.run, "wall_time_s": round(r.wall_time_s, 3), "cpu_time_s": round(r.cpu_time_s, 3),
                                                                   "steps": r.steps, "healthy": r.healthy} for r in results]}
    print_table(headline(table), f"{runs[0][1].name} — {runs[0][1].title}" if runs[0][1].title else runs[0][1].name, csv_path=out / "measurements.csv")
    for r in results:
        if not r.healthy:
            over, below = r.overspeeding(), r.below_separation()
            why = "; ".join(([f"above the permitted speed: {', '.join(over)}"] if over else [])
                            + ([f"below the safe separation: {', '.join(below)}"] if below else [])) or "a collision, or the true barrier above zero"
            out_console.print(f"{r.run}: NOT HEALTHY ({why}: see measurements.csv)", markup=False, highlight=False)
        unguarded = r.below_separation(guarded=False)
        if unguarded:
            out_console.print(f"{r.run}: below the safe separation without the separation guard (guard: false, not judged): {', '.join(unguarded)}",
                              markup=False, highlight=False)
        missed = r.missed_emergency_brake()
        if missed:
            out_console.print(f"{r.run}: {missed}", markup=False, highlight=False)
        stop = r.measurements[r.measurements["quantity"] == "leader_stop_time_s"]["value"]
        if len(stop) and stop.isna().all():
            out_console.print(f"{r.run}: the leader did not stop within the run: no stop measured", markup=False, highlight=False)
    out_console.print(f"wrote {out}")
    require_clean("the experiment", len(results), 0, sum(not r.healthy for r in results), out / "measurements.csv", noun="runs")
