"""Monte Carlo safety campaign: seeded random VC scenarios on the shipped lines, every controller.

``vcsumo study safety`` draws ``scenarios`` seeded scenarios (:func:`draw_scenario`) and runs each
of them once per controller (``mpc``, ``cbc``, ``cbf-mpc``, ``cbf-cbc`` by default) in the offline
closed loop (no SUMO, :mod:`vcsumo.sim.offline`): every train is a :class:`~vcsumo.plant.TrainPlant` — the train model
shared with the controllers and the supervisor (Felez eq. 1, force lag, jerk limit) — integrated
with its *true* parameters drawn inside the rolling stock's uncertainty box or at one of its
corners (Terlizzi eq. 7), on the line's real gradient, tunnel and speed-limit profile.

What a scenario draws (one seeded generator per scenario, so a scenario is the same for every
controller and does not depend on how many scenarios are run):

* a line, a direction and a kind:

  - ``cruise`` — the convoy runs coupled at the controller's own spacing (× 1.0–1.3);
  - ``forming`` — the followers start 2–5 times that spacing behind and up to 10 m/s faster, so the
    convoy is still forming when the leader brakes;
  - ``merge`` — at one of the line's junctions: the first follower has just come off the branch
    at the diverging speed, admitted by the interlocking at its absolute braking distance plus
    its minimum safe gap (× 1.0–1.3), behind a leader on the trunk;
  - ``split`` — the leader leaves the trunk at a junction (it brakes for the turnout's diverging
    speed) while the followers go straight on; the pair is watched until the leader's rear has
    cleared the junction;

* the leader's cruise speed (30–100 % of the line speed there) and the time of its **emergency
  brake** (its emergency brake at the top of its box — the separation model's range, nominal
  +10 % in the default assumption set: ETR1000 1.32 m/s² — built up through its lag and jerk
  limit, held to a stop; :func:`true_params`): 10–120 s (cruise), 5–120 s (forming), 0–120 s
  (merge), around its arrival at the turnout (split);
* 1..``followers_max`` followers;
* the channel (Terlizzi §VII): constant delay 0–``delay_max_s`` + exponential extra delay of mean
  0–``mean_extra_max_s``, independent loss 0–``loss_max``, and with probability
  ``outage_probability`` an outage of 1–``outage_max_s`` s (longer outages trip T^max, eq. 18);
* every train's true parameters (at a box corner with probability ``corner_probability``; its
  emergency deceleration scaled like its service brake);
* the convoy has been communicating before the scenario starts: every follower knows its
  predecessor's state at t = 0 (so Algorithm 1 starts at once and the T^max rule of eq. 18 runs
  from the start; a follower that had never heard of its predecessor would drive on its nominal
  controller alone, as Algorithm 1 of the paper does before the first packet);
* the position error of every train's odometry, bounded by e_s drawn in 0–``position_error_max_m``
  (Felez eq. 9: a bias and a noise, each within ±e_s/2); the controllers and the supervisor see
  measured positions (their own, in the messages, and the on-board sensed gap), the safety
  bookkeeping uses the true ones.

Per scenario and controller one row of ``safety.csv`` (:data:`SAFETY_COLUMNS`): the minimum true
front-to-rear gap, the controller's minimum safe gap (d_min of its parameter file; for a
CBF-supervised controller the CBF safety distance d, which the barrier protects: b'' ≤ 0 of eq.
15b), gap violations (the gap falling below the minimum safe gap), collisions (gap ≤ 0),
emergency activations (rising edges of an emergency command), for CBF-supervised controllers the
largest *true* barrier b(x) (eq. 15 on the true states; Theorem VI.1 says it stays ≤ 0), and the
time lost: how much later than an unhindered run from its initial state each follower is at the
leader's emergency brake (mean over followers) — what supervision and communication faults cost
in normal running.

Every follower runs the stack the SUMO loop runs, built by the controller registry
(:mod:`vcsumo.control.registry`): nominal controller → CBF supervisor (``cbf-`` names) →
separation guard (:mod:`vcsumo.control.guard`) → fault stage, in the one offline loop
(:func:`vcsumo.sim.offline.run_convoy`).  A command flagged ``emergency`` (a fault, the CBF's
K_E^F, a guard intervention beyond the service brake) is applied with the train's emergency brake
(its true rate), everything else within its true service envelope.

Rows are appended to ``safety.csv`` as scenarios finish (one whole line at a time, each row once:
the folder's store, :mod:`vcsumo.engine.store`), so an interrupted campaign keeps its finished
scenarios and re-running the same command resumes it; scenarios run through
:mod:`vcsumo.engine.campaign` (processes or Dask, a dying worker fails only its scenario).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
from pydantic import Field, field_validator

from vcsumo.config import StrictModel
from vcsumo.control.base import Command, Observation
from vcsumo.control.cbf import barrier_from_stops
from vcsumo.control.channel import Channel, ChannelConfig, Window
from vcsumo.control.proxies import sample_params
from vcsumo.control.params import resolve_params
from vcsumo.control.registry import check_controller
from vcsumo.control.stack import FollowerStack, SampledController  # noqa: F401 - SampledController re-exported
from vcsumo.dynamics import TrainParams
from vcsumo.engine.campaign import Outcome, Runner, Task, run_campaign
from vcsumo.engine.store import ResultStore, Table, read_table
from vcsumo.errors import InputError, VcsumoError
from vcsumo.plant import PlantState
from vcsumo.rolling_stock import RollingStock, load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.running_time import unhindered_run
from vcsumo.sim.offline import Odometry, OfflineTrain, follower_stacks, run_convoy, steady_force, tracking_force

SAFETY_CONTROLLERS = ("mpc", "cbc", "cbf-mpc", "cbf-cbc")
KINDS = ("cruise", "forming", "merge", "split")

SAFETY_COLUMNS = [
    "key", "scenario", "controller", "supervised", "line", "direction", "kind", "followers", "km_start",
    "leader_speed_mps", "brake_time_s", "delay_s", "mean_extra_delay_s", "loss_probability", "outage_s",
    "position_error_m", "corner_trains", "initial_gap_m", "safe_gap_m", "min_gap_m", "min_gap_margin_m",
    "gap_violations", "collisions", "emergency_activations", "emergency_time_s", "initial_true_barrier_m", "max_true_barrier_m",
    "time_lost_s", "simulated_s", "wall_time_s", "error",
]


class SafetyCampaign(StrictModel):
    """Parameters of a safety campaign (``vcsumo study safety`` options or a study file)."""

    lines: list[str] = Field(default_factory=lambda: ["firenze_bologna", "milano_bologna", "hcmc_line1"], min_length=1, description="Shipped line names or line.yaml paths the scenarios are drawn on")
    controllers: list[str] = Field(default_factory=lambda: list(SAFETY_CONTROLLERS), min_length=1, description="Controllers (mpc, cbc, cbf-mpc, cbf-cbc, cbf-cruise; NAME:PARAMS picks a parameter file)")
    scenarios: int = Field(default=1000, ge=1, le=1_000_000, description="Number of scenarios, -")
    seed: int = Field(default=2026, ge=0, description="Campaign seed; scenario k uses the generator seeded with (seed, k)")
    step_s: float = Field(default=0.2, gt=0, le=1.0, description="Control and integration step, s")
    followers_max: int = Field(default=2, ge=1, le=3, description="Largest number of followers behind the leader, -")
    kinds: list[str] = Field(default_factory=lambda: list(KINDS), min_length=1, description="Scenario kinds drawn (cruise, forming, merge, split; merge/split only on lines with junctions)")
    channel_period_s: float = Field(default=0.5, gt=0, le=5.0, description="Message period of every train, s")
    delay_max_s: float = Field(default=1.0, ge=0, le=30.0, description="Largest constant part of the channel delay, s")
    mean_extra_max_s: float = Field(default=2.0, ge=0, le=30.0, description="Largest mean of the exponential extra delay, s")
    loss_max: float = Field(default=0.5, ge=0, lt=1.0, description="Largest independent packet-loss probability, -")
    outage_probability: float = Field(default=0.3, ge=0, le=1, description="Probability of one outage in a scenario, -")
    outage_max_s: float = Field(default=30.0, ge=1.0, le=600.0, description="Longest outage, s")
    corner_probability: float = Field(default=0.3, ge=0, le=1, description="Probability that a train's true parameters sit at a corner of its uncertainty box, -")
    position_error_max_m: float = Field(default=1.0, ge=0, le=50.0, description="Largest bound e_s of the odometry error (Felez eq. 9), m")
    control_period_s: float = Field(default=0.4, gt=0, le=2.0, description="Period of the nominal controllers (the ATO cycle; the CBF supervisor runs every step), s")
    max_duration_s: float = Field(default=900.0, gt=0, le=7200.0, description="Longest simulated time of a scenario, s")
    cbf_config: str | None = Field(default=None, description="CBF parameter file (default controllers/cbf.yaml)")

    @field_validator("kinds")
    @classmethod
    def _kinds(cls, v: list[str]) -> list[str]:
        bad = [k for k in v if k not in KINDS]
        if bad:
            raise ValueError(f"unknown scenario kind(s) {bad} (choose from {', '.join(KINDS)})")
        return v

    def scenario_hash(self) -> str:
        """Hash of everything that shapes the scenarios and their runs (not their number or the controllers)."""
        d = self.model_dump(exclude={"scenarios", "controllers"})
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]


# -------------------------------------------------------------------------------------------
# Routes


@dataclass(frozen=True)
class Junction:
    name: str
    s_m: float
    """Position of the turnout on the trunk route, m."""
    diverging_speed_mps: float


@dataclass
class LineRoute:
    line: str
    direction: str
    stock: RollingStock
    profile: RouteProfile
    junctions: list[Junction]


@lru_cache(maxsize=None)
def line_route(line_spec: str, direction: str) -> LineRoute:
    """The line's main track in ``direction`` as a route profile, its default train and junctions (cached per process)."""
    from vcsumo.line import load_line
    from vcsumo.topology import build_topology

    line = load_line(line_spec)
    topo = build_topology(line)
    profile = RouteProfile.from_edges(topo, topo.track_for("main", direction).edges)
    junctions = []
    for br in line.data.branches:
        try:
            s = profile.s_of("main", br.junction_km)
        except KeyError:
            continue
        junctions.append(Junction(br.junction_name or br.id, s, br.diverging_speed_kmh / 3.6))
    return LineRoute(line.name, direction, load_rolling_stock(line.data.default_train), profile, junctions)


