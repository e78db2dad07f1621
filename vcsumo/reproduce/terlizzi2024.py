"""Reproduction of Terlizzi, Liuzza & Glielmo (2024), §VII (OS1, OS2): runs of the shipped experiment files.

The set-ups are files in ``vcsumo/data/studies/experiments/`` (read them for every number and its
source), run by :mod:`vcsumo.studies.experiment` on the offline loop:

* ``terlizzi2024_os1_3s.yaml`` / ``terlizzi2024_os1_08s.yaml`` — OS1 with the paper's equations
  (eq. 15 with L^L + d, Table II–III), channel delay 3 s / 0.8 s;
* ``terlizzi2024_os2.yaml`` — OS2 with the authors' channel (rate 15 → 3 /s at 500 s, 6 s loss at
  1,200 s), delay estimator on (its run) and off (variant ``estimator_off``);
* ``terlizzi2024_os1_authors.yaml`` — OS1 as the authors' public code runs it (490 t / 540 t,
  0.12 s, N = 17 / 65, 0.4 s + Exp(15/s) every 0.84 s) with their barrier conventions
  (``convention: authors``: d front to front, the halved stopping term, fixed brake forces).

:func:`run_os1`, :func:`run_os2` and :func:`run_authors` return the summary row of a run (the
coupled distances at the paper's speeds in both conventions, activations, barrier extremes,
packets, CPU times) and its trajectory as one row per recorded step (``leader_*``, ``follower_*``,
``gap_m`` front to rear, ``interdistance_m`` front to front, mode, barrier, τ̄, references).
:class:`OS1Spec` / :class:`OS2Spec` change a file's set-up (None: the file's value), e.g. the
shorter timelines of the tests.  ``python -m vcsumo.reproduce.terlizzi2024 --out DIR`` writes
``summary.csv`` and one trajectory CSV per run.
"""

from __future__ import annotations

import argparse
import copy
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from vcsumo.config import read_yaml
from vcsumo.line import load_line
from vcsumo.route_profile import RouteProfile
from vcsumo.studies.experiment import RunResult, run_experiment
from vcsumo.studies.experiment_model import resolve_experiment, runs_of
from vcsumo.topology import build_topology

FILES = {"os1_3s": "terlizzi2024_os1_3s", "os1_0.8s": "terlizzi2024_os1_08s", "os2": "terlizzi2024_os2", "authors": "terlizzi2024_os1_authors"}
PAPER = {"coupled_interdistance_50_m": 1300.0, "os2_interdistance_m": 1260.0}
"""§VII-B: "stabilizes the follower at a distance of approximately 1300m" (OS1, 50 m/s, Fig. 5b);
OS2 starts "maintaining a separation of approximately 1260m" (Fig. 6b) — leader to follower."""
AUTHORS_CODE = {"coupled_interdistance_50_m": 1254.0, "coupled_interdistance_60_m": 1333.0, "coupled_interdistance_40_m": 1261.0, "both_stopped_interdistance_m": 1006.7}
"""The authors' own OS1 output shipped in their repository (Data_simulation/txt/interDistance.txt,
commit 5946346): mean front-to-front distance over 600–800 s, 1,400–1,600 s, 2,100–2,250 s and at rest."""


@dataclass(frozen=True)
class OS1Spec:
    """Changes of an OS1 file (None: the file's value)."""

    duration_s: float | None = None
    dt_s: float | None = None
    leader_start_m: float | None = None
    initial_gap_m: float | None = None
    """Front-to-rear gap at t = 0, m (the files: 6,000 m front to front)."""
    speed_schedule: tuple[tuple[float, float], ...] | None = None
    """(from time s, leader target speed m/s)."""
    brake_time_s: float | None = None
    """The leader's target is 0 from here, s."""
    steady_window_s: float | None = None
    """The coupled distance is the mean gap over [brake_time − window, brake_time) (None: the file's windows at 50/60/40 m/s)."""


@dataclass(frozen=True)
class OS2Spec:
    """Changes of the OS2 file (None: the file's value)."""

    duration_s: float | None = None
    dt_s: float | None = None
    leader_start_m: float | None = None
    speed_mps: float | None = None
    base_delay_s: float | None = None
    base_mean_extra_s: float | None = None
    degradations: tuple[tuple[float, float, float, float, float], ...] | None = None
    """(start s, end s, extra delay s, mean extra exponential delay s, loss probability)."""
    outage: tuple[float, float] | None = None
    fixed_delay_s: float | None = None
    steady_window: tuple[float, float] | None = None
    degraded_window: tuple[float, float] | None = None


