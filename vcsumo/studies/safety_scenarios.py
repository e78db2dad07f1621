"""The safety campaign's parameters and its seeded scenarios (offline loop and SUMO loop alike).

A scenario (:func:`draw_scenario`, one seeded generator per scenario, so a scenario is the same
for every controller and does not depend on how many scenarios are run) draws:

* a line, a direction and the **rolling stock of every train**: with probability
  ``heterogeneous_probability`` each train is drawn from ``rolling_stock`` (a heterogeneous convoy:
  e.g. a regional EMU behind an ETR1000), else every train is the line's default train;
* a kind:

  - ``cruise`` — the convoy runs coupled at the controller's own spacing (× 1.0–1.3);
  - ``forming`` — the followers start 2–5 times that spacing behind and up to 10 m/s faster, so the
    convoy is still forming when the leader brakes;
  - ``merge`` — at one of the line's junctions: the first follower has just come off the branch
    at the diverging speed, admitted by the interlocking at its absolute braking distance plus
    its minimum safe gap (× 1.0–1.3), behind a leader on the trunk;
  - ``split`` — the leader leaves the trunk at a junction (it brakes for the turnout's diverging
    speed) while the followers go straight on; the pair is watched until the leader's rear has
    cleared the junction;

  every follower starts outside the safe separation of the run-health monitor's rule (and of the
  CBF's barrier for ``cbf-`` controllers) at the speeds the trains start at;
* every train starts at most at the speed it is permitted where it stands (:func:`start_speed_limit`:
  the limit under its whole train, its top speed, its service-brake curve to every lower limit ahead
  after its brake build-up) — the leader in the draw, each follower where :func:`initial_gaps`
  places it (the one start of the offline and the SUMO loop);
* the leader's cruise speed (30–100 % of the line speed there, at most every train's top speed)
  and the time of its **emergency brake** (at the top of its emergency range under the assumption
  set, :func:`true_params`): 10–120 s (cruise), 5–120 s (forming), 0–120 s (merge), around its
  arrival at the turnout (split);
* 1..``followers_max`` followers;
* the channel (Terlizzi §VII): constant delay 0–``delay_max_s`` + exponential extra delay of mean
  0–``mean_extra_max_s``, independent loss 0–``loss_max``, and with probability
  ``outage_probability`` an outage of 1–``outage_max_s`` s;
* every train's true parameters (at a box corner with probability ``corner_probability``; its
  emergency deceleration within the separation model's ±10 % range, at the same place in it as the
  drawn service brake in its box; the leader's at the top);
* the position error of every train's odometry, bounded by e_s in 0–``position_error_max_m``.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Literal

import numpy as np
from pydantic import Field, ValidationInfo, field_validator, model_validator

from vcsumo.config import StrictModel
from vcsumo.control.proxies import sample_params
from vcsumo.control.brake_build_up import BrakeBuildUp
from vcsumo.control.stack import FollowerStack
from vcsumo.dynamics import TrainParams
from vcsumo.errors import VcsumoError
from vcsumo.rolling_stock import RollingStock, load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel, brake_range
from vcsumo.sim.convoy_plan import load_channel
from vcsumo.sim.offline import follower_stacks, steady_force

SAFETY_CONTROLLERS = ("mpc", "cbc", "cbf-mpc", "cbf-cbc")
KINDS = ("cruise", "forming", "merge", "split")
SUMO_KINDS = ("cruise", "forming")
"""Kinds the SUMO loop runs (merge and split need the interlocking's routing of a second route)."""


class SafetyCampaign(StrictModel):
    """Parameters of a safety campaign (``vcsumo study safety`` options or a study file)."""

    loop: Literal["offline", "sumo"] = Field(default="offline", description="Where the scenarios run: the offline closed loop (vcsumo.sim.offline) or the SUMO loop itself (vcsumo.sim.loop with the VC driver)")
    lines: list[str] = Field(default_factory=lambda: ["firenze_bologna", "milano_bologna", "hcmc_line1"], min_length=1, description="Shipped line names or line.yaml paths the scenarios are drawn on")
    controllers: list[str] = Field(default_factory=lambda: list(SAFETY_CONTROLLERS), min_length=1, description="Controllers (mpc, cbc, cbf-mpc, cbf-cbc, cbf-cruise; NAME:PARAMS picks a parameter file)")
    scenarios: int = Field(default=1000, ge=1, le=1_000_000, description="Number of scenarios, -")
    seed: int = Field(default=2026, ge=0, description="Campaign seed; scenario k uses the generator seeded with (seed, k)")
    step_s: float = Field(default=0.2, gt=0, le=1.0, description="Control and integration step, s")
    followers_max: int = Field(default=2, ge=1, le=3, description="Largest number of followers behind the leader, -")
    kinds: list[str] = Field(default_factory=lambda: list(KINDS), min_length=1, description="Scenario kinds drawn (cruise, forming, merge, split; merge/split only on lines with junctions and only offline)")
    rolling_stock: list[str] = Field(default_factory=lambda: ["etr1000", "regional_emu160", "hcmc_l1"], min_length=1, description="Rolling stock a heterogeneous convoy's trains are drawn from (names or paths)")
    heterogeneous_probability: float = Field(default=0.5, ge=0, le=1, description="Probability that a scenario's trains are drawn from rolling_stock (else all are the line's default train), -")
    channel_period_s: float = Field(default=0.5, gt=0, le=5.0, description="Message period of every train, s")
    delay_max_s: float = Field(default=1.0, ge=0, le=30.0, description="Largest constant part of the channel delay, s")
    mean_extra_max_s: float = Field(default=2.0, ge=0, le=30.0, description="Largest mean of the exponential extra delay, s")
    loss_max: float = Field(default=0.5, ge=0, lt=1.0, description="Largest independent packet-loss probability, -")
    outage_probability: float = Field(default=0.3, ge=0, le=1, description="Probability of one outage in a scenario, -")
    outage_max_s: float = Field(default=30.0, ge=1.0, le=600.0, description="Longest outage, s")
    corner_probability: float = Field(default=0.3, ge=0, le=1, description="Probability that a train's true parameters sit at a corner of its uncertainty box, -")
    position_error_max_m: float = Field(default=1.0, ge=0, le=50.0, description="Largest bound e_s of the odometry error (Felez eq. 9), m (offline loop)")
    control_period_s: float | None = Field(
        default=None, gt=0, le=2.0,
        description="Period of the nominal controllers (an ATO cycle; the CBF supervisor and the guard run every step), s; none: every step, as "
                    "the stacks of the capacity study and of the SUMO loop (offline loop only)")
    max_duration_s: float = Field(default=900.0, gt=0, le=7200.0, description="Longest simulated time of a scenario, s")
    cbf_config: str | None = Field(default=None, description="CBF parameter file (default controllers/cbf.yaml)")
    assumptions: str | None = Field(default=None, description="Assumption set of the separation model (shipped name or path; default etcs_typical): the stacks' and the measurement's")

    @field_validator("kinds")
    @classmethod
    def _kinds(cls, v: list[str]) -> list[str]:
        bad = [k for k in v if k not in KINDS]
        if bad:
            raise ValueError(f"unknown scenario kind(s) {bad} (choose from {', '.join(KINDS)})")
        return v

    @field_validator("control_period_s")
    @classmethod
    def _sumo_every_step(cls, v: float | None, info: ValidationInfo) -> float | None:
        if v is not None and info.data.get("loop") == "sumo" and abs(v - info.data.get("step_s", v)) > 1e-9:
            raise ValueError(f"{v} s: the SUMO loop runs the nominal controllers every step, as the capacity study (leave it out)")
        return v

    @model_validator(mode="after")
    def _sumo_kinds(self) -> "SafetyCampaign":
        if self.loop == "sumo":
            bad = [k for k in self.kinds if k not in SUMO_KINDS]
            if bad and set(self.kinds) != set(KINDS):
                raise ValueError(f"the SUMO loop runs the kinds {', '.join(SUMO_KINDS)} (not {', '.join(bad)})")
        return self

    @property
    def drawn_kinds(self) -> list[str]:
        """The kinds scenarios are drawn from (the SUMO loop: cruise and forming only)."""
        return [k for k in self.kinds if self.loop == "offline" or k in SUMO_KINDS]

    def scenario_hash(self) -> str:
        """Hash of everything that shapes the scenarios and their runs (not their number or the controllers)."""
        d = self.model_dump(exclude={"scenarios", "controllers"})
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]


