"""The ``vcsumo`` command: thin — parse options, load and validate inputs, call a library function.

Every problem the user can fix ends in one line ``error: <file>: <field>: <message>`` and exit
status 2; results folders are written completely or not at all (:mod:`vcsumo.results`).
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import click

from vcsumo.cli.ui import console, out_console, print_table, progress_bar, progress_task
from vcsumo.errors import VcsumoError
from vcsumo.log import set_verbosity, setup_logging, verbosity

log = logging.getLogger(__name__)

SEED_HELP = "Random seed of SUMO and of the VC channels (message delays and losses); the same seed gives the same results"


def _louder(ctx: click.Context, _param: click.Parameter, value: int) -> None:
    if value:
        set_verbosity(max(verbosity(), 0) + value)


def _quieter(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    if value:
        set_verbosity(-1)


def _add_verbosity_options(cmd: click.Command) -> None:
    """``-v``/``-q`` on the group and on every command under it: ``vcsumo -v run ...`` and
    ``vcsumo run ... -v`` both work (a command's own flags add to the group's)."""
    if not any(p.name == "verbose" for p in cmd.params):
        cmd.params.append(click.Option(["-v", "--verbose"], count=True, expose_value=False, callback=_louder,
                                       help="More diagnostics on stderr (-vv: debugging detail)"))
        cmd.params.append(click.Option(["-q", "--quiet"], is_flag=True, expose_value=False, callback=_quieter,
                                       help="Only errors and results: no warnings, no progress bars"))
    for sub in getattr(cmd, "commands", {}).values():
        _add_verbosity_options(sub)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="vcsumo")
def cli() -> None:
    """vcsumo: fixed block, moving block and virtual coupling on real lines, in SUMO.

    Results (tables, where files were written) go to stdout; progress bars, warnings and
    diagnostics (-v, -vv) to stderr. Shipped lines, timetables and trains come with the package;
    set VCSUMO_HOME to a folder of the same shape (networks/, routes/, controllers/, studies/) to
    use your own, VCSUMO_CACHE to move the network cache (default: the user cache folder).

    \b
    Example:
      vcsumo study capacity --line firenze_bologna
    """


def network(line, block_length_m: float | None, force: bool = False):
    """The line's SUMO network (built or reused from the cache), saying which with ``-v``."""
    import time

    from vcsumo.sim.network import build_network, cache_dir, fingerprint

    cached = (cache_dir() / "networks" / line.name / fingerprint(line, block_length_m) / "line.net.xml").is_file() and not force
    t0 = time.perf_counter()
    net = build_network(line, block_length_m, force=force)
    log.info("network of %s %s %s (%.1f s)", line.name, "reused from the cache:" if cached else "built:", net.folder, time.perf_counter() - t0)
    return net


# ----------------------------------------------------------------------------------------------
@cli.command("lines")
def lines_cmd() -> None:
    """List the shipped lines and train types (or those under $VCSUMO_HOME)."""
    from vcsumo.line import load_line, project_root, shipped_lines
    from vcsumo.network_file import load_network, shipped_networks
    from vcsumo.rolling_stock import load_rolling_stock, rolling_stock_dir, shipped_rolling_stock

    names = shipped_lines()
    if not names:
        import os

        how = "$VCSUMO_HOME is set to " + os.environ["VCSUMO_HOME"] if os.environ.get("VCSUMO_HOME") else "the package was installed without its data"
        raise VcsumoError(f"{project_root() / 'networks'}: no line files (<line>/line.yaml) found ({how})")
    if not shipped_rolling_stock():
        raise VcsumoError(f"{rolling_stock_dir()}: no train type files (<name>.yaml) found")
    log.info("lines and train types from %s", project_root())
    for name in names:
        ln = load_line(name)
        out_console.print(f"[bold]{name}[/]: {ln.data.title} ({ln.data.km_start}–{ln.data.km_end} km, {ln.data.tracks} track, "
                          f"{len(ln.data.stations)} stations, {len(ln.data.branches)} branches)")
    for name in shipped_networks():
        net = load_network(name)
        out_console.print(f"[bold]{name}[/] (network): {net.title} (lines {', '.join(net.lines)}; {len(net.all_station_ids())} stations)")
    for name in shipped_rolling_stock():
        st = load_rolling_stock(name)
        out_console.print(f"  train [bold]{name}[/]: {st.title}")


