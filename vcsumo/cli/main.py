"""The ``vcsumo`` command: thin — parse options, load and validate inputs, call a library function.

The commands of :mod:`vcsumo.cli.commands` and :mod:`vcsumo.cli.batch` are generated from their
configuration models (:mod:`vcsumo.studies.configs`), which study files (``vcsumo study run``,
:mod:`vcsumo.cli.study_files`) fill too.  Every problem the user can fix ends in one line
``error: <file>: <field>: <message>`` or ``error: --option: <message>`` (several problems of one
input: one line each) and exit status 2; a command whose results are empty, all failed or not
healthy exits 1 with one line saying so; results folders are written completely or not at all
(:mod:`vcsumo.results`).
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import click

from vcsumo.cli.experiment import experiment_cmd
from vcsumo.cli.tradeoff import tradeoff_cmd
from vcsumo.cli.ui import console, out_console, print_table, progress_bar, progress_task
from vcsumo.errors import VcsumoError
from vcsumo.log import set_verbosity, setup_logging, verbosity

log = logging.getLogger(__name__)


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
    listing = []  # every file is read before anything is printed: a bad one is its error alone, not a list cut off before it
    for name in names:
        ln = load_line(name)
        listing.append(f"[bold]{name}[/]: {ln.data.title} ({ln.data.km_start}–{ln.data.km_end} km, {ln.data.tracks} track, "
                       f"{_count(len(ln.data.stations), 'station')}, {_count(len(ln.data.branches), 'branch', 'branches')})")
    for name in shipped_networks():
        net = load_network(name)
        listing.append(f"[bold]{name}[/] (network): {net.title} (lines {', '.join(net.lines)}; {_count(len(net.all_station_ids()), 'station')})")
    for name in shipped_rolling_stock():
        st = load_rolling_stock(name)
        listing.append(f"  train [bold]{name}[/]: {st.title}")
    for text in listing:
        out_console.print(text)


def _count(n: int, one: str, many: str | None = None) -> str:
    return f"{n} {one if n == 1 else many or one + 's'}"


# ----------------------------------------------------------------------------------------------
@cli.group("study")
def study() -> None:
    """Studies: capacity, headway, junction, safety, tradeoff, and run (a study file).

    \b
    Example:
      vcsumo study capacity --line felez_test --controllers cbc --convoy-sizes 2
    """


@study.command("run")
@click.argument("study_file", type=click.Path(path_type=Path))
@click.option("--out", default=None, help="Results folder (overrides the file's out)")
def study_run_cmd(study_file: Path, out: str | None) -> None:
    """Run a study definition file: capacity, headway, batch, junction, safety or tradeoff.

    STUDY_FILE is a path, or the name of a shipped study (e.g. capacity_hcmc_line1, from the
    package's data/studies/ or $VCSUMO_HOME/studies/).  Paths in the file are relative to it; the
    file's fields are the command's options (same names in snake_case, same units and bounds).
    """
    from vcsumo.cli.study_files import load_study, run_study, shipped_or_path
    from vcsumo.studies.configs import StudyRunConfig

    cfg = StudyRunConfig.from_options({"out": out} if out is not None else {})
    run_study(load_study(shipped_or_path(study_file)), cfg.out_path)


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
    from vcsumo.line import package_data
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
            with package_data():  # the paper's own files, whatever $VCSUMO_HOME holds
                table = reproduce_felez2019(rf.path, strats, horizon, sweep=not no_sweep, convoy=not no_convoy, progress=upd)
    print_table(table, "Felez et al. (2019) §IV-A — reproduced vs paper",
                ["strategy", "variant", "a_follower_mps2", "stop_distance_m", "paper_stop_distance_m", "stop_delay_s", "paper_stop_delay_s", "gap_at_rest_m", "min_gap_m",
                 "collisions"],
                csv_path=out / "felez2019.csv")
    out_console.print(f"wrote {out / 'felez2019.csv'}")


@reproduce.command("terlizzi2024")
@click.option("--scenario", type=click.Choice(["os1", "os2", "authors", "both", "all"]), default="all", show_default=True,
              help="os1 (delays 3 s, 0.8 s), os2 (estimator on/off), authors (the authors' code set-up), both (os1 + os2), all")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (default: new folder under results/)")
def terlizzi2024_cmd(scenario: str, out: Path | None) -> None:
    """Terlizzi, Liuzza & Glielmo (2024) OS1 (delays 3 s / 0.8 s), OS2 (delay estimator on/off) and the authors'-code OS1 (the shipped experiment files)."""
    from vcsumo.line import package_data
    from vcsumo.reproduce.report import reproduce_terlizzi2024
    from vcsumo.results import ResultsFolder, default_out

    scen = {"both": ("os1", "os2"), "all": ("os1", "os2", "authors")}.get(scenario, (scenario,))
    out = out or default_out("reproduce", "terlizzi2024")
    with ResultsFolder(out, params={"scenarios": scen}) as rf:
        with progress_bar() as prog, progress_task(prog, "terlizzi2024") as upd:
            with package_data():
                summary = reproduce_terlizzi2024(rf.path, scen, progress=upd)
    cols = [c for c in ["run", "coupled_distance_m", "coupled_interdistance_m", "emergency_activations", "min_gap_m", "both_stopped_gap_m", "true_barrier_max",
                        "robust_barrier_max"] if c in summary]
    print_table(summary, "Terlizzi et al. (2024) — reproduced", cols)
    out_console.print(f"wrote {out}")


def _register_commands() -> None:
    from vcsumo.cli.batch import batch_cmd
    from vcsumo.cli.commands import build_network_cmd, capacity_cmd, headway_cmd, run_cmd

    cli.add_command(build_network_cmd)
    cli.add_command(run_cmd)
    study.add_command(headway_cmd)
    study.add_command(capacity_cmd)
    cli.add_command(batch_cmd)


_register_commands()


def _register_junction() -> None:
    from vcsumo.cli.junction import junction_cmd

    study.add_command(junction_cmd)


_register_junction()


def _register_safety() -> None:
    from vcsumo.cli.safety import safety_cmd

    study.add_command(safety_cmd)


_register_safety()
cli.add_command(experiment_cmd)
study.add_command(tradeoff_cmd)

EXAMPLES = {
    "lines": "vcsumo lines",
    "build-network": "vcsumo build-network --line felez_test",
    "run": "vcsumo run --line felez_test --timetable test --regime fbs --out results/felez-fbs",
    "study headway": "vcsumo study headway --line felez_test --regime both",
    "study capacity": "vcsumo study capacity --line firenze_bologna --controllers cbc,cbf-cbc --workers 2",
    "study junction": "vcsumo study junction --line firenze_bologna --controllers cbc",
    "study safety": "vcsumo study safety --scenarios 100 --controllers cbc,cbf-cbc --seed 7",
    "study tradeoff": "vcsumo study tradeoff --line firenze_bologna --grid --simulate-check 2",
    "study run": "vcsumo study run capacity_hcmc_line1 --out results/hcmc",
    "batch": "vcsumo batch --line felez_test --timetables convoy --regimes fbs,vc --seeds 3",
    "experiment": "vcsumo experiment terlizzi2024_os1_authors --out results/os1-authors",
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


def usage_problem(exc: click.exceptions.UsageError) -> str:
    """click's usage error as one line, ``--option: problem (see 'vcsumo cmd --help')``: before, click's
    three lines (``Usage: ...``, ``Try ... --help``, ``Error: No such option '--bogus'.``)."""
    if isinstance(exc, click.BadParameter) and not isinstance(exc, click.MissingParameter) and exc.param is not None:
        name = exc.param.opts[0] if isinstance(exc.param, click.Option) and exc.param.opts else exc.param.human_readable_name
        text = f"{name}: {exc.message}"
    else:
        text = exc.format_message()
    text = " ".join(text.split()).rstrip(".")
    return text + (f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else "")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``vcsumo`` console script."""
    setup_logging(0, console)
    from vcsumo.loaded_files import noting_loaded_files
    from vcsumo.engine.campaign import Interrupted, sigterm_as_interrupt

    try:
        with sigterm_as_interrupt(), noting_loaded_files():  # SIGTERM (timeout, kill) cleans up like Ctrl-C; meta.json names every file read
            cli.main(args=argv, prog_name="vcsumo", standalone_mode=False)
    except VcsumoError as exc:
        for problem in getattr(exc, "problems", None) or [exc]:  # several problems of one input: one line each
            console.print(f"error: {problem}", highlight=False, markup=False, soft_wrap=True)
        return getattr(exc, "exit_code", 2)  # 2: bad input; 1: the command ran but every case failed
    except click.exceptions.Abort as exc:
        if isinstance(exc.__cause__, Interrupted):  # click turns KeyboardInterrupt into Abort
            console.print("terminated")
            return 128 + exc.__cause__.signum
        console.print("interrupted" if isinstance(exc.__cause__, KeyboardInterrupt) else "aborted")
        return 130
    except click.exceptions.UsageError as exc:  # an unknown option or command, a value click itself rejects: one line, as every input error
        console.print(f"error: {usage_problem(exc)}", highlight=False, markup=False, soft_wrap=True)
        return 2
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
