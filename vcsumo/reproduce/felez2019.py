"""Reproduction of Felez, Kim & Borrelli (2019), §IV-A: the test environment (Fig. 10, 11, 12).

Set-up
------
* Straight level track, line limit 27.78 m/s (Fig. 8).  The leader starts at rest at the
  origin, accelerates towards the objective speed v_max = 20 m/s and stops 3,700 m from the
  origin with a full emergency braking.  Followers start at rest, d_min behind each other (as
  in §IV-B).
* Every train is the ``felez2019`` rolling stock (Table II: M, L, A, B, T_f·C, τ, P_dr, P_br,
  a_dr, a_br, j_max) integrated by :class:`vcsumo.plant.TrainPlant` (eq. 6b with the force lag
  1c and the jerk limit |F_{k+1} − F_k| ≤ j_max·M·Δt, Δt = 0.1 s) — the NMPC's own model and
  constraint 12o, so the plant clips nothing the NMPC plans.
* Leader: :class:`~vcsumo.control.mpc.LeaderMPC` (eq. 11), v_max = 20 m/s, its DP terminal set
  (eq. 10, 11i) ending at rest at 3,700 m.  For the "full emergency braking" its NMPC plans with
  the emergency brake — no brake-power limit and a force limit that gives at most a^l = 1.25 m/s²
  in total — so the braking is in the plan it communicates (``leader_braking="mpc-emergency"``).
* Followers: :class:`~vcsumo.control.mpc.FollowerMPC` (eq. 12) with the SH (eq. 16: the
  predecessor's plan from t−1, resampled, anchored at the sensed state), NP (eq. 17 from the
  sensed state) or MB (eq. 18) predictor.  Table II parameters: N_p = 40, d_des = 10 m,
  d_min = 4 m (= d_0 + 2·e_s), K_V = 100, K_J = 0.5, K_D = 100, a^l = 1.25 m/s²
  (``controllers/mpc_felez2019.yaml``).

What is compared with the paper
-------------------------------
``stop_distance_m`` is the following distance at the onset of the leader's stop (its emergency
braking) — the distance the convoy keeps while running into the stop, the largest of the run;
this is what the paper's 28.5 / 208.3 / 352.4 m are (MB matches to 0.1 m).  The gap once both
trains are at rest is reported as ``gap_at_rest_m``: it is 4.6–5.5 m for *every* strategy, because
once the leader stands the follower's cost 12a pulls it towards d_des = 10 m and nothing holds it
back, so it closes up to between d_min and d_des — the paper's numbers cannot be rest gaps.
``stop_delay_s`` is the time the follower comes to rest minus the time the leader does.

a^f (eq. 12m) — not given for §IV-A
----------------------------------
The paper studies a^f ∈ [0.5, 1.0] m/s² (0.5: service braking limited to 50 %).  Its three
distances are not consistent with one a^f under eq. 12m:

* MB 352.4 m is exactly our steady MB distance with a^f = 0.5 (352.4 m; 263 m with a^f = 0.75);
* NP 208.3 m also needs a^f ≈ 0.5 (194 m with 0.5, 103 m with 0.75);
* SH 28.5 m is impossible with a^f = 0.5: at 20 m/s, 12m needs
  d_N ≥ d_min + v_N²/(2a^f) − v̄_l²/(2a^l) = 4 + v_N² − 160 m, and in the 4 s horizon the train
  sheds at most ≈ 3.7 m/s (0.94 m/s² at 20 m/s with P_br), so d ≥ 4 + 16.3² − 160 ≈ 110 m (we
  get 115 m).  28.5 m requires a^f ≳ 0.71.

We therefore use a^f = 0.75 for SH and 0.5 for NP and MB (``a_follower_by_strategy_mps2``), all
inside the paper's range.  a^f = 1.0 is not used: this train cannot guarantee 1 m/s² at speed
(0.94 m/s² at 20 m/s, plus the jerk-limited ramp), and with it the followers end up infeasible
and below d_min.

Results (N_p = 40, two trains; paper in brackets)
--------------------------------------------------
=========  ====  ===================  ============  ==========  =======
strategy   a^f   distance m           delay s       rest gap m  min gap
=========  ====  ===================  ============  ==========  =======
SH         0.75  24.5   (28.5, −14 %)  3.0  (2)     4.6         4.0
NP         0.50  194.0  (208.3, −7 %)  13.4 (17)    5.5         4.0
MB         0.50  352.4  (352.4, 0 %)   21.5 (23)    5.5         4.0
=========  ====  ===================  ============  ==========  =======

No collision, no infeasible step; the leader stops at 3,700.0 m.  With one a^f for all:
a^f = 0.5 gives 115.0 / 194.0 / 352.4 m, a^f = 0.75 gives 24.5 / 103.4 / 263.0 m (order kept,
SH resp. NP and MB off the paper).  With the leader's service brake instead of the emergency
brake (``leader_braking="mpc"``) the distances are the same and the delays 2.5 / 12.8 / 20.8 s.
An *unannounced* emergency stop (``leader_braking="emergency"``: the leader's plan does not
contain it) ends in a collision with SH and a^f = 0.75 (NP and MB stay safe): the terminal set
12m covers braking of the leader only after the horizon, so SH relies on the leader honouring
the plan it sent.

Fig. 11 (SH, :func:`horizon_sweep`): N_p = 20 / 30 / 40 / 50 / 60 gives 74.5 / 49.3 / 24.5 /
9.8 / 8.2 m and a mean solve time of 0.30 / 0.32 / 0.51 / 0.68 / 0.90 ms: as in the paper the
distance falls and the computing time grows with the horizon (a longer horizon lets the follower
plan its own braking before the end of the horizon, so 12m binds later).

Fig. 10 (four trains, SH, :func:`convoy`): running distances 24.5 / 79.4 / 79.7 m, stop delays
3.0 / 7.5 / 11.8 s, every gap ≥ d_min, no infeasible step.  Trains 3 and 4 keep larger
distances than train 2 because their predecessor's plan (a follower's) ends decelerating — it
plans the braking that 12m asks of it at the end of its horizon — so v̄^l_N in their 12m is
lower than a leader's.

Other differences from the paper: the prediction model uses the force after the lag in the
step, as TrainPlant does; v ≥ 0 is a smooth max (ε = 0.01 m/s); the terminal set is the DP
boundary also computed for the time-discrete model with 98 % of the brake and shifted by the
force ramp (see :mod:`vcsumo.control.mpc`); the NMPC is solved by real-time SQP iterations, not
to optimality each step.  The paper's computation time (Table I: 709 s for two trains) is not
comparable: here one run takes 3–5 s (≈ 0.6 ms per NMPC solve).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from vcsumo.control.base import Message, Observation, TrainStateMsg
from vcsumo.control.dp_profile import straight_route_profile
from vcsumo.control.mpc import FollowerMPC, LeaderMPC, MPCSettings, load_mpc_settings
from vcsumo.dynamics import TrainParams, running_resistance
from vcsumo.line import project_root
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import load_rolling_stock

PAPER = {
    "SH": {"stop_distance_m": 28.5, "stop_delay_s": 2.0},
    "NP": {"stop_distance_m": 208.3, "stop_delay_s": 17.0},
    "MB": {"stop_distance_m": 352.4, "stop_delay_s": 23.0},
}
"""Values reported in §IV-A.3 (Fig. 12) of the paper."""


def default_settings_path() -> Path:
    return project_root() / "controllers" / "mpc_felez2019.yaml"


@dataclass(frozen=True)
class Scenario:
    """The §IV-A test environment."""

    settings: MPCSettings
    train: str = "felez2019"
    speed_limit_mps: float = 27.78
    """Line speed limit of the test track (Fig. 8), m/s."""
    objective_speed_mps: float = 20.0
    """The leader's objective speed v_max (Fig. 8), m/s."""
    stop_from_origin_m: float = 3700.0
    """The leader stops this far from its start, m."""
    origin_m: float = 400.0
    """Route position of the leader's start (room behind it for the followers), m."""
    initial_gap_m: float | None = None
    """Gap between consecutive trains at rest at t = 0 (None: d_min, as in §IV-B), m."""
    leader_braking: str = "mpc-emergency"
    """How the leader stops at ``stop_from_origin_m`` ("a full emergency braking", §IV-A):

    * ``mpc-emergency`` (default): its NMPC (eq. 11) plans the stop with the emergency brake
      (no brake-power limit, force limit M·a^l − R(v_max): at most a^l = 1.25 m/s² in total, the
      deceleration the followers assume) through the DP terminal set, so the braking is in the
      plan it communicates (SH);
    * ``mpc``: the same with the service brake (eq. 4a/4b of Table II);
    * ``emergency``: the NMPC only drives; at the point from which it stops there it brakes at a^l
      without having announced it (an unplanned emergency: with SH the follower learns it one
      step late).
    """
    a_follower_by_strategy_mps2: tuple[tuple[str, float], ...] = (("SH", 0.75), ("NP", 0.5), ("MB", 0.5))
    """a^f of eq. 12m per predictor (the paper does not give it for §IV-A; see the module doc)."""
    plant_jerk: bool = True
    """TrainPlant's jerk limit on the applied force (the NMPC plans within it, eq. 12o)."""
    settle_s: float = 20.0
    """Simulated time after the last train has stopped, s."""
    max_time_s: float = 600.0


