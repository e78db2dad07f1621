"""Trade-off study: line capacity of FBS, MB and VC against the assumptions the safety case rests on.

The question a VC researcher asks is not "how much more capacity does VC give" but "how much, as a
function of what I have to guarantee": the age of the newest train-to-train message the relative
braking rule may rely on (``t2t_delay_bound_s``), how uncertain braking is
(``braking_uncertainty``) and how uncertain positions are (``position_error_m``).  This study
changes one of them at a time around a named assumption set (``model_copy(update=...)`` of
:class:`~vcsumo.signalling.assumptions.AssumptionSet`, every value validated as in an assumption
file) and, for each value, computes the line capacity of every regime **under the same changed
set**:

* each regime's minimum headway comes from the separation model alone
  (:meth:`vcsumo.signalling.regimes.base.Regime.analytic_headway`), on the line's route and the
  unit leader's unhindered run with guaranteed braking, exactly as the capacity study predicts its
  cases (:func:`vcsumo.studies.capacity_route.route_setup`, :func:`~vcsumo.studies.capacity_route.leader_run`,
  :func:`~vcsumo.studies.capacity_route.analytic_headway`, checked at
  :func:`~vcsumo.studies.capacity_route.check_position_m`; FBS and MB at the SUMO step ``step_s``, VC at
  ``vc_step_s``, whose 1.5 steps the supervision adds to the dead time);
* capacity = 3600·n / headway, trains/h (every train of a convoy counts); ``gain_vs_fbs`` and
  ``gain_vs_mb`` against FBS and MB at the same value.

Which assumptions each regime's rule uses is :data:`RULE_INPUTS` (``parameter_in_rule`` in the
table): the T2T delay bound enters VC only, so FBS and MB stay flat under a delay sweep; the report
period enters MB and VC (VC convoys keep moving-block distance between them); the braking
uncertainty and the position error enter every rule.  A flat FBS/MB line is the same computation
under the changed set, not a copy of the base value.

``grid`` adds the T2T delay × braking uncertainty grid.  ``breakeven``: for every convoy size, the
T2T delay bound at which VC's capacity falls to MB's (bisection up to the largest bound an
assumption set admits; empty when VC stays ahead up to it).  ``simulate_check`` N: the capacity
study's simulation (:func:`vcsumo.studies.capacity.run_case`, VC n=2, the named controller) at N
of the swept points, beside the analytic figure.

Writes ``tradeoff.csv`` (tidy, :data:`TRADEOFF_COLUMNS`), ``tradeoff_breakeven.csv``,
``tradeoff_check.csv`` (with ``simulate_check``), ``tradeoff.png`` (drawn from the CSVs only,
:mod:`vcsumo.plots.tradeoff`) and ``meta.json`` (the base assumption set in full).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Callable, Literal

import pandas as pd
from pydantic import Field, TypeAdapter, ValidationError, field_validator

from vcsumo.config import StrictModel
from vcsumo.errors import InfeasibleBraking, InputError, VcsumoError
from vcsumo.line import Line
from vcsumo.rolling_stock import RollingStock
from vcsumo.signalling.assumptions import AssumptionSet
from vcsumo.signalling.separation import SeparationModel
from vcsumo.sim.network import BuiltNetwork
from vcsumo.studies.capacity_route import (STANDSTILL_EXTRA_M, Case, analytic_headway, check_position_m, convoy_spacing,  # noqa: F401 (STANDSTILL_EXTRA_M: also from here)
                                           convoys_longer_than_platforms, leader_run, route_setup)
from vcsumo.sim.convoy_plan import load_channel

SWEPT = ("t2t_delay_bound_s", "braking_uncertainty", "position_error_m")
"""Assumptions the study sweeps (fields of :class:`~vcsumo.signalling.assumptions.AssumptionSet`)."""
GRID = "grid"
"""``parameter`` of the T2T delay × braking uncertainty grid rows (the coordinates are in the
``t2t_delay_bound_s`` and ``braking_uncertainty`` columns)."""

_ABSOLUTE = ("braking_uncertainty", "reaction_time_s", "brake_build_up_s", "position_error_m", "fixed_time_s")
RULE_INPUTS: dict[str, frozenset[str]] = {
    "fbs": frozenset(_ABSOLUTE + ("overlap_m",)),
    "mb": frozenset(_ABSOLUTE + ("safety_margin_m", "position_report_period_s")),
    "vc": frozenset(_ABSOLUTE + ("safety_margin_m", "position_report_period_s", "t2t_delay_bound_s", "relative_braking")),
}
"""The assumption-set fields each regime's analytic headway depends on.

