"""Monte Carlo safety campaign: seeded random VC scenarios on the shipped lines, every controller.

``vcsumo study safety`` draws ``scenarios`` seeded scenarios (:func:`~vcsumo.studies.safety_scenarios.draw_scenario`:
line, direction, kind, the rolling stock of every train — heterogeneous convoys included —, the
leader's speed and the time of its emergency brake at the top of its range, the channel, the true
parameters of every train, odometry errors) and runs each of them once per controller (``mpc``,
``cbc``, ``cbf-mpc``, ``cbf-cbc`` by default) in one of two loops (``loop``):

* ``offline`` (:func:`run_scenario`) — the offline closed loop (no SUMO, :mod:`vcsumo.sim.offline`): every
  train is a :class:`~vcsumo.plant.TrainPlant` (Felez eq. 1, force lag, jerk limit) with its *true*
  parameters, on the line's real gradient, tunnel and speed-limit profile;
* ``sumo`` (:mod:`vcsumo.studies.safety_sumo`) — the SUMO loop itself (:func:`vcsumo.sim.loop.simulate` with the VC driver).

Every follower runs the stack the capacity studies run, built by the controller registry
(:mod:`vcsumo.control.registry`): nominal controller → CBF supervisor (``cbf-`` names) →
separation guard (:mod:`vcsumo.control.guard`) → fault stage, under the campaign's assumption set.
A command flagged ``emergency`` (a fault, the CBF's K_E^F, a guard intervention beyond the service
brake) is applied with the train's emergency brake (its true rate), everything else within its
true service envelope.

What is measured is what the SUMO loop's run-health monitor measures (:mod:`vcsumo.sim.health`):
for every follower at every step from the first, at every speed, the margin of its true gap to the
safe separation of the relative-braking rule on the true states
(:meth:`vcsumo.signalling.separation.RelativeBraking.required_gap`, the set's dead time), the
separation violations (the margin falling below −1 cm, counted once per episode), the time below,
collisions (gap ≤ 0, with the impact speed); plus emergency activations (rising edges of an
emergency command), for CBF-supervised controllers the largest *true* barrier (on the true
states; Theorem VI.1 says it stays ≤ 0 from a safe start), and the time lost: how much later than
an unhindered run from its initial state each follower is at the leader's emergency brake.

Per scenario and controller one row of ``safety.csv`` (:data:`SAFETY_COLUMNS`, a ``loop`` column
says which loop ran it); rows are appended as scenarios finish (the folder's store,
:mod:`vcsumo.engine.store`), so an interrupted campaign keeps its finished scenarios and
re-running the same command resumes it; scenarios run through :mod:`vcsumo.engine.campaign`
(processes or Dask, a dying worker fails only its scenario).  :func:`summarize_safety` states the
campaign size and the 95 % upper bound on the violation probability (:func:`violation_upper_bound`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from vcsumo.control.base import Command, Observation
from vcsumo.control.channel import Channel, ChannelConfig, Window
from vcsumo.control.params import resolve_params
from vcsumo.control.registry import check_controller
from vcsumo.control.stack import SampledController  # noqa: F401 - SampledController re-exported
from vcsumo.dynamics import TrainParams
from vcsumo.engine.campaign import Outcome, Runner, Task, run_campaign
from vcsumo.engine.store import ResultStore, Table, read_table
from vcsumo.errors import InputError, VcsumoError
from vcsumo.plant import PlantState
from vcsumo.route_profile import RouteProfile
from vcsumo.running_time import unhindered_run
from vcsumo.signalling.separation import RelativeBraking, SeparationModel
from vcsumo.sim.health import GAP_TOLERANCE_M
from vcsumo.sim.offline import Odometry, OfflineTrain, run_convoy, steady_force, tracking_force
from vcsumo.studies.safety_inputs import check_lines_and_trains
from vcsumo.studies.safety_scenarios import (  # noqa: F401 - the campaign's scenarios are part of this module's interface
    HEALTH_FAULT_COLUMNS, KINDS, SAFETY_CONTROLLERS, Junction, LineRoute, SafetyCampaign, ScenarioSpec, campaign_assumptions, capped_profile, draw_scenario, follower_stacks_for,
    initial_gaps, line_route, spec_columns, stock, true_params,
)

SAFETY_COLUMNS = [
    "key", "loop", "scenario", "controller", "supervised", "line", "direction", "kind", "followers", "leader_stock", "follower_stocks", "km_start",
    "leader_speed_mps", "brake_time_s", "delay_s", "mean_extra_delay_s", "loss_probability", "outage_s", "position_error_m", "corner_trains",
    "initial_gap_m", "min_gap_m", "min_margin_m", "separation_violations", "below_separation_time_s", "collisions", "max_impact_kmh",
    "overspeed_events", "beyond_service_brakings", "authority_overruns", "sumo_emergency_stops", "teleports",
    "emergency_activations", "emergency_time_s", "initial_true_barrier_m", "max_true_barrier_m", "time_lost_s", "simulated_s", "wall_time_s", "error",
]
"""``safety.csv``: min_margin_m is the smallest (true gap − safe separation of the run-health
monitor's rule), m; separation_violations its episodes below −1 cm; the barrier columns are NaN
for unsupervised controllers; :data:`HEALTH_FAULT_COLUMNS` the SUMO loop's run-health counters
(empty in the offline loop, which does not measure them)."""



def barrier_gap_m(sup, profile: RouteProfile, s_m: float, v_mps: float, length_m: float) -> float:
    """Smallest front-to-rear gap at which two trains at speed v have a barrier b ≤ −1 m, m (the
    follower holding its speed)."""
    return sup.required_gap_m(profile, s_m, v_mps, s_m - length_m - 1000.0, v_mps) + 1.0


@dataclass
class SeparationWatch:
    """The run-health monitor's separation counters of one follower (:class:`vcsumo.sim.health.TrainHealth`'s
    rule): margin to the safe separation at every step, episodes below it, time below, collisions."""

    min_margin_m: float = math.inf
    violations: int = 0
    below_s: float = 0.0
    collisions: int = 0
    max_impact_kmh: float = 0.0
    below: bool = False
    touching: bool = False

    def update(self, dt: float, gap_m: float, required_m: float, v_f: float, v_l: float) -> None:
        margin = gap_m - required_m
        self.min_margin_m = min(self.min_margin_m, margin)
        below = margin < -GAP_TOLERANCE_M
        if below:
            self.below_s += dt
            if not self.below:
                self.violations += 1
        self.below = below
        touching = gap_m <= 0.0
        if touching and not self.touching:
            self.collisions += 1
            self.max_impact_kmh = max(self.max_impact_kmh, 3.6 * max(0.0, v_f - v_l))
        self.touching = touching


# -------------------------------------------------------------------------------------------
# One offline run


@dataclass
class _Run:
    t: np.ndarray
    s: np.ndarray
    v: np.ndarray


def _unhindered(p: TrainParams, profile: RouteProfile, s0: float, v0: float, t_max: float) -> _Run:
    df = unhindered_run(p, profile, dt=0.5, s0=s0, v0=v0, stop_at_end=True, t_max=t_max)
    return _Run(df.time_s.to_numpy(), df.s_m.to_numpy(), df.speed_mps.to_numpy())


class CampaignLeader:
    """The scenario's leader: tracks its unhindered run (P law with feed-forward on its nominal
    model) and broadcasts that run as its plan; from ``brake_time_s`` it applies its emergency brake
    and holds it (the plant brakes at its true emergency rate, the top of its range) and broadcasts
    its nominal emergency stop."""

    def __init__(self, run: _Run, nominal: TrainParams, brake_time_s: float, dt: float):
        self.run, self.p, self.brake_time_s, self.dt = run, nominal, brake_time_s, dt

    def make_step(self, obs: Observation) -> Command:
        t = obs.time_s
        if t >= self.brake_time_s:
            return Command(-math.inf, mode="emergency", emergency=True)
        run = self.run
        v_ref = float(np.interp(t, run.t, run.v))
        a_ff = float(np.interp(t + self.dt, run.t, run.v) - v_ref) / self.dt
        return Command(tracking_force(obs, v_ref, a_ff, 0.5), mode="leader")

    def plan(self, t: float, s: float, v: float) -> tuple:
        if t < self.brake_time_s:
            grid = t + np.arange(0.0, 8.0 + 1e-9, 0.5)
            pos = np.interp(grid, self.run.t, self.run.s)
            spd = np.interp(grid, self.run.t, self.run.v)
            return grid, pos - pos[0] + s, spd, np.zeros_like(spd)
        a = max(self.p.emergency_brake_decel_mps2, 1e-3)  # its own nominal emergency stop
        tau = np.arange(0.0, 8.0 + 1e-9, 0.5)
        tt = np.minimum(tau, v / a)
        return t + tau, s + v * tt - 0.5 * a * tt * tt, np.maximum(v - a * tau, 0.0), -self.p.mass_kg * a * np.ones_like(tau)


class _Watch:
    """The campaign's bookkeeping on the true states, at the start of every step (the offline loop's
    ``stop_when``): the run-health monitor's separation rule for every follower, the true barrier,
    time lost; it ends the run at a collision, when a split is complete or 5 s after everything stopped."""

    def __init__(self, spec: ScenarioSpec, lengths: list[float], rules: list[RelativeBraking], dead_time_s: float, sups: list, profile: RouteProfile,
                 free_runs: list[_Run], dt: float):
        self.spec, self.lengths, self.rules, self.dead, self.sups, self.profile, self.free_runs, self.dt = spec, lengths, rules, dead_time_s, sups, profile, free_runs, dt
        self.watch = [SeparationWatch() for _ in rules]
        self.min_gap = math.inf
        self.max_b = self.b_init = -math.inf
        self.lost: list[float] = []
        self.rest_since: float | None = None

    def __call__(self, t: float, xs: list[PlantState]) -> bool:
        spec = self.spec
        for i in range(1, len(xs)):
            xl, xf = xs[i - 1], xs[i]
            gap = xl.s_m - self.lengths[i - 1] - xf.s_m
            self.min_gap = min(self.min_gap, gap)
            required = self.rules[i - 1].required_gap(xf.s_m, xf.v_mps, xl.s_m, xl.v_mps, self.dead)
            self.watch[i - 1].update(self.dt, gap, required, xf.v_mps, xl.v_mps)
            sup = self.sups[i - 1]
            if sup is not None:
                b = sup.true_barrier(self.profile, xl.s_m, xl.v_mps, xf.s_m, xf.v_mps, xf.force_n)
                self.max_b = max(self.max_b, b)
                if t == 0.0:
                    self.b_init = max(self.b_init, b)
        if any(w.collisions for w in self.watch):
            return True
        if spec.kind == "split" and xs[0].s_m - self.lengths[0] > spec.junction_s_m + 50.0:
            return True  # the leader has left the trunk: the first follower is no longer behind it
        if t >= spec.brake_time_s and not self.lost:
            for i in range(1, len(xs)):
                fr = self.free_runs[i - 1]
                self.lost.append(t - float(np.interp(xs[i].s_m, fr.s, fr.t)))
        if t > spec.brake_time_s and all(x.v_mps < 0.01 for x in xs):
            self.rest_since = t if self.rest_since is None else self.rest_since
            if t - self.rest_since >= 5.0:
                return True
        else:
            self.rest_since = None
        return False


def run_scenario(spec: ScenarioSpec, controller: str, cfg: SafetyCampaign) -> dict:
    """Run one scenario with one controller in the offline loop; return its row of ``safety.csv``."""
    t_wall = time.perf_counter()
    route = line_route(spec.line, spec.direction)
    prof = route.profile
    a = campaign_assumptions(cfg.assumptions)
    model = SeparationModel(a)
    dt = cfg.step_s
    stocks = [stock(s) for s in spec.stocks]
    rng = np.random.default_rng(spec.seed)
    n = spec.followers + 1
    # the leader's emergency brake at the top of its range; every other parameter drawn
    params = [true_params(stocks[k], rng, c, emergency_top=(k == 0), assumptions=a) for k, c in enumerate(spec.corners)]
    ids = [f"T{k}" for k in range(n)]
    stacks = follower_stacks_for(controller, route, ids, cfg, stocks)
    rules = [RelativeBraking(model, stocks[k], stocks[k - 1], prof) for k in range(1, n)]
    positions, speeds, gaps0 = initial_gaps(spec, stacks, stocks, rules, model, prof, dt)

    # the leader's target speed: its unhindered run capped at its cruise speed (and the turnout for a split)
    plims = [(spec.junction_s_m, spec.diverging_speed_mps)] if spec.kind == "split" else []
    v_l0 = speeds[0]
    horizon = cfg.max_duration_s + 60.0
    lead_run = _unhindered(stocks[0].params(), capped_profile(prof, max(v_l0, 1.0), plims), positions[0], v_l0, horizon)
    cap_f = capped_profile(prof, max(max(speeds), 1.0))
    free_runs = [_unhindered(stocks[k].params(), cap_f, positions[k], speeds[k], horizon) for k in range(1, n)]

    outages = [Window(start_s=spec.outage[0], end_s=spec.outage[1])] if spec.outage else []
    channel = Channel(ChannelConfig(model="exponential", period_s=cfg.channel_period_s, delay_s=spec.delay_s, mean_extra_s=spec.mean_extra_delay_s,
                                    loss_probability=spec.loss_probability, outages=outages, seed=spec.seed))
    e_s = spec.position_error_m
    odometry = Odometry(rng.uniform(-0.5 * e_s, 0.5 * e_s, size=n), e_s, rng)
    leader = CampaignLeader(lead_run, stocks[0].params(), spec.brake_time_s, dt)
    trains = [OfflineTrain(ids[k], params[k], PlantState(positions[k], speeds[k], steady_force(params[k], speeds[k], prof, positions[k]), 0.0),
                           leader if k == 0 else stacks[k - 1], nominal=stocks[k].params(), plan=leader.plan if k == 0 else None) for k in range(n)]
    sups = [s.supervisor for s in stacks]
    watch = _Watch(spec, [s.length_m for s in stocks], rules, model.dead_time_s, sups, prof, free_runs, dt)
    # the convoy has been communicating before the scenario starts: every follower knows its predecessor at t = 0
    run = run_convoy(trains, prof, dt, math.ceil(cfg.max_duration_s / dt) * dt, channel=channel, send_plans=stacks[0].uses_plans, odometry=odometry,
                     known_at_start=True, record_every=0, stop_when=watch)
    supervised = sups[0] is not None
    return {
        **spec_columns(spec, prof), "loop": "offline", "controller": controller, "supervised": supervised, "initial_gap_m": min(gaps0),
        "min_gap_m": watch.min_gap, "min_margin_m": min(w.min_margin_m for w in watch.watch),
        "separation_violations": sum(w.violations for w in watch.watch), "below_separation_time_s": sum(w.below_s for w in watch.watch),
        "collisions": sum(w.collisions for w in watch.watch), "max_impact_kmh": max(w.max_impact_kmh for w in watch.watch),
        "emergency_activations": sum(run.emergency_activations[i] for i in ids[1:]), "emergency_time_s": sum(run.emergency_time_s[i] for i in ids[1:]),
        "initial_true_barrier_m": watch.b_init if supervised else math.nan, "max_true_barrier_m": watch.max_b if supervised else math.nan,
        "time_lost_s": float(np.mean(watch.lost)) if watch.lost else math.nan,  # NaN: the scenario ended before the brake (a split completed first)
        "simulated_s": run.end_time_s, "wall_time_s": time.perf_counter() - t_wall, "error": "",
    }


# -------------------------------------------------------------------------------------------
# The campaign


def _row_key(cfg_hash: str, loop: str, scenario: str, controller: str) -> str:
    return f"{cfg_hash}:{loop}:{scenario}:{controller}"


def scenario_task(args: tuple) -> list[dict]:
    """Run one scenario for every controller in the campaign's loop (a worker task); failures become rows with ``error``."""
    cfg, index, controllers = args
    rows = []
    try:
        spec = draw_scenario(cfg, index)
    except Exception as exc:  # noqa: BLE001 - reported as the scenario's rows
        return [{"scenario": f"s{index:05d}", "loop": cfg.loop, "controller": c, "error": f"{type(exc).__name__}: {exc}"} for c in controllers]
    if cfg.loop == "sumo":
        from vcsumo.studies.safety_sumo import run_sumo_scenario as run
    else:
        run = run_scenario
    for c in controllers:
        t0 = time.perf_counter()
        try:
            row = run(spec, c, cfg)
        except VcsumoError as exc:
            row = {"scenario": spec.id, "controller": c, "error": str(exc)}
        except Exception as exc:  # noqa: BLE001 - a failing run is a row, never the end of the campaign
            row = {"scenario": spec.id, "controller": c, "error": f"{type(exc).__name__}: {exc}", "wall_time_s": time.perf_counter() - t0}
        row["loop"] = cfg.loop
        rows.append(row)
    return rows