def load_scenario(settings_path: str | Path | None = None, **changes) -> Scenario:
    """The scenario with the Table II parameter set (``controllers/mpc_felez2019.yaml``)."""
    settings = load_mpc_settings(settings_path or default_settings_path())
    return replace(Scenario(settings=settings), **changes)


@dataclass
class RunResult:
    """One closed-loop run: metrics and the time series."""

    metrics: dict
    trajectory: pd.DataFrame
    solve_times_s: dict = field(default_factory=dict)


def _message(sender: str, t: float, plant: TrainPlant, cmd, length_m: float) -> Message:
    st = TrainStateMsg(time_s=t, position_m=plant.x.s_m, speed_mps=plant.x.v_mps, accel_mps2=plant.x.accel_mps2, force_n=plant.x.force_n)
    if cmd is None:
        return Message(sender=sender, sent_time_s=t, state=st, length_m=length_m, received_time_s=t)
    return Message(sender=sender, sent_time_s=t, state=st, length_m=length_m, plan_times_s=cmd.plan_times_s, plan_positions_m=cmd.plan_positions_m,
                   plan_speeds_mps=cmd.plan_speeds_mps, plan_forces_n=cmd.plan_forces_n, received_time_s=t)


def simulate(strategy: str = "SH", n_trains: int = 2, horizon: int | None = None, scenario: Scenario | None = None) -> RunResult:
    """Run the leader (eq. 11) and ``n_trains − 1`` followers (eq. 12 with the ``strategy`` predictor).

    Every train is a :class:`TrainPlant` (eq. 6b with the force lag 1c) of the ``felez2019``
    rolling stock; the controllers are called through ``make_step`` with an
    :class:`Observation` each Δt.  A follower measures its predecessor's gap and speed (on-board
    sensor, §III-A) and, for SH, receives the predecessor's plan computed one step earlier
    (eq. 16: u*_{·|t−1}).
    """
    sc = scenario or load_scenario()
    update = {} if horizon is None else {"horizon_steps": int(horizon)}
    a_f = dict(sc.a_follower_by_strategy_mps2).get(strategy.upper())
    if a_f is not None:
        update["a_follower_mps2"] = float(a_f)
    cfg = sc.settings.model_copy(update=update) if update else sc.settings
    stock = load_rolling_stock(sc.train)
    params: TrainParams = stock.params()
    dt = cfg.step_s
    stop_m = sc.origin_m + sc.stop_from_origin_m
    route = straight_route_profile(stop_m, sc.speed_limit_mps)
    gap0 = cfg.d_min_m if sc.initial_gap_m is None else sc.initial_gap_m
    ids = [f"T{i}" for i in range(n_trains)]
    plants, ctrls = [], []
    emergency = sc.leader_braking == "emergency"
    if emergency:  # the NMPC's movement authority ends beyond the emergency stop
        route = straight_route_profile(stop_m + 1000.0, sc.speed_limit_mps)
    if emergency:
        lead_params = params.with_(service_brake_decel_mps2=params.emergency_brake_decel_mps2 + 0.5, max_brake_power_w=math.inf)
    elif sc.leader_braking == "mpc-emergency":
        # the NMPC plans with the emergency brake: no brake-power limit and a force limit giving a
        # total deceleration (brake + running resistance) of a^l at the objective speed, so the
        # leader never brakes harder than the a^l its followers assume (eq. 12m, 17)
        a_brake = cfg.a_leader_mps2 - float(running_resistance(params, sc.objective_speed_mps)) / params.mass_kg
        lead_params = params.with_(service_brake_decel_mps2=a_brake, max_brake_power_w=math.inf)
    else:
        lead_params = params
    for i in range(n_trains):
        s0 = sc.origin_m - i * (params.length_m + gap0)
        plants.append(TrainPlant(lead_params if i == 0 else params, PlantState(s0, 0.0, 0.0), route, apply_lag=True, apply_jerk=sc.plant_jerk))
        if i == 0:
            ctrls.append(LeaderMPC(lead_params if sc.leader_braking == "mpc-emergency" else params, cfg, route_end_m=None if emergency else stop_m))
        else:
            ctrls.append(FollowerMPC(params, cfg, predictor=strategy, route_end_m=None if emergency else stop_m))
    braking = False
    rows = []
    last_cmd = [None] * n_trains
    t = 0.0
    stopped_since = None
    moved = False
    n_steps = int(round(sc.max_time_s / dt))
    for k in range(n_steps):
        t = k * dt
        cmds = []
        for i in range(n_trains):
            pl = plants[i]
            ego = TrainStateMsg(time_s=t, position_m=pl.x.s_m, speed_mps=pl.x.v_mps, accel_mps2=pl.x.accel_mps2, force_n=pl.x.force_n)
            if i == 0:
                obs = Observation(time_s=t, step_s=dt, ego_id=ids[0], ego=ego, params=params, profile=route, convoy=tuple(ids),
                                  target_speed_mps=sc.objective_speed_mps)
                if emergency:
                    braking = braking or pl.x.s_m + _emergency_distance(pl.x.v_mps, cfg.a_leader_mps2, params, dt) >= stop_m
                    if braking:
                        cmds.append(_emergency_command(pl, params, cfg.a_leader_mps2, t, dt, cfg.horizon_steps))
                        continue
            else:
                pred = plants[i - 1]
                msg = _message(ids[i - 1], t, pred, last_cmd[i - 1], params.length_m)
                obs = Observation(time_s=t, step_s=dt, ego_id=ids[i], ego=ego, params=params, profile=route, received={ids[i - 1]: msg},
                                  predecessor=ids[i - 1], convoy=tuple(ids), sensed_gap_m=pred.x.s_m - params.length_m - pl.x.s_m,
                                  sensed_speed_mps=pred.x.v_mps, target_speed_mps=sc.objective_speed_mps)
            cmds.append(ctrls[i].make_step(obs))
        row = {"time_s": t}
        for i in range(n_trains):
            x = plants[i].x
            row[f"s{i}_m"] = x.s_m - sc.origin_m
            row[f"v{i}_mps"] = x.v_mps
            row[f"F{i}_n"] = x.force_n
            row[f"u{i}_n"] = cmds[i].force_n
            row[f"infeasible{i}"] = cmds[i].infeasible
            if i > 0:
                row[f"gap{i}_m"] = plants[i - 1].x.s_m - params.length_m - x.s_m
        rows.append(row)
        for i in range(n_trains):
            plants[i].step(cmds[i].force_n, dt)
        last_cmd = cmds
        moving = any(p.x.v_mps > 0.01 for p in plants)
        moved = moved or moving
        if moved and not moving:
            stopped_since = t if stopped_since is None else stopped_since
            if t - stopped_since >= sc.settle_s:
                break
        else:
            stopped_since = None
    traj = pd.DataFrame(rows)
    metrics = _metrics(traj, n_trains, strategy, sc)
    metrics["horizon"] = cfg.horizon_steps
    metrics["a_follower_mps2"] = cfg.a_follower_mps2
    times = {ids[i]: np.array(ctrls[i].stats.solve_times_s) for i in range(n_trains)}
    metrics["infeasible_steps"] = int(sum(c.stats.infeasible for c in ctrls))
    fol = np.concatenate([times[i] for i in ids[1:]]) if n_trains > 1 else times[ids[0]]
    metrics["solve_time_median_ms"] = float(np.median(fol) * 1e3)
    metrics["solve_time_mean_ms"] = float(np.mean(fol) * 1e3)
    metrics["solve_time_p99_ms"] = float(np.percentile(fol, 99) * 1e3)
    return RunResult(metrics=metrics, trajectory=traj, solve_times_s=times)