@lru_cache(maxsize=8)
def campaign_assumptions(spec: str | None) -> AssumptionSet:
    """The campaign's assumption set (cached per process)."""
    return load_assumptions(spec, "assumptions")


@lru_cache(maxsize=32)
def stock(spec: str) -> RollingStock:
    """A rolling stock by name or path (cached per process)."""
    return load_rolling_stock(spec)


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
    """The line's default train."""
    profile: RouteProfile
    junctions: list[Junction]
    edges: list[str]
    """The main track's SUMO edges in ``direction`` (the route of ``profile``)."""
    stock_spec: str = ""
    """The line's ``default_train`` as written (a name or a path: what :func:`stock` loads it by)."""


@lru_cache(maxsize=None)
def line_route(line_spec: str, direction: str) -> LineRoute:
    """The line's main track in ``direction`` as a route profile, its default train and junctions (cached per process)."""
    from vcsumo.line import load_line
    from vcsumo.topology import build_topology

    line = load_line(line_spec)
    topo = build_topology(line)
    edges = list(topo.track_for("main", direction).edges)
    profile = RouteProfile.from_edges(topo, edges)
    junctions = []
    for br in line.data.branches:
        try:
            s = profile.s_of("main", br.junction_km)
        except KeyError:
            continue
        junctions.append(Junction(br.junction_name or br.id, s, br.diverging_speed_kmh / 3.6))
    return LineRoute(line.name, direction, load_rolling_stock(line.data.default_train), profile, junctions, edges, line.data.default_train)