def capped_profile(profile: RouteProfile, v_cap_mps: float, point_limits: list[tuple[float, float]] = ()) -> RouteProfile:
    """The same route with every limit capped at ``v_cap_mps`` and extra turnout limits (for target speeds)."""
    from dataclasses import replace

    return replace(profile, speeds_ms=np.minimum(profile.speeds_ms, v_cap_mps), point_limits=list(profile.point_limits) + list(point_limits))


# -------------------------------------------------------------------------------------------
# Scenarios


@dataclass(frozen=True)
class ScenarioSpec:
    """One drawn scenario (the same for every controller)."""

    index: int
    id: str
    line: str
    direction: str
    kind: str
    followers: int
    leader_start_m: float
    leader_speed_mps: float
    follower_speed_mps: float
    """Initial speed of the first follower (others start at the leader's speed), m/s."""
    brake_time_s: float
    spacing_factor: float
    """Initial gap = factor × the controller's coupled spacing (cruise, forming) or admission gap (merge)."""
    junction_s_m: float
    diverging_speed_mps: float
    delay_s: float
    mean_extra_delay_s: float
    loss_probability: float
    outage: tuple[float, float] | None
    corners: tuple[bool, ...]
    position_error_m: float
    seed: int


def _kinds_for(cfg: SafetyCampaign, route: LineRoute) -> list[str]:
    return [k for k in cfg.kinds if k in ("cruise", "forming") or route.junctions]


