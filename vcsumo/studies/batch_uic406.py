"""UIC 406 capacity consumption of a batch's timetables (no delays), cached in the batch folder's
``uic406.csv`` per timetable, regime, step length, window and assumption set (:mod:`vcsumo.signalling.uic406`:
the blocking times of the separation model under the set the batch's runs are supervised and judged with).
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from vcsumo.engine.store import atomic_csv
from vcsumo.errors import VcsumoError
from vcsumo.line import Line
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.separation import SeparationModel
from vcsumo.studies.batch_run import RunSpec, assumptions_digest

UIC_COLUMNS = ["timetable", "timetable_sha256", "regime", "assumptions", "assumptions_sha256", "step_length_s", "window_s", "direction", "section", "from_km", "to_km",
               "length_m", "blocks", "trains", "scheduled_span_s", "occupation_s", "consumption_pct", "cycle_s", "cyclic_consumption_pct",
               "peak_window_start_s", "trains_in_window"]


def uic_table(out: Path, line: Line, specs: list[RunSpec], window_s: float, step_length_s: float, block_length_m: float | None,
              assumptions: AssumptionSet | None = None) -> pd.DataFrame:
    """The folder's ``uic406.csv`` (``UIC_COLUMNS``), completed with every timetable and regime of
    ``specs`` not yet in it (a timetable that fails to plan is skipped: its runs fail with the error)."""
    path = out / "uic406.csv"
    have = pd.read_csv(path, dtype={"timetable_sha256": str, "timetable": str, "assumptions": str, "assumptions_sha256": str}) if path.is_file() \
        else pd.DataFrame(columns=UIC_COLUMNS)
    if list(have.columns) != UIC_COLUMNS:  # (a folder of an older vcsumo: its figures were on SUMO's nominal braking, computed again)
        have = pd.DataFrame(columns=UIC_COLUMNS)
    model = SeparationModel(assumptions or load_assumptions())  # the set every run of the batch is supervised with (vcsumo.studies.batch_run)
    set_name = model.assumptions.name
    set_sha = assumptions_digest(model.assumptions.record())  # (a set edited under the same name is another set)

    def cached(sha: str, regime: str) -> bool:
        m = (have["timetable_sha256"] == sha) & (have["regime"] == regime) & (have["window_s"] == window_s) & (have["step_length_s"] == step_length_s) \
            & (have["assumptions_sha256"] == set_sha)
        return bool(m.any())

    need: dict[str, tuple[RunSpec, set[str]]] = {}
    for s in specs:
        if not cached(s.timetable_sha256, s.regime):
            need.setdefault(s.timetable_sha256, (s, set()))[1].add(s.regime)
    if not need:
        return have
    from vcsumo.sim.network import build_network
    from vcsumo.timetable import load_timetable, plan_trains
    from vcsumo.signalling.uic406 import capacity_consumption, convoy_pairs

    net = build_network(line, block_length_m)
    new = []
    for sha, (spec, regimes) in need.items():
        try:
            tt, p = load_timetable(Path(spec.timetable_path), line)
            trains = plan_trains(tt, p, line, net.topology, dt=step_length_s)
            pairs = convoy_pairs(tt, trains)
        except VcsumoError:
            continue  # the runs fail with the same error
        cache: dict = {}
        for regime in sorted(regimes):
            try:
                df = capacity_consumption(line, net.topology, trains, regime, pairs, window_s=window_s, step_s=step_length_s, cache=cache, model=model)
            except VcsumoError:
                break  # infeasible under the set (a brake that does not hold a train on a descent): its runs fail with the error
            df.insert(0, "timetable", spec.timetable)
            df.insert(1, "timetable_sha256", sha)
            df.insert(3, "assumptions", set_name)
            df.insert(4, "assumptions_sha256", set_sha)
            df.insert(5, "step_length_s", step_length_s)
            new.append(df[UIC_COLUMNS])
    if new:
        have = pd.concat([have] + new, ignore_index=True) if len(have) else pd.concat(new, ignore_index=True)
        atomic_csv(have, path)
    return have


def run_capacity(uic: pd.DataFrame, spec: RunSpec, window_s: float) -> tuple[float, float]:
    """(largest, largest cyclic) consumption over the line sections for a run's timetable and regime, % (nan if none)."""
    m = (uic["timetable_sha256"] == spec.timetable_sha256) & (uic["regime"] == spec.regime) & (uic["window_s"] == window_s) & (uic["step_length_s"] == spec.step_length_s) \
        & (uic["assumptions_sha256"] == spec.assumptions_sha256)
    sel = uic[m]
    if sel.empty:
        return math.nan, math.nan
    return float(sel["consumption_pct"].max()), float(sel["cyclic_consumption_pct"].max())
