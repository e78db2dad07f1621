"""Reproduction of Felez, Kim & Borrelli (2019), §IV-A (Fig. 10, 11, 12): runs of the shipped experiment files.

The set-up is in ``vcsumo/data/studies/experiments/felez2019_{sh,np,mb}.yaml`` (read them for every
number and its source), run by :mod:`vcsumo.studies.experiment` on the offline loop: the leader NMPC
(eq. 11) starts at rest, runs towards v_max = 20 m/s and stops 3,700 m from its start with a
planned full emergency braking (a^l = 1.25 m/s²); the followers run the follower NMPC (eq. 12,
Table II) with the SH, NP or MB predictor; every train is the ``felez2019`` stock with its lag and
jerk limit.

What is compared with the paper
-------------------------------
``stop_distance_m`` is the gap (front to rear) at the **leader's brake onset** — the distance the
convoy keeps while running into the stop, the largest of the run; this is what the paper's
28.5 / 208.3 / 352.4 m are.  ``gap_at_rest_m`` is the gap once both stand: 4.6–5.5 m for every
predictor (the follower's cost 12a pulls it towards d_des = 10 m), so the paper's numbers cannot be
rest gaps.  ``stop_delay_s``: the follower comes to rest this long after the leader.  In the convoy
table every follower i has ``gap_at_brake_onset{i}_m``, ``gap_at_rest{i}_m`` and ``stop_delay{i}_s``.

a^f (eq. 12m) — not given for §IV-A
----------------------------------
The files run **one a^f for every predictor**, 0.5 m/s² (the paper's lower bound, the parameter
file's); their variant ``fitted`` uses 0.75 for SH and 0.5 for NP and MB, the values that fit the
paper's three distances (no single value fits: with 0.5, SH cannot get below ≈ 110 m — 12m at
20 m/s needs d ≥ 4 + v_N² − 160 m and the train sheds at most ≈ 3.7 m/s in the 4 s horizon; 28.5 m
needs a^f ≳ 0.71).  ``variant=None`` is the files' run, ``variant="fitted"`` the labelled fit.

Other differences from the paper: the prediction model uses the force after the lag in the step,
as the plant does; v ≥ 0 is a smooth max; the terminal set is the DP boundary for the time-discrete
model with 98 % of the brake, shifted by the force ramp (:mod:`vcsumo.control.mpc`); the NMPC is
solved by real-time SQP iterations.  The paper's computation time (Table I: 709 s for two trains) is
not comparable: one run takes 3–5 s here.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from vcsumo.config import read_yaml
from vcsumo.control.mpc import MPCSettings, load_mpc_settings
from vcsumo.control.params import resolve_params
from vcsumo.studies.experiment import RunResult as ExperimentRun
from vcsumo.studies.experiment import run_experiment
from vcsumo.studies.experiment_model import resolve_experiment, runs_of, set_path

PAPER = {
    "SH": {"stop_distance_m": 28.5, "stop_delay_s": 2.0},
    "NP": {"stop_distance_m": 208.3, "stop_delay_s": 17.0},
    "MB": {"stop_distance_m": 352.4, "stop_delay_s": 23.0},
}
"""Values reported in §IV-A.3 (Fig. 12) of the paper."""
FILES = {"SH": "felez2019_sh", "NP": "felez2019_np", "MB": "felez2019_mb"}


def default_settings_path() -> Path:
    return resolve_params(None, "mpc_felez2019")


@dataclass(frozen=True)
class Scenario:
    """Changes of the §IV-A files (None: the file's value)."""

    settings: MPCSettings
    """The Table II parameter set (``controllers/mpc_felez2019.yaml`` unless another file is named)."""
    settings_path: Path | None = None
    leader_braking: str | None = None
    """``mpc-emergency`` (the files': planned-emergency), ``mpc`` (service brake) or ``emergency``
    (unannounced: the leader brakes at a^l from the point it must, without having announced it)."""
    initial_gap_m: float | None = None
    plant_jerk: bool | None = None
    settle_s: float | None = None
    max_time_s: float | None = None
    variant: str | None = None
    """None: the files' run (one a^f); ``fitted``: a^f fitted per predictor."""


def load_scenario(settings_path: str | Path | None = None, **changes) -> Scenario:
    """The scenario with the Table II parameter set (``controllers/mpc_felez2019.yaml`` or ``settings_path``)."""
    path = resolve_params(settings_path, "mpc_felez2019", "settings_path")
    return Scenario(settings=load_mpc_settings(path), settings_path=Path(path) if settings_path is not None else None, **changes)


@dataclass
class RunResult:
    """One closed-loop run: metrics and the time series."""

    metrics: dict
    trajectory: pd.DataFrame
    solve_times_s: dict = field(default_factory=dict)
    run: ExperimentRun | None = field(default=None, repr=False)


_BRAKING = {"mpc-emergency": "planned-emergency", "mpc": "service", "emergency": "unannounced-emergency"}


def _data(strategy: str, n_trains: int, horizon: int | None, sc: Scenario) -> tuple[Path, dict, str]:
    path = resolve_experiment(FILES[strategy.upper()])
    data = copy.deepcopy(read_yaml(path))
    fol = data["trains"][1]
    if horizon is not None:
        fol["horizon_steps"] = int(horizon)
        data["leader"]["felez"]["horizon_steps"] = int(horizon)
    if sc.settings_path is not None:
        fol["params"] = data["leader"]["felez"]["params"] = str(sc.settings_path.resolve())
    if sc.initial_gap_m is not None:
        fol["gap_m"] = sc.initial_gap_m
    if sc.plant_jerk is not None:
        data["plant"]["jerk"] = sc.plant_jerk
    if sc.settle_s is not None:
        data["stop_when_at_rest_s"] = sc.settle_s
    if sc.max_time_s is not None:
        data["duration_s"] = sc.max_time_s
    if sc.leader_braking is not None:
        data["leader"]["felez"]["braking"] = _BRAKING[sc.leader_braking]
        if sc.leader_braking == "emergency":  # its movement authority ends beyond the emergency stop
            data["track"]["straight"]["length_m"] = data["leader"]["felez"]["stop_at_m"] + 1000.0
    label = data.get("label", "default")
    if sc.variant is not None and sc.variant != label:  # the variant's changes first, so that every follower gets them
        variant = next((v for v in data.get("variants", []) if v.get("name") == sc.variant), None)
        if variant is None:
            raise ValueError(f"{path.name} has no variant '{sc.variant}'")
        for key, value in variant["set"].items():
            set_path(data, key, value)
        label = data["label"] = sc.variant
    data.pop("variants", None)
    fol = data["trains"][1]
    data["trains"] = [data["trains"][0]] + [{**copy.deepcopy(fol), "id": f"T{i}"} for i in range(1, n_trains)]
    return path, data, label


def _wide(res: ExperimentRun, origin_m: float) -> pd.DataFrame:
    """One row per step: time_s, s{i}_m (from the leader's start), v{i}_mps, F{i}_n (applied force),
    u{i}_n (command), infeasible{i}, gap{i}_m (followers, front to rear)."""
    tr = res.trajectories
    ids = [t.id for t in res.experiment.trains]
    out = pd.DataFrame({"time_s": tr.loc[tr.train == ids[0], "time_s"].to_numpy()})
    for i, tid in enumerate(ids):
        f = tr[tr.train == tid]
        out[f"s{i}_m"] = f.position_m.to_numpy() - origin_m
        out[f"v{i}_mps"] = f.speed_mps.to_numpy()
        out[f"F{i}_n"] = f.force_n.to_numpy()
        out[f"u{i}_n"] = f.force_cmd_n.to_numpy()
        out[f"infeasible{i}"] = f.infeasible.to_numpy()
        if i > 0:
            out[f"gap{i}_m"] = f.gap_front_to_rear_m.to_numpy()
    return out


def simulate(strategy: str = "SH", n_trains: int = 2, horizon: int | None = None, scenario: Scenario | None = None) -> RunResult:
    """Run the §IV-A file of ``strategy`` (with ``n_trains − 1`` identical followers and the scenario's changes)."""
    sc = scenario or load_scenario()
    path, data, label = _data(strategy, n_trains, horizon, sc)
    exp = dict(runs_of(data, path))[label]
    res = run_experiment(exp, exp.seeds[0], path.parent, path, None, label)
    origin = exp.trains[0].position_m
    ids = [t.id for t in exp.trains]
    v = res.value
    m = {"strategy": strategy.upper(), "variant": label, "n_trains": n_trains, "leader_stop_time_s": v("leader_stop_time_s", ids[0], "stop"),
         "leader_stop_position_m": float(res.arrays["pos"][-1, 0] - origin), "leader_brake_time_s": v("leader_brake_onset_s", ids[0], "stop")}
    if n_trains > 1:
        f = ids[1]
        m.update({
            "stop_distance_m": v("gap_at_brake_onset_m", f, "stop"), "max_gap_m": v("max_gap_before_brake_onset_m", f, "stop"),
            "gap_at_rest_m": v("gap_at_rest_m", f, "stop"), "stop_delay_s": v("stop_delay_s", f, "stop"), "gap_at_leader_stop_m": v("gap_at_leader_stop_m", f, "stop"),
            "follower_stop_time_s": v("stop_time_s", f, "stop"), "cruise_gap_m": v("cruise_gap_median_m", f, "stop"),
            "min_gap_m": min(v("min_gap_front_to_rear_m", t) for t in ids[1:]), "collisions": int(sum(v("collisions", t) for t in ids[1:])),
        })
        for i in range(1, n_trains):
            m[f"gap_at_brake_onset{i}_m"] = v("gap_at_brake_onset_m", ids[i], "stop")
            m[f"gap_at_rest{i}_m"] = v("gap_at_rest_m", ids[i], "stop")
            m[f"stop_delay{i}_s"] = v("stop_delay_s", ids[i], "stop")
    fol_cfg = res.setup.followers[0].stack.nominal.settings if n_trains > 1 else None
    m["horizon"] = fol_cfg.horizon_steps if fol_cfg is not None else horizon
    m["a_follower_mps2"] = fol_cfg.a_follower_mps2 if fol_cfg is not None else math.nan
    ctrls = [res.setup.leader_driver] + [fs.stack.nominal for fs in res.setup.followers]
    times = {ids[i]: np.array(c.stats.solve_times_s) for i, c in enumerate(ctrls)}
    m["infeasible_steps"] = int(sum(c.stats.infeasible for c in ctrls))
    fol = np.concatenate([times[i] for i in ids[1:]]) if n_trains > 1 else times[ids[0]]
    m["solve_time_median_ms"] = float(np.median(fol) * 1e3)
    m["solve_time_mean_ms"] = float(np.mean(fol) * 1e3)
    m["solve_time_p99_ms"] = float(np.percentile(fol, 99) * 1e3)
    return RunResult(metrics=m, trajectory=_wide(res, origin), solve_times_s=times, run=res)


def run_felez2019(strategies=("SH", "NP", "MB"), horizon: int = 40, n_trains: int = 2, scenario: Scenario | None = None, variant: str | None = None) -> pd.DataFrame:
    """One row per predictor: stop distance and delay beside the paper's (Fig. 12).

    ``variant``: None (the files' one a^f) or ``fitted``.  The time series are in
    ``df.attrs["trajectories"][strategy]``."""
    sc = scenario or load_scenario()
    if variant is not None:
        sc = Scenario(**{**sc.__dict__, "variant": variant})
    rows, trajs = [], {}
    for strat in strategies:
        t0 = time.perf_counter()
        res = simulate(strat, n_trains, horizon, sc)
        m = dict(res.metrics)
        m["wall_time_s"] = time.perf_counter() - t0
        paper = PAPER.get(strat.upper(), {})
        m["paper_stop_distance_m"] = paper.get("stop_distance_m", math.nan)
        m["paper_stop_delay_s"] = paper.get("stop_delay_s", math.nan)
        rows.append(m)
        trajs[strat.upper()] = res.trajectory
    cols = ["strategy", "variant", "stop_distance_m", "paper_stop_distance_m", "stop_delay_s", "paper_stop_delay_s", "gap_at_rest_m", "min_gap_m", "collisions",
            "a_follower_mps2"]
    df = pd.DataFrame(rows)
    df = df[cols + [c for c in df.columns if c not in cols]]
    df.attrs["trajectories"] = trajs
    return df


def convoy(n_trains: int = 4, strategy: str = "SH", horizon: int = 40, scenario: Scenario | None = None, variant: str | None = None) -> RunResult:
    """The four-train convoy of Fig. 10: speeds and gaps of consecutive trains."""
    sc = scenario or load_scenario()
    if variant is not None:
        sc = Scenario(**{**sc.__dict__, "variant": variant})
    return simulate(strategy, n_trains, horizon, sc)


def horizon_sweep(horizons=(20, 30, 40, 50, 60), strategy: str = "SH", scenario: Scenario | None = None, variant: str | None = None) -> pd.DataFrame:
    """Fig. 11: gap at the leader's brake onset and NMPC solve time against the horizon N_p (two trains)."""
    sc = scenario or load_scenario()
    if variant is not None:
        sc = Scenario(**{**sc.__dict__, "variant": variant})
    rows = []
    for n in horizons:
        t0 = time.perf_counter()
        m = simulate(strategy, 2, int(n), sc).metrics
        rows.append({"horizon": int(n), "variant": m["variant"], "a_follower_mps2": m["a_follower_mps2"], "stop_distance_m": m["stop_distance_m"],
                     "gap_at_rest_m": m["gap_at_rest_m"], "stop_delay_s": m["stop_delay_s"], "gap_at_leader_stop_m": m["gap_at_leader_stop_m"],
                     "cruise_gap_m": m["cruise_gap_m"], "min_gap_m": m["min_gap_m"], "mean_solve_time_ms": m["solve_time_mean_ms"],
                     "median_solve_time_ms": m["solve_time_median_ms"], "infeasible_steps": m["infeasible_steps"], "wall_time_s": time.perf_counter() - t0})
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> None:
    """``python -m vcsumo.reproduce.felez2019 [SH NP MB] [--fitted] [--sweep] [--convoy]``: print the tables."""
    import argparse

    ap = argparse.ArgumentParser(description="Felez, Kim & Borrelli (2019) §IV-A reproduction")
    ap.add_argument("strategies", nargs="*", default=["SH", "NP", "MB"])
    ap.add_argument("--horizon", type=int, default=40)
    ap.add_argument("--fitted", action="store_true", help="a^f fitted per predictor (0.75 SH, 0.5 NP/MB) instead of one a^f")
    ap.add_argument("--sweep", action="store_true", help="also the horizon sweep of Fig. 11")
    ap.add_argument("--convoy", action="store_true", help="also the four-train convoy of Fig. 10")
    args = ap.parse_args(argv)
    variant = "fitted" if args.fitted else None
    cols = ["strategy", "variant", "a_follower_mps2", "stop_distance_m", "paper_stop_distance_m", "stop_delay_s", "paper_stop_delay_s", "gap_at_rest_m",
            "min_gap_m", "collisions", "infeasible_steps", "solve_time_median_ms", "wall_time_s"]
    df = run_felez2019(tuple(s.upper() for s in args.strategies), args.horizon, variant=variant)
    print(df[cols].to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    if args.sweep:
        print(horizon_sweep(variant=variant).to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    if args.convoy:
        m = convoy(4, variant=variant).metrics
        print({k: (round(v, 2) if isinstance(v, float) else v) for k, v in m.items()})


if __name__ == "__main__":
    main()