def line_profile(direction: str = "up") -> RouteProfile:
    """The Firenze–Bologna main track as a route profile (positions from the Bologna end for "up")."""
    topo = build_topology(load_line("firenze_bologna"))
    return RouteProfile.from_edges(topo, topo.track_for("main", direction).edges)


def _file(key: str) -> tuple[Path, dict]:
    path = resolve_experiment(FILES[key])
    return path, read_yaml(path)


def _run(path: Path, data: dict, label: str, seed: int, profile: RouteProfile | None) -> RunResult:
    runs = dict(runs_of(data, path))
    return run_experiment(runs[label], seed, path.parent, path, profile, label)


def _overrides(data: dict, cbf, cruise) -> None:
    fol = data["trains"][1]
    if cruise is not None:
        fol["overrides"] = {**cruise.model_dump(), **fol.get("overrides", {})}
    if cbf is not None:
        fol["supervisor_overrides"] = {**cbf.model_dump(), **fol.get("supervisor_overrides", {})}


def wide_trajectory(res: RunResult) -> pd.DataFrame:
    """One row per recorded step: the leader's and the follower's state, gaps, mode, barrier, τ̄, references."""
    tr = res.trajectories
    lead, fol = tr[tr.train == tr.train.iloc[0]].reset_index(drop=True), tr[tr.train != tr.train.iloc[0]].reset_index(drop=True)
    out = pd.DataFrame({"time_s": lead.time_s, "leader_position_m": lead.position_m, "leader_speed_mps": lead.speed_mps, "leader_force_n": lead.force_n,
                        "follower_position_m": fol.position_m, "follower_speed_mps": fol.speed_mps, "follower_force_n": fol.force_n,
                        "gap_m": fol.gap_front_to_rear_m, "interdistance_m": fol.gap_front_to_front_m})
    for c in ("mode", "nominal_mode", "emergency", "robust_barrier_m", "true_barrier_m", "info_age_s", "tau_bar_s", "z_tau1_m", "z_tau2_m", "z_tau3_m",
              "packet_received", "packet_delay_s"):
        out[c] = fol[c]
    return out


def summary_row(res: RunResult, scenario: str) -> dict:
    """The summary row of a run: the coupled distances in its first gap window (and in every window,
    front to rear ``gap_<window>_m`` and front to front ``interdistance_<window>_m``) and its counters."""
    windows = [w.name for w in res.experiment.measurements.gap_windows]
    fid = res.experiment.trains[1].id
    v = res.value
    w0 = windows[0]
    cbf = res.setup.followers[0].stack.supervisor
    cruise = res.setup.followers[0].stack.nominal
    arr = res.arrays
    modes = np.array(arr["modes"][0])
    k2 = np.flatnonzero((modes == "cruise-2") & (arr["t"] > 0))
    speeds = arr["speed"][-1]
    stopped = bool(speeds[0] < 0.1 and speeds[1] < 0.1)
    row = {
        "scenario": scenario, "delay_estimator": bool(cruise.cfg.delay_estimator), "convention": cbf.cfg.convention,
        "coupled_distance_m": v("gap_front_to_rear_mean_m", fid, w0), "coupled_interdistance_m": v("gap_front_to_front_mean_m", fid, w0),
        "reference_gap_m": v("reference_gap_mean_m", fid, w0), "coupled_speed_mps": v("leader_speed_mean_mps", fid, w0), "tau_bar_s": v("tau_bar_mean_s", fid, w0),
        "first_k2_time_s": float(arr["t"][k2[0]]) if len(k2) else math.nan,
        "emergency_activations": int(v("emergency_activations", fid)), "emergency_episodes": int(v("emergency_episodes", fid)),
        "tmax_activations": int(v("tmax_activations", fid)), "emergency_steps": int(round(v("emergency_time_s", fid) / res.experiment.step_s)),
        "emergency_time_s": round(v("emergency_time_s", fid), 3), "min_gap_m": v("min_gap_front_to_rear_m", fid),
        "min_interdistance_m": v("min_gap_front_to_front_m", fid), "true_barrier_max": v("true_barrier_max_m", fid),
        "robust_barrier_max": v("robust_barrier_max_m", fid), "packets_sent": int(v("packets_sent")), "packets_delivered": int(v("packets_delivered")),
        "packets_lost": int(v("packets_lost")), "qp_solves": int(v("qp_solves", fid)), "qp_failures": int(v("qp_failures", fid)),
        "follower_step_mean_ms": v("step_time_mean_ms", fid), "follower_step_p99_ms": v("step_time_p99_ms", fid), "seed": res.seed,
        "both_stopped": stopped, "both_stopped_gap_m": float(arr["gap_fr"][-1, 0]) if stopped else math.nan,
        "both_stopped_interdistance_m": float(arr["gap_ff"][-1, 0]) if stopped else math.nan, "safety_distance_m": cbf.cfg.safety_distance_m,
        "wall_time_s": res.wall_time_s, "cpu_time_s": res.cpu_time_s,
    }
    for w in windows:
        row[f"gap_{w}_m"] = v("gap_front_to_rear_mean_m", fid, w)
        row[f"interdistance_{w}_m"] = v("gap_front_to_front_mean_m", fid, w)
    for m in res.measurements[(res.measurements.train == fid) & res.measurements.quantity.str.startswith("share_")].itertuples():
        row[m.quantity] = round(m.value, 4)
    return row


