"""``vcsumo batch``: timetable experiments with primary delays over regimes, controllers and seeds.

A command built from :class:`~vcsumo.studies.configs.BatchConfig` (the options and the ``study:
batch`` file fields are one model): load inputs, call :func:`vcsumo.studies.batch.run_batch` with a
progress bar, print a summary table and where it wrote.  :mod:`vcsumo.cli.main` registers it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from vcsumo.cli.options import config_command
from vcsumo.cli.ui import out_console, print_table, progress_bar
from vcsumo.cli.verdict import require_clean
from vcsumo.studies.configs import BatchConfig


@config_command(BatchConfig, "batch")
def batch_cmd(cfg: BatchConfig) -> None:
    """Run timetables × regimes × controllers × seeds with random primary delays; resume when re-run.

    Writes batch.csv (one row per run), batch_trains.csv (one row per train and run), uic406.csv
    and report/ (summary table, delay and punctuality plots, meta.json).
    """
    batch(cfg)


def batch(cfg: BatchConfig) -> None:
    """The batch of ``cfg`` (``vcsumo batch`` and ``vcsumo study run`` of a batch study file)."""
    from vcsumo.engine.campaign import CampaignFailed, check_scheduler, check_workers
    from vcsumo.results import recording
    from vcsumo.studies.batch import run_batch, summarize, unhealthy

    inp = cfg.inputs()
    line = inp.line
    check_workers(cfg.workers)
    with cfg.blame("scheduler"):
        check_scheduler(cfg.scheduler)
    command = " ".join(["vcsumo"] + sys.argv[1:]) if Path(sys.argv[0]).name.startswith("vcsumo") else ""

    with progress_bar() as prog:
        task = prog.add_task(f"batch {line.name}", total=None)

        def progress(done: int, total: int, row: dict | None) -> None:
            desc = f"batch {line.name}"
            if row is not None:
                mark = "" if row["status"] == "ok" else " [failed]"
                desc = f"{row['timetable']} {row['regime']}{'/' + row['controller'] if row['controller'] else ''} s{row['seed']}{mark}"
            prog.update(task, total=max(total, 1), completed=done if total else 1, description=desc)

        with recording(cfg.recorded_inputs()):
            df = run_batch(line, inp.timetables, cfg.regimes, inp.seeds, cfg.controllers, inp.delays, inp.delay_config, cfg.out_path, cfg.workers,
                           cfg.scheduler, cfg.step_length_s, cfg.block_length_m, cfg.window_s, cfg.retry_failed, progress, command,
                           assumptions=inp.assumptions)
    folder = df.attrs["out"]
    summ = summarize(df)
    if len(summ):
        view = summ.copy()
        view["punct_3min_%"] = (100 * view["punctuality_3min_share"]).round(1)
        view["punct_5min_%"] = (100 * view["punctuality_5min_share"]).round(1)
        view["uic406_%"] = view["capacity_consumption_pct"]
        view["uic406_cyc_%"] = view["capacity_consumption_cyclic_pct"]
        print_table(view, f"batch — {line.name}", ["timetable", "regime", "controller", "runs", "failed", "unhealthy_runs", "punct_3min_%", "punct_5min_%",
                                                    "mean_arrival_delay_s", "knock_on_delay_s", "uic406_%", "uic406_cyc_%", "collisions"],
                    csv_path=folder / "report" / "batch_summary.csv")
    out_console.print(f"{len(df)} runs: {df.attrs['new_runs']} run now, {df.attrs['resumed_runs']} already in batch.csv; "
                      f"{df.attrs['failed_runs']} failed")
    n_unhealthy = int(unhealthy(df).sum())
    if n_unhealthy:  # a run that is not healthy is never shown as clean
        out_console.print(f"  {n_unhealthy} finished runs are not healthy (see healthy and the run-health "
                          f"counters beside it in batch.csv)", markup=False, highlight=False)
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
    if len(df) == 0:
        raise CampaignFailed(f"the batch has no run ({folder / 'batch.csv'} is empty)")
    if len(failed) == len(df):
        raise CampaignFailed(f"every run of the batch failed ({len(df)} of {len(df)}; errors above and in {folder / 'batch.csv'})")
    require_clean("the batch", len(df), len(failed), n_unhealthy, folder / "batch.csv", noun="runs")