def capped_profile(profile: RouteProfile, v_cap_mps: float, point_limits: list[tuple[float, float]] = ()) -> RouteProfile:
    """The same route with every limit capped at ``v_cap_mps`` and extra turnout limits (for target speeds)."""
    return replace(profile, speeds_ms=np.minimum(profile.speeds_ms, v_cap_mps), point_limits=list(profile.point_limits) + list(point_limits))


# -------------------------------------------------------------------------------------------
# Scenarios


@dataclass(frozen=True)
class ScenarioSpec:
    """One drawn scenario (the same for every controller)."""

    index: int
    id: str
    line: str
    """The line as the campaign names it (a shipped name or a line.yaml path: what :func:`line_route` loads)."""
    direction: str
    kind: str
    followers: int
    stocks: tuple[str, ...]
    """Rolling stock of every train, leader first."""
    leader_start_m: float
    leader_speed_mps: float
    """The leader's initial speed, m/s: drawn, at most what :func:`start_speed_limit` permits where it stands."""
    follower_speed_mps: float
    """Drawn initial speed of the first follower (of every follower in a merge; the others are drawn at the
    leader's speed), m/s: each starts at most at what it is permitted where it stands (:func:`initial_gaps`)."""
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
    return [k for k in cfg.drawn_kinds if k in ("cruise", "forming") or route.junctions]