def _emergency_distance(v: float, a: float, params: TrainParams, dt: float) -> float:
    """Distance to stop from v braking at a after the force lag (≈ v·τ/… + v²/(2a)) plus one step."""
    return v * v / (2.0 * a) + v * (params.traction_lag_s + dt)


def _emergency_command(plant: TrainPlant, params: TrainParams, a: float, t: float, dt: float, horizon: int):
    """Emergency brake: the force giving a total deceleration a (resistance included); the plan
    communicated with it is the constant-deceleration stop (what the leader will do)."""
    from vcsumo.control.base import Command
    from vcsumo.dynamics import running_resistance

    x = plant.x
    u = -(params.mass_kg * a - running_resistance(params, x.v_mps)) if x.v_mps > 0 else -params.mass_kg * a
    k = np.arange(horizon + 1)
    tt = np.minimum(k * dt, x.v_mps / a)
    return Command(force_n=float(u), mode="emergency", emergency=True, plan_times_s=t + k * dt, plan_positions_m=x.s_m + x.v_mps * tt - 0.5 * a * tt * tt,
                   plan_speeds_mps=np.maximum(x.v_mps - a * k * dt, 0.0), plan_forces_n=np.full(horizon + 1, u))


def _stop_time(t: np.ndarray, v: np.ndarray, after: float, v_stop: float = 0.01) -> float:
    """First time ≥ ``after`` from which the train stays below ``v_stop`` to the end of the run."""
    moving = np.flatnonzero((v > v_stop) & (t >= after - 1e-9))
    if len(moving) == 0:
        idx = np.flatnonzero(t >= after - 1e-9)
        return float(t[idx[0]]) if len(idx) else math.nan
    last = moving[-1]
    return float(t[last + 1]) if last + 1 < len(t) else math.nan


