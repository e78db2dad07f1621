"""Offline convoy experiments from files: ``vcsumo experiment FILE.yaml``.

An experiment file (:mod:`vcsumo.studies.experiment_model`) is built into the offline loop's inputs
(:mod:`vcsumo.studies.experiment_build`) and run by :func:`vcsumo.sim.offline.run_convoy` — the one
loop of the safety campaign and the paper reproductions — once per variant and seed.  Each run is
recorded and measured (:mod:`vcsumo.studies.experiment_measure`) and drawn
(:mod:`vcsumo.studies.experiment_plot`).  :func:`write_results` writes a results folder:

* ``trajectories.csv`` — per run, variant, seed, time and train: position, speed, force, gaps front
  to rear and front to front, mode, barrier, τ̄, references, packets
  (:data:`~vcsumo.studies.experiment_measure.TRAJECTORY_COLUMNS`);
* ``measurements.csv`` — tidy: ``run, variant, seed, train, window, quantity, value, unit``;
* ``<run>.png`` — speed, gap, force and active mode over time (and the barrier with a CBF);
* ``meta.json`` (by :class:`vcsumo.results.ResultsFolder`).

    >>> from vcsumo.studies.experiment import run_file
    >>> results = run_file("terlizzi2024_os1_authors")                      # doctest: +SKIP
    >>> results[0].value("gap_front_to_front_mean_m", "follower", "at_50")  # doctest: +SKIP
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vcsumo.control.channel import Channel
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel, RelativeBraking
from vcsumo.sim.health import GAP_TOLERANCE_M
from vcsumo.route_profile import RouteProfile
from vcsumo.sim.offline import run_convoy
from vcsumo.studies.experiment_build import Setup, build_setup
from vcsumo.studies.experiment_leaders import LeaderEvents
from vcsumo.studies.experiment_measure import TRAJECTORY_COLUMNS, Recorder, Timed, measure
from vcsumo.studies.experiment_model import Experiment, load_experiment

MEASUREMENT_COLUMNS = ["run", "variant", "seed", "train", "window", "quantity", "value", "unit"]


@dataclass
class RunResult:
    """One run of an experiment (a variant and a seed)."""

    run: str
    variant: str
    seed: int
    experiment: Experiment
    trajectories: pd.DataFrame
    measurements: pd.DataFrame
    arrays: dict
    setup: Setup = field(repr=False)
    wall_time_s: float = 0.0
    cpu_time_s: float = 0.0
    steps: int = 0

    def value(self, quantity: str, train: str = "", window: str = "") -> float:
        """One measured value (NaN if it was not measured)."""
        m = self.measurements
        hit = m[(m.quantity == quantity) & (m.train == train) & (m.window == window)]
        return float(hit.value.iloc[0]) if len(hit) else math.nan

    @property
    def healthy(self) -> bool:
        """No collision, where a CBF reports it the true barrier never positive, no train above the
        track's permitted speed by more than the run-health tolerance (``OVERSPEED_TOLERANCE_KMH``), and
        no follower with vcsumo's separation guard below the safe separation (:meth:`below_separation`)."""
        m = self.measurements
        coll = m[m.quantity == "collisions"].value.sum()
        tb = m[m.quantity == "true_barrier_max_m"].value
        over = m[m.quantity == "overspeed_max_kmh"].value
        return bool(coll == 0 and not (tb > 0).any() and not (over > OVERSPEED_TOLERANCE_KMH).any() and not self.below_separation())

    def below_separation(self, guarded: bool = True) -> list[str]:
        """Followers below the run-health monitor's safe separation, with their episodes and smallest
        margin; ``guarded``: only those whose stack has the separation guard (one without it, ``guard:
        false``, runs a paper's own architecture: measured, not judged by vcsumo's rule)."""
        m = self.measurements
        guard = {t.id: t.guard for t in self.experiment.trains[1:]}
        out = []
        for r in m[(m.quantity == "separation_violations") & (m.value > 0)].itertuples():
            if guard.get(r.train, True) == guarded:
                out.append(f"{r.train} {int(r.value)} episode{'s' if r.value != 1 else ''}, margin {self.value('min_margin_m', r.train):.1f} m")
        return out

    def missed_emergency_brake(self) -> str | None:
        """Where the file's leader emergency brake was to come, if it never came within the run (the
        leader stopped, or the run ended, before it), in words; None when it came or the file has none."""
        drv = self.setup.leader_driver
        if not isinstance(drv, LeaderEvents) or drv.braking_since_s is not None:
            return None
        where = ([f"at {drv.at_m:.0f} m"] if math.isfinite(drv.at_m) else []) + ([f"at {drv.at_s:.0f} s"] if math.isfinite(drv.at_s) else [])
        end = self.arrays["pos"][-1, 0] if len(self.arrays["t"]) else math.nan
        return f"the leader's emergency brake ({' or '.join(where)}) did not come within the run (the leader ended at {end:.0f} m, {self.arrays['t'][-1]:.0f} s)"

    def overspeeding(self) -> list[str]:
        """The trains above the permitted speed by more than the tolerance, with their largest excess."""
        m = self.measurements
        over = m[(m.quantity == "overspeed_max_kmh") & (m.value > OVERSPEED_TOLERANCE_KMH)]
        return [f"{r.train} +{r.value:.1f} km/h" for r in over.itertuples()]


