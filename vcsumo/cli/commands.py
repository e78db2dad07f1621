"""The commands built from a configuration model: ``build-network``, ``run``, ``study headway``, ``study capacity``.

Each command is one function of its validated configuration (:mod:`vcsumo.studies.configs`), the
function ``vcsumo study run FILE`` calls too: load and check the inputs the configuration names
(errors blame the option or the study file's field; nothing is written yet), run the library
function with a progress bar, print the table and where it wrote.  A command whose results are
empty, or whose run or any case failed or is not healthy, says so on one line and exits 1 (results
kept: :mod:`vcsumo.cli.verdict`).  The click commands are generated from the models (:func:`vcsumo.cli.options.config_command`).
"""

from __future__ import annotations

import logging
import math
import time

from vcsumo.cli.options import config_command
from vcsumo.cli.ui import out_console, print_table, progress_bar, progress_task
from vcsumo.cli.verdict import NotClean, count_not_healthy, require_clean
from vcsumo.studies.configs import BuildNetworkConfig, CapacityConfig, HeadwayConfig, RunConfig

log = logging.getLogger(__name__)



def in_cache(line, block_length_m: float | None, force: bool = False) -> bool:
    """Whether the line's SUMO network will be reused from the cache (not built)."""
    from vcsumo.sim.network import cache_dir, fingerprint

    return (cache_dir() / "networks" / line.name / fingerprint(line, block_length_m) / "line.net.xml").is_file() and not force


def network(line, block_length_m: float | None, force: bool = False):
    """The line's SUMO network (built or reused from the cache), saying which with ``-v``."""
    from vcsumo.sim.network import build_network

    cached = in_cache(line, block_length_m, force)
    t0 = time.perf_counter()
    net = build_network(line, block_length_m, force=force)
    log.info("network of %s %s %s (%.1f s)", line.name, "reused from the cache:" if cached else "built:", net.folder, time.perf_counter() - t0)
    return net


# ----------------------------------------------------------------------------------------------
def build_network(cfg: BuildNetworkConfig) -> None:
    """Build (or reuse) the SUMO network of a line."""
    line = cfg.inputs()
    reused = in_cache(line, cfg.block_length_m, cfg.force)
    net = network(line, cfg.block_length_m, force=cfg.force)
    topo = net.topology
    signals = sum(1 for n in topo.nodes.values() if n.signal)
    out_console.print(f"network of {line.name}: {len(topo.edges)} edges, {signals} signals, {len(topo.platforms)} platforms")
    did = "reused (cached)" if reused else "wrote"  # nothing is written when the cache holds it
    out_console.print(f"{did} {net.net_file}")
    out_console.print(f"{did} {net.stations_file}")


@config_command(BuildNetworkConfig, "build-network")
def build_network_cmd(cfg: BuildNetworkConfig) -> None:
    """Build (or reuse) the SUMO network of a line."""
    build_network(cfg)


# ----------------------------------------------------------------------------------------------
UNHEALTHY = [("stops_skipped", "scheduled stops skipped"), ("short_dwells", "stops left before the minimum dwell"), ("collisions", "collisions"), ("gap_violations", "gap violations"),
             ("overspeed_events", "overspeed events"), ("authority_overruns", "movement authority overruns"),
             ("beyond_service_brakings", "brakings beyond the service rate"), ("sumo_emergency_stops", "SUMO emergency stops"),
             ("sumo_emergency_brakings", "SUMO emergency brakings"), ("sumo_stop_warnings", "SUMO stop warnings"), ("teleports", "teleports")]
"""Counters of a run summary that make it not healthy (:mod:`vcsumo.sim.health`), as words."""


def unhealthy_reasons(summary: dict, cut_short: bool = False) -> list[str]:
    """What made a run not healthy, as short phrases (empty: healthy).  ``cut_short``: the run was
    stopped at a time the user chose, so trains still running then (not arrived) and the stops they
    had not reached (``stops_not_reached``) are not counted (:func:`cut_short_note` says them); a stop
    a train passed without serving is (``stops_skipped``)."""
    out = []
    if summary.get("trains_arrived") != summary.get("trains") and not cut_short:
        missed = f" ({summary['stops_not_reached']} stops not reached)" if summary.get("stops_not_reached") else ""
        out.append(f"{summary.get('trains_arrived')} of {summary.get('trains')} trains arrived{missed}")
    out += [f"{summary[k]} {words}" for k, words in UNHEALTHY if summary.get(k)]
    return out if out or cut_short or summary.get("healthy", True) else ["not healthy (see summary.json)"]