def run_os1(delay_s: float, seed: int = 1, spec: OS1Spec | None = None, cbf=None, cruise=None, profile: RouteProfile | None = None, full: bool = False):
    """OS1 for a constant channel delay (3 s and 0.8 s are the shipped files; another delay edits the 0.8 s one).

    Returns (summary row, trajectory) or, with ``full``, the :class:`~vcsumo.studies.experiment.RunResult`."""
    path, data = _file("os1_3s" if abs(delay_s - 3.0) < 1e-9 else "os1_0.8s")
    data = copy.deepcopy(data)
    fol, lead = data["trains"][1], data["trains"][0]
    data["channel"]["delay_s"] = float(delay_s)
    fol.setdefault("overrides", {})["fixed_delay_s"] = float(delay_s)
    _overrides(data, cbf, cruise)
    spec = spec or OS1Spec()
    if spec.duration_s is not None:
        data["duration_s"] = spec.duration_s
    if spec.dt_s is not None:
        data["step_s"] = spec.dt_s
    if spec.leader_start_m is not None:
        offset = lead["position_m"] - fol["position_m"]
        lead["position_m"] = spec.leader_start_m
        fol["position_m"] = spec.leader_start_m - offset
    if spec.initial_gap_m is not None:
        fol.pop("position_m", None)
        fol["gap_m"] = spec.initial_gap_m
    sched = [list(p) for p in data["leader"]["schedule"] if p[1] > 0] if spec.speed_schedule is None else [list(p) for p in spec.speed_schedule]
    stop = spec.brake_time_s if spec.brake_time_s is not None else next((t for t, v in data["leader"]["schedule"] if v == 0), None)
    data["leader"]["schedule"] = sched + ([[stop, 0.0]] if stop is not None else [])
    if spec.steady_window_s is not None:
        data["measurements"]["gap_windows"] = [{"name": "coupled", "from_s": stop - spec.steady_window_s, "to_s": stop}]
    res = _run(path, data, data["label"], seed, profile)
    if full:
        return res
    row = {"run": f"os1_delay_{delay_s:g}s", **summary_row(res, "OS1"), "delay_s": float(delay_s)}
    return row, wide_trajectory(res)


