"""``vcsumo study tradeoff``: capacity of FBS, MB and VC against the T2T delay bound, the braking
uncertainty and the position error (:mod:`vcsumo.studies.tradeoff`).

A thin command: build the study's Config from the options (a study file ``study: tradeoff`` fills
the same options, :class:`vcsumo.cli.study_files.TradeoffStudy`), run it with a progress bar, print the capacities and where it
wrote.  :mod:`vcsumo.cli.main` registers it under the ``study`` group.
"""

from __future__ import annotations

from pathlib import Path

import click
from pydantic import ValidationError

from vcsumo.cli.ui import out_console, print_table, progress_bar
from vcsumo.cli.verdict import count_not_healthy, require_clean
from vcsumo.errors import InputError

OPTION_OF = {"delays_s": "--delays", "position_errors_m": "--position-errors", "step_length_s": "--step-length",
             "vc_step_length_s": "--vc-step-length", "simulate_check": "--simulate-check"}
"""Config field -> option, where the names differ by more than ``_`` and ``-``."""


UNHEALTHY_COUNTERS = ("gap_violations", "collisions", "below_separation_time_s", "overspeed_events", "beyond_service_brakings", "authority_overruns",
                      "stops_skipped", "short_dwells", "sumo_emergency_stops", "sumo_emergency_brakings", "sumo_stop_warnings", "teleports")
"""The counters a simulated check is not healthy for, named in its line (every one the capacity row's health rests on)."""


def _floats(value: str, option: str) -> list[float]:
    try:
        return [float(x) for x in value.split(",") if x.strip()]
    except ValueError:
        raise InputError(None, option, f"'{value}' is not a comma-separated list of numbers") from None


def _ints(value: str, option: str) -> list[int]:
    try:
        return [int(x) for x in value.split(",") if x.strip()]
    except ValueError:
        raise InputError(None, option, f"'{value}' is not a comma-separated list of integers") from None


@click.command("tradeoff")
@click.option("--line", "line_spec", required=True, help="Shipped line name or path to a line.yaml")
@click.option("--train", default=None, help="Train type (default: the line's default_train)")
@click.option("--convoy-sizes", default="2,3,4", show_default=True, help="VC convoy sizes (2-8), comma-separated")
@click.option("--delays", default="0.1,0.25,0.5,1,2,3", show_default=True, help="T2T delay bounds swept, s ('' : not swept)")
@click.option("--uncertainties", default="0,0.05,0.1,0.15,0.2", show_default=True, help="Braking uncertainties swept (0.1 = ±10 %; '' : not swept)")
@click.option("--position-errors", default="0,5,10,20,50", show_default=True, help="Position errors per train swept, m ('' : not swept)")
@click.option("--grid", is_flag=True, help="Also the T2T delay × braking uncertainty grid")
@click.option("--assumptions", default=None, help="Base assumption set: a shipped name or a .yaml path (default: etcs_typical)")
@click.option("--pattern", type=click.Choice(["non-stop", "all-stops"]), default="non-stop", show_default=True, help="Stopping pattern")
@click.option("--direction", type=click.Choice(["up", "down"]), default="up", show_default=True, help="Direction")
@click.option("--simulate-check", type=int, default=0, show_default=True,
              help="Also simulate VC n=2 (the capacity study's loop) at this many swept points and report sim vs analytic")