@cli.command("build-network")
@click.option("--line", "line_spec", required=True, help="Shipped line or network name, or path to a line.yaml or network.yaml")
@click.option("--block-length-m", type=float, default=None, help="Override the line's block length, m")
@click.option("--force", is_flag=True, help="Rebuild even if the cached network is up to date")
def build_network_cmd(line_spec: str, block_length_m: float | None, force: bool) -> None:
    """Build (or reuse) the SUMO network of a line."""
    from vcsumo.network_file import load_line_or_network

    line = load_line_or_network(line_spec)
    net = network(line, block_length_m, force=force)
    topo = net.topology
    signals = sum(1 for n in topo.nodes.values() if n.signal)
    out_console.print(f"network of {line.name}: {len(topo.edges)} edges, {signals} signals, {len(topo.platforms)} platforms")
    out_console.print(f"wrote {net.net_file}")
    out_console.print(f"wrote {net.stations_file}")


# ----------------------------------------------------------------------------------------------
@cli.command("run")
@click.option("--line", "line_spec", required=True, help="Shipped line or network name, or path to a line.yaml or network.yaml")
@click.option("--timetable", required=True, help="Timetable name (routes/<line>/<name>.yaml) or path")
@click.option("--regime", type=click.Choice(["fbs", "mb", "vc"]), required=True, help="Signalling regime")
@click.option("--controller", default=None, help="VC controller: mpc, cbc, cbf-mpc, cbf-cbc, cbf-cruise (NAME:PARAMS picks a parameter file); vc only")
@click.option("--channel", default=None, help="Train-to-train channel settings (controllers/<name>.yaml or a path; default: channel); vc only")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (default: new folder under results/)")
@click.option("--step-length", type=float, default=None, help="SUMO step, s (default 0.5; 0.1 for vc)")
@click.option("--block-length-m", type=float, default=None, help="Override the line's block length, m")
@click.option("--assumptions", default=None, help="Assumption set of the separation model: a shipped name or a .yaml path (default: etcs_typical)")
@click.option("--seed", type=int, default=42, show_default=True, help=SEED_HELP)
@click.option("--end-time", default=None, help="Stop the simulation at this time, HH:MM[:SS] or s (default: when every train has arrived)")
@click.option("--sumo-fcd", is_flag=True, help="Also write SUMO's fcd.xml (the same 1 s samples as trajectories.csv; off by default)")
def run_cmd(line_spec: str, timetable: str, regime: str, controller: str | None, channel: str | None, out: Path | None, step_length: float | None, block_length_m: float | None,
            assumptions: str | None, seed: int, end_time: str | None, sumo_fcd: bool = False) -> None:
    """Run a timetable on a line under one regime; write trajectories, stop events and a summary."""
    if step_length is None:
        step_length = 0.1 if regime == "vc" else 0.5
    from vcsumo.infrastructure import write_infrastructure
    from vcsumo.network_file import load_line_or_network
    from vcsumo.units import parse_clock
    from vcsumo.plots.charts import plot_run
    from vcsumo.results import ResultsFolder, default_out
    from vcsumo.signalling.assumptions import load_assumptions
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.timetable import load_timetable, plan_trains

    if step_length <= 0 or step_length > 2:
        raise VcsumoError(f"--step-length: {step_length} s is outside (0, 2] s")
    end_s = None
    if end_time is not None:
        try:
            end_s = float(end_time) if end_time.replace(".", "", 1).isdigit() else parse_clock(end_time)
        except ValueError:
            raise VcsumoError(f"--end-time: '{end_time}' is not a time (HH:MM[:SS] or s)") from None
    line = load_line_or_network(line_spec)
    tt, tt_path = load_timetable(timetable, line)
    net = network(line, block_length_m)
    trains = plan_trains(tt, tt_path, line, net.topology, dt=step_length)
    driver = None
    aset = load_assumptions(assumptions)
    if regime == "vc":
        from vcsumo.sim.vc_driver import make_vc_driver

        driver = make_vc_driver(tt, tt_path, trains, controller or "cbf-cbc", step_length, seed, channel=channel, assumptions=aset)
    elif controller or channel:
        raise VcsumoError(f"--controller/--channel: only the vc regime takes a controller and a channel (regime is {regime})")
    out = out or default_out("run", f"{line.name}-{tt.name}-{regime}")
    with ResultsFolder(out, inputs={**line.input_files(), "timetable": tt_path}, seed=seed,
                       params={"regime": regime, "controller": controller, "step_length_s": step_length, "block_length_m": block_length_m, "end_time_s": end_s,
                               "assumptions": aset.record()}) as rf:
        with progress_bar() as prog, progress_task(prog, f"{line.name} {tt.name} {regime}") as upd:
            scn = Scenario(line, net, trains, regime, step_length_s=step_length, seed=seed, driver=driver, end_time_s=end_s, assumptions=aset,
                           sumo_fcd=sumo_fcd)
            res = simulate(scn, rf.path, upd)
        log.info("SUMO's messages: %s, %s", out / "sumo_messages.log", out / "sumo_errors.log")
        infra = write_infrastructure(net.topology, rf.path)
        plot_run(res.trajectories, rf.path / "time_distance.png", f"{line.name} {tt.name} {regime}", infrastructure=infra)
        if driver is not None:
            driver.write_report(rf.path)
            res.summary.update(driver.summary())
            (rf.path / "summary.json").write_text(__import__("json").dumps(res.summary, indent=2))
    s = res.summary
    from vcsumo.units import format_clock

    view = res.trains.copy()
    view["departure"] = view["departure_s"].map(lambda x: format_clock(x) if x == x else "-")
    view["arrival"] = view["arrival_s"].map(lambda x: format_clock(x) if x == x else "-")
    view["run_min"] = view["running_time_s"] / 60.0
    view["delay_s"] = view["arrival_delay_s"]
    print_table(view, f"{line.name} / {tt.name} / {regime}",
                ["train", "departure", "arrival", "run_min", "delay_s", "min_gap_m", "gap_violations", "emergency_brakes"], csv_path=out / "summary.csv")
    gap = s.get("min_gap_m")
    gap_text = f"{gap:.1f} m" if isinstance(gap, (int, float)) and gap == gap else "– (no train ran behind another)"
    out_console.print(f"trains arrived {s['trains_arrived']}/{s['trains']}, min gap {gap_text}, "
                      f"gap violations {s['gap_violations']}, collisions {s['collisions']}, emergency brakes {s['emergency_brakes']}")
    out_console.print(f"wrote {out}")