def check_campaign(cfg: SafetyCampaign, source: Path | None = None) -> None:
    """Validate lines, trains, controllers and the assumption set before anything runs (one clear error naming the input)."""
    from vcsumo.line import load_line

    for ln in cfg.lines:
        load_line(ln)
    for i, name in enumerate(cfg.rolling_stock):
        try:
            stock(name)
        except InputError as exc:
            raise InputError(source, "--rolling-stock" if source is None else f"rolling_stock[{i}]", exc.message) from None
    check_lines_and_trains(cfg)  # a kind a line cannot draw, a train a line cannot brake or start on
    aset = campaign_assumptions(cfg.assumptions)
    for i, c in enumerate(cfg.controllers):
        check_controller(c, "--controllers" if source is None else f"controllers[{i}]", supervisor_params=cfg.cbf_config)
    if cfg.cbf_config:
        from vcsumo.control.cbf import load_cbf_config, model_leader_braking

        path = resolve_params(cfg.cbf_config, "cbf", "--cbf" if source is None else "cbf_config")
        cbf = load_cbf_config(path)
        if cbf.distance == "model":  # a leader brake weaker than the set's: refused before anything runs
            try:
                model_leader_braking(SeparationModel(aset), cbf)
            except VcsumoError:
                raise InputError(path, "leader_braking", f"'{cbf.leader_braking}' is weaker than the assumption set '{aset.name}' relative_braking "
                                 f"'{aset.relative_braking}' (leave leader_braking out to follow the set)") from None
    if len(set(cfg.controllers)) != len(cfg.controllers):
        raise InputError(source, "controllers", "a controller is listed twice")