def draw_scenario(cfg: SafetyCampaign, index: int) -> ScenarioSpec:
    """Scenario ``index`` of the campaign (seeded by (seed, index); see the module doc)."""
    rng = np.random.default_rng([cfg.seed, index])
    line = cfg.lines[int(rng.integers(len(cfg.lines)))]
    direction = ("up", "down")[int(rng.integers(2))]
    route = line_route(line, direction)
    kinds = _kinds_for(cfg, route) or ["cruise"]
    kind = kinds[int(rng.integers(len(kinds)))]
    prof = route.profile
    n_f = int(rng.integers(1, cfg.followers_max + 1))
    if rng.random() < cfg.heterogeneous_probability:
        names = tuple(cfg.rolling_stock[int(rng.integers(len(cfg.rolling_stock)))] for _ in range(n_f + 1))
    else:
        names = (route.stock_spec,) * (n_f + 1)
    v_train = min(stock(n).max_speed_ms for n in names)

    def permitted(v: float, turnouts: tuple = ()) -> float:  # the leader's start speed: at most what it is permitted where it stands
        return start_speed_limit(stock(names[0]), prof, s_lead, v, campaign_assumptions(cfg.assumptions), cfg.step_s, turnouts)

    j_s, v_div = math.nan, math.nan
    follower_speed = math.nan
    if kind in ("merge", "split"):
        j = route.junctions[int(rng.integers(len(route.junctions)))]
        j_s, v_div = j.s_m, min(j.diverging_speed_mps, v_train)
    if kind == "split":
        # the leader is 1-4 km before the turnout at up to its line speed
        s_lead = max(j_s - float(rng.uniform(1000.0, 4000.0)), 6000.0)
        v_line = min(prof.min_speed_over(s_lead, j_s), v_train)
        v0 = permitted(float(rng.uniform(max(v_div, 0.3 * v_line), v_line)) if v_line > v_div else v_line, ((j_s, v_div),))
        t_arrive = (j_s - s_lead) / max(v0, 1.0)
        t_brake = float(rng.uniform(0.3 * t_arrive, t_arrive + 30.0))
        follower_speed = v0
    elif kind == "merge":
        # the leader has passed the junction by 0-2 km; the first follower runs off the branch at the diverging speed
        s_lead = j_s + float(rng.uniform(stock(names[0]).length_m + 100.0, 2000.0))
        v_line = min(prof.speed_limit_at(s_lead), v_train)
        v0 = permitted(float(rng.uniform(0.3 * v_line, v_line)))
        follower_speed = min(v_div, prof.speed_limit_at(j_s))
        t_brake = float(rng.uniform(0.0, 120.0))
    else:
        lo, hi = 8000.0, prof.length_m - 30000.0
        if hi <= lo:
            lo, hi = 0.25 * prof.length_m, 0.5 * prof.length_m
        s_lead = float(rng.uniform(lo, hi))
        v_line = min(prof.speed_limit_at(s_lead), v_train)
        v0 = permitted(float(rng.uniform(0.3 * v_line, v_line)))
        follower_speed = v0 if kind == "cruise" else min(v0 + float(rng.uniform(0.0, 10.0)), v_line)
        t_brake = float(rng.uniform(10.0, 120.0) if kind == "cruise" else rng.uniform(5.0, 120.0))
    factor = float(rng.uniform(2.0, 5.0) if kind == "forming" else rng.uniform(1.0, 1.3))
    outage = None
    if rng.random() < cfg.outage_probability:
        start = float(rng.uniform(0.0, t_brake + 30.0))
        outage = (start, start + float(rng.uniform(1.0, cfg.outage_max_s)))
    return ScenarioSpec(
        index=index, id=f"s{index:05d}", line=line, direction=direction, kind=kind, followers=n_f, stocks=names, leader_start_m=s_lead,
        leader_speed_mps=v0, follower_speed_mps=follower_speed, brake_time_s=t_brake, spacing_factor=factor, junction_s_m=j_s, diverging_speed_mps=v_div,
        delay_s=float(rng.uniform(0.0, cfg.delay_max_s)), mean_extra_delay_s=float(rng.uniform(0.0, cfg.mean_extra_max_s)),
        loss_probability=float(rng.uniform(0.0, cfg.loss_max)), outage=outage,
        corners=tuple(bool(rng.random() < cfg.corner_probability) for _ in range(n_f + 1)),
        position_error_m=float(rng.uniform(0.0, cfg.position_error_max_m)), seed=int(rng.integers(2**31 - 1)),
    )