def draw_scenario(cfg: SafetyCampaign, index: int) -> ScenarioSpec:
    """Scenario ``index`` of the campaign (seeded by (seed, index); see the module doc)."""
    rng = np.random.default_rng([cfg.seed, index])
    line = cfg.lines[int(rng.integers(len(cfg.lines)))]
    direction = ("up", "down")[int(rng.integers(2))]
    route = line_route(line, direction)
    kinds = _kinds_for(cfg, route) or ["cruise"]
    kind = kinds[int(rng.integers(len(kinds)))]
    prof, stock = route.profile, route.stock
    n_f = int(rng.integers(1, cfg.followers_max + 1))
    v_train = stock.params().max_speed_ms
    j_s, v_div = math.nan, math.nan
    follower_speed = math.nan
    if kind in ("merge", "split"):
        j = route.junctions[int(rng.integers(len(route.junctions)))]
        j_s, v_div = j.s_m, min(j.diverging_speed_mps, v_train)
    if kind == "split":
        # the leader is 1-4 km before the turnout at up to its line speed
        s_lead = max(j_s - float(rng.uniform(1000.0, 4000.0)), 6000.0)
        v_line = min(prof.min_speed_over(s_lead, j_s), v_train)
        v0 = float(rng.uniform(max(v_div, 0.3 * v_line), v_line)) if v_line > v_div else v_line
        t_arrive = (j_s - s_lead) / max(v0, 1.0)
        t_brake = float(rng.uniform(0.3 * t_arrive, t_arrive + 30.0))
        follower_speed = v0
    elif kind == "merge":
        # the leader has passed the junction by 0-2 km; the first follower runs off the branch at the diverging speed
        s_lead = j_s + float(rng.uniform(stock.length_m + 100.0, 2000.0))
        v_line = min(prof.speed_limit_at(s_lead), v_train)
        v0 = float(rng.uniform(0.3 * v_line, v_line))
        follower_speed = min(v_div, prof.speed_limit_at(j_s))
        t_brake = float(rng.uniform(0.0, 120.0))
    else:
        lo, hi = 8000.0, prof.length_m - 30000.0
        if hi <= lo:
            lo, hi = 0.25 * prof.length_m, 0.5 * prof.length_m
        s_lead = float(rng.uniform(lo, hi))
        v_line = min(prof.speed_limit_at(s_lead), v_train)
        v0 = float(rng.uniform(0.3 * v_line, v_line))
        follower_speed = v0 if kind == "cruise" else min(v0 + float(rng.uniform(0.0, 10.0)), v_line)
        t_brake = float(rng.uniform(10.0, 120.0) if kind == "cruise" else rng.uniform(5.0, 120.0))
    factor = float(rng.uniform(2.0, 5.0) if kind == "forming" else rng.uniform(1.0, 1.3))
    outage = None
    if rng.random() < cfg.outage_probability:
        start = float(rng.uniform(0.0, t_brake + 30.0))
        outage = (start, start + float(rng.uniform(1.0, cfg.outage_max_s)))
    return ScenarioSpec(
        index=index, id=f"s{index:05d}", line=route.line, direction=direction, kind=kind, followers=n_f, leader_start_m=s_lead, leader_speed_mps=v0,
        follower_speed_mps=follower_speed, brake_time_s=t_brake, spacing_factor=factor, junction_s_m=j_s, diverging_speed_mps=v_div,
        delay_s=float(rng.uniform(0.0, cfg.delay_max_s)), mean_extra_delay_s=float(rng.uniform(0.0, cfg.mean_extra_max_s)),
        loss_probability=float(rng.uniform(0.0, cfg.loss_max)), outage=outage,
        corners=tuple(bool(rng.random() < cfg.corner_probability) for _ in range(n_f + 1)),
        position_error_m=float(rng.uniform(0.0, cfg.position_error_max_m)), seed=int(rng.integers(2**31 - 1)),
    )