SAFETY_TABLE = Table("safety.csv", tuple(SAFETY_COLUMNS), "key", text=("controller", "error", "loop", "leader_stock", "follower_stocks"))
"""The campaign's result store: one row per scenario and controller, keyed by (scenario hash, loop, scenario, controller)."""


def run_safety_campaign(cfg: SafetyCampaign, out: Path, workers: int | None = 1, progress: Callable[[int, int], None] | None = None,
                        scheduler: str | None = None) -> pd.DataFrame:
    """Run (or resume) the campaign into ``out``; returns this campaign's rows of ``safety.csv``.

    Scenarios run through :mod:`vcsumo.engine.campaign` (``workers`` processes, 1: in this
    process; or a Dask ``scheduler``); each scenario × controller row is recorded once in the
    folder's store (:mod:`vcsumo.engine.store`) as its scenario finishes, so re-running resumes.
    ``progress(done, total)`` counts scenarios, those already in the store included.
    """
    check_campaign(cfg)
    out = Path(out)
    runner = Runner(workers, scheduler, log_path=out / "workers.log")
    h = cfg.scenario_hash()

    def key(k: int, c: str) -> str:
        return _row_key(h, cfg.loop, f"s{k:05d}", c)

    def to_rows(task: Task, outcome: Outcome) -> tuple[list[dict], dict]:
        _, k, missing = task.arg
        rows = outcome.value if outcome.ok else [{"scenario": f"s{k:05d}", "loop": cfg.loop, "controller": c, "error": f"worker failed: {outcome.error}"}
                                                 for c in missing]
        for r in rows:
            r["key"] = _row_key(h, cfg.loop, r["scenario"], r["controller"])
            r.setdefault("error", "")
        return rows, {}

    with runner, ResultStore(out, SAFETY_TABLE, kind="safety") as store:
        tasks = []
        for k in range(cfg.scenarios):
            missing = tuple(c for c in cfg.controllers if key(k, c) not in store)
            if missing:
                tasks.append(Task(f"{h}:{cfg.loop}:s{k:05d}", scenario_task, (cfg, k, missing), f"scenario {k}", keys=tuple(key(k, c) for c in missing)))
        before = cfg.scenarios - len(tasks)
        run_campaign(store, tasks, runner, to_rows, (lambda done, _n, _rows: progress(before + done, cfg.scenarios)) if progress else None)
        df = read_safety(out)
    keys = {key(k, c) for k in range(cfg.scenarios) for c in cfg.controllers}
    return df[df["key"].isin(keys)].reset_index(drop=True)