OVERSPEED_TOLERANCE_KMH = 2.0
"""A train counts as above its permitted speed beyond this, km/h (the run-health monitor's ``speed_tolerance_kmh``)."""


def overspeed_rows(profile: RouteProfile, pos: np.ndarray, speed: np.ndarray, ids: list[str], lengths_m: list[float],
                   max_speeds_mps: list[float] | None = None) -> list[tuple[str, str, str, float, str]]:
    """Per train, the largest excess over its permitted speed — the track's (the lowest limit under the
    whole train, as SUMO and the run-health monitor read it) and its own maximum speed (``max_speeds_mps``,
    SUMO's cap on every train; the offline plant has none) —, km/h, and the steps above it + the tolerance."""
    rows = []
    for i, tid in enumerate(ids):
        own = max_speeds_mps[i] if max_speeds_mps is not None else np.inf
        limit = np.array([min(profile.speed_limit_train(float(x), lengths_m[i]), own) for x in pos[:, i]])
        excess = (speed[:, i] - limit) * 3.6
        rows.append((tid, "", "overspeed_max_kmh", float(max(excess.max(), 0.0)), "km/h"))
        rows.append((tid, "", "overspeed_steps", float(np.sum(excess > OVERSPEED_TOLERANCE_KMH)), "-"))
    return rows


def separation_rows(profile: RouteProfile, arr: dict, stocks: list, model: SeparationModel, step_s: float, ids: list[str]) -> list[tuple[str, str, str, float, str]]:
    """Per follower, the run-health monitor's separation rule on the true states at every step (relative
    braking behind the train ahead, :meth:`~vcsumo.signalling.separation.RelativeBraking.required_gap`
    with the set's dead time): the smallest margin (gap − safe separation), the episodes below it (1 cm
    tolerance, as the monitor) and the time below it."""
    rows = []
    for i in range(1, len(ids)):
        rule = RelativeBraking(model, stocks[i], stocks[i - 1], profile)
        pos, v = arr["pos"], arr["speed"]
        req = np.array([rule.required_gap(pos[k, i], v[k, i], pos[k, i - 1], v[k, i - 1], model.dead_time_s) for k in range(len(arr["t"]))])
        margin = arr["gap_fr"][:, i - 1] - req
        below = margin < -GAP_TOLERANCE_M
        episodes = int(np.sum(below[1:] & ~below[:-1]) + (below[0] if len(below) else 0))
        rows += [(ids[i], "", "min_margin_m", float(margin.min()) if len(margin) else math.nan, "m"),
                 (ids[i], "", "separation_violations", float(episodes), "-"), (ids[i], "", "below_separation_time_s", float(below.sum() * step_s), "s")]
    return rows


def _at_rest_stop(step_s: float, settle_s: float):
    """``stop_when``: every train at rest for ``settle_s`` after having moved (checked on the states the last step produced)."""
    still: dict[str, Any] = {"since": None, "moved": False}

    def settled(t: float, xs: list) -> bool:
        if t == 0.0:
            return False
        t_prev = t - step_s
        moving = any(x.v_mps > 0.01 for x in xs)
        still["moved"] = still["moved"] or moving
        if still["moved"] and not moving:
            still["since"] = t_prev if still["since"] is None else still["since"]
            return t_prev - still["since"] >= settle_s
        still["since"] = None
        return False

    return settled