def _metrics(traj: pd.DataFrame, n_trains: int, strategy: str, sc: Scenario) -> dict:
    t = traj["time_s"].to_numpy()
    v0 = traj["v0_mps"].to_numpy()
    t_l = _stop_time(t, v0, 0.0)
    out = {"strategy": strategy, "n_trains": n_trains, "leader_stop_time_s": t_l,
           "leader_stop_position_m": float(traj["s0_m"].iloc[-1])}
    gaps_min, collisions = [], 0
    for i in range(1, n_trains):
        gap = traj[f"gap{i}_m"].to_numpy()
        gaps_min.append(float(gap.min()))
        collisions += int(np.sum((gap[1:] < 0) & (gap[:-1] >= 0)))
    if n_trains > 1:
        v1 = traj["v1_mps"].to_numpy()
        gap1 = traj["gap1_m"].to_numpy()
        t_f = _stop_time(t, v1, 0.0)
        i_l = int(np.searchsorted(t, t_l)) if math.isfinite(t_l) else len(t) - 1
        i_f = int(np.searchsorted(t, t_f)) if math.isfinite(t_f) else len(t) - 1
        i_both = min(max(i_l, i_f), len(t) - 1)
        # onset of the leader's stop: last time it still ran at its objective speed
        v_obj = sc.objective_speed_mps
        cruise = np.flatnonzero((v0 >= v_obj - 0.05) & (t < (t_l if math.isfinite(t_l) else np.inf)))
        i_b = int(cruise[-1]) if len(cruise) else i_l
        out.update({
            "stop_distance_m": float(gap1[i_b]),
            "max_gap_m": float(gap1[: i_b + 1].max()),
            "leader_brake_time_s": float(t[i_b]),
            "gap_at_rest_m": float(gap1[i_both]),
            "stop_delay_s": float(t_f - t_l),
            "gap_at_leader_stop_m": float(gap1[min(i_l, len(t) - 1)]),
            "follower_stop_time_s": t_f,
            "cruise_gap_m": float(np.median(gap1[(v0 > sc.objective_speed_mps - 0.05) & (t < t_l)])) if np.any((v0 > sc.objective_speed_mps - 0.05) & (t < t_l)) else math.nan,
            "min_gap_m": float(min(gaps_min)),
            "collisions": collisions,
        })
        for i in range(2, n_trains):
            vi = traj[f"v{i}_mps"].to_numpy()
            ti = _stop_time(t, vi, 0.0)
            out[f"stop_distance{i}_m"] = float(traj[f"gap{i}_m"].to_numpy()[min(int(np.searchsorted(t, ti)), len(t) - 1)]) if math.isfinite(ti) else math.nan
            out[f"stop_delay{i}_s"] = float(ti - t_l)
    return out