# -------------------------------------------------------------------------------------------
# Controllers: the registry's stacks, as in the SUMO loop

_REUSE: dict = {}
"""Expensive controller parts kept between scenarios in one process (the NMPC's route DP), see
:class:`~vcsumo.control.registry.StackContext`."""


def follower_stacks_for(controller: str, route: LineRoute, ids: list[str], cfg: SafetyCampaign) -> list[FollowerStack]:
    """Every follower's stack, built by the registry exactly as the SUMO loop builds it (nominal
    controller → CBF supervisor for ``cbf-`` names → separation guard → fault stage), with the
    campaign's ATO cycle (``control_period_s``) and odometry error bound."""
    return follower_stacks(controller, [route.stock] * len(ids), ids, cfg.step_s, route.profile, supervisor_params=cfg.cbf_config,
                           control_period_s=cfg.control_period_s, position_error_m=cfg.position_error_max_m, record=False, reuse=_REUSE)


def barrier_gap_m(sup, profile: RouteProfile, s_m: float, v_mps: float, length_m: float) -> float:
    """Smallest front-to-rear gap at which two trains at speed v have a robust barrier b ≤ −1 m (eq. 15), m."""
    model = sup.model_for(profile)

    def b(gap: float) -> float:
        return model.value(s_m, v_mps, s_m - length_m - gap, v_mps)[0]

    lo, hi = 0.0, sup.cfg.safety_distance_m
    while b(hi) > -1.0:
        lo, hi = hi, 2.0 * hi
        if hi > 1e6:
            return hi
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if b(mid) > -1.0 else (lo, mid)
    return hi