# ----------------------------------------------------------------------------------------------
@cli.group("study")
def study() -> None:
    """Studies: capacity, headway, junction, safety, and run (a study file).

    \b
    Example:
      vcsumo study capacity --line felez_test --controllers cbc --convoy-sizes 2
    """


def _parse_points(points: str | None) -> list[float] | None:
    if not points:
        return None
    try:
        return [float(x) for x in points.split(",") if x.strip()]
    except ValueError:
        raise VcsumoError(f"--points: '{points}' is not a comma-separated list of km") from None


@study.command("headway")
@click.option("--line", "line_spec", required=True, help="Shipped line name or path to a line.yaml")
@click.option("--regime", type=click.Choice(["fbs", "mb", "both"]), default="both", show_default=True)
@click.option("--train", "trains", multiple=True, help="Train type(s) (default: the line's default_train)")
@click.option("--points", default=None, help="Measuring points, comma-separated km (default: the line file's)")
@click.option("--block-length-m", type=float, default=None, help="Override the line's block length, m")
@click.option("--step-length", type=float, default=0.5, show_default=True, help="SUMO step, s")
@click.option("--trains-per-run", type=int, default=2, show_default=True, help="Trains released per probe (2 = blocking-time pair)")
@click.option("--assumptions", default=None, help="Assumption set of the separation model: a shipped name or a .yaml path (default: etcs_typical)")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (default: new folder under results/)")
def headway_cmd(line_spec: str, regime: str, trains: tuple[str, ...], points: str | None, block_length_m: float | None, step_length: float, trains_per_run: int,
                assumptions: str | None, out: Path | None) -> None:
    """Minimum headway by simulation vs blocking-time theory, per direction and measuring point."""
    from vcsumo.line import load_line
    from vcsumo.results import ResultsFolder, default_out
    from vcsumo.rolling_stock import load_rolling_stock
    from vcsumo.signalling.assumptions import load_assumptions
    from vcsumo.studies.headway import run_headway_study

    line = load_line(line_spec)
    aset = load_assumptions(assumptions)
    names = list(trains) or ([line.data.default_train] if line.data.default_train else [])
    if not names:
        raise VcsumoError(f"{line.path}: default_train: the line names no default train; pass --train")
    stocks = [load_rolling_stock(n) for n in names]
    if trains_per_run < 2:
        raise VcsumoError("--trains-per-run: at least 2 trains are needed")
    regimes = ["fbs", "mb"] if regime == "both" else [regime]
    pts = _parse_points(points)
    net = network(line, block_length_m)
    out = out or default_out("headway", line.name)
    with ResultsFolder(out, inputs={"line": line.path}, params={"regimes": regimes, "trains": names, "block_length_m": block_length_m, "step_length_s": step_length,
                                                                "assumptions": aset.record()}) as rf:
        with progress_bar() as prog:
            def factory(desc: str):
                task = prog.add_task(desc, total=1.0)
                return lambda d, t: prog.update(task, completed=d / t if t else 1.0)

            df = run_headway_study(line, net, stocks, regimes, rf.path, pts, step_s=step_length, n_trains=trains_per_run, progress_factory=factory, assumptions=aset)
    print_table(df, f"headway — {line.name}", ["direction", "regime", "train", "measuring_point_km", "headway_sim_s", "headway_analytic_s", "deviation_pct",
                "speed_at_point_mps"], csv_path=out / "headway.csv")
    out_console.print(f"wrote {out / 'headway.csv'}")


