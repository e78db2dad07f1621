"""Offline closed-loop convoy simulator (no SUMO): n trains, a leader profile, T2T channel, any controller.

Each train is a :class:`~vcsumo.plant.TrainPlant` (eq. 1 of the train model, explicit Euler, force
lag, jerk limit) with parameters from its rolling-stock file.  Train 0 is the convoy leader and
follows a :class:`SpeedProfile` (P speed tracker with the profile's slope as feed-forward), a
:class:`ForceProfile`, or any callable ``t -> target speed``.  Trains 1..n−1 are driven by
controllers built by ``controller_factory(train_id)`` implementing
:class:`~vcsumo.control.base.Controller`; each sees an :class:`~vcsumo.control.base.Observation`
whose ``received`` holds only what the :class:`~vcsumo.control.channel.Channel` delivered (seeded
delay/loss, every train broadcasting its state every ``channel_cfg.period_s``), plus the on-board
sensed gap and predecessor speed.

Within a step at time t: every due train sends its state (stamped t); the channel delivers; the
leader and the controllers compute their commands; one row per train is recorded; the plants
advance by dt.

Faults: every follower's controller runs inside a :class:`~vcsumo.control.faults.FaultStage` (the
same stage as in the SUMO loop): a controller that raises, returns a non-finite force or reports an
infeasible problem without a usable fallback, or an observation holding a non-finite state, gives
that follower the emergency brake (mode ``fault-emergency``) until the data and the controller have
been valid for ``recovery_s``.  The events are in ``df.attrs["faults"]`` (rows of ``faults.csv``,
:data:`~vcsumo.control.faults.FAULT_COLUMNS`) and appended to ``fault_log`` when given.

    >>> df = simulate_convoy(["etr1000"] * 4, lambda tid: ConsensusController(),
    ...                      SpeedProfile((0, 600), (50, 50)), 300.0, 0.1, None, [150, 150, 150])
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence, Union

import numpy as np
import pandas as pd

from vcsumo.control.base import Controller, Message, Observation, TrainStateMsg
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.faults import FaultEvent, FaultStage, faults_frame
from vcsumo.dynamics import TrainParams, gradient_force, running_resistance
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile

COLUMNS = ["time_s", "train", "position_m", "speed_mps", "accel_mps2", "force_n", "gap_m", "force_cmd_n", "gap_ref_m", "mode"]


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


@dataclass(frozen=True)
class ForceProfile:
    """Piecewise-linear traction/brake force of the leader, N (clipped by the plant's envelope)."""

    times_s: Sequence[float]
    forces_n: Sequence[float]

    def force_n(self, t: float) -> float:
        return float(np.interp(t, self.times_s, self.forces_n))


LeaderProfile = Union[SpeedProfile, ForceProfile, Callable[[float], float]]


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


def simulate_convoy(
    stock_names: Sequence[str],
    controller_factory: Callable[[str], Controller],
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
    """Simulate a convoy and return a tidy DataFrame (one row per train and recorded step).

    Parameters
    ----------
    stock_names: rolling-stock names (or YAML paths), leader first.
    controller_factory: ``train_id -> Controller`` for each follower (called once per follower).
    leader_profile: :class:`SpeedProfile`, :class:`ForceProfile` or ``t -> target speed (m/s)``.
    duration_s, dt: simulated time and step, s.
    channel_cfg: T2T channel (None: ideal, messages every step).
    initial_gaps_m: front-to-rear gap of each follower to its predecessor at t = 0, m (n−1 values).
    initial_speeds_mps: every train's initial speed (default: the leader profile's speed at t = 0).
    profile: the route (default: a level straight line long enough, 100 m/s limit).
    train_ids: ids (default ``T0..T{n−1}``).
    channel: a ready :class:`~vcsumo.control.channel.Channel` to use instead of one built from
        ``channel_cfg`` (e.g. one that injects corrupted messages).
    fault_handling: wrap every follower's controller in a :class:`~vcsumo.control.faults.FaultStage`
        (False: the controller's command goes to the plant as it is, exceptions propagate).
    recovery_s: the fault stage's latch, s (valid data and commands needed before it releases).
    fault_log: a list the fault events are appended to.

    Columns: time_s, train, position_m (front), speed_mps, accel_mps2, force_n (force applied by the
    plant), gap_m (front-to-rear to the predecessor, NaN for the leader), force_cmd_n (controller
    output before the plant's envelope/jerk/lag), gap_ref_m (the controller's reference, if it
    reports ``info['gap_ref_m']``), mode.
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
    params = [load_rolling_stock(s).params() for s in stock_names]
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
    plants = [
        TrainPlant(p, PlantState(s, v, steady_force(p, v, profile, s), 0.0), profile, apply_lag=apply_lag, apply_jerk=apply_jerk)
        for p, s, v in zip(params, positions, v_init)
    ]
    controllers: dict[str, Controller] = {ids[k]: controller_factory(ids[k]) for k in range(1, n)}
    if fault_handling:
        controllers = {tid: FaultStage(c, params[ids.index(tid)], train_id=tid, recovery_s=recovery_s) for tid, c in controllers.items()}
    convoy = tuple(ids)
    steps = int(round(duration_s / dt))
    rows: list[tuple] = []
    for k in range(steps + 1):
        t = k * dt
        for idx, tid in enumerate(ids):
            if channel.due(tid, t):
                x = plants[idx].x
                msg = Message(tid, t, TrainStateMsg(t, x.s_m, x.v_mps, x.accel_mps2, x.force_n), params[idx].length_m)
                channel.send(msg, [r for r in ids if r != tid], t)
        commands: list[float] = []
        refs: list[float] = []
        modes: list[str] = []
        lead = plants[0]
        commands.append(_leader_force(leader_profile, params[0], lead.x, profile, t))
        refs.append(np.nan)
        modes.append("leader")
        for idx in range(1, n):
            tid = ids[idx]
            x = plants[idx].x
            ahead = plants[idx - 1].x
            obs = Observation(
                time_s=t, step_s=dt, ego_id=tid, ego=TrainStateMsg(t, x.s_m, x.v_mps, x.accel_mps2, x.force_n), params=params[idx],
                profile=profile, received=channel.deliver(tid, t), predecessor=ids[idx - 1], convoy=convoy,
                sensed_gap_m=ahead.s_m - params[idx - 1].length_m - x.s_m, sensed_speed_mps=ahead.v_mps,
            )
            cmd = controllers[tid].make_step(obs)
            commands.append(float(cmd.force_n))
            refs.append(float(cmd.info.get("gap_ref_m", np.nan)) if isinstance(cmd.info, dict) else np.nan)
            modes.append(cmd.mode)
        if k % record_every == 0:
            for idx, tid in enumerate(ids):
                x = plants[idx].x
                gap = np.nan if idx == 0 else plants[idx - 1].x.s_m - params[idx - 1].length_m - x.s_m
                rows.append((t, tid, x.s_m, x.v_mps, x.accel_mps2, x.force_n, gap, commands[idx], refs[idx], modes[idx]))
        if k == steps:
            break
        for idx in range(n):
            plants[idx].step(commands[idx], dt)
    df = pd.DataFrame.from_records(rows, columns=COLUMNS)
    events = [e for c in controllers.values() if isinstance(c, FaultStage) for e in c.events]
    if fault_log is not None:
        fault_log.extend(events)
    df.attrs["faults"] = faults_frame(events).to_dict("records")
    return df


def _initial_speed(lp: LeaderProfile) -> float:
    if isinstance(lp, SpeedProfile):
        return lp.speed_mps(0.0)
    if isinstance(lp, ForceProfile):
        return 0.0
    return float(lp(0.0))


def _leader_force(lp: LeaderProfile, p: TrainParams, x: PlantState, profile: RouteProfile, t: float) -> float:
    if isinstance(lp, ForceProfile):
        return lp.force_n(t)
    if isinstance(lp, SpeedProfile):
        v_ref, a_ff, gain = lp.speed_mps(t), lp.accel_mps2(t), lp.gain_per_s
    else:
        v_ref, a_ff, gain = float(lp(t)), 0.0, 0.5
    a = a_ff + gain * (v_ref - x.v_mps)
    return p.mass_kg * p.rotating_mass_factor * a + steady_force(p, x.v_mps, profile, x.s_m)


def gap_errors(df: pd.DataFrame) -> pd.DataFrame:
    """Add ``gap_error_m`` = gap_m − gap_ref_m (followers) to a :func:`simulate_convoy` frame."""
    out = df.copy()
    out["gap_error_m"] = out["gap_m"] - out["gap_ref_m"]
    return out