def true_params(stock: RollingStock, rng: np.random.Generator, corner: bool, emergency_top: bool = False) -> TrainParams:
    """A train's true parameters inside its uncertainty box (:func:`~vcsumo.control.proxies.sample_params`)
    with an emergency deceleration inside the separation model's emergency-brake range
    (:func:`vcsumo.signalling.separation.brake_range`, the default assumption set: nominal ±10 %):
    at the same place in that range as the drawn service brake in its interval (a corner stays a
    corner), or at its top with ``emergency_top`` (the leader's worst case: ETR1000 1.2 → 1.32 m/s²)."""
    from vcsumo.signalling.assumptions import load_assumptions
    from vcsumo.signalling.separation import brake_range

    p = sample_params(stock, rng, corner=corner)
    lo, hi = brake_range(stock, load_assumptions(), "emergency")
    box = stock.uncertainty_box().service_brake_decel_mps2
    frac = 1.0 if emergency_top else ((p.service_brake_decel_mps2 - box.low) / (box.high - box.low) if box.high > box.low else 0.5)
    return p.with_(emergency_brake_decel_mps2=max(lo + frac * (hi - lo), p.service_brake_decel_mps2))


# -------------------------------------------------------------------------------------------
# One run


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
    and holds it (the plant brakes at its true emergency rate, the top of its box) and broadcasts
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
            times, pos, spd, frc = _plan_slice(self.run, t, 8.0)
            return times, pos - pos[0] + s, spd, frc
        return _braking_plan(self.p, s, v, t, 8.0)