Every regime: the follower's guaranteed service braking (uncertainty, reaction and build-up: the
dead time; not ``absolute_braking``, the brake the separation is certified with: trains approach
their end of authority on the service brake whatever it says) and the leader's run on its
guaranteed braking curve; the position error (FBS: the
follower stops its error short of the signal and the leader's rear is an overlap plus its error
beyond the next; MB, VC: twice in the margin behind the confirmed rear); the fixed times.  FBS: the
overlap.  MB: the margin and the position-report period.  VC: MB's (between convoys), and inside a
convoy the relative-braking gap with the T2T delay bound and the relative-braking brake."""

TRADEOFF_COLUMNS = [
    "parameter", "value", "regime", "convoy_size", "headway_s", "capacity_trains_per_h", "gain_vs_fbs", "gain_vs_mb", "parameter_in_rule",
    "base_value", "t2t_delay_bound_s", "braking_uncertainty", "position_error_m", "critical_km", "coupled_gap_m", "release_speed_kmh",
    "assumptions", "line", "train", "direction", "pattern", "error",
]
BREAKEVEN_COLUMNS = ["parameter", "convoy_size", "breakeven_value", "searched_up_to", "mb_capacity_trains_per_h", "assumptions", "line",
                     "train", "direction", "pattern"]
CHECK_COLUMNS = [
    "parameter", "value", "regime", "controller", "convoy_size", "headway_analytic_s", "headway_sim_s", "deviation_pct",
    "capacity_analytic_trains_per_h", "capacity_sim_trains_per_h", "healthy", "gap_violations", "collisions", "min_margin_m",
    "below_separation_time_s", "overspeed_events", "beyond_service_brakings", "authority_overruns", "stops_skipped", "short_dwells",
    "sumo_emergency_stops", "sumo_emergency_brakings", "sumo_stop_warnings", "teleports", "emergency_brakes", "simulations", "error",
]
HEALTH_COUNTERS = ("gap_violations", "collisions", "min_margin_m", "below_separation_time_s", "overspeed_events", "beyond_service_brakings",
                   "authority_overruns", "stops_skipped", "short_dwells", "sumo_emergency_stops", "sumo_emergency_brakings", "sumo_stop_warnings",
                   "teleports", "emergency_brakes", "simulations")
"""Counters of the simulated check, as the capacity study reports them (:mod:`vcsumo.sim.health`)."""

ConvoySize = Annotated[int, Field(ge=2, le=8, description="Trains in a VC convoy (2–8)")]
Step = Annotated[float, Field(gt=0, le=2, description="Simulation step, s (at most 2 s)")]


def _check_values(field: str, values: list[float]) -> list[float]:
    """Every value within the bounds an assumption file admits for ``field`` (one source: the set's own field)."""
    adapter = TypeAdapter(Annotated[(float, *AssumptionSet.model_fields[field].metadata)])
    for k, v in enumerate(values):
        try:
            adapter.validate_python(v)
        except ValidationError as exc:
            raise ValueError(f"value {k + 1} ({v:g}): {exc.errors()[0]['msg']}") from None
    return sorted(set(values))


class TradeoffConfig(StrictModel):
    """Options of ``vcsumo study tradeoff`` (a study file ``study: tradeoff`` gives the same)."""

    line: str = Field(description="Shipped line name or path to a line.yaml")
    train: str | None = Field(default=None, description="Train type (default: the line's default_train)")
    convoy_sizes: list[ConvoySize] = Field(default_factory=lambda: [2, 3, 4], min_length=1, description="VC convoy sizes (2–8)")
    delays_s: list[float] = Field(default_factory=lambda: [0.1, 0.25, 0.5, 1.0, 2.0, 3.0],
                                  description="T2T delay bounds swept, s (t2t_delay_bound_s; empty: not swept)")
    uncertainties: list[float] = Field(default_factory=lambda: [0.0, 0.05, 0.1, 0.15, 0.2],
                                       description="Braking uncertainties swept, relative half-width (0.1 = ±10 %; empty: not swept)")
    position_errors_m: list[float] = Field(default_factory=lambda: [0.0, 5.0, 10.0, 20.0, 50.0],
                                           description="Position errors per train swept, m (empty: not swept)")
    grid: bool = Field(default=False, description="Also the T2T delay × braking uncertainty grid")
    assumptions: str | None = Field(default=None, description="Base assumption set: shipped name or .yaml path (default: etcs_typical)")
    pattern: Literal["non-stop", "all-stops"] = Field(default="non-stop", description="Stopping pattern")
    direction: Literal["up", "down"] = Field(default="up", description="Direction")
    simulate_check: int = Field(default=0, ge=0, le=50, description="Swept points also simulated (VC n=2, capacity study's loop), 0–50")
    controller: str = Field(default="cbc", description="VC controller: the spacing its stack certifies sets the VC figures, and it runs the simulated check")
    block_length_m: float | None = Field(default=None, ge=100, le=50000, description="Override the line's block length, m")
    step_length_s: Step = 0.5
    vc_step_length_s: Step = 0.2
    seed: int = Field(default=42, ge=0, description="Random seed of the simulated check")

    @field_validator("delays_s")
    @classmethod
    def _delays(cls, v: list[float]) -> list[float]:
        return _check_values("t2t_delay_bound_s", v)

    @field_validator("uncertainties")
    @classmethod
    def _uncertainties(cls, v: list[float]) -> list[float]:
        return _check_values("braking_uncertainty", v)

    @field_validator("position_errors_m")
    @classmethod
    def _position_errors(cls, v: list[float]) -> list[float]:
        return _check_values("position_error_m", v)

    def sweeps(self) -> dict[str, list[float]]:
        """Swept field of the assumption set -> its values (non-empty sweeps only)."""
        sw = {"t2t_delay_bound_s": self.delays_s, "braking_uncertainty": self.uncertainties, "position_error_m": self.position_errors_m}
        return {k: v for k, v in sw.items() if v}


@dataclass(frozen=True)
class TradeoffLine:
    """What every point of the study shares: the line, its network, the train, direction and pattern."""

    line: Line
    net: BuiltNetwork
    stock: RollingStock
    direction: str
    pattern: str
    step_s: float = 0.5
    vc_step_s: float = 0.2
    vc_controller: str | None = None
    """The controller whose certified spacing VC convoys keep (its stack's coupled gap, as the
    capacity study's analytic headway); None: the separation model's coupled gap ``vc_gap(v)``."""


def changed(base: AssumptionSet, **update) -> AssumptionSet:
    """The base set with some fields changed (same name: the change is in the row's parameter and value)."""
    return base.model_copy(update=update)


def capacities(tl: TradeoffLine, aset: AssumptionSet, units: list[tuple[str, int]]) -> list[dict]:
    """Analytic headway and capacity of each (regime, convoy size) under ``aset``.

    Columns ``regime, convoy_size, headway_s, capacity_trains_per_h, critical_km, coupled_gap_m,
    release_speed_kmh, error`` (a set under which the train has no guaranteed braking somewhere:
    every row carries the error and no figure)."""
    model = SeparationModel(aset)
    try:
        setup = route_setup(tl.line, tl.net, tl.stock, tl.direction, tl.step_s, model)
        s_check = check_position_m(setup)
        runs: dict[float, pd.DataFrame] = {}
        rows = []
        for regime, n in units:
            dt = tl.vc_step_s if regime == "vc" else tl.step_s
            case = Case(tl.direction, regime, None, n, tl.pattern)
            if dt not in runs:
                runs[dt] = leader_run(setup, tl.stock, case, dt, model)
            # the capacity study's spacing: on the route, with the message age of its runs' channel
            spacing = (convoy_spacing(tl.vc_controller, tl.stock, dt, aset, setup.full, load_channel(None).age_budget_s())
                       if regime == "vc" and n > 1 and tl.vc_controller else None)
            th = analytic_headway(tl.net, setup, runs[dt], tl.stock, case, model, dt, s_check, spacing, on_route=True)
            rows.append({"regime": regime, "convoy_size": n, "headway_s": round(th.headway_s, 3),
                         "capacity_trains_per_h": round(3600.0 * n / th.headway_s, 3), "critical_km": round(setup.full.km_at(th.critical_m)[1], 3),
                         "coupled_gap_m": round(th.coupled_gap_m, 1) if th.coupled_gap_m is not None else math.nan,
                         "release_speed_kmh": round(3.6 * setup.v0, 1), "error": ""})
        return rows
    except InfeasibleBraking as exc:  # no guaranteed braking on a descent under this set
        return [{"regime": r, "convoy_size": n, "headway_s": math.nan, "capacity_trains_per_h": math.nan, "critical_km": math.nan,
                 "coupled_gap_m": math.nan, "release_speed_kmh": math.nan, "error": str(exc)} for r, n in units]


def study_units(convoy_sizes: list[int]) -> list[tuple[str, int]]:
    return [("fbs", 1), ("mb", 1)] + [("vc", n) for n in convoy_sizes]


def sweep_points(base: AssumptionSet, sweeps: dict[str, list[float]], grid: bool) -> list[tuple[str, float, AssumptionSet]]:
    """(parameter, value, changed set) for every point: one parameter at a time (the base value
    added to each sweep, so every line passes through the base), then the grid if asked (its
    axes: the delay and uncertainty sweeps, with their base values)."""
    pts = []
    for field, values in sweeps.items():
        for v in sorted(set(values) | {float(getattr(base, field))}):
            pts.append((field, float(v), changed(base, **{field: float(v)})))
    if grid:
        delays = sorted(set(sweeps.get("t2t_delay_bound_s", [])) | {base.t2t_delay_bound_s})
        uncs = sorted(set(sweeps.get("braking_uncertainty", [])) | {base.braking_uncertainty})
        for u in uncs:
            for d in delays:
                pts.append((GRID, math.nan, changed(base, t2t_delay_bound_s=float(d), braking_uncertainty=float(u))))
    return pts


def tradeoff_table(tl: TradeoffLine, base: AssumptionSet, sweeps: dict[str, list[float]], convoy_sizes: list[int], grid: bool = False,
                   progress: Callable[[int, int, str], None] | None = None) -> pd.DataFrame:
    """Every point's capacities, gains and labels (:data:`TRADEOFF_COLUMNS`)."""
    pts = sweep_points(base, sweeps, grid)
    units = study_units(convoy_sizes)
    rows = []
    for k, (param, value, aset) in enumerate(pts):
        part = capacities(tl, aset, units)
        fbs, mb = part[0]["capacity_trains_per_h"], part[1]["capacity_trains_per_h"]
        for r in part:
            r.update(parameter=param, value=value, gain_vs_fbs=round(r["capacity_trains_per_h"] / fbs, 4),
                     gain_vs_mb=round(r["capacity_trains_per_h"] / mb, 4),
                     parameter_in_rule=(param in RULE_INPUTS[r["regime"]]) if param != GRID else True,
                     base_value=float(getattr(base, param)) if param != GRID else math.nan,
                     **{f: float(getattr(aset, f)) for f in SWEPT})
            rows.append(r)
        if progress:
            progress(k + 1, len(pts), f"{param} = {value:g}" if param != GRID else f"grid {aset.t2t_delay_bound_s:g} s, ±{100 * aset.braking_uncertainty:g} %")
    df = pd.DataFrame(rows)
    df = df.assign(assumptions=base.name, line=tl.line.name, train=tl.stock.name, direction=tl.direction, pattern=tl.pattern)
    return df[TRADEOFF_COLUMNS]


def breakeven_delays(tl: TradeoffLine, base: AssumptionSet, convoy_sizes: list[int], tol_s: float = 0.01) -> pd.DataFrame:
    """For each convoy size, the T2T delay bound at which VC's capacity falls to MB's (the rest of
    ``base`` unchanged), s; NaN when VC stays ahead up to the largest bound a set admits.

    The delay enters VC only (MB is computed once) and VC's capacity falls as it grows, so a
    bisection finds the crossing."""
    hi_bound = float(_field_bound("t2t_delay_bound_s"))
    mb = capacities(tl, base, [("mb", 1)])[0]["capacity_trains_per_h"]
    rows = []
    for n in convoy_sizes:
        def excess(d: float) -> float:
            return capacities(tl, changed(base, t2t_delay_bound_s=d), [("vc", n)])[0]["capacity_trains_per_h"] - mb

        lo, hi = 0.0, hi_bound
        value = math.nan
        if math.isfinite(mb) and excess(lo) <= 0.0:
            value = 0.0
        elif math.isfinite(mb) and excess(hi) < 0.0:
            while hi - lo > tol_s:
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if excess(mid) > 0.0 else (lo, mid)
            value = round(0.5 * (lo + hi), 3)
        rows.append({"parameter": "t2t_delay_bound_s", "convoy_size": n, "breakeven_value": value, "searched_up_to": hi_bound,
                     "mb_capacity_trains_per_h": mb})
    df = pd.DataFrame(rows, columns=BREAKEVEN_COLUMNS[:5])
    return df.assign(assumptions=base.name, line=tl.line.name, train=tl.stock.name, direction=tl.direction, pattern=tl.pattern)[BREAKEVEN_COLUMNS]


def _field_bound(field: str) -> float:
    for m in AssumptionSet.model_fields[field].metadata:
        if hasattr(m, "le"):
            return float(m.le)
    raise KeyError(field)


def check_points(table: pd.DataFrame, n: int) -> list[tuple[str, float]]:
    """The ``n`` swept points simulated: the base set first, then round-robin over the parameters,
    each parameter's values farthest from its base first."""
    sweep = table[(table.parameter != GRID) & (table.regime == "vc") & (table.convoy_size == 2)]
    order: dict[str, list[float]] = {}
    for param, g in sweep.groupby("parameter", sort=False):
        base = float(g.base_value.iloc[0])
        order[param] = sorted((float(v) for v in g.value if v != base), key=lambda v: -abs(v - base))
    out: list[tuple[str, float]] = []
    if len(sweep):
        first = sweep.iloc[0]
        out.append((str(first.parameter), float(first.base_value)))
    while len(out) < n and any(order.values()):
        for param in list(order):
            if order[param] and len(out) < n:
                out.append((param, order[param].pop(0)))
    return out[:n]


def simulate_check(tl: TradeoffLine, base: AssumptionSet, table: pd.DataFrame, n: int, controller: str, out: Path, seed: int = 42,
                   progress: Callable[[int, int, str], None] | None = None) -> pd.DataFrame:
    """The capacity study's simulation (VC n=2) at ``n`` swept points, beside the analytic figure (:data:`CHECK_COLUMNS`)."""
    from vcsumo.results import safe_component
    from vcsumo.studies.capacity import run_case

    rows = []
    pts = check_points(table, n)
    for k, (param, value) in enumerate(pts):
        aset = changed(base, **{param: value})
        an = table[(table.parameter == param) & (table.value == value) & (table.regime == "vc") & (table.convoy_size == 2)].iloc[0]
        row = {"parameter": param, "value": value, "regime": "vc", "controller": controller, "convoy_size": 2,
               "headway_analytic_s": an.headway_s, "capacity_analytic_trains_per_h": an.capacity_trains_per_h, "error": ""}
        if progress:
            progress(k, len(pts), f"simulating VC n=2 at {param} = {value:g}")
        try:
            setup = route_setup(tl.line, tl.net, tl.stock, tl.direction, tl.step_s, SeparationModel(aset))
            res = run_case(tl.line, tl.net, tl.stock, setup, Case(tl.direction, "vc", controller, 2, tl.pattern),
                           out / "checks" / safe_component(f"{param}-{value:g}"), tl.step_s, tl.vc_step_s, resolution_s=1.0, seed=seed, assumptions=aset)
            r = res.row
            if abs(r["headway_analytic_s"] - an.headway_s) > 0.01:  # the same prediction, or the comparison means nothing
                raise VcsumoError(f"analytic headway {an.headway_s} s here, {r['headway_analytic_s']} s in the capacity case")
            row.update(headway_sim_s=r["headway_sim_s"], deviation_pct=round(100.0 * (r["headway_sim_s"] - an.headway_s) / an.headway_s, 2),
                       capacity_sim_trains_per_h=r["capacity_trains_per_h"], healthy=r["healthy"], **{k: r[k] for k in HEALTH_COUNTERS})
        except VcsumoError as exc:
            row["error"] = str(exc)
        rows.append(row)
    if progress:
        progress(len(pts), len(pts), "simulated checks done")
    return pd.DataFrame(rows, columns=CHECK_COLUMNS)


@dataclass
class TradeoffResult:
    table: pd.DataFrame
    breakeven: pd.DataFrame
    check: pd.DataFrame | None
    base: AssumptionSet
    out: Path


def load_inputs(cfg: TradeoffConfig) -> tuple[Line, RollingStock, AssumptionSet]:
    """The line, train and base assumption set a config names (InputError naming the option if not)."""
    from vcsumo.line import load_line
    from vcsumo.rolling_stock import load_rolling_stock
    from vcsumo.signalling.assumptions import load_assumptions

    line = load_line(cfg.line)
    name = cfg.train or line.data.default_train
    if not name:
        raise InputError(line.path, "default_train", "the line names no default train; pass --train")
    try:
        stock = load_rolling_stock(name)
    except InputError as exc:
        if exc.path is None and not cfg.train:  # the line's default_train: the line file is to blame
            raise InputError(line.path, "default_train", exc.message) from None
        raise InputError(exc.path, exc.field if exc.path else "--train", exc.message) from None
    return line, stock, load_assumptions(cfg.assumptions)


def run_tradeoff_study(cfg: TradeoffConfig, out: Path, progress: Callable[[int, int, str], None] | None = None) -> TradeoffResult:
    """The whole study into the results folder ``out`` (written whole or not at all)."""
    from vcsumo.control.registry import parse_controller
    from vcsumo.plots.tradeoff import plot_tradeoff
    from vcsumo.results import ResultsFolder
    from vcsumo.sim.network import build_network

    t0 = time.perf_counter()
    if not cfg.sweeps():
        raise InputError(None, "--delays", "nothing to sweep (--delays, --uncertainties and --position-errors are all empty)")
    if cfg.simulate_check:
        parse_controller(cfg.controller)
    line, stock, base = load_inputs(cfg)
    net = build_network(line, cfg.block_length_m)
    tl = TradeoffLine(line, net, stock, cfg.direction, cfg.pattern, cfg.step_length_s, cfg.vc_step_length_s, vc_controller=cfg.controller)
    if cfg.pattern == "all-stops":
        model = SeparationModel(base)
        stops = route_setup(line, net, stock, cfg.direction, cfg.step_length_s, model).stops_full
        if not stops:
            raise InputError(None, "--pattern", f"all-stops: {line.name} has no intermediate station after the release point in direction {cfg.direction}")
        for msg in convoys_longer_than_platforms(stops, stock, cfg.convoy_sizes, model.margin_m + STANDSTILL_EXTRA_M):
            warnings.warn(msg, stacklevel=2)
    at_base = capacities(tl, base, [("mb", 1)])[0]
    if at_base["error"]:  # the train cannot run the route safely under the study's own set: nothing to trade off
        raise VcsumoError(f"infeasible: {at_base['error']} on {line.name} ({cfg.direction}) under the assumption set '{base.name}'")
    params = {**cfg.model_dump(mode="json"), "train": stock.name, "assumptions": base.record(), "rule_inputs": {k: sorted(v) for k, v in RULE_INPUTS.items()}}
    with ResultsFolder(out, inputs={"line": line.path}, seed=cfg.seed, params=params) as rf:
        table = tradeoff_table(tl, base, cfg.sweeps(), cfg.convoy_sizes, cfg.grid, progress)
        table.to_csv(rf.path / "tradeoff.csv", index=False)
        breakeven = breakeven_delays(tl, base, cfg.convoy_sizes)
        breakeven.to_csv(rf.path / "tradeoff_breakeven.csv", index=False)
        check = None
        if cfg.simulate_check:
            check = simulate_check(tl, base, table, cfg.simulate_check, cfg.controller, rf.path, cfg.seed, progress)
            check.to_csv(rf.path / "tradeoff_check.csv", index=False)
        plot_tradeoff(rf.path / "tradeoff.csv", rf.path / "tradeoff.png", rf.path / "tradeoff_check.csv" if check is not None else None,
                      rf.path / "tradeoff_breakeven.csv")
        rf.extra_meta = {"points": int(table[["parameter", "value", "t2t_delay_bound_s", "braking_uncertainty", "position_error_m"]].drop_duplicates().shape[0]),
                         "study_wall_time_s": round(time.perf_counter() - t0, 2)}
    return TradeoffResult(table, breakeven, check, base, Path(out))