def health_line(summary: dict, reasons: list[str], cut_short: bool = False) -> str:
    """The run's health in one terminal line: the verdict, then every counter it rests on.
    ``cut_short``: the run was stopped at ``--end-time`` (see :func:`unhealthy_reasons`); with no
    reason against it, the verdict says that nothing was wrong until then, not that it is healthy."""
    s = summary
    gap, margin = s.get("min_gap_m"), s.get("min_margin_m")
    def metres(x) -> str:
        return f"{x:.1f} m" if isinstance(x, (int, float)) and math.isfinite(x) else "– (no train ran behind another)"
    verdict = "healthy" if s.get("healthy") and not reasons else "NOT healthy"
    if verdict != "healthy" and cut_short and not reasons:
        verdict = "cut short at --end-time, nothing wrong until then (NOT healthy as a whole run)"
    return (f"health: {verdict} — trains arrived {s.get('trains_arrived')}/{s.get('trains')}, stops served {s.get('stops_served', 0)}/"
            f"{s.get('stops_scheduled', 0)} (skipped {s.get('stops_skipped', 0)}, short dwell {s.get('short_dwells', 0)}), min margin to the safe separation {metres(margin)}, "
            f"min gap {metres(gap)}, gap violations {s.get('gap_violations', 0)}, collisions {s.get('collisions', 0)}, "
            f"overspeed {s.get('overspeed_events', 0)}, braking beyond service {s.get('beyond_service_brakings', 0)}, "
            f"authority overruns {s.get('authority_overruns', 0)}, SUMO emergency brakings {s.get('sumo_emergency_brakings', 0)}, "
            f"SUMO emergency stops {s.get('sumo_emergency_stops', 0)}, SUMO stop warnings {s.get('sumo_stop_warnings', 0)}, teleports {s.get('teleports', 0)}")


def cut_short_note(summary: dict) -> str:
    """The terminal line of a run ended by ``--end-time`` before every train arrived (empty when all
    did): its summary is not healthy, for that reason alone unless another is given."""
    if summary.get("trains_arrived") == summary.get("trains"):
        return ""
    return (f"run ended at --end-time with {summary.get('trains_arrived')} of {summary.get('trains')} trains arrived and "
            f"{summary.get('stops_not_reached', 0)} stops not reached (not skipped): not healthy as a whole run")