def read_safety(out: Path) -> pd.DataFrame:
    """``safety.csv`` of a campaign folder (one row per key), empty frame if none."""
    return read_table(Path(out), SAFETY_TABLE)


# -------------------------------------------------------------------------------------------
# Summary


def violation_upper_bound(k: int, n: int, confidence: float = 0.95) -> float:
    """One-sided upper confidence bound on a probability seen k times in n runs: 3/n for k = 0 (the
    rule of three), else the exact binomial (Clopper–Pearson) bound — the p at which P(X ≤ k) = 1 − confidence."""
    if n <= 0:
        return math.nan
    if k <= 0:
        return min(1.0, 3.0 / n)
    if k >= n:
        return 1.0
    alpha = 1.0 - confidence
    log_c = [math.lgamma(n + 1) - math.lgamma(i + 1) - math.lgamma(n - i + 1) for i in range(k + 1)]

    def cdf(p: float) -> float:
        lp, lq = math.log(p), math.log1p(-p)
        return sum(math.exp(c + i * lp + (n - i) * lq) for i, c in enumerate(log_c))

    lo, hi = k / n, 1.0 - 1e-15
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) > alpha else (lo, mid)
    return hi


SUMMARY_COLUMNS = [
    "loop", "controller", "supervised", "scenarios", "failed_runs", "scenarios_with_violation", "violation_rate", "violation_rate_upper95",
    "separation_violations", "collisions", "max_impact_kmh", "min_gap_m", "min_margin_m", "max_true_barrier_m", "started_outside_safe_set",
    "barrier_breaches", "runs_with_health_fault", "emergency_activations_mean", "emergency_time_s_mean", "time_lost_s_mean", "time_lost_s_p95", "wall_time_s_mean",
]