class _Watch:
    """The campaign's safety bookkeeping on the true states, at the start of every step (the
    offline loop's ``stop_when``): gaps, violations, collisions, the true barrier, time lost; it
    ends the run at a collision, when a split is complete or 5 s after everything stopped."""

    def __init__(self, spec: ScenarioSpec, L: float, safe_gap: float, models: list, d_cbf: float, free_runs: list[_Run]):
        self.spec, self.L, self.safe_gap, self.models, self.d_cbf, self.free_runs = spec, L, safe_gap, models, d_cbf, free_runs
        n = spec.followers + 1
        self.min_gap = math.inf
        self.violations = self.collisions = 0
        self.armed = [True] * n
        self.max_b = self.b_init = -math.inf
        self.lost: list[float] = []
        self.rest_since: float | None = None
        self.error = ""

    def __call__(self, t: float, xs: list[PlantState]) -> bool:
        spec, L = self.spec, self.L
        split_done = False
        for i in range(1, len(xs)):
            gap = xs[i - 1].s_m - L - xs[i].s_m
            self.min_gap = min(self.min_gap, gap)
            if gap < self.safe_gap - 1e-6:
                if self.armed[i]:
                    self.violations += 1
                    self.armed[i] = False
            else:
                self.armed[i] = True
            if gap <= 0.0:
                self.collisions += 1
                self.error = "collision"
            m = self.models[i - 1]
            if m is not None:
                # eq. 15 on the true states, the follower's dead time from the force it really applies
                b_true = barrier_from_stops(xs[i - 1].s_m, m.leader_stop(xs[i - 1].s_m, xs[i - 1].v_mps), xs[i].s_m,
                                            m.follower_stop(xs[i].s_m, xs[i].v_mps, 0.0, xs[i].force_n), L, self.d_cbf)[0]
                self.max_b = max(self.max_b, b_true)
                if t == 0.0:
                    self.b_init = max(self.b_init, b_true)
        if self.error:
            return True
        if spec.kind == "split" and xs[0].s_m - L > spec.junction_s_m + 50.0:
            split_done = True  # the leader has left the trunk: the first follower is no longer behind it
        if split_done:
            return True
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
    prof, stock = route.profile, route.stock
    dt = cfg.step_s
    nom = stock.params()
    rng = np.random.default_rng(spec.seed)
    n = spec.followers + 1
    # the leader's emergency brake at the top of its box; every other parameter drawn
    params = [true_params(stock, rng, c, emergency_top=(k == 0)) for k, c in enumerate(spec.corners)]
    ids = [f"T{k}" for k in range(n)]
    stacks = follower_stacks_for(controller, route, ids, cfg)
    safe_gap = stacks[0].d_min_m
    sup0 = stacks[0].supervisor
    models = [s.supervisor.model_for(prof) if s.supervisor is not None else None for s in stacks]
    d_cbf = sup0.cfg.safety_distance_m if sup0 is not None else math.nan
    L = stock.length_m

    # initial spacing of every follower
    def spacing(k: int, v: float, s_pred: float) -> float:
        f = stacks[k - 1]
        g = f.coupled_gap_m(v)
        if f.supervisor is not None:
            g = max(g, barrier_gap_m(f.supervisor, prof, s_pred, v, L))
        return max(g, f.d_min_m + 1.0)

    v_l0 = spec.leader_speed_mps
    speeds = [v_l0] + [spec.follower_speed_mps] + [v_l0] * (n - 2) if n > 1 else [v_l0]
    if spec.kind == "merge":
        speeds = [v_l0] + [spec.follower_speed_mps] * (n - 1)
    positions = [spec.leader_start_m]
    gaps0 = []
    for k in range(1, n):
        v = speeds[k]
        if spec.kind == "merge" and k == 1:
            # admitted by the interlocking: absolute braking distance at the nominal brake + the minimum safe gap
            g = spec.spacing_factor * (v * v / (2.0 * nom.service_brake_decel_mps2) + safe_gap + 1.0)
            g = max(g, positions[0] - L - spec.junction_s_m + 1.0)  # the follower is at or before the turnout
        elif spec.kind == "merge":
            g = spacing(k, v, positions[-1]) * 1.05
        else:
            g = spec.spacing_factor * spacing(k, max(v, speeds[k - 1]), positions[-1]) if (k == 1 or spec.kind != "forming") else spacing(k, v, positions[-1]) * 1.05
        gaps0.append(g)
        positions.append(positions[-1] - L - g)
    if positions[-1] < L + 10.0:
        shift = L + 10.0 - positions[-1]
        positions = [x + shift for x in positions]

    # the leader's target speed: its unhindered run capped at its cruise speed (and the turnout for a split)
    plims = [(spec.junction_s_m, spec.diverging_speed_mps)] if spec.kind == "split" else []
    lead_prof = capped_profile(prof, max(v_l0, 1.0), plims)
    horizon = cfg.max_duration_s + 60.0
    lead_run = _unhindered(nom, lead_prof, positions[0], v_l0, horizon)
    cap_f = capped_profile(prof, max(max(speeds), 1.0))
    free_runs = [_unhindered(nom, cap_f, positions[k], speeds[k], horizon) for k in range(1, n)]

    outages = [Window(start_s=spec.outage[0], end_s=spec.outage[1])] if spec.outage else []
    channel = Channel(ChannelConfig(model="exponential", period_s=cfg.channel_period_s, delay_s=spec.delay_s, mean_extra_s=spec.mean_extra_delay_s,
                                    loss_probability=spec.loss_probability, outages=outages, seed=spec.seed))
    e_s = spec.position_error_m
    odometry = Odometry(rng.uniform(-0.5 * e_s, 0.5 * e_s, size=n), e_s, rng)
    leader = CampaignLeader(lead_run, nom, spec.brake_time_s, dt)
    trains = [OfflineTrain(ids[k], params[k], PlantState(positions[k], speeds[k], steady_force(params[k], speeds[k], prof, positions[k]), 0.0),
                           leader if k == 0 else stacks[k - 1], nominal=nom, plan=leader.plan if k == 0 else None) for k in range(n)]
    watch = _Watch(spec, L, safe_gap, models, d_cbf, free_runs)
    # the convoy has been communicating before the scenario starts: every follower knows its predecessor at t = 0
    run = run_convoy(trains, prof, dt, math.ceil(cfg.max_duration_s / dt) * dt, channel=channel, send_plans=stacks[0].uses_plans, odometry=odometry,
                     known_at_start=True, record_every=0, stop_when=watch)
    lost = watch.lost or [math.nan]  # the scenario ended before the brake (a split completed first)
    supervised = sup0 is not None
    return {
        "scenario": spec.id, "controller": controller, "supervised": supervised, "line": spec.line, "direction": spec.direction, "kind": spec.kind,
        "followers": spec.followers, "km_start": round(prof.km_at(spec.leader_start_m)[1], 3), "leader_speed_mps": spec.leader_speed_mps,
        "brake_time_s": spec.brake_time_s, "delay_s": spec.delay_s, "mean_extra_delay_s": spec.mean_extra_delay_s, "loss_probability": spec.loss_probability,
        "outage_s": 0.0 if spec.outage is None else spec.outage[1] - spec.outage[0], "position_error_m": spec.position_error_m,
        "corner_trains": int(sum(spec.corners)), "initial_gap_m": min(gaps0) if gaps0 else math.nan, "safe_gap_m": safe_gap,
        "min_gap_m": watch.min_gap, "min_gap_margin_m": watch.min_gap - safe_gap, "gap_violations": watch.violations, "collisions": watch.collisions,
        "emergency_activations": sum(run.emergency_activations[i] for i in ids[1:]), "emergency_time_s": sum(run.emergency_time_s[i] for i in ids[1:]),
        "initial_true_barrier_m": watch.b_init if supervised else math.nan, "max_true_barrier_m": watch.max_b if supervised else math.nan,
        "time_lost_s": float(np.mean(lost)), "simulated_s": run.end_time_s, "wall_time_s": time.perf_counter() - t_wall, "error": "",
    }