@click.option("--controller", default="cbc", show_default=True, help="VC controller: the spacing its stack certifies sets the VC figures, and it runs the simulated check")
@click.option("--block-length-m", type=float, default=None, help="Override the line's block length, m")
@click.option("--step-length", type=float, default=0.5, show_default=True, help="SUMO step for FBS/MB, s (its 1.5 steps add to their dead time)")
@click.option("--vc-step-length", type=float, default=0.2, show_default=True, help="SUMO and controller step for VC, s")
@click.option("--seed", type=int, default=42, show_default=True, help="Random seed of the simulated check")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (default: new folder under results/)")
def tradeoff_cmd(line_spec: str, train: str | None, convoy_sizes: str, delays: str, uncertainties: str, position_errors: str, grid: bool,
                 assumptions: str | None, pattern: str, direction: str, simulate_check: int, controller: str, block_length_m: float | None,
                 step_length: float, vc_step_length: float, seed: int, out: Path | None) -> None:
    """Capacity of FBS, MB and VC n=2..4 against the T2T delay bound, braking uncertainty and position error (analytic, same assumptions for all)."""
    from vcsumo.results import default_out
    from vcsumo.studies.tradeoff import TradeoffConfig, run_tradeoff_study

    try:
        cfg = TradeoffConfig(line=line_spec, train=train, convoy_sizes=_ints(convoy_sizes, "--convoy-sizes"), delays_s=_floats(delays, "--delays"),
                             uncertainties=_floats(uncertainties, "--uncertainties"), position_errors_m=_floats(position_errors, "--position-errors"),
                             grid=grid, assumptions=assumptions, pattern=pattern, direction=direction, simulate_check=simulate_check,
                             controller=controller, block_length_m=block_length_m, step_length_s=step_length, vc_step_length_s=vc_step_length,
                             seed=seed)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = str(err["loc"][0])
        msg = " ".join(str(err["msg"]).split()).removeprefix("Value error, ")
        if len(err["loc"]) > 1 and isinstance(err["loc"][1], int):  # an item of a list option: its place and value, as the sweeps' own checks
            msg = f"value {err['loc'][1] + 1} ({err.get('input')}): {msg}"
        elif len(err["loc"]) > 1:
            msg += f" ({', '.join(str(x) for x in err['loc'][1:])})"
        raise InputError(None, OPTION_OF.get(field, "--" + field.replace("_", "-")), msg) from None
    from vcsumo.line import load_line

    out = out or default_out("tradeoff", load_line(cfg.line).name)
    prog = progress_bar()
    task = prog.add_task("tradeoff", total=1.0)
    shown = []

    def upd(k: int, n: int, desc: str) -> None:
        if not shown:  # the bar starts with the first point: input errors come before any bar
            prog.start()
            shown.append(True)
        prog.update(task, completed=k / n if n else 1.0, description=f"tradeoff: {desc}")

    try:
        res = run_tradeoff_study(cfg, out, upd)
    finally:
        if shown:
            prog.stop()
    t = res.table[res.table.parameter != "grid"].copy()
    t["unit"] = [r.upper() if r != "vc" else f"VC n={n}" for r, n in zip(t.regime, t.convoy_size)]
    view = t.pivot_table(index=["parameter", "value"], columns="unit", values="capacity_trains_per_h").reset_index()
    order = list(dict.fromkeys(t.parameter))
    view = view.sort_values(["parameter", "value"], key=lambda c: c.map(order.index) if c.name == "parameter" else c, ignore_index=True)
    units = list(dict.fromkeys(t.unit))
    vc2 = t[(t.regime == "vc") & (t.convoy_size == min(cfg.convoy_sizes))].set_index(["parameter", "value"]).gain_vs_mb
    view[f"VC n={min(cfg.convoy_sizes)} / MB"] = [vc2.get((p, v)) for p, v in zip(view.parameter, view.value)]
    view["value"] = [f"{v:g}" for v in view.value]
    print_table(view, f"trade-off — {t.line.iloc[0]} ({t.train.iloc[0]}, {cfg.direction}, {cfg.pattern}), capacity trains/h under {res.base.name} "
                "changed one assumption at a time", ["parameter", "value", *units, f"VC n={min(cfg.convoy_sizes)} / MB"], csv_path=out / "tradeoff.csv")
    for _, b in res.breakeven.iterrows():
        v = b.breakeven_value
        out_console.print(f"VC n={b.convoy_size}: falls to MB's capacity at a T2T delay bound of {v:g} s" if v == v
                          else f"VC n={b.convoy_size}: beats MB at every T2T delay bound up to {b.searched_up_to:g} s")
    if res.check is not None:
        for _, c in res.check.iterrows():
            why = [f"{k.replace('_', ' ')} {c[k]:g}" for k in UNHEALTHY_COUNTERS if c[k] == c[k] and c[k] > 0]
            health = "healthy" if c.healthy else f"NOT healthy ({', '.join(why) or 'a train did not arrive or a stop was not reached'})"
            text = (f"error: {c.error}" if c.error else f"sim {c.headway_sim_s:.1f} s vs analytic {c.headway_analytic_s:.1f} s "
                    f"({c.deviation_pct:+.1f} %), {health}, gap violations {int(c.gap_violations)}, collisions {int(c.collisions)}, "
                    f"min margin {c.min_margin_m:.1f} m")
            out_console.print(f"check VC n=2 ({c.controller}) at {c.parameter} = {c.value:g}: {text}", markup=False, highlight=False)
    out_console.print(f"wrote {out / 'tradeoff.csv'} and {out / 'tradeoff.png'}")
    if res.check is not None:
        chk = res.check
        errored = chk["error"].astype(str).str.len() > 0
        require_clean("the trade-off's simulated check", len(chk), int(errored.sum()), count_not_healthy(chk.loc[~errored, "healthy"]),
                      out / "tradeoff.csv", noun="cases")
