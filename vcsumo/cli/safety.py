"""``vcsumo study safety``: the Monte Carlo safety campaign (:mod:`vcsumo.studies.safety`).

A thin command in the style of :mod:`vcsumo.cli.main`: build and validate the campaign parameters,
run (or resume) the campaign with a progress bar, write the report, print the summary table and
whether the bar is met.  :mod:`vcsumo.cli.main` registers it under the ``study`` group.
"""

from __future__ import annotations

import datetime as _dt
import time
from pathlib import Path

import click
from pydantic import ValidationError

from vcsumo.cli.ui import out_console, print_table, progress_bar
from vcsumo.cli.verdict import require_clean
from vcsumo.errors import InputError


def _csv(value: str) -> list[str]:
    return [x.strip() for x in value.split(",") if x.strip()]


@click.command("safety")
@click.option("--loop", type=click.Choice(["offline", "sumo"]), default="offline", show_default=True, help="Run the scenarios in the offline closed loop or in the SUMO loop itself")
@click.option("--scenarios", type=int, default=1000, show_default=True, help="Number of seeded random scenarios")
@click.option("--lines", default="firenze_bologna,milano_bologna,hcmc_line1", show_default=True, help="Lines the scenarios are drawn on (names or line.yaml paths), comma-separated")
@click.option("--controllers", default="mpc,cbc,cbf-mpc,cbf-cbc", show_default=True, help="Controllers (NAME or NAME:PARAMS), comma-separated")
@click.option("--seed", type=int, default=2026, show_default=True, help="Campaign seed (scenario k is seeded with (seed, k))")
@click.option("--workers", type=int, default=None, help="Parallel processes, 1 or more (default: number of CPUs; 1 = in this process)")
@click.option("--scheduler", default=None, help="Run the scenarios on a Dask cluster: address of its scheduler, tcp://HOST:PORT")
@click.option("--step-s", type=float, default=0.2, show_default=True, help="Control and integration step, s")
@click.option("--control-period-s", type=float, default=None, help="Period of the nominal controllers (an ATO cycle), s, offline loop only (default: every step, as the capacity study's stacks)")
@click.option("--followers-max", type=int, default=2, show_default=True, help="Largest number of followers behind the leader")
@click.option("--kinds", default="cruise,forming,merge,split", show_default=True, help="Scenario kinds, comma-separated (the SUMO loop runs cruise and forming)")
@click.option("--rolling-stock", default="etr1000,regional_emu160,hcmc_l1", show_default=True, help="Trains a heterogeneous convoy is drawn from (names or paths), comma-separated")
@click.option("--heterogeneous-probability", type=float, default=0.5, show_default=True, help="Probability that a scenario's trains are drawn from --rolling-stock (else the line's train)")
@click.option("--loss-max", type=float, default=0.5, show_default=True, help="Largest packet-loss probability")
@click.option("--delay-max-s", type=float, default=1.0, show_default=True, help="Largest constant channel delay, s")
@click.option("--mean-extra-max-s", type=float, default=2.0, show_default=True, help="Largest mean exponential extra delay, s")
@click.option("--outage-max-s", type=float, default=30.0, show_default=True, help="Longest communication outage, s")
@click.option("--position-error-max-m", type=float, default=1.0, show_default=True, help="Largest odometry error bound e_s (Felez eq. 9), m")
@click.option("--channel-period-s", type=float, default=0.5, show_default=True, help="Message period of every train, s")
@click.option("--outage-probability", type=float, default=0.3, show_default=True, help="Probability of one outage in a scenario")
@click.option("--corner-probability", type=float, default=0.3, show_default=True, help="Probability that a train's true parameters sit at a corner of its uncertainty box")
@click.option("--max-duration-s", type=float, default=900.0, show_default=True, help="Longest simulated time of a scenario, s")
@click.option("--cbf", "cbf_config", default=None, help="CBF parameter file (controllers/<name>.yaml or a path; default: cbf)")
@click.option("--assumptions", default=None, help="Assumption set of the separation model (shipped name or path; default etcs_typical)")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (re-running with the same --out resumes)")
def safety_cmd(loop: str, scenarios: int, lines: str, controllers: str, seed: int, workers: int | None, scheduler: str | None, step_s: float, control_period_s: float | None,
               followers_max: int, kinds: str, rolling_stock: str, heterogeneous_probability: float, loss_max: float, delay_max_s: float, mean_extra_max_s: float,
               outage_max_s: float, position_error_max_m: float, channel_period_s: float, outage_probability: float, corner_probability: float,
               max_duration_s: float, cbf_config: str | None, assumptions: str | None, out: Path | None) -> None:
    """Monte Carlo safety campaign: leader emergency brakes, lossy delayed channel, outages, uncertain and heterogeneous trains, odometry errors."""
    from vcsumo.engine.campaign import CampaignFailed, check_scheduler, check_workers
    from vcsumo.studies.safety import (
        SafetyCampaign, bar_met, check_campaign, describe_run_faults, run_faults, run_safety_campaign, summarize_safety, write_safety_report,
    )

    try:
        cfg = SafetyCampaign(loop=loop, scenarios=scenarios, lines=_csv(lines), controllers=_csv(controllers), seed=seed, step_s=step_s,
                             control_period_s=control_period_s, followers_max=followers_max, kinds=_csv(kinds), rolling_stock=_csv(rolling_stock),
                             heterogeneous_probability=heterogeneous_probability, loss_max=loss_max, delay_max_s=delay_max_s, mean_extra_max_s=mean_extra_max_s,
                             outage_max_s=outage_max_s, position_error_max_m=position_error_max_m, cbf_config=cbf_config, channel_period_s=channel_period_s,
                             outage_probability=outage_probability, corner_probability=corner_probability, max_duration_s=max_duration_s, assumptions=assumptions)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = err["loc"][0] if err["loc"] else "kinds"
        raise InputError(None, "--" + str(loc).replace("_", "-"), err["msg"]) from None
    n_workers = check_workers(workers)
    check_scheduler(scheduler)
    check_campaign(cfg)  # lines, trains, controllers, parameter files and the set: one error line before any progress is shown
    if out is None:
        out = Path("results") / f"safety-{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}"
    t0 = time.perf_counter()
    with progress_bar() as prog:
        task = prog.add_task(f"safety ({cfg.loop}) {cfg.scenarios} scenarios × {len(cfg.controllers)} controllers", total=1.0)
        df = run_safety_campaign(cfg, out, workers=n_workers, progress=lambda d, t: prog.update(task, completed=d / t if t else 1.0),
                                 scheduler=scheduler)
    summary = summarize_safety(df)
    write_safety_report(out, cfg, df, summary, time.perf_counter() - t0)
    print_table(summary, f"safety campaign ({cfg.loop} loop) — {cfg.scenarios} scenarios", ["controller", "supervised", "scenarios", "failed_runs",
                 "scenarios_with_violation", "violation_rate_upper95", "collisions", "min_margin_m", "max_true_barrier_m", "barrier_breaches",
                 "emergency_activations_mean", "time_lost_s_mean"], csv_path=out / "report" / "safety_summary.csv")
    for _, r in summary.iterrows():
        out_console.print(f"  {r['controller']}: {r['scenarios_with_violation']} of {r['scenarios']} scenarios with a separation violation or a collision; "
                          f"95 % upper bound on the violation probability {r['violation_rate_upper95']:.2%}", markup=False, highlight=False)
    met = bar_met(summary, min(cfg.scenarios, 1000))
    out_console.print(("bar met" if met else "bar NOT met") + ": every controller has 0 separation violations (the run-health monitor's rule) and 0 collisions"
                      + ("" if met else " (see the table)") + f" over {cfg.scenarios} scenarios in the {cfg.loop} loop")
    out_console.print(f"wrote {out / 'safety.csv'} and {out / 'report'}")
    failed = df[df["error"] != ""]
    for _, r in failed.drop_duplicates("error").head(5).iterrows():
        same = int((failed["error"] == r["error"]).sum())
        more = f" (and {same - 1} more runs with this error)" if same > 1 else ""
        out_console.print(f"  failed: {r['scenario']} {r['controller']}: {r['error']}{more}", markup=False, highlight=False)
    if len(df) == 0 or len(failed) == len(df):
        raise CampaignFailed(f"every run of the safety campaign failed ({len(failed)} of {len(df)}; errors above and in {out / 'safety.csv'})")
    faults = run_faults(df[df["error"] == ""])  # the rule the summary counts by, per run
    unsafe = faults.any(axis=1)
    require_clean("the safety campaign", len(df), len(failed), int(unsafe.sum()), out / "safety.csv", noun="runs",
                  unhealthy_detail=describe_run_faults(faults[unsafe]))