def run(cfg: RunConfig) -> None:
    """Run a timetable on a line under one regime; write trajectories, stop events and a summary."""
    from vcsumo.infrastructure import write_infrastructure
    from vcsumo.plots.charts import plot_run
    from vcsumo.results import ResultsFolder, default_out, write_json
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.timetable import plan_trains
    from vcsumo.units import format_clock

    inp = cfg.inputs()
    line, tt = inp.line, inp.timetable
    net = network(line, cfg.block_length_m)
    trains = plan_trains(tt, inp.timetable_path, line, net.topology, dt=cfg.step_s)
    driver = None
    if cfg.regime == "vc":
        from vcsumo.sim.vc_driver import make_vc_driver

        driver = make_vc_driver(tt, inp.timetable_path, trains, cfg.controller or "cbf-cbc", cfg.step_s, cfg.seed, channel=cfg.channel,
                                assumptions=inp.assumptions)
    out = cfg.out_path or default_out("run", f"{line.name}-{tt.name}-{cfg.regime}")
    inputs = {**line.input_files(), "timetable": inp.timetable_path, **cfg.recorded_inputs()}
    params = {"regime": cfg.regime, "controller": cfg.controller, "step_length_s": cfg.step_s, "block_length_m": cfg.block_length_m,
              "end_time_s": cfg.end_time, "assumptions": inp.assumptions.record()}
    with ResultsFolder(out, inputs=inputs, seed=cfg.seed, params=params) as rf:
        with progress_bar() as prog, progress_task(prog, f"{line.name} {tt.name} {cfg.regime}") as upd:
            scn = Scenario(line, net, trains, cfg.regime, step_length_s=cfg.step_s, seed=cfg.seed, driver=driver, end_time_s=cfg.end_time,
                           assumptions=inp.assumptions, sumo_fcd=cfg.sumo_fcd)
            res = simulate(scn, rf.path, upd)
        log.info("SUMO's messages: %s, %s", out / "sumo_messages.log", out / "sumo_errors.log")
        infra = write_infrastructure(net.topology, rf.path)
        plot_run(res.trajectories, rf.path / "time_distance.png", f"{line.name} {tt.name} {cfg.regime}", infrastructure=infra)
        if driver is not None:
            driver.write_report(rf.path)
            res.summary.update(driver.summary())
            write_json(rf.path / "summary.json", res.summary)
    s = res.summary
    view = res.trains.copy()
    view["departure"] = view["departure_s"].map(lambda x: format_clock(x) if x == x else "-")
    view["arrival"] = view["arrival_s"].map(lambda x: format_clock(x) if x == x else "-")
    view["run_min"] = view["running_time_s"] / 60.0
    view["delay_s"] = view["arrival_delay_s"]
    print_table(view, f"{line.name} / {tt.name} / {cfg.regime}",
                ["train", "departure", "arrival", "run_min", "delay_s", "min_gap_m", "gap_violations", "emergency_brakes"], csv_path=out / "summary.csv")
    cut_short = cfg.end_time is not None and s.get("simulated_until_s", 0) >= cfg.end_time - cfg.step_s
    reasons = unhealthy_reasons(s, cut_short=cut_short)
    out_console.print(health_line(s, reasons, cut_short))
    if driver is not None:
        loose = {fid: f.formation.reason() for fid, f in driver.followers.items() if f.formation.reason()}
        text = "; ".join(f"{fid}: {why}" for fid, why in sorted(loose.items())[:6]) + (" …" if len(loose) > 6 else "")
        out_console.print(f"convoy followers formed {s.get('followers_formed', 0)}/{len(driver.followers)}"
                          + (f" — not formed: {text} (vc_summary.json)" if loose else ""))
        out_console.print(f"followers' safety layers: {s.get('vc_emergency_activations', 0)} emergency brake applications "
                          f"({s.get('vc_emergency_steps', 0)} steps), {s.get('guard_interventions', 0)} separation-guard interventions, "
                          f"{s.get('controller_infeasible_steps', 0)} infeasible controller steps, {s.get('fault_events', 0)} controller faults")
    out_console.print(f"wrote {out}")
    if cut_short and cut_short_note(s):
        out_console.print(cut_short_note(s))
    if reasons:
        until = f" (simulated until {format_clock(s['simulated_until_s'])})" if s.get("simulated_until_s") else ""
        raise NotClean(f"the run is not healthy: {', '.join(reasons)}{until}; results in {out}")


@config_command(RunConfig, "run")
def run_cmd(cfg: RunConfig) -> None:
    """Run a timetable on a line under one regime; write trajectories, stop events and a summary.

    Exits 1 (results kept) when the run is not healthy: a train did not arrive or skipped a stop
    (trains still running at --end-time and the stops they had not reached, stops_not_reached,
    are reported, not counted), a collision, a gap below the safe separation, overspeed, an overrun
    of the movement authority.
    """
    run(cfg)


# ----------------------------------------------------------------------------------------------
def headway(cfg: HeadwayConfig) -> None:
    """Minimum headway by simulation vs blocking-time theory, per direction and measuring point."""
    from vcsumo.engine.campaign import CampaignFailed
    from vcsumo.results import ResultsFolder, default_out
    from vcsumo.studies.headway import run_headway_study

    inp = cfg.inputs()
    line = inp.line
    regimes = ["fbs", "mb"] if cfg.regime == "both" else [cfg.regime]
    names = [st.name for st in inp.trains]
    net = network(line, cfg.block_length_m)
    out = cfg.out_path or default_out("headway", line.name)
    with ResultsFolder(out, inputs={"line": line.path, **cfg.recorded_inputs()},
                       params={"regimes": regimes, "trains": names, "block_length_m": cfg.block_length_m, "step_length_s": cfg.step_length_s,
                               "points_km": cfg.points_km, "trains_per_run": cfg.trains_per_run, "directions": list(cfg.directions),
                               "assumptions": inp.assumptions.record()}) as rf:
        with progress_bar() as prog:
            def factory(desc: str):
                task = prog.add_task(desc, total=1.0)
                return lambda d, t: prog.update(task, completed=d / t if t else 1.0)

            df = run_headway_study(line, net, inp.trains, regimes, rf.path, cfg.points_km, step_s=cfg.step_length_s, n_trains=cfg.trains_per_run,
                                   directions=tuple(cfg.directions), progress_factory=factory, assumptions=inp.assumptions)
    print_table(df, f"headway — {line.name}", ["direction", "regime", "train", "measuring_point_km", "headway_sim_s", "headway_analytic_s", "deviation_pct",
                "speed_at_point_mps", "healthy"], csv_path=out / "headway.csv")
    out_console.print(f"wrote {out / 'headway.csv'}")
    if len(df) == 0:
        raise CampaignFailed(f"no headway was measured: no measuring point lies after the release point of a direction ({out / 'headway.csv'} is empty)")
    failed = df["error"].fillna("").astype(str) != ""
    require_clean("the headway study", len(df), int(failed.sum()), count_not_healthy(df.loc[~failed, "healthy"]), out / "headway.csv", noun="rows")