def true_params(train: RollingStock, rng: np.random.Generator, corner: bool, emergency_top: bool = False, assumptions: AssumptionSet | None = None) -> TrainParams:
    """A train's true parameters inside its uncertainty box (:func:`~vcsumo.control.proxies.sample_params`)
    with an emergency deceleration inside the separation model's emergency-brake range
    (:func:`vcsumo.signalling.separation.brake_range` under ``assumptions``, default etcs_typical:
    nominal ±10 %): at the same place in that range as the drawn service brake in its interval (a
    corner stays a corner), or at its top with ``emergency_top`` (the leader's worst case: ETR1000
    1.2 → 1.32 m/s²)."""
    p = sample_params(train, rng, corner=corner)
    lo, hi = brake_range(train, assumptions or load_assumptions(), "emergency")
    box = train.uncertainty_box().service_brake_decel_mps2
    frac = 1.0 if emergency_top else ((p.service_brake_decel_mps2 - box.low) / (box.high - box.low) if box.high > box.low else 0.5)
    return p.with_(emergency_brake_decel_mps2=max(lo + frac * (hi - lo), p.service_brake_decel_mps2))


# -------------------------------------------------------------------------------------------
# Controllers (the registry's stacks, as in the SUMO loop) and the convoy at t = 0

_REUSE: dict = {}
"""Expensive controller parts kept between scenarios in one process (the NMPC's route DP), see
:class:`~vcsumo.control.registry.StackContext`."""


@lru_cache(maxsize=8)
def _age_budget_s(period_s: float) -> float:
    return load_channel(None).model_copy(update={"period_s": period_s}).age_budget_s()


def stack_message_age_s(cfg: SafetyCampaign) -> float:
    """The message age the followers' stacks are configured for, s: what the shipped default channel
    (``controllers/channel.yaml``, the studies' channel) keeps at the campaign's message period
    (:meth:`~vcsumo.control.channel.ChannelConfig.age_budget_s`; 1.35 s at 2 Hz).  Each scenario's
    channel (its delays, losses and outages) is a disturbance the stack was not configured for, as a
    degraded link is in service: the safety layers act on the true age."""
    return _age_budget_s(float(cfg.channel_period_s))


def follower_stacks_for(controller: str, route: LineRoute, ids: list[str], cfg: SafetyCampaign, stocks: list[RollingStock] | None = None) -> list[FollowerStack]:
    """Every follower's stack, built by the registry exactly as the SUMO loop builds it (nominal
    controller → CBF supervisor for ``cbf-`` names → separation guard → fault stage), with the
    campaign's ATO cycle (``control_period_s``), odometry error bound and assumption set, and the
    message age of the channel it is configured for (:func:`stack_message_age_s`); ``stocks`` the
    convoy's trains, leader first (default: the line's train)."""
    return follower_stacks(controller, stocks or [route.stock] * len(ids), ids, cfg.step_s, route.profile, supervisor_params=cfg.cbf_config,
                           control_period_s=cfg.control_period_s, position_error_m=cfg.position_error_max_m, record=False, reuse=_REUSE,
                           assumptions=campaign_assumptions(cfg.assumptions), message_age_s=stack_message_age_s(cfg))


class _StartCurve:
    """A train's braking to the line's lower limits, for its start speed (:func:`start_speed_limit`)."""

    def __init__(self, train: RollingStock, profile: RouteProfile, assumptions: AssumptionSet):
        self.keep = (train, profile, assumptions)  # the key's objects stay alive while the entry does
        self.service = RouteBraking(SeparationModel(assumptions), train, profile, "service")
        build = BrakeBuildUp(train, assumptions)
        self.build_up_s = build.actuation_time(None, build.service_mps2)
        self.targets = profile.restriction_targets()