def _plan_slice(run: _Run, t: float, horizon_s: float) -> tuple:
    grid = t + np.arange(0.0, horizon_s + 1e-9, 0.5)
    v = np.interp(grid, run.t, run.v)
    return grid, np.interp(grid, run.t, run.s), v, np.zeros_like(v)


def _braking_plan(p: TrainParams, s: float, v: float, t: float, horizon_s: float) -> tuple:
    """The braking leader's own plan: its nominal emergency stop from its state."""
    a = max(p.emergency_brake_decel_mps2, 1e-3)
    tau = np.arange(0.0, horizon_s + 1e-9, 0.5)
    tt = np.minimum(tau, v / a)
    return t + tau, s + v * tt - 0.5 * a * tt * tt, np.maximum(v - a * tau, 0.0), -p.mass_kg * a * np.ones_like(tau)


# -------------------------------------------------------------------------------------------
# The campaign


def _row_key(cfg_hash: str, scenario: str, controller: str) -> str:
    return f"{cfg_hash}:{scenario}:{controller}"


def scenario_task(args: tuple) -> list[dict]:
    """Run one scenario for every controller (a worker task); failures become rows with ``error``."""
    cfg, index, controllers = args
    rows = []
    try:
        spec = draw_scenario(cfg, index)
    except Exception as exc:  # noqa: BLE001 - reported as the scenario's rows
        return [{"scenario": f"s{index:05d}", "controller": c, "error": f"{type(exc).__name__}: {exc}"} for c in controllers]
    for c in controllers:
        t0 = time.perf_counter()
        try:
            row = run_scenario(spec, c, cfg)
        except VcsumoError as exc:
            row = {"scenario": spec.id, "controller": c, "error": str(exc)}
        except Exception as exc:  # noqa: BLE001 - a failing run is a row, never the end of the campaign
            row = {"scenario": spec.id, "controller": c, "error": f"{type(exc).__name__}: {exc}", "wall_time_s": time.perf_counter() - t0}
        rows.append(row)
    return rows


def check_campaign(cfg: SafetyCampaign, source: Path | None = None) -> None:
    """Validate lines and controllers before anything runs (one clear error naming the input)."""
    from vcsumo.line import load_line

    for ln in cfg.lines:
        load_line(ln)
    for i, c in enumerate(cfg.controllers):
        check_controller(c, "--controllers" if source is None else f"controllers[{i}]", supervisor_params=cfg.cbf_config)
    if cfg.cbf_config:
        resolve_params(cfg.cbf_config, "cbf", "--cbf" if source is None else "cbf_config")
    if len(set(cfg.controllers)) != len(cfg.controllers):
        raise InputError(source, "controllers", "a controller is listed twice")


SAFETY_TABLE = Table("safety.csv", tuple(SAFETY_COLUMNS), "key", text=("controller", "error"))
"""The campaign's result store: one row per scenario and controller, keyed by (scenario hash, scenario, controller)."""


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

    def to_rows(task: Task, outcome: Outcome) -> tuple[list[dict], dict]:
        _, k, missing = task.arg
        rows = outcome.value if outcome.ok else [{"scenario": f"s{k:05d}", "controller": c, "error": f"worker failed: {outcome.error}"} for c in missing]
        for r in rows:
            r["key"] = _row_key(h, r["scenario"], r["controller"])
            r.setdefault("error", "")
        return rows, {}

    with runner, ResultStore(out, SAFETY_TABLE, kind="safety") as store:
        tasks = []
        for k in range(cfg.scenarios):
            missing = tuple(c for c in cfg.controllers if _row_key(h, f"s{k:05d}", c) not in store)
            if missing:
                tasks.append(Task(f"{h}:s{k:05d}", scenario_task, (cfg, k, missing), f"scenario {k}",
                                  keys=tuple(_row_key(h, f"s{k:05d}", c) for c in missing)))
        before = cfg.scenarios - len(tasks)
        run_campaign(store, tasks, runner, to_rows, (lambda done, _n, _rows: progress(before + done, cfg.scenarios)) if progress else None)
        df = read_safety(out)
    keys = {_row_key(h, f"s{k:05d}", c) for k in range(cfg.scenarios) for c in cfg.controllers}
    return df[df["key"].isin(keys)].reset_index(drop=True)


def read_safety(out: Path) -> pd.DataFrame:
    """``safety.csv`` of a campaign folder (one row per key), empty frame if none."""
    return read_table(Path(out), SAFETY_TABLE)