@config_command(HeadwayConfig, "headway")
def headway_cmd(cfg: HeadwayConfig) -> None:
    """Minimum headway by simulation vs blocking-time theory, per direction and measuring point."""
    headway(cfg)


# ----------------------------------------------------------------------------------------------
def capacity(cfg: CapacityConfig) -> None:
    """Line capacity under FBS, MB and VC (each controller, convoy sizes), per direction and stopping pattern."""
    from vcsumo.engine.campaign import CampaignFailed, check_scheduler, check_workers
    from vcsumo.results import default_out, recording
    from vcsumo.studies.capacity import run_capacity_study

    inp = cfg.inputs()
    line, stock = inp.line, inp.trains[0]
    n_workers = check_workers(cfg.workers)
    with cfg.blame("scheduler"):
        check_scheduler(cfg.scheduler)
    net = network(line, cfg.block_length_m)
    out = cfg.out_path or default_out("capacity", line.name)
    prog = progress_bar()
    task = prog.add_task(f"capacity {line.name}", total=1.0)
    shown = []

    def upd(k: int, n: int, desc: str) -> None:
        if not shown:  # the bar starts with the first case: input errors come before any bar
            prog.start()
            shown.append(True)
        prog.update(task, completed=k / n if n else 1.0, description=f"capacity {line.name}: {desc}")

    try:
        with recording(cfg.recorded_inputs()):
            df = run_capacity_study(line, net, stock, out, list(cfg.controllers), list(cfg.convoy_sizes), tuple(cfg.directions),
                                    tuple(cfg.patterns) if cfg.patterns else None, cfg.step_length_s, cfg.vc_step_length_s, cfg.seed, progress=upd,
                                    workers=n_workers, scheduler=cfg.scheduler, assumptions=inp.assumptions)
    finally:
        if shown:
            prog.stop()
    print_table(df, f"capacity — {line.name} ({stock.name})", ["direction", "stopping_pattern", "regime", "controller", "convoy_size", "headway_sim_s",
                "headway_analytic_s", "intra_convoy_gap_m", "convoy_formed", "capacity_trains_per_h", "gain_vs_fbs", "healthy", "min_margin_m"],
                csv_path=out / "capacity.csv", drop_first=["headway_analytic_s", "intra_convoy_gap_m", "min_margin_m", "convoy_formed"])
    failed = df[df.error.astype(str) != ""]  # listed with their errors under the table
    if df.attrs.get("resumed_cases"):
        out_console.print(f"{df.attrs['new_cases']} cases run now, {df.attrs['resumed_cases']} already in {out / 'capacity_cases.csv'}")
    out_console.print(f"wrote {out / 'capacity.csv'}")
    if len(df) == 0:
        raise CampaignFailed(f"the capacity study has no case ({out / 'capacity.csv'} is empty)")
    if len(failed) == len(df):
        raise CampaignFailed(f"every case of the capacity study failed ({len(df)} of {len(df)}; errors above and in {out / 'capacity.csv'})")
    finished = df[df.error.astype(str) == ""]
    require_clean("the capacity study", len(df), len(failed), count_not_healthy(finished["healthy"]), out / "capacity.csv")


@config_command(CapacityConfig, "capacity")
def capacity_cmd(cfg: CapacityConfig) -> None:
    """Line capacity under FBS, MB and VC (each controller, convoy sizes), per direction and stopping pattern."""
    capacity(cfg)


__all__ = ["build_network_cmd", "run_cmd", "headway_cmd", "capacity_cmd", "build_network", "run", "headway", "capacity", "NotClean"]