_START_CURVES: dict[tuple[int, int, int], _StartCurve] = {}


def start_speed_limit(train: RollingStock, profile: RouteProfile, s_m: float, v_mps: float, assumptions: AssumptionSet, step_s: float,
                      turnouts: tuple[tuple[float, float], ...] = ()) -> float:
    """The highest speed ≤ ``v_mps`` a train may start a scenario at with its front at ``s_m``, m/s:
    the limit under its whole train (SUMO's rule and the run-health monitor's,
    :meth:`RouteProfile.speed_limit_train`), its top speed, and its guaranteed service-brake curve to
    every lower limit ahead (and the ``turnouts`` (position, speed) it diverges at) after its brake build-up from full traction (the longest,
    :meth:`~vcsumo.control.brake_build_up.BrakeBuildUp.actuation_time`) and 1.5 steps — at least
    what the separation guard's line test and the loop's supervision of SUMO-driven trains ask, so
    no train starts where its own protection has to brake it harder than service."""
    key = (id(train), id(profile), id(assumptions))
    c = _START_CURVES.get(key)
    if c is None:
        c = _START_CURVES[key] = _StartCurve(train, profile, assumptions)
    v = min(v_mps, profile.speed_limit_train(s_m, train.length_m), train.max_speed_ms)
    dead = c.build_up_s + 1.5 * step_s
    reach = s_m + c.service.stopping_distance(s_m, v, dead) + 50.0
    v_curve = math.inf
    for s_t, v_t in (sorted(c.targets + list(turnouts)) if turnouts else c.targets):
        if s_t > reach:
            break
        if s_t > s_m:
            v_curve = min(v_curve, c.service.permitted_speed(s_m, s_t, v_t, dead, v))
    # the curve at v holds at every lower speed (the brake power limit only eases as the train slows)
    return max(min(v, v_curve), 0.0)


def initial_gaps(spec: ScenarioSpec, stacks: list[FollowerStack], stocks: list[RollingStock], rules: list[RelativeBraking], model: SeparationModel,
                 profile: RouteProfile, step_s: float) -> tuple[list[float], list[float], list[float]]:
    """(positions, speeds, gaps) of the convoy at t = 0 — the one start of both loops: every train at
    its drawn speed, at most what :func:`start_speed_limit` permits **at its own position**; the
    kind's spacing at those speeds, never inside any follower's safe separation at them (the
    monitor's rule, and the CBF's barrier for ``cbf-`` stacks, each + 1 % + 2 m: the true train's
    force and mass differ a little from the nominal ones the gap is computed with).  The convoy is
    moved forward (and placed again) when its last train would not be on the route."""
    start = spec.leader_start_m
    for _ in range(4):
        positions, speeds, gaps = _convoy_at(start, spec, stacks, stocks, rules, model, profile, step_s)
        shift = stocks[-1].length_m + 10.0 - positions[-1]
        if shift <= 0.0:
            return positions, speeds, gaps
        start += shift
    raise VcsumoError(f"scenario {spec.id}: the convoy does not fit on the route ({spec.line} {spec.direction})")


