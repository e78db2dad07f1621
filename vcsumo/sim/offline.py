"""The offline closed loop (no SUMO): train plants, a T2T channel, the leader's driver and every follower's stack.

One loop (:func:`run_convoy`) serves the safety campaign (:mod:`vcsumo.studies.safety`), the paper
reproductions (:mod:`vcsumo.reproduce.felez2019`, :mod:`vcsumo.reproduce.terlizzi2024`), the
convoy experiments and the tests.  Each train is an :class:`OfflineTrain`: a
:class:`~vcsumo.plant.TrainPlant` (eq. 1 of the train model, explicit Euler, force lag, jerk
limit) with its *true* parameters, the nominal model its controllers see, and a driver with the
controller verb ``make_step(obs) -> Command``:

* the convoy **leader** (train 0) is driven by a :class:`SpeedProfile` (P speed tracker with the
  profile's slope as feed-forward), a :class:`ForceProfile`, a :class:`SpeedFunction`, a
  controller of its own (e.g. the leader NMPC), and events — :class:`EmergencyBrake` applies the
  full emergency brake from a given time and holds it;
* every **follower** is driven by the same :class:`~vcsumo.control.stack.FollowerStack` the SUMO
  loop uses, built by name in :mod:`vcsumo.control.registry` (:func:`follower_stacks`): nominal
  controller → supervisor → separation guard → fault stage.

Within a step at time t:

1. ``stop_when(t, states)`` may end the run (true states, before anything else);
2. measured positions: true ones, or with the odometry error of an :class:`Odometry` (Felez eq. 9);
3. every due train that sends broadcasts its state (stamped t, measured position) with a predicted
   trajectory — its ``plan`` hook's, else (``send_plans``) its last command's — to every other train
   over the seeded :class:`~vcsumo.control.channel.Channel`;
4. every driver gets an :class:`~vcsumo.control.base.Observation`: its measured state, what the
   channel has delivered to it (with ``known_at_start`` a follower also knows its predecessor's
   state at t = 0), and the on-board sensed gap and speed of its predecessor;
5. ``on_step`` sees the step; a row per train is recorded every ``record_every`` steps;
6. the plants advance by dt.  A command flagged ``emergency`` (the leader's emergency brake, a
   fault, the CBF's K_E^F, a guard intervention beyond the service brake) is applied with the
   plant's emergency brake (``emergency_brake=False``: the service envelope only, as in the papers'
   own simulations); a non-finite force is the full emergency brake.

Faults are the stacks' (the fault stage's events, in ``OfflineRun.faults``).

    >>> run = run_convoy(trains, flat_profile(20000.0), 0.2, 300.0)           # doctest: +SKIP
    >>> df = simulate_convoy(["etr1000"] * 3, "cbf-cbc", SpeedProfile((0, 600), (50, 50)), 300.0, 0.2, None, [1500, 1500])  # doctest: +SKIP
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence, Union

import numpy as np
import pandas as pd

from vcsumo.control.base import Command, Controller, Message, Observation, TrainStateMsg
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.faults import FaultEvent, FaultStage, faults_frame
from vcsumo.dynamics import TrainParams, gradient_force, running_resistance
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import RollingStock, load_rolling_stock
from vcsumo.route_profile import RouteProfile

COLUMNS = ["time_s", "train", "position_m", "speed_mps", "accel_mps2", "force_n", "gap_m", "force_cmd_n", "gap_ref_m", "mode", "emergency", "infeasible"]
"""Columns of the recorded frame: time_s, train, position_m (true front, m), speed_mps, accel_mps2,
force_n (force applied by the plant, N), gap_m (true front-to-rear gap to the predecessor, m; NaN
for the leader), force_cmd_n (the driver's command before the plant's envelope, lag and jerk, N),
gap_ref_m (the controller's reference if it reports ``info['gap_ref_m']``, m), mode, emergency,
infeasible."""


# -------------------------------------------------------------------------------------------
# Leader drivers


@dataclass(frozen=True)
class SpeedProfile:
    """Piecewise-linear target speed of the leader, tracked by a P law with the slope as feed-forward."""

    times_s: Sequence[float]
    speeds_mps: Sequence[float]
    gain_per_s: float = 0.5

    def speed_mps(self, t: float) -> float:
        return float(np.interp(t, self.times_s, self.speeds_mps))

    def accel_mps2(self, t: float) -> float:
        ts, vs = np.asarray(self.times_s, float), np.asarray(self.speeds_mps, float)
        k = int(np.searchsorted(ts, t, side="right")) - 1
        if k < 0 or k >= len(ts) - 1:
            return 0.0
        return float((vs[k + 1] - vs[k]) / (ts[k + 1] - ts[k]))

    def make_step(self, obs: Observation) -> Command:
        return Command(tracking_force(obs, self.speed_mps(obs.time_s), self.accel_mps2(obs.time_s), self.gain_per_s), mode="leader")


@dataclass(frozen=True)
class ForceProfile:
    """Piecewise-linear traction/brake force of the leader, N (clipped by the plant's envelope)."""

    times_s: Sequence[float]
    forces_n: Sequence[float]

    def force_n(self, t: float) -> float:
        return float(np.interp(t, self.times_s, self.forces_n))

    def make_step(self, obs: Observation) -> Command:
        return Command(self.force_n(obs.time_s), mode="leader")


@dataclass(frozen=True)
class SpeedFunction:
    """Any ``t -> target speed`` (m/s), tracked with the P law of :class:`SpeedProfile` (gain 0.5 1/s)."""

    fn: Callable[[float], float]
    gain_per_s: float = 0.5

    def make_step(self, obs: Observation) -> Command:
        return Command(tracking_force(obs, float(self.fn(obs.time_s)), 0.0, self.gain_per_s), mode="leader")


@dataclass
class EmergencyBrake:
    """``driver`` until ``at_s``, then the full emergency brake, held (an event of the scenario).

    The command is ``-inf`` N flagged ``emergency``: the plant brakes with its emergency brake at
    the rate of its (true) parameters, built up through its lag and jerk limit."""

    driver: Controller
    at_s: float

    def make_step(self, obs: Observation) -> Command:
        if obs.time_s >= self.at_s - 1e-9:
            return Command(-math.inf, mode="emergency", emergency=True)
        return self.driver.make_step(obs)


LeaderProfile = Union[SpeedProfile, ForceProfile, Callable[[float], float]]


def leader_driver(lp) -> Controller:
    """A leader driver from a :class:`SpeedProfile`, :class:`ForceProfile`, controller or ``t -> speed``."""
    if hasattr(lp, "make_step"):
        return lp
    if callable(lp):
        return SpeedFunction(lp)
    raise TypeError(f"not a leader profile: {lp!r}")


def tracking_force(obs: Observation, v_ref: float, a_ff: float, gain_per_s: float) -> float:
    """M·ρ·(a_ff + k·(v_ref − v)) + the steady force at the train's state (eq. 1b with the model of ``obs.params``), N."""
    p = obs.params
    a = a_ff + gain_per_s * (v_ref - obs.ego.speed_mps)
    return p.mass_kg * p.rotating_mass_factor * a + steady_force(p, obs.ego.speed_mps, obs.profile, obs.ego.position_m)


def flat_profile(length_m: float, speed_limit_mps: float = 100.0, gradient: float = 0.0) -> RouteProfile:
    """A single straight, level (or constant-gradient) open-air route of ``length_m``."""
    return RouteProfile(
        edges=["convoy_sim"], starts_m=np.array([0.0]), lengths_m=np.array([float(length_m)]), speeds_ms=np.array([float(speed_limit_mps)]),
        gradients=np.array([float(gradient)]), tunnel_factors=np.array([1.0]), sections=["convoy_sim"], km_from=np.array([0.0]),
        km_to=np.array([length_m / 1000.0]), point_limits=[],
    )


def steady_force(p: TrainParams, v: float, profile: RouteProfile, s: float) -> float:
    """Force that holds speed v at position s: running resistance + gradient over the train (eq. 1b with a = 0), N."""
    return float(running_resistance(p, v, profile.tunnel_factor_at(s)) + gradient_force(p, profile.mean_gradient(s, p.length_m)))


# -------------------------------------------------------------------------------------------
# The loop


PlanHook = Callable[[float, float, float], "tuple | None"]
"""``(t, measured position, speed) -> (times_s, positions_m, speeds_mps, forces_n)`` or None: the
predicted trajectory a train broadcasts with its state."""


@dataclass
class OfflineTrain:
    """One train of the offline loop."""

    id: str
    params: TrainParams
    """The plant's (true) parameters."""
    state: PlantState
    """Initial state."""
    driver: Controller
    """``make_step(obs) -> Command``: a leader driver or a follower's stack."""
    nominal: TrainParams | None = None
    """The model in the train's Observation (default: ``params``)."""
    sends: bool = True
    """Broadcasts its state over the channel."""
    plan: PlanHook | None = None
    """The predicted trajectory it broadcasts (None: its last command's, if ``send_plans``)."""
    target_speed_mps: float | None = None
    """``Observation.target_speed_mps``."""


@dataclass
class Odometry:
    """Position measurement with the error of Felez eq. 9: a bias per train and a noise, each within ±e_s/2."""

    bias_m: Sequence[float]
    noise_bound_m: float
    rng: np.random.Generator

    def measure(self, i: int, s_m: float) -> float:
        return s_m + self.bias_m[i] + self.rng.uniform(-0.5 * self.noise_bound_m, 0.5 * self.noise_bound_m)


@dataclass
class OfflineStep:
    """What ``on_step`` sees: the step's true states (before the plants advance), measured
    positions, the observations (their ``received``) and the commands, indexed like the trains."""

    k: int
    time_s: float
    states: list[PlantState]
    measured_m: list[float]
    observations: list[Observation]
    commands: list[Command]


@dataclass
class OfflineRun:
    """The result of :func:`run_convoy`."""

    frame: pd.DataFrame
    """Recorded rows (:data:`COLUMNS`)."""
    faults: list[FaultEvent]
    end_time_s: float
    """Time of the last step run, s."""
    emergency_activations: dict[str, int] = field(default_factory=dict)
    """Per train: rising edges of an ``emergency`` command."""
    emergency_time_s: dict[str, float] = field(default_factory=dict)
    """Per train: time under an ``emergency`` command, s."""
    channel: Channel | None = None
    plants: list[TrainPlant] = field(default_factory=list)


def run_convoy(trains: Sequence[OfflineTrain], profile: RouteProfile, dt: float, duration_s: float, *, channel: Channel | None = None,
               send_plans: bool = True, odometry: Odometry | None = None, known_at_start: bool = False, apply_lag: bool = True,
               apply_jerk: bool = True, record_every: int = 1, emergency_brake: bool = True,
               stop_when: Callable[[float, list[PlantState]], bool] | None = None, on_step: Callable[[OfflineStep], None] | None = None) -> OfflineRun:
    """Run the trains (leader first, each follower behind the previous one) for ``duration_s`` (see the module doc).

    ``channel``: a ready channel (default: ideal, every train every step); ``record_every``: record
    every k-th step (0: nothing); the other options as in the module doc."""
    n = len(trains)
    if n < 1:
        raise ValueError("need at least one train")
    ids = [tr.id for tr in trains]
    if len(set(ids)) != n:
        raise ValueError("train ids must be distinct")
    plants = [TrainPlant(tr.params, tr.state, profile, apply_lag=apply_lag, apply_jerk=apply_jerk) for tr in trains]
    models = [tr.nominal or tr.params for tr in trains]
    lengths = [p.length_m for p in models]
    true_len = [tr.params.length_m for tr in trains]
    channel = channel or Channel(ChannelConfig(period_s=dt))
    convoy = tuple(ids)
    others = [[r for r in ids if r != ids[i]] for i in range(n)]
    last: list[Command | None] = [None] * n
    known: dict[int, Message] = {}
    in_em = [False] * n
    activations = [0] * n
    em_steps = [0] * n
    rows: list[tuple] = []
    steps = int(round(duration_s / dt))
    t = 0.0
    for k in range(steps + 1):
        t = k * dt
        xs = [pl.x for pl in plants]
        if stop_when is not None and stop_when(t, xs):
            break
        meas = [odometry.measure(i, x.s_m) for i, x in enumerate(xs)] if odometry is not None else [x.s_m for x in xs]
        if k == 0 and known_at_start:
            known = {i: Message(ids[i - 1], t, TrainStateMsg(t, meas[i - 1], xs[i - 1].v_mps, xs[i - 1].accel_mps2, xs[i - 1].force_n), lengths[i - 1],
                                received_time_s=t) for i in range(1, n)}
        for i, tr in enumerate(trains):
            if not tr.sends or not channel.due(ids[i], t):
                continue
            x = xs[i]
            plan = None
            if tr.plan is not None:
                plan = tr.plan(t, meas[i], x.v_mps)
            elif send_plans and last[i] is not None and last[i].plan_times_s is not None:
                c = last[i]
                plan = (c.plan_times_s, c.plan_positions_m, c.plan_speeds_mps, c.plan_forces_n)
            st = TrainStateMsg(t, meas[i], x.v_mps, x.accel_mps2, x.force_n)
            msg = Message(ids[i], t, st, lengths[i]) if plan is None else Message(ids[i], t, st, lengths[i], *plan)
            channel.send(msg, others[i], t)
        cmds: list[Command] = []
        obss: list[Observation] = []
        for i, tr in enumerate(trains):
            x = xs[i]
            received = channel.deliver(ids[i], t)
            if i in known:
                received = {ids[i - 1]: known[i], **received}
            obs = Observation(
                time_s=t, step_s=dt, ego_id=ids[i], ego=TrainStateMsg(t, meas[i], x.v_mps, x.accel_mps2, x.force_n), params=models[i],
                profile=profile, received=received, predecessor=ids[i - 1] if i else None, convoy=convoy,
                sensed_gap_m=meas[i - 1] - lengths[i - 1] - meas[i] if i else None, sensed_speed_mps=xs[i - 1].v_mps if i else None,
                target_speed_mps=tr.target_speed_mps,
            )
            cmd = tr.driver.make_step(obs)
            cmds.append(cmd)
            obss.append(obs)
            if cmd.emergency:
                em_steps[i] += 1
                if not in_em[i]:
                    activations[i] += 1
            in_em[i] = cmd.emergency
        if on_step is not None:
            on_step(OfflineStep(k, t, xs, meas, obss, cmds))
        if record_every and k % record_every == 0:
            for i in range(n):
                x, c = xs[i], cmds[i]
                gap = np.nan if i == 0 else xs[i - 1].s_m - true_len[i - 1] - x.s_m
                ref = float(c.info.get("gap_ref_m", np.nan)) if isinstance(c.info, dict) else np.nan
                rows.append((t, ids[i], x.s_m, x.v_mps, x.accel_mps2, x.force_n, gap, float(c.force_n), ref, c.mode, bool(c.emergency), bool(c.infeasible)))
        if k == steps:
            break
        for i in range(n):
            c = cmds[i]
            u = float(c.force_n)
            finite = math.isfinite(u)
            plants[i].step(u if finite else -math.inf, dt, emergency=emergency_brake and (c.emergency or not finite))
        last = cmds
    events = [e for tr in trains for e in (getattr(tr.driver, "events", None) or [])]
    return OfflineRun(
        frame=pd.DataFrame.from_records(rows, columns=COLUMNS), faults=events, end_time_s=t,
        emergency_activations=dict(zip(ids, activations)), emergency_time_s={ids[i]: em_steps[i] * dt for i in range(n)},
        channel=channel, plants=plants,
    )


# -------------------------------------------------------------------------------------------
# Stacks by name, and the convoy of rolling-stock names


def follower_stacks(controller: str, stocks: Sequence[RollingStock], ids: Sequence[str], step_s: float, profile: RouteProfile | None = None, **context) -> list:
    """The registry's stack for every follower of a convoy (``stocks``/``ids`` leader first);
    ``context``: further :class:`~vcsumo.control.registry.StackContext` fields."""
    from vcsumo.control.registry import StackContext, build_follower_stack

    return [build_follower_stack(controller, StackContext(ego=stocks[k], predecessor=stocks[k - 1], step_s=step_s, profile=profile, ego_id=ids[k],
                                                          predecessor_id=ids[k - 1], **context)) for k in range(1, len(stocks))]


def simulate_convoy(
    stock_names: Sequence[str],
    controller_factory: Callable[[str], Controller] | str,
    leader_profile: LeaderProfile,
    duration_s: float,
    dt: float = 0.1,
    channel_cfg: ChannelConfig | None = None,
    initial_gaps_m: Sequence[float] | None = None,
    *,
    initial_speeds_mps: Sequence[float] | None = None,
    profile: RouteProfile | None = None,
    train_ids: Sequence[str] | None = None,
    leader_position_m: float | None = None,
    apply_lag: bool = True,
    apply_jerk: bool = True,
    record_every: int = 1,
    channel: Channel | None = None,
    fault_handling: bool = True,
    recovery_s: float = 1.0,
    fault_log: list[FaultEvent] | None = None,
) -> pd.DataFrame:
    """Simulate a convoy of rolling-stock names (exact parameters) and return the tidy frame (:data:`COLUMNS`).

    Parameters
    ----------
    stock_names: rolling-stock names (or YAML paths), leader first.
    controller_factory: a registered controller name (every follower gets the registry's stack:
        supervisor, guard and fault stage included), or ``train_id -> Controller`` for each
        follower (called once per follower; then no guard — the controller alone, in a fault stage).
    leader_profile: :class:`SpeedProfile`, :class:`ForceProfile`, a leader driver (e.g.
        :class:`EmergencyBrake`) or ``t -> target speed (m/s)``.
    duration_s, dt: simulated time and step, s.
    channel_cfg: T2T channel (None: ideal, messages every step).
    initial_gaps_m: front-to-rear gap of each follower to its predecessor at t = 0, m (n−1 values).
    initial_speeds_mps: every train's initial speed (default: the leader profile's speed at t = 0).
    profile: the route (default: a level straight line long enough, 100 m/s limit).
    train_ids: ids (default ``T0..T{n−1}``).
    channel: a ready :class:`~vcsumo.control.channel.Channel` to use instead of one built from
        ``channel_cfg`` (e.g. one that injects corrupted messages).
    fault_handling: wrap a factory's controllers in a :class:`~vcsumo.control.faults.FaultStage`
        (False: the controller's command goes to the plant as it is, exceptions propagate).
    recovery_s: the fault stage's latch, s (valid data and commands needed before it releases).
    fault_log: a list the fault events are appended to.

    The fault events are also in ``df.attrs["faults"]`` (rows of ``faults.csv``).
    """
    n = len(stock_names)
    if n < 1:
        raise ValueError("need at least one train")
    ids = list(train_ids) if train_ids is not None else [f"T{k}" for k in range(n)]
    if len(ids) != n or len(set(ids)) != n:
        raise ValueError("train_ids must be n distinct ids")
    gaps = list(initial_gaps_m) if initial_gaps_m is not None else []
    if len(gaps) != n - 1:
        raise ValueError(f"initial_gaps_m needs {n - 1} values (one per follower)")
    stocks = [load_rolling_stock(s) for s in stock_names]
    params = [s.params() for s in stocks]
    driver0 = leader_driver(leader_profile)
    v_init = list(initial_speeds_mps) if initial_speeds_mps is not None else [_initial_speed(leader_profile)] * n
    if len(v_init) != n:
        raise ValueError("initial_speeds_mps needs one value per train")
    if channel is None:
        channel = Channel(channel_cfg or ChannelConfig(period_s=dt))
    span = sum(p.length_m for p in params[:-1]) + sum(gaps)
    x0 = leader_position_m if leader_position_m is not None else span + params[-1].length_m + 10.0
    if profile is None:
        profile = flat_profile(x0 + 100.0 * duration_s + 1000.0)
    positions = [x0]
    for k in range(1, n):
        positions.append(positions[-1] - params[k - 1].length_m - gaps[k - 1])
    if isinstance(controller_factory, str):
        drivers = follower_stacks(controller_factory, stocks, ids, dt, profile, recovery_s=recovery_s, message_age_s=channel.cfg.age_budget_s())
    else:
        drivers = [controller_factory(ids[k]) for k in range(1, n)]
        if fault_handling:
            drivers = [FaultStage(c, params[k + 1], train_id=ids[k + 1], recovery_s=recovery_s) for k, c in enumerate(drivers)]
    trains = [OfflineTrain(ids[k], params[k], PlantState(positions[k], v_init[k], steady_force(params[k], v_init[k], profile, positions[k]), 0.0),
                           driver0 if k == 0 else drivers[k - 1]) for k in range(n)]
    run = run_convoy(trains, profile, dt, duration_s, channel=channel, apply_lag=apply_lag, apply_jerk=apply_jerk, record_every=record_every)
    df = run.frame
    if fault_log is not None:
        fault_log.extend(run.faults)
    df.attrs["faults"] = faults_frame(run.faults).to_dict("records")
    return df


def _initial_speed(lp) -> float:
    if isinstance(lp, EmergencyBrake):
        return _initial_speed(lp.driver)
    if isinstance(lp, SpeedProfile):
        return lp.speed_mps(0.0)
    if isinstance(lp, SpeedFunction):
        return float(lp.fn(0.0))
    if isinstance(lp, ForceProfile) or hasattr(lp, "make_step"):
        return 0.0
    return float(lp(0.0))


def gap_errors(df: pd.DataFrame) -> pd.DataFrame:
    """Add ``gap_error_m`` = gap_m − gap_ref_m (followers) to a :func:`simulate_convoy` frame."""
    out = df.copy()
    out["gap_error_m"] = out["gap_m"] - out["gap_ref_m"]
    return out


__all__ = [
    "COLUMNS", "SpeedProfile", "ForceProfile", "SpeedFunction", "EmergencyBrake", "LeaderProfile", "leader_driver", "tracking_force", "flat_profile",
    "steady_force", "OfflineTrain", "Odometry", "OfflineStep", "OfflineRun", "run_convoy", "follower_stacks", "simulate_convoy", "gap_errors",
]