@study.command("capacity")
@click.option("--line", "line_spec", required=True, help="Shipped line name or path to a line.yaml")
@click.option("--train", default=None, help="Train type (default: the line's default_train)")
@click.option("--controllers", default="cbc,cbf-cbc", show_default=True, help="VC controllers (NAME or NAME:PARAMS), comma-separated; '' for none")
@click.option("--convoy-sizes", default="1,2,3,4", show_default=True, help="VC convoy sizes, comma-separated")
@click.option("--directions", default="up,down", show_default=True, help="Directions to study")
@click.option("--patterns", default=None, help="Stopping patterns: non-stop, all-stops (default: both where the line has intermediate stations)")
@click.option("--block-length-m", type=float, default=None, help="Override the line's block length, m")
@click.option("--step-length", type=float, default=0.5, show_default=True, help="SUMO step for FBS/MB, s")
@click.option("--vc-step-length", type=float, default=0.2, show_default=True, help="SUMO and controller step for VC, s")
@click.option("--fixed-time-s", type=float, default=None,
              help="ETCS fixed times (route setting + MA transmission + reaction), s, overriding the assumption set's: in the simulation and in the analytic headway; 10-20 s is typical")
@click.option("--workers", type=int, default=None, help="Parallel processes, 1 or more (default: number of CPUs; 1 = in this process)")
@click.option("--scheduler", default=None, help="Run the cases on a Dask cluster: address of its scheduler, tcp://HOST:PORT")
@click.option("--assumptions", default=None, help="Assumption set of the separation model: a shipped name or a .yaml path (default: etcs_typical)")
@click.option("--seed", type=int, default=42, show_default=True, help=SEED_HELP)
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="Results folder (default: new folder under results/); run again into the same folder to finish a stopped study (only missing cases run)")
def capacity_cmd(line_spec: str, train: str | None, controllers: str, convoy_sizes: str, directions: str, patterns: str | None, block_length_m: float | None,
                 step_length: float, vc_step_length: float, fixed_time_s: float | None, workers: int | None, scheduler: str | None, assumptions: str | None,
                 seed: int, out: Path | None) -> None:
    """Line capacity under FBS, MB and VC (each controller, convoy sizes), per direction and stopping pattern."""
    from vcsumo.line import load_line
    from vcsumo.results import default_out
    from vcsumo.rolling_stock import load_rolling_stock
    from vcsumo.signalling.assumptions import load_assumptions
    from vcsumo.studies.capacity import PATTERNS, run_capacity_study

    line = load_line(line_spec)
    aset = load_assumptions(assumptions)
    name = train or line.data.default_train
    if not name:
        raise VcsumoError(f"{line.path}: default_train: the line names no default train; pass --train")
    stock = load_rolling_stock(name)
    ctrls = [c.strip() for c in controllers.split(",") if c.strip()]
    try:
        sizes = [int(x) for x in convoy_sizes.split(",") if x.strip()]
    except ValueError:
        raise VcsumoError(f"--convoy-sizes: '{convoy_sizes}' is not a comma-separated list of integers") from None
    dirs = tuple(d.strip() for d in directions.split(",") if d.strip())
    if not dirs or any(d not in ("up", "down") for d in dirs):
        raise VcsumoError(f"--directions: '{directions}' (choose up, down)")
    pats = None
    if patterns:
        pats = tuple(p.strip() for p in patterns.split(",") if p.strip())
        if any(p not in PATTERNS for p in pats):
            raise VcsumoError(f"--patterns: '{patterns}' (choose from {', '.join(PATTERNS)})")
    if fixed_time_s is not None and fixed_time_s < 0:
        raise VcsumoError(f"--fixed-time-s: {fixed_time_s} s is negative")
    if fixed_time_s is not None:
        aset = aset.model_copy(update={"fixed_time_s": fixed_time_s})
    from vcsumo.engine.campaign import CampaignFailed, check_scheduler, check_workers

    n_workers = check_workers(workers)
    check_scheduler(scheduler)
    net = network(line, block_length_m)
    out = out or default_out("capacity", line.name)
    prog = progress_bar()
    task = prog.add_task(f"capacity {line.name}", total=1.0)
    shown = []

    def upd(k: int, n: int, desc: str) -> None:
        if not shown:  # the bar starts with the first case: input errors come before any bar
            prog.start()
            shown.append(True)
        prog.update(task, completed=k / n if n else 1.0, description=f"capacity {line.name}: {desc}")

    try:
        df = run_capacity_study(line, net, stock, out, ctrls, sizes, dirs, pats, step_length, vc_step_length, seed, progress=upd,
                                workers=n_workers, scheduler=scheduler, assumptions=aset)
    finally:
        if shown:
            prog.stop()
    print_table(df, f"capacity — {line.name} ({name})", ["direction", "stopping_pattern", "regime", "controller", "convoy_size", "headway_sim_s",
                "headway_analytic_s", "intra_convoy_gap_m", "capacity_trains_per_h", "gain_vs_fbs", "min_gap_m", "gap_violations", "collisions"],
                csv_path=out / "capacity.csv", drop_first=["headway_analytic_s", "intra_convoy_gap_m", "min_gap_m"])
    failed = df[df.error.astype(str) != ""]  # listed with their errors under the table
    if df.attrs.get("resumed_cases"):
        out_console.print(f"{df.attrs['new_cases']} cases run now, {df.attrs['resumed_cases']} already in {out / 'capacity_cases.csv'}")
    out_console.print(f"wrote {out / 'capacity.csv'}")
    if len(failed) == len(df):
        raise CampaignFailed(f"every case of the capacity study failed ({len(df)} of {len(df)}; errors above and in {out / 'capacity.csv'})")