def run_os2(delay_estimator: bool, seed: int = 2, spec: OS2Spec | None = None, cbf=None, cruise=None, profile: RouteProfile | None = None, full: bool = False):
    """OS2 with or without the delay estimator; returns (summary row, trajectory) (or the RunResult with ``full``)."""
    path, data = _file("os2")
    data = copy.deepcopy(data)
    _overrides(data, cbf, cruise)
    spec = spec or OS2Spec()
    fol, ch = data["trains"][1], data["channel"]
    if spec.duration_s is not None:
        data["duration_s"] = spec.duration_s
    if spec.dt_s is not None:
        data["step_s"] = spec.dt_s
    if spec.leader_start_m is not None:
        data["trains"][0]["position_m"] = spec.leader_start_m
    if spec.speed_mps is not None:
        data["trains"][0]["speed_mps"] = fol["speed_mps"] = spec.speed_mps
        data["leader"]["schedule"] = [[0.0, spec.speed_mps]]
    if spec.base_delay_s is not None:
        ch["delay_s"] = spec.base_delay_s
    if spec.base_mean_extra_s is not None:
        ch["exp_rate_per_s"] = 1.0 / spec.base_mean_extra_s
    if spec.degradations is not None:
        ch["degradations"] = [{"start_s": a, "end_s": b, "extra_delay_s": d, "extra_mean_s": m, "loss_probability": p} for a, b, d, m, p in spec.degradations]
    if spec.outage is not None:
        ch["outages"] = [{"start_s": spec.outage[0], "end_s": spec.outage[1]}]
    if spec.fixed_delay_s is not None:
        fol.setdefault("overrides", {})["fixed_delay_s"] = spec.fixed_delay_s
    windows = data["measurements"]["gap_windows"]
    for name, w in (("steady", spec.steady_window), ("degraded", spec.degraded_window)):
        if w is not None:
            windows[:] = [x for x in windows if x["name"] != name] + [{"name": name, "from_s": w[0], "to_s": w[1]}]
    label = "estimator_on" if delay_estimator else "estimator_off"
    res = _run(path, data, label, seed, profile)
    if full:
        return res
    return {"run": f"os2_{label}", **os2_row(res), "delay_s": math.nan}, wide_trajectory(res)


def os2_row(res: RunResult) -> dict:
    """:func:`summary_row` of an OS2 run with the degraded window, τ̄ there and the activations before and after the outage."""
    row = summary_row(res, "OS2")
    fid = res.experiment.trains[1].id
    row["degraded_distance_m"] = res.value("gap_front_to_rear_mean_m", fid, "degraded")
    row["tau_bar_degraded_s"] = res.value("tau_bar_mean_s", fid, "degraded")
    row["initial_gap_m"] = float(res.arrays["gap_fr"][0, 0])
    exp_ch = res.experiment.channel
    t_deg = min((w.start_s for w in exp_ch.degradations), default=math.inf)
    out_w = exp_ch.outages[0] if exp_ch.outages else None
    em = res.arrays["emergency"][:, 1]
    on = res.arrays["t"][np.flatnonzero(em & ~np.concatenate(([False], em[:-1])))]
    row["activations_before_outage"] = int(((on >= t_deg) & (on < (out_w.start_s if out_w else math.inf))).sum())
    row["activations_after_outage"] = int((on >= out_w.end_s).sum()) if out_w else 0
    return row


def run_authors(seed: int = 1, full: bool = False):
    """OS1 of the authors' code set-up and conventions (``terlizzi2024_os1_authors.yaml``)."""
    path, data = _file("authors")
    res = _run(path, data, data["label"], seed, None)
    if full:
        return res
    return {"run": "os1_authors", **summary_row(res, "OS1"), "delay_s": math.nan}, wide_trajectory(res)


def run_all(out: Path | None = None, seed_os1: int = 1, seed_os2: int = 2, authors: bool = True) -> pd.DataFrame:
    """OS1 (3 s, 0.8 s), OS2 (estimator on, off) and the authors' OS1; writes CSVs to ``out`` if given."""
    rows, trajs = [], {}
    for d in (3.0, 0.8):
        r, df = run_os1(d, seed=seed_os1)
        rows.append(r)
        trajs[r["run"]] = df
    for est in (True, False):
        r, df = run_os2(est, seed=seed_os2)
        rows.append(r)
        trajs[r["run"]] = df
    if authors:
        r, df = run_authors(seed_os1)
        rows.append(r)
        trajs[r["run"]] = df
    summary = pd.DataFrame(rows)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        summary.to_csv(out / "summary.csv", index=False)
        for name, df in trajs.items():
            df.to_csv(out / f"{name}.csv", index=False)
    return summary


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Reproduce Terlizzi et al. (2024) OS1/OS2 offline")
    ap.add_argument("--out", type=Path, default=Path("results") / "terlizzi2024")
    args = ap.parse_args(argv)
    summary = run_all(args.out)
    with pd.option_context("display.max_columns", None, "display.width", 200):
        print(summary.T)


if __name__ == "__main__":
    main()