BARRIER_TOLERANCE_M = 1e-6
"""How far the CBF's true barrier may rise above max(b(0), 0) before the run is a barrier breach, m
(and how far above 0 b(0) must be for a run to have started outside the safe set)."""

RUN_FAULTS = {"separation_violation": "a separation violation", "collision": "a collision", "barrier_breach": "a barrier breach",
              "health_fault": "a run-health fault (overspeed, braking beyond service, authority overrun, SUMO emergency stop or teleport)"}
"""The safety faults of a finished run (the columns of :func:`run_faults`) and how a message names them."""


def run_faults(runs: pd.DataFrame) -> pd.DataFrame:
    """Which safety faults each finished run (a row of ``safety.csv`` without error) has: one boolean
    column per :data:`RUN_FAULTS` —

    * ``separation_violation``: an episode below the safe separation of the run-health monitor's rule;
    * ``collision``: the gap reached 0;
    * ``barrier_breach`` (CBF-supervised runs): the largest true barrier rose above max(b(0), 0) +
      :data:`BARRIER_TOLERANCE_M` (Theorem VI.1: from b(0) ≤ 0, b stays ≤ 0; a run started with
      b(0) > 0 must not see b rise above b(0)); never for unsupervised runs (NaN barrier);
    * ``health_fault`` (SUMO loop): any of :data:`HEALTH_FAULT_COLUMNS` non-zero (until 2026-11-28
      the SUMO loop's rows left them out: such a run was reported clean).

    A run is clean when no column is true.  The one rule behind both :func:`summarize_safety`'s
    counts and the exit status of ``vcsumo study safety``."""
    b0 = pd.to_numeric(runs["initial_true_barrier_m"], errors="coerce")
    bmax = pd.to_numeric(runs["max_true_barrier_m"], errors="coerce")
    return pd.DataFrame({
        "separation_violation": runs["separation_violations"] > 0,
        "collision": runs["collisions"] > 0,
        "barrier_breach": bmax > b0.fillna(0.0).clip(lower=0.0) + BARRIER_TOLERANCE_M,
        "health_fault": np.logical_or.reduce([np.zeros(len(runs), bool)] + [pd.to_numeric(runs[c], errors="coerce").fillna(0).to_numpy() > 0 for c in HEALTH_FAULT_COLUMNS if c in runs]),
    }, index=runs.index, columns=list(RUN_FAULTS))