SUMMARY_COLUMNS = [
    "controller", "supervised", "scenarios", "failed_runs", "scenarios_with_violation", "gap_violations", "violation_rate", "collisions",
    "min_gap_m", "min_gap_margin_m", "max_true_barrier_m", "started_outside_safe_set", "barrier_breaches", "emergency_activations_mean", "emergency_time_s_mean",
    "time_lost_s_mean", "time_lost_s_p95", "wall_time_s_mean",
]


def summarize_safety(df: pd.DataFrame) -> pd.DataFrame:
    """One row per controller: violation counts and rates, collisions, margins, the true barrier
    (runs that started outside the safe set b ≤ 0 — merges admitted at the interlocking's nominal
    moving-block distance — and breaches: runs where b rose above max(b(0), 0)), emergencies, time lost."""
    rows = []
    for c, g in df.groupby("controller", sort=False):
        ok = g[g["error"] == ""]
        b0 = pd.to_numeric(ok.get("initial_true_barrier_m", pd.Series(math.nan, index=ok.index)), errors="coerce")
        bmax = pd.to_numeric(ok["max_true_barrier_m"], errors="coerce")
        rows.append({
            "controller": c, "supervised": bool(ok["supervised"].astype(bool).any()) if len(ok) else str(c).startswith("cbf-"),
            "scenarios": len(ok), "failed_runs": int((g["error"] != "").sum()),
            "scenarios_with_violation": int((ok["gap_violations"] > 0).sum()), "gap_violations": int(ok["gap_violations"].sum()),
            "violation_rate": float((ok["gap_violations"] > 0).mean()) if len(ok) else math.nan, "collisions": int(ok["collisions"].sum()),
            "min_gap_m": float(ok["min_gap_m"].min()) if len(ok) else math.nan, "min_gap_margin_m": float(ok["min_gap_margin_m"].min()) if len(ok) else math.nan,
            "max_true_barrier_m": float(bmax.max()) if len(ok) else math.nan,
            # Theorem VI.1: from b(0) ≤ 0, b stays ≤ 0; a run admitted with b(0) > 0 must not see b rise above b(0)
            "started_outside_safe_set": int((b0 > 0).sum()),
            "barrier_breaches": int((bmax > b0.clip(lower=0.0) + 1e-6).sum()),
            "emergency_activations_mean": float(ok["emergency_activations"].mean()) if len(ok) else math.nan,
            "emergency_time_s_mean": float(ok["emergency_time_s"].mean()) if len(ok) else math.nan,
            "time_lost_s_mean": float(ok["time_lost_s"].mean()) if len(ok) else math.nan,
            "time_lost_s_p95": float(ok["time_lost_s"].quantile(0.95)) if len(ok) else math.nan,
            "wall_time_s_mean": float(ok["wall_time_s"].mean()) if len(ok) else math.nan,
        })
    return pd.DataFrame(rows, columns=SUMMARY_COLUMNS)


def bar_met(summary: pd.DataFrame, min_scenarios: int = 1000) -> bool:
    """Issue 5's bar: every CBF-supervised controller has ≥ ``min_scenarios`` runs, none failed, 0 violations, 0 collisions
    (and no barrier breach)."""
    sup = summary[summary["supervised"].astype(bool)]
    ok = (sup["scenarios"] >= min_scenarios) & (sup["failed_runs"] == 0) & (sup["gap_violations"] == 0) & (sup["collisions"] == 0) & (sup["barrier_breaches"] == 0)
    return bool(len(sup)) and bool(ok.all())


def write_safety_report(out: Path, cfg: SafetyCampaign, df: pd.DataFrame, summary: pd.DataFrame, wall_time_s: float) -> None:
    """``report/``: safety_runs.csv (this campaign's rows), safety_summary.csv, safety_gaps.png and meta.json."""
    from vcsumo.line import load_line
    from vcsumo.plots.safety import plot_safety
    from vcsumo.results import ResultsFolder

    inputs = {f"line_{ln}": load_line(ln).path for ln in cfg.lines}
    params = {**cfg.model_dump(mode="json"), "scenario_hash": cfg.scenario_hash(), "campaign_wall_time_s": round(wall_time_s, 3), "runs": len(df)}
    with ResultsFolder(Path(out) / "report", inputs=inputs, seed=cfg.seed, params=params, overwrite=True) as rf:
        df.to_csv(rf.path / "safety_runs.csv", index=False)
        summary.to_csv(rf.path / "safety_summary.csv", index=False)
        plot_safety(rf.path / "safety_runs.csv", rf.path / "safety_gaps.png")