def run_felez2019(strategies=("SH", "NP", "MB"), horizon: int = 40, n_trains: int = 2, scenario: Scenario | None = None) -> pd.DataFrame:
    """One row per predictor strategy: stop distance and delay next to the paper's (Fig. 12).

    Columns: strategy, stop_distance_m, stop_delay_s, min_gap_m, collisions, the paper's values,
    gap_at_leader_stop_m, cruise_gap_m, infeasible_steps, solve times, wall_time_s.  The time
    series of every run are in ``df.attrs["trajectories"][strategy]``.
    """
    sc = scenario or load_scenario()
    rows, trajs = [], {}
    for strat in strategies:
        t0 = time.perf_counter()
        res = simulate(strat, n_trains, horizon, sc)
        m = dict(res.metrics)
        m["wall_time_s"] = time.perf_counter() - t0
        paper = PAPER.get(strat, {})
        m["paper_stop_distance_m"] = paper.get("stop_distance_m", math.nan)
        m["paper_stop_delay_s"] = paper.get("stop_delay_s", math.nan)
        rows.append(m)
        trajs[strat] = res.trajectory
    cols = ["strategy", "stop_distance_m", "paper_stop_distance_m", "stop_delay_s", "paper_stop_delay_s", "gap_at_rest_m", "min_gap_m", "collisions", "a_follower_mps2"]
    df = pd.DataFrame(rows)
    df = df[cols + [c for c in df.columns if c not in cols]]
    df.attrs["trajectories"] = trajs
    return df