def describe_run_faults(faults: pd.DataFrame) -> str:
    """How many runs have each fault of :func:`run_faults`, for a message: "2 with a separation
    violation, 1 with a barrier breach" (faults no run has are left out; a run with two faults counts in both)."""
    return ", ".join(f"{int(faults[col].sum())} with {name}" for col, name in RUN_FAULTS.items() if faults[col].any())


def summarize_safety(df: pd.DataFrame) -> pd.DataFrame:
    """One row per loop and controller: the campaign size (``scenarios``: runs without error),
    scenarios with a separation violation (the monitor's rule) or a collision, their rate and its 95 %
    upper bound (:func:`violation_upper_bound`), collisions and impact speed, the smallest gap and
    margin, the true barrier (runs that started outside the CBF's safe set b ≤ 0 and breaches: runs
    where b rose above max(b(0), 0)), emergencies, time lost, wall time per run."""
    rows = []
    loops = df["loop"] if "loop" in df else pd.Series("offline", index=df.index)
    for (loop, c), g in df.assign(loop=loops).groupby(["loop", "controller"], sort=False):
        ok = g[g["error"] == ""]
        n = len(ok)
        faults = run_faults(ok)
        bad = int((faults["separation_violation"] | faults["collision"]).sum())

        def agg(col: str, fn: str) -> float:
            x = pd.to_numeric(ok[col], errors="coerce")
            return float(getattr(x, fn)()) if n else math.nan

        rows.append({
            "loop": loop, "controller": c, "supervised": bool(ok["supervised"].astype(bool).any()) if n else str(c).startswith("cbf-"),
            "scenarios": n, "failed_runs": int((g["error"] != "").sum()), "scenarios_with_violation": bad,
            "violation_rate": bad / n if n else math.nan, "violation_rate_upper95": violation_upper_bound(bad, n),
            "separation_violations": int(ok["separation_violations"].sum()), "collisions": int(ok["collisions"].sum()), "max_impact_kmh": agg("max_impact_kmh", "max"),
            "min_gap_m": agg("min_gap_m", "min"), "min_margin_m": agg("min_margin_m", "min"), "max_true_barrier_m": agg("max_true_barrier_m", "max"),
            "started_outside_safe_set": int((pd.to_numeric(ok["initial_true_barrier_m"], errors="coerce") > BARRIER_TOLERANCE_M).sum()),
            "barrier_breaches": int(faults["barrier_breach"].sum()), "runs_with_health_fault": int(faults["health_fault"].sum()),
            "emergency_activations_mean": agg("emergency_activations", "mean"), "emergency_time_s_mean": agg("emergency_time_s", "mean"),
            "time_lost_s_mean": agg("time_lost_s", "mean"), "time_lost_s_p95": float(pd.to_numeric(ok["time_lost_s"], errors="coerce").quantile(0.95)) if n else math.nan,
            "wall_time_s_mean": agg("wall_time_s", "mean"),
        })
    return pd.DataFrame(rows, columns=SUMMARY_COLUMNS)


