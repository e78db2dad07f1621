"""``vcsumo study junction``: convoys merging and splitting at speed, against FBS and MB.

A thin command in the style of :mod:`vcsumo.cli.main`: parse options, load inputs, call
:func:`vcsumo.studies.junction.run_junction_study` with a progress bar, print the table and where
it wrote.  :mod:`vcsumo.cli.main` registers it under the ``study`` group (this module imports
:mod:`vcsumo.cli.main` only when the command runs).
"""

from __future__ import annotations

from pathlib import Path

import click

from vcsumo.cli.ui import out_console, print_table, progress_bar, progress_task
from vcsumo.cli.verdict import count_not_healthy, not_healthy, require_clean
from vcsumo.errors import InputError, VcsumoError


def _csv(value: str, option: str) -> list[str]:
    return [x.strip() for x in value.split(",") if x.strip()]


def _floats(value: str, option: str) -> tuple[float, ...]:
    try:
        out = tuple(float(x) for x in _csv(value, option))
    except ValueError:
        raise InputError(None, option, f"'{value}' is not a comma-separated list of numbers") from None
    if not out:
        raise InputError(None, option, "empty list")
    return out


@click.command("junction")
@click.option("--line", "line_spec", required=True, help="Shipped line name or path to a line.yaml (with at least one branch)")
@click.option("--junction", "junctions", default=None, help="Branch id(s) of the junction(s) to study, comma-separated, or 'all' (default: chosen from the line file)")
@click.option("--train", default=None, help="Train type (default: the line's default_train)")
@click.option("--controllers", default="cbc,cbf-cbc", show_default=True, help="VC controllers (NAME or NAME:PARAMS), comma-separated; '' for none")
@click.option("--first", type=click.Choice(["main", "branch", "both"]), default="both", show_default=True,
              help="Which service passes the first junction first (the convoy leader)")
@click.option("--junction-signal", "variants", type=click.Choice(["sumo", "braking-curve", "both"]), default="braking-curve", show_default=True,
              help="VC follower at a red merge signal: a braking curve to the signal, SUMO's own handling (speed mode 26: stopped at the "
                   "signal within one step), or both for the comparison")