def _convoy_at(s_lead: float, spec: ScenarioSpec, stacks: list[FollowerStack], stocks: list[RollingStock], rules: list[RelativeBraking],
               model: SeparationModel, profile: RouteProfile, step_s: float) -> tuple[list[float], list[float], list[float]]:
    n = spec.followers + 1
    a = model.assumptions
    v_l0 = spec.leader_speed_mps
    drawn = [v_l0, spec.follower_speed_mps] + [v_l0] * (n - 2) if spec.kind != "merge" else [v_l0] + [spec.follower_speed_mps] * (n - 1)
    positions = [s_lead]
    turnouts = ((spec.junction_s_m, spec.diverging_speed_mps),) if spec.kind == "split" else ()  # where the leader of a split diverges
    speeds = [start_speed_limit(stocks[0], profile, s_lead, v_l0, a, step_s, turnouts)]
    gaps = []
    for k in range(1, n):
        st, f, v_p, s_p = stocks[k], stacks[k - 1], speeds[k - 1], positions[-1]
        L_p = stocks[k - 1].length_m

        def safe(g: float, v: float) -> float:  # the safe separation at that gap and speed, + 1 % + 2 m
            s_f = s_p - L_p - g
            need = rules[k - 1].required_gap(s_f, v, s_p, v_p, model.dead_time_s)
            if f.supervisor is not None:
                need = max(need, f.supervisor.required_gap_m(profile, s_p, v_p, s_f, v, steady_force(st.params(), v, profile, s_f)))
            return 1.01 * need + 2.0

        def spacing(v: float) -> float:  # the kind's spacing at the follower's speed
            own = max(f.coupled_gap_m(max(v, v_p)), f.d_min_m + 1.0)
            if spec.kind == "merge" and k == 1:
                # admitted by the interlocking: absolute braking distance at the nominal service brake + the minimum safe gap
                g = spec.spacing_factor * (v * v / (2.0 * st.service_brake_decel_mps2) + f.d_min_m + 1.0)
                return max(g, s_p - L_p - spec.junction_s_m + 1.0)  # the follower is at or before the turnout
            return spec.spacing_factor * own if spec.kind in ("cruise", "split") or k == 1 else 1.05 * own

        # the follower's speed depends on where it stands, its gap on that speed: placed again until the
        # gap is the kind's spacing (or the safe separation) at the speed permitted where that gap puts it
        # (after 20 placements the gap only grows, so a follower between two limits cannot swing for ever)
        g = spacing(drawn[k])
        for it in range(100):
            v = start_speed_limit(st, profile, s_p - L_p - g, drawn[k], a, step_s)
            g_new = max(spacing(v), safe(g, v))
            if it >= 20:
                g_new = max(g, g_new)
            if abs(g_new - g) <= 1e-3:
                break
            g = g_new
        else:
            raise VcsumoError(f"scenario {spec.id}: no start for follower {k} where its gap holds at its permitted speed")
        speeds.append(v)
        gaps.append(g)
        positions.append(s_p - L_p - g)
    return positions, speeds, gaps


def spec_columns(spec: ScenarioSpec, prof: RouteProfile) -> dict:
    return {
        "scenario": spec.id, "line": spec.line, "direction": spec.direction, "kind": spec.kind, "followers": spec.followers,
        "leader_stock": spec.stocks[0], "follower_stocks": "+".join(spec.stocks[1:]), "km_start": round(prof.km_at(spec.leader_start_m)[1], 3),
        "leader_speed_mps": spec.leader_speed_mps, "brake_time_s": spec.brake_time_s, "delay_s": spec.delay_s, "mean_extra_delay_s": spec.mean_extra_delay_s,
        "loss_probability": spec.loss_probability, "outage_s": 0.0 if spec.outage is None else spec.outage[1] - spec.outage[0],
        "position_error_m": spec.position_error_m, "corner_trains": int(sum(spec.corners)),
    }


HEALTH_FAULT_COLUMNS = ("overspeed_events", "beyond_service_brakings", "authority_overruns", "sumo_emergency_stops", "teleports")
"""The run-health counters of a SUMO-loop run besides separation and collisions (:mod:`vcsumo.sim.health`):
any of them non-zero is a fault of the run (:func:`vcsumo.studies.safety.run_faults`)."""


__all__ = [
    "HEALTH_FAULT_COLUMNS",
    "SAFETY_CONTROLLERS", "KINDS", "SUMO_KINDS", "SafetyCampaign", "campaign_assumptions", "stock", "Junction", "LineRoute", "line_route",
    "capped_profile", "ScenarioSpec", "draw_scenario", "true_params", "stack_message_age_s", "follower_stacks_for", "start_speed_limit", "initial_gaps",
    "spec_columns",
]