def bar_met(summary: pd.DataFrame, min_scenarios: int = 1000) -> bool:
    """Issue 10's bar: every controller of the campaign has ≥ ``min_scenarios`` runs, none failed,
    0 separation violations and 0 collisions (and no barrier breach, no run-health fault)."""
    ok = (summary["scenarios"] >= min_scenarios) & (summary["failed_runs"] == 0) & (summary["scenarios_with_violation"] == 0) \
        & (summary["collisions"] == 0) & (summary["barrier_breaches"] == 0) & (summary["runs_with_health_fault"] == 0)
    return bool(len(summary)) and bool(ok.all())


def write_safety_report(out: Path, cfg: SafetyCampaign, df: pd.DataFrame, summary: pd.DataFrame, wall_time_s: float) -> None:
    """``report/``: safety_runs.csv (this campaign's rows), safety_summary.csv, safety_gaps.png and meta.json."""
    from vcsumo.line import load_line
    from vcsumo.plots.safety import plot_safety
    from vcsumo.results import ResultsFolder

    inputs = {f"line_{ln}": load_line(ln).path for ln in cfg.lines}
    params = {**cfg.model_dump(mode="json"), "scenario_hash": cfg.scenario_hash(), "campaign_wall_time_s": round(wall_time_s, 3), "runs": len(df),
              "assumption_set": campaign_assumptions(cfg.assumptions).record()}
    with ResultsFolder(Path(out) / "report", inputs=inputs, seed=cfg.seed, params=params, overwrite=True) as rf:
        df.to_csv(rf.path / "safety_runs.csv", index=False)
        summary.to_csv(rf.path / "safety_summary.csv", index=False)
        plot_safety(rf.path / "safety_runs.csv", rf.path / "safety_gaps.png")