@click.option("--directions", default="up,down", show_default=True, help="Directions to study")
@click.option("--offsets", default="0,10,20,30,45,60,90,120", show_default=True, help="Arrival offsets swept before the bisection, s")
@click.option("--tolerance-s", type=float, default=2.0, show_default=True, help="Lost time still counted as unhindered, s")
@click.option("--resolution-s", type=float, default=1.0, show_default=True, help="Bisection resolution on the offset, s")
@click.option("--window-m", type=float, default=5000.0, show_default=True, help="Half-width of the merge/split windows for min gap and violations, m")
@click.option("--approach-m", type=float, default=12000.0, show_default=True, help="Main-line release distance before the first junction, m")
@click.option("--block-length-m", type=float, default=None, help="Override the line's block length, m")
@click.option("--step-length", type=float, default=0.5, show_default=True, help="SUMO step for FBS/MB, s")
@click.option("--vc-step-length", type=float, default=0.2, show_default=True, help="SUMO and controller step for VC, s")
@click.option("--assumptions", default=None, help="Assumption set of the separation model: a shipped name or a .yaml path (default: etcs_typical)")
@click.option("--seed", type=int, default=42, show_default=True, help="Random seed of SUMO and of the VC channels (message delays and losses); the same seed gives the same results")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Results folder (default: new folder under results/)")
def junction_cmd(line_spec: str, junctions: str | None, train: str | None, controllers: str, first: str, variants: str, directions: str, offsets: str,
                 tolerance_s: float, resolution_s: float, window_m: float, approach_m: float, block_length_m: float | None, step_length: float,
                 vc_step_length: float, assumptions: str | None, seed: int, out: Path | None) -> None:
    """Convoy merge and split at speed: formation, junction throughput, delay and safety under FBS, MB and VC."""
    from vcsumo.line import load_line
    from vcsumo.sim.network import build_network
    from vcsumo.results import ResultsFolder, default_out
    from vcsumo.rolling_stock import load_rolling_stock
    from vcsumo.studies.junction import ROLES, SIGNAL_VARIANTS, resolve_junctions, run_junction_study
    from vcsumo.control.registry import parse_controller
    from vcsumo.signalling.assumptions import load_assumptions

    for name, v in (("--step-length", step_length), ("--vc-step-length", vc_step_length)):
        if v <= 0 or v > 2:
            raise VcsumoError(f"{name}: {v} s is outside (0, 2] s")
    aset = load_assumptions(assumptions)
    line = load_line(line_spec)
    jids = resolve_junctions(line, junctions)
    name = train or line.data.default_train
    if not name:
        raise VcsumoError(f"{line.path}: default_train: the line names no default train; pass --train")
    stock = load_rolling_stock(name)
    ctrls = _csv(controllers, "--controllers")
    for c in ctrls:
        parse_controller(c, "--controllers")
    dirs = tuple(_csv(directions, "--directions"))
    if not dirs or any(d not in ("up", "down") for d in dirs):
        raise InputError(None, "--directions", f"'{directions}' (choose up, down)")
    firsts = ROLES if first == "both" else (first,)
    vars_ = SIGNAL_VARIANTS if variants == "both" else (variants,)
    offs = _floats(offsets, "--offsets")
    net = build_network(line, block_length_m)
    out = out or default_out("junction", line.name)
    params = {"junctions": jids, "train": name, "controllers": ctrls, "first": list(firsts), "junction_signal": list(vars_), "directions": list(dirs),
              "offsets_s": list(offs), "tolerance_s": tolerance_s, "resolution_s": resolution_s, "window_m": window_m, "approach_m": approach_m,
              "block_length_m": block_length_m, "step_length_s": step_length, "vc_step_length_s": vc_step_length,
              "assumptions": aset.record()}
    with ResultsFolder(out, inputs={"line": line.path}, seed=seed, params=params) as rf:
        with progress_bar() as prog:
            task = prog.add_task(f"junction {line.name}", total=1.0)

            def upd(k: int, n: int, desc: str) -> None:
                prog.update(task, completed=k / n if n else 1.0, description=f"junction {line.name}: {desc}")

            df = run_junction_study(line, net, stock, rf.path, ctrls, jids, dirs, firsts, vars_, offs, tolerance_s, resolution_s, window_m, approach_m,
                                    step_s=step_length, vc_step_s=vc_step_length, seed=seed, progress=upd, assumptions=aset)
    view = df.copy()
    view["controller"] = [f"{c} ({v})" if c else "" for c, v in zip(view.controller, view.junction_signal)]
    view = view.rename(columns={"junction_throughput_trains_per_h": "trains_per_h", "merging_service_delay_s": "delay_s", "leader_service": "leader",
                                "formation_start_m_before_merge": "forms_before_m", "gap_violations": "violations"})
    view["min_gap_m"] = view.min_gap_merge_m.where(view.junction_kind == "merge", view.min_gap_split_m)
    print_table(view, f"junction — {line.name} ({stock.name})", ["junction", "direction", "junction_kind", "leader", "regime", "controller", "trains_per_h",
                 "delay_s", "forms_before_m", "min_gap_m", "min_margin_m", "violations", "collisions", "healthy"], csv_path=out / "junction.csv",
                drop_first=["forms_before_m", "min_gap_m", "junction"])
    out_console.print(f"wrote {out / 'junction.csv'}")
    bad = df[not_healthy(df["healthy"])]
    for _, r in bad.head(5).iterrows():
        out_console.print(f"  not healthy: {r['junction']} {r['direction']} {r['regime']}{' ' + str(r['controller']) if r['controller'] else ''} "
                          f"({r['unhealthy_runs']} of its simulations; see junction.csv)", markup=False, highlight=False)
    require_clean("the junction study", len(df), 0, count_not_healthy(df["healthy"]), out / "junction.csv")