def run_experiment(exp: Experiment, seed: int, base_dir: Path | None = None, path=None, profile: RouteProfile | None = None, variant: str | None = None) -> RunResult:
    """Run one experiment for one seed on :func:`~vcsumo.sim.offline.run_convoy` and measure it."""
    variant = variant or exp.label
    setup = build_setup(exp, seed, base_dir, path, profile)
    timers = [Timed(f.stack) for f in setup.followers]
    for k, tm in enumerate(timers, start=1):
        setup.trains[k].driver = tm
    ids = [t.id for t in setup.trains]
    true_lengths = [t.params.length_m for t in setup.trains]
    rec = Recorder(ids, true_lengths, exp.record_every)
    channel = Channel(setup.channel)
    stop = _at_rest_stop(exp.step_s, exp.stop_when_at_rest_s) if exp.stop_when_at_rest_s is not None else None
    n = int(round(exp.duration_s / exp.step_s))
    w0, c0 = time.perf_counter(), time.process_time()
    run = run_convoy(setup.trains, setup.profile, exp.step_s, n * exp.step_s, channel=channel, known_at_start=exp.known_at_start, apply_lag=exp.plant.lag,
                     apply_jerk=exp.plant.jerk, record_every=0, emergency_brake=exp.plant.emergency_brake, stop_when=stop, on_step=rec)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    arr = rec.arrays()
    brake = setup.leader_driver.braking_since_s if isinstance(setup.leader_driver, LeaderEvents) else None
    rows = measure(exp, arr, ids, true_lengths, setup.followers, timers, brake, rec.packets, channel if exp.channel is not None else None)
    rows += overspeed_rows(setup.profile, arr["pos"], arr["speed"], ids, true_lengths, [s.max_speed_kmh / 3.6 for s in setup.stocks])
    rows += separation_rows(setup.profile, arr, setup.stocks, SeparationModel(load_assumptions()), exp.step_s, ids)
    rows += [("", "", "steps", float(len(arr["t"])), "-"), ("", "", "end_time_s", run.end_time_s, "s"), ("", "", "wall_time_s", wall, "s"),
             ("", "", "cpu_time_s", cpu, "s")]
    name = f"{variant}-seed{seed}"
    meas = pd.DataFrame(rows, columns=["train", "window", "quantity", "value", "unit"])
    meas.insert(0, "seed", seed)
    meas.insert(0, "variant", variant)
    meas.insert(0, "run", name)
    traj = pd.DataFrame.from_records(rec.rows, columns=TRAJECTORY_COLUMNS)
    return RunResult(name, variant, seed, exp, traj, meas, arr, setup, wall, cpu, len(arr["t"]))


def plan_runs(spec: str | Path, variants: list[str] | None = None, seeds: list[int] | None = None, check: bool = False) -> tuple[Path, list[tuple[str, Experiment, int]]]:
    """(the file's path, [(run name, experiment, seed)]) of an experiment file's runs: its own and its
    variants' (or those named in ``variants``), for each seed (the file's, or ``seeds``).

    ``check``: build every run's set-up once (track, stocks, stacks, parameter overrides) so that a
    problem is reported before anything runs."""
    from vcsumo.errors import InputError

    path, _, runs = load_experiment(spec)
    variant_index = {n: k - 1 for k, (n, _) in enumerate(runs) if k}
    if variants:
        known = [n for n, _ in runs]
        bad = [v for v in variants if v not in known]
        if bad:
            raise InputError(None, "--variants", f"unknown run {bad[0]!r} (the file has: {', '.join(known)})")
        runs = [(n, e) for n, e in runs if n in variants]
    if check:
        for name, exp in runs:
            try:
                build_setup(exp, (seeds or exp.seeds)[0], path.parent, path)
            except InputError as exc:  # a variant's problem is the variant's, not the file's own run's
                if name not in variant_index:
                    raise
                where = f"variants[{variant_index[name]}] ({name})"
                raise InputError(path, f"{where}: {exc.field}" if exc.field else where, exc.message) from None
    return path, [(n, e, s) for n, e in runs for s in (seeds or e.seeds)]


def run_file(spec: str | Path, variants: list[str] | None = None, seeds: list[int] | None = None, progress=None) -> list[RunResult]:
    """Every run of an experiment file (path or shipped name): its own and its variants', for each seed.

    ``variants``/``seeds`` select (names of runs, seeds); ``progress(done, total)`` is called after each run."""
    path, todo = plan_runs(spec, variants, seeds)
    out = []
    profiles: dict[str, RouteProfile] = {}
    for k, (name, exp, seed) in enumerate(todo):
        key = exp.track.model_dump_json()
        res = run_experiment(exp, seed, path.parent, path, profiles.get(key), name)
        profiles[key] = res.setup.profile
        out.append(res)
        if progress:
            progress(k + 1, len(todo))
    return out


def write_results(results: list[RunResult], folder: Path, plots: bool = True) -> pd.DataFrame:
    """trajectories.csv, measurements.csv and one PNG per run into ``folder``; returns the measurements."""
    from vcsumo.studies.experiment_plot import plot_run

    folder = Path(folder)
    trajs, meas = [], []
    for r in results:
        t = r.trajectories.copy()
        t.insert(0, "seed", r.seed)
        t.insert(0, "variant", r.variant)
        t.insert(0, "run", r.run)
        trajs.append(t)
        meas.append(r.measurements)
        if plots:
            plot_run(r, folder / f"{r.run}.png")
    table = pd.concat(meas, ignore_index=True)[MEASUREMENT_COLUMNS]
    pd.concat(trajs, ignore_index=True).to_csv(folder / "trajectories.csv", index=False)
    table.to_csv(folder / "measurements.csv", index=False)
    return table


def input_files(spec: str | Path, results: list[RunResult]) -> dict[str, Path]:
    """The experiment file and the parameter and stock files its runs read (for meta.json)."""
    path, _, _ = load_experiment(spec)
    files = {"experiment": path}
    for r in results:
        files.update(r.setup.input_files)
    return files


__all__ = ["MEASUREMENT_COLUMNS", "RunResult", "run_experiment", "plan_runs", "run_file", "write_results", "input_files"]