@study.command("run")
@click.argument("study_file", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (overrides the file's out)")
def study_run_cmd(study_file: Path, out: Path | None) -> None:
    """Run a study definition file: capacity, headway, batch, junction or safety.

    STUDY_FILE is a path, or the name of a shipped study (e.g. capacity_hcmc_line1, from the
    package's data/studies/ or $VCSUMO_HOME/studies/).
    """
    import os

    from vcsumo.cli.study_files import load_study, study_arguments
    from vcsumo.line import project_root

    shipped = project_root() / "studies" / f"{study_file}.yaml"
    if not study_file.exists() and study_file.suffix not in (".yaml", ".yml") and shipped.is_file():
        study_file = shipped
    st = load_study(study_file)
    args = study_arguments(st, Path(study_file), out)
    os.environ["VCSUMO_STUDY_FILE"] = str(Path(study_file).resolve())
    try:
        cli.main(args=args, prog_name="vcsumo", standalone_mode=False)
    finally:
        os.environ.pop("VCSUMO_STUDY_FILE", None)


# ----------------------------------------------------------------------------------------------
@cli.group("reproduce")
def reproduce() -> None:
    """Reproduce the seed papers' experiments (offline, on the papers' own train model)."""


@reproduce.command("felez2019")
@click.option("--strategies", default="SH,NP,MB", show_default=True, help="Leader predictors (eq. 16-18)")
@click.option("--horizon", type=int, default=40, show_default=True, help="Prediction horizon N_p, steps")
@click.option("--no-sweep", is_flag=True, help="Skip the horizon sweep 20-60 (Fig. 11)")
@click.option("--no-convoy", is_flag=True, help="Skip the 4-train convoy (Fig. 10)")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (default: new folder under results/)")
def felez2019_cmd(strategies: str, horizon: int, no_sweep: bool, no_convoy: bool, out: Path | None) -> None:
    """Felez, Kim & Borrelli (2019) §IV-A: SH / NP / MB stop distance and delay, convoy, horizon sweep."""
    from vcsumo.reproduce.report import reproduce_felez2019
    from vcsumo.results import ResultsFolder, default_out

    strats = tuple(x.strip().upper() for x in strategies.split(",") if x.strip())
    bad = [x for x in strats if x not in ("SH", "NP", "MB")]
    if bad or not strats:
        raise VcsumoError(f"--strategies: unknown strategy {bad or strategies} (choose from SH, NP, MB)")
    if not 2 <= horizon <= 400:
        raise VcsumoError(f"--horizon: {horizon} steps is outside 2-400")
    out = out or default_out("reproduce", "felez2019")
    with ResultsFolder(out, params={"strategies": strats, "horizon": horizon}) as rf:
        with progress_bar() as prog, progress_task(prog, "felez2019") as upd:
            table = reproduce_felez2019(rf.path, strats, horizon, sweep=not no_sweep, convoy=not no_convoy, progress=upd)
    print_table(table, "Felez et al. (2019) §IV-A — reproduced vs paper",
                ["strategy", "stop_distance_m", "paper_stop_distance_m", "stop_delay_s", "paper_stop_delay_s", "gap_at_rest_m", "min_gap_m", "collisions"],
                csv_path=out / "felez2019.csv")
    out_console.print(f"wrote {out / 'felez2019.csv'}")


@reproduce.command("terlizzi2024")
@click.option("--scenario", type=click.Choice(["os1", "os2", "both"]), default="both", show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (default: new folder under results/)")
def terlizzi2024_cmd(scenario: str, out: Path | None) -> None:
    """Terlizzi, Liuzza & Glielmo (2024) OS1 (delays 3 s / 0.8 s) and OS2 (delay estimator on/off)."""
    from vcsumo.reproduce.report import reproduce_terlizzi2024
    from vcsumo.results import ResultsFolder, default_out

    scen = ("os1", "os2") if scenario == "both" else (scenario,)
    out = out or default_out("reproduce", "terlizzi2024")
    with ResultsFolder(out, params={"scenarios": scen}) as rf:
        with progress_bar() as prog, progress_task(prog, "terlizzi2024") as upd:
            summary = reproduce_terlizzi2024(rf.path, scen, progress=upd)
    cols = [c for c in ["run", "coupled_distance_m", "emergency_activations", "min_gap_m", "both_stopped_gap_m", "true_barrier_max", "robust_barrier_max"] if c in summary]
    print_table(summary, "Terlizzi et al. (2024) — reproduced", cols)
    out_console.print(f"wrote {out}")


def _register_batch() -> None:
    from vcsumo.cli.batch import batch_cmd

    cli.add_command(batch_cmd)


_register_batch()


def _register_junction() -> None:
    from vcsumo.cli.junction import junction_cmd

    study.add_command(junction_cmd)


_register_junction()


def _register_safety() -> None:
    from vcsumo.cli.safety import safety_cmd

    study.add_command(safety_cmd)


_register_safety()

EXAMPLES = {
    "lines": "vcsumo lines",
    "build-network": "vcsumo build-network --line felez_test",
    "run": "vcsumo run --line felez_test --timetable test --regime fbs --out results/felez-fbs",
    "study headway": "vcsumo study headway --line felez_test --regime both",
    "study capacity": "vcsumo study capacity --line firenze_bologna --controllers cbc,cbf-cbc --workers 2",
    "study junction": "vcsumo study junction --line firenze_bologna --controllers cbc",
    "study safety": "vcsumo study safety --scenarios 100 --controllers cbc,cbf-cbc --seed 7",
    "study run": "vcsumo study run capacity_hcmc_line1 --out results/hcmc",
    "batch": "vcsumo batch --line felez_test --timetables convoy --regimes fbs,vc --seeds 3",
    "reproduce felez2019": "vcsumo reproduce felez2019 --strategies SH,MB --no-sweep",
    "reproduce terlizzi2024": "vcsumo reproduce terlizzi2024 --scenario os1",
    "reproduce": "vcsumo reproduce felez2019",
}
"""One example per command, shown at the end of its ``--help``."""


def _add_examples(cmd: click.Command, path: str = "") -> None:
    example = EXAMPLES.get(path)
    if example and "Example:" not in (cmd.help or ""):
        cmd.help = (cmd.help or "").rstrip() + f"\n\n\b\nExample:\n  {example}"
    for name, sub in getattr(cmd, "commands", {}).items():
        _add_examples(sub, f"{path} {name}".strip())


_add_examples(cli)
_add_verbosity_options(cli)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``vcsumo`` console script."""
    setup_logging(0, console)
    from vcsumo.engine.campaign import Interrupted, sigterm_as_interrupt

    try:
        with sigterm_as_interrupt():  # SIGTERM (timeout, kill) cleans up like Ctrl-C
            cli.main(args=argv, prog_name="vcsumo", standalone_mode=False)
    except VcsumoError as exc:
        console.print(f"error: {exc}", highlight=False, markup=False, soft_wrap=True)
        return getattr(exc, "exit_code", 2)  # 2: bad input; 1: the command ran but every case failed
    except click.exceptions.Abort as exc:
        if isinstance(exc.__cause__, Interrupted):  # click turns KeyboardInterrupt into Abort
            console.print("terminated")
            return 128 + exc.__cause__.signum
        console.print("interrupted" if isinstance(exc.__cause__, KeyboardInterrupt) else "aborted")
        return 130
    except click.exceptions.ClickException as exc:
        exc.show()
        return exc.exit_code
    except Interrupted as exc:
        console.print("terminated")
        return 128 + exc.signum
    except KeyboardInterrupt:
        console.print("interrupted")
        return 130
    except OSError as exc:  # a file or folder the user named cannot be read or written (permissions, disk full)
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        console.print(f"error: {where}{exc.strerror or exc}", highlight=False, markup=False, soft_wrap=True)
        return 2
    except Exception as exc:  # a bug in vcsumo: one line, the traceback only on request
        import os

        if os.environ.get("VCSUMO_DEBUG"):
            raise
        text = " ".join(str(exc).split())[:500]
        console.print(f"error: internal error {type(exc).__name__}: {text} (a bug in vcsumo; set VCSUMO_DEBUG=1 for the traceback)",
                      highlight=False, markup=False, soft_wrap=True)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