def convoy(n_trains: int = 4, strategy: str = "SH", horizon: int = 40, scenario: Scenario | None = None) -> RunResult:
    """The four-train convoy of Fig. 10 (SH predictor): speeds and gaps of consecutive trains."""
    return simulate(strategy, n_trains, horizon, scenario)


def horizon_sweep(horizons=(20, 30, 40, 50, 60), strategy: str = "SH", scenario: Scenario | None = None) -> pd.DataFrame:
    """Fig. 11: gap at the stop and NMPC solve time against the horizon N_p (two trains)."""
    rows = []
    for n in horizons:
        t0 = time.perf_counter()
        res = simulate(strategy, 2, int(n), scenario)
        m = res.metrics
        rows.append({"horizon": int(n), "stop_distance_m": m["stop_distance_m"], "gap_at_rest_m": m["gap_at_rest_m"], "stop_delay_s": m["stop_delay_s"],
                     "gap_at_leader_stop_m": m["gap_at_leader_stop_m"], "cruise_gap_m": m["cruise_gap_m"], "min_gap_m": m["min_gap_m"],
                     "mean_solve_time_ms": m["solve_time_mean_ms"], "median_solve_time_ms": m["solve_time_median_ms"],
                     "infeasible_steps": m["infeasible_steps"], "wall_time_s": time.perf_counter() - t0})
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> None:
    """``python -m vcsumo.reproduce.felez2019 [SH NP MB] [--sweep] [--convoy]``: print the tables."""
    import argparse

    ap = argparse.ArgumentParser(description="Felez, Kim & Borrelli (2019) §IV-A reproduction")
    ap.add_argument("strategies", nargs="*", default=["SH", "NP", "MB"])
    ap.add_argument("--horizon", type=int, default=40)
    ap.add_argument("--sweep", action="store_true", help="also the horizon sweep of Fig. 11")
    ap.add_argument("--convoy", action="store_true", help="also the four-train convoy of Fig. 10")
    args = ap.parse_args(argv)
    cols = ["strategy", "a_follower_mps2", "stop_distance_m", "paper_stop_distance_m", "stop_delay_s", "paper_stop_delay_s", "gap_at_rest_m",
            "min_gap_m", "collisions", "infeasible_steps", "solve_time_median_ms", "wall_time_s"]
    df = run_felez2019(tuple(s.upper() for s in args.strategies), args.horizon)
    print(df[cols].to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    if args.sweep:
        print(horizon_sweep().to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    if args.convoy:
        m = convoy(4).metrics
        print({k: (round(v, 2) if isinstance(v, float) else v) for k, v in m.items()})


if __name__ == "__main__":
    main()
