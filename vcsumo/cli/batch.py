"""``vcsumo batch``: timetable experiments with primary delays over regimes, controllers and seeds.

A thin command in the style of :mod:`vcsumo.cli.main`: parse options, load inputs, call
:func:`vcsumo.studies.batch.run_batch` with a progress bar, print a summary table and where it wrote.
Register it in :mod:`vcsumo.cli.main` with ``from vcsumo.cli.batch import batch_cmd`` and
``cli.add_command(batch_cmd)`` (this module imports :mod:`vcsumo.cli.main` only when the command runs).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from vcsumo.cli.ui import out_console, print_table, progress_bar

from vcsumo.errors import InputError


def _csv_list(value: str | None, option: str) -> list[str] | None:
    if value is None:
        return None
    items = [x.strip() for x in value.split(",") if x.strip()]
    if not items:
        raise InputError(None, option, "empty list")
    return items


def _seeds(count: int, first: int) -> list[int]:
    if count < 1:
        raise InputError(None, "--seeds", f"{count}: at least one seed is needed")
    return list(range(first, first + count))


@click.command("batch")
@click.option("--line", "line_spec", required=True, help="Shipped line or network name, or path to a line.yaml or network.yaml")
@click.option("--timetables", default=None,
              help="Timetables: comma-separated names, paths or glob patterns, e.g. 'routes/L/*.yaml' (default: every timetable of the line)")
@click.option("--regimes", default="fbs,mb,vc", show_default=True, help="Comma-separated regimes (fbs, mb, vc)")
@click.option("--seeds", "n_seeds", type=int, default=3, show_default=True, help="Number of seeds per combination")
@click.option("--first-seed", type=int, default=1, show_default=True, help="Seeds are first-seed, first-seed+1, ...")
@click.option("--controllers", default=None, help="Comma-separated VC controllers, vc only (default: cbf-cbc)")
@click.option("--delay-config", type=click.Path(path_type=Path), default=None,
              help="YAML file of primary delays (default: 30 % of trains exp(120 s) at origin, 10 % of stops exp(30 s))")
@click.option("--workers", type=int, default=None, help="Parallel worker processes, 1 or more (default: number of CPUs; 1 = in this process)")
@click.option("--scheduler", default=None, help="Run on a Dask cluster: address of its scheduler, tcp://HOST:PORT")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="Batch folder (default: results/batch-<line>-<hash of line and delays>; the same command resumes there)")
@click.option("--step-length", type=float, default=0.5, show_default=True, help="SUMO step, s")
@click.option("--block-length-m", type=float, default=None, help="Override the line's block length, m")
@click.option("--window-s", type=float, default=3600.0, show_default=True, help="UIC 406 observation window, s")
@click.option("--retry-failed", is_flag=True, help="Run again the runs that failed in an earlier invocation")
def batch_cmd(line_spec: str, timetables: str | None, regimes: str, n_seeds: int, first_seed: int, controllers: str | None,
              delay_config: Path | None, workers: int | None, scheduler: str | None, out: Path | None, step_length: float,
              block_length_m: float | None, window_s: float, retry_failed: bool) -> None:
    """Run timetables × regimes × controllers × seeds with random primary delays; resume when re-run.

    Writes batch.csv (one row per run), batch_trains.csv (one row per train and run), uic406.csv
    and report/ (summary table, delay and punctuality plots, meta.json).
    """
    from vcsumo.engine.campaign import CampaignFailed, check_scheduler, check_workers
    from vcsumo.studies.batch import REGIMES, resolve_timetables, run_batch, summarize
    from vcsumo.delays import load_delay_config
    from vcsumo.network_file import load_line_or_network

    line = load_line_or_network(line_spec)
    regime_list = _csv_list(regimes, "--regimes") or []
    for r in regime_list:
        if r not in REGIMES:
            raise InputError(None, "--regimes", f"unknown regime '{r}' (choose from {', '.join(REGIMES)})")
    ctrl_list = _csv_list(controllers, "--controllers")
    if ctrl_list is not None and "vc" not in regime_list:
        raise InputError(None, "--controllers", f"only the vc regime takes a controller (regimes are {', '.join(regime_list)})")
    tt_files = resolve_timetables(timetables, line)
    check_workers(workers)
    check_scheduler(scheduler)
    delays = load_delay_config(delay_config)
    seeds = _seeds(n_seeds, first_seed)
    command = " ".join(["vcsumo"] + sys.argv[1:]) if Path(sys.argv[0]).name.startswith("vcsumo") else ""

    with progress_bar() as prog:
        task = prog.add_task(f"batch {line.name}", total=None)

        def progress(done: int, total: int, row: dict | None) -> None:
            desc = f"batch {line.name}"
            if row is not None:
                mark = "" if row["status"] == "ok" else " [failed]"
                desc = f"{row['timetable']} {row['regime']}{'/' + row['controller'] if row['controller'] else ''} s{row['seed']}{mark}"
            prog.update(task, total=max(total, 1), completed=done if total else 1, description=desc)

        df = run_batch(line, tt_files, regime_list, seeds, ctrl_list, delays, delay_config, out, workers, scheduler,
                       step_length, block_length_m, window_s, retry_failed, progress, command)
    folder = df.attrs["out"]
    summ = summarize(df)
    if len(summ):
        view = summ.copy()
        view["punct_3min_%"] = (100 * view["punctuality_3min_share"]).round(1)
        view["punct_5min_%"] = (100 * view["punctuality_5min_share"]).round(1)
        view["uic406_%"] = view["capacity_consumption_pct"]
        view["uic406_cyc_%"] = view["capacity_consumption_cyclic_pct"]
        print_table(view, f"batch — {line.name}", ["timetable", "regime", "controller", "runs", "failed", "punct_3min_%", "punct_5min_%",
                                                    "mean_arrival_delay_s", "knock_on_delay_s", "uic406_%", "uic406_cyc_%", "collisions"])
    out_console.print(f"{len(df)} runs: {df.attrs['new_runs']} run now, {df.attrs['resumed_runs']} already in batch.csv; "
                      f"{df.attrs['failed_runs']} failed")
    failed = df[df["status"] != "ok"]
    if len(failed):
        shown = failed.drop_duplicates("error").head(5)
        for _, r in shown.iterrows():
            same = int((failed["error"] == r["error"]).sum())
            more = f" (and {same - 1} more runs with this error)" if same > 1 else ""
            out_console.print(f"  failed: {r['timetable']} {r['regime']}{'/' + r['controller'] if r['controller'] else ''} seed {r['seed']}: "
                              f"{r['error']}{more}", markup=False, highlight=False)
    out_console.print(f"wrote {folder / 'batch.csv'}")
    out_console.print(f"wrote {folder / 'report'}")
    if len(df) and len(failed) == len(df):
        raise CampaignFailed(f"every run of the batch failed ({len(df)} of {len(df)}; errors above and in {folder / 'batch.csv'})")
