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

from vcsumo.control.base import Command, Observation
from vcsumo.control.dp_profile import straight_route_profile
from vcsumo.control.mpc import LeaderMPC, MPCSettings, load_mpc_settings
from vcsumo.control.params import resolve_params
from vcsumo.dynamics import TrainParams, running_resistance
from vcsumo.plant import PlantState
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.sim.offline import OfflineTrain, follower_stacks, run_convoy

PAPER = {
    "SH": {"stop_distance_m": 28.5, "stop_delay_s": 2.0},
    "NP": {"stop_distance_m": 208.3, "stop_delay_s": 17.0},
    "MB": {"stop_distance_m": 352.4, "stop_delay_s": 23.0},
}
"""Values reported in §IV-A.3 (Fig. 12) of the paper."""


def default_settings_path() -> Path:
    return resolve_params(None, "mpc_felez2019")


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
    settings = load_mpc_settings(resolve_params(settings_path, "mpc_felez2019", "settings_path"))
    return replace(Scenario(settings=settings), **changes)


@dataclass
class RunResult:
    """One closed-loop run: metrics and the time series."""

    metrics: dict
    trajectory: pd.DataFrame
    solve_times_s: dict = field(default_factory=dict)


class _UnannouncedStop:
    """The leader of ``leader_braking="emergency"``: its NMPC drives until, from the point from which
    it stops at ``stop_m``, it brakes at a^l without having announced it (its plan is the
    constant-deceleration stop it then performs)."""

    def __init__(self, mpc: LeaderMPC, params: TrainParams, a_mps2: float, stop_m: float, horizon: int):
        self.mpc, self.p, self.a, self.stop_m, self.horizon = mpc, params, a_mps2, stop_m, horizon
        self.braking = False

    def make_step(self, obs: Observation):
        x = obs.ego
        self.braking = self.braking or x.position_m + _emergency_distance(x.speed_mps, self.a, self.p, obs.step_s) >= self.stop_m
        if self.braking:
            return _emergency_command(x.position_m, x.speed_mps, self.p, self.a, obs.time_s, obs.step_s, self.horizon)
        return self.mpc.make_step(obs)


def simulate(strategy: str = "SH", n_trains: int = 2, horizon: int | None = None, scenario: Scenario | None = None) -> RunResult:
    """Run the leader (eq. 11) and ``n_trains − 1`` followers (eq. 12 with the ``strategy`` predictor).

    Every train is a :class:`TrainPlant` (eq. 6b with the force lag 1c) of the ``felez2019``
    rolling stock, in the offline loop :func:`vcsumo.sim.offline.run_convoy`; the followers are the
    registry's ``mpc`` stacks in the paper's architecture (no separation guard), stepped each Δt.  A
    follower measures its predecessor's gap and speed (on-board sensor, §III-A) and, for SH,
    receives the predecessor's plan computed one step earlier (eq. 16: u*_{·|t−1}) over an ideal
    channel.
    """
    sc = scenario or load_scenario()
    update = {"predictor": strategy.upper()} if horizon is None else {"horizon_steps": int(horizon), "predictor": strategy.upper()}
    a_f = dict(sc.a_follower_by_strategy_mps2).get(strategy.upper())
    if a_f is not None:
        update["a_follower_mps2"] = float(a_f)
    cfg = sc.settings.model_copy(update=update)
    stock = load_rolling_stock(sc.train)
    params: TrainParams = stock.params()
    dt = cfg.step_s
    stop_m = sc.origin_m + sc.stop_from_origin_m
    route = straight_route_profile(stop_m, sc.speed_limit_mps)
    gap0 = cfg.d_min_m if sc.initial_gap_m is None else sc.initial_gap_m
    ids = [f"T{i}" for i in range(n_trains)]
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
    leader = LeaderMPC(lead_params if sc.leader_braking == "mpc-emergency" else params, cfg, route_end_m=None if emergency else stop_m)
    stacks = follower_stacks("mpc", [stock] * n_trains, ids, dt, route, params=cfg, guard=False)
    trains = []
    for i in range(n_trains):
        s0 = sc.origin_m - i * (params.length_m + gap0)
        driver = (_UnannouncedStop(leader, params, cfg.a_leader_mps2, stop_m, cfg.horizon_steps) if emergency else leader) if i == 0 else stacks[i - 1]
        trains.append(OfflineTrain(ids[i], lead_params if i == 0 else params, PlantState(s0, 0.0, 0.0), driver, nominal=params,
                                   target_speed_mps=sc.objective_speed_mps))
    still = {"since": None, "moved": False}

    def settled(t: float, xs: list) -> bool:
        """All trains at rest for ``settle_s`` after having moved (checked on the states the last step produced)."""
        if t == 0.0:
            return False
        t_prev = t - dt
        moving = any(x.v_mps > 0.01 for x in xs)
        still["moved"] = still["moved"] or moving
        if still["moved"] and not moving:
            still["since"] = t_prev if still["since"] is None else still["since"]
            return t_prev - still["since"] >= sc.settle_s
        still["since"] = None
        return False

    n_steps = int(round(sc.max_time_s / dt))
    # the paper's plant has one brake: the leader's emergency command is its (planned) braking force
    run = run_convoy(trains, route, dt, (n_steps - 1) * dt, apply_lag=True, apply_jerk=sc.plant_jerk, emergency_brake=False, stop_when=settled)
    traj = _wide(run.frame, ids, sc.origin_m)
    metrics = _metrics(traj, n_trains, strategy, sc)
    metrics["horizon"] = cfg.horizon_steps
    metrics["a_follower_mps2"] = cfg.a_follower_mps2
    ctrls = [leader] + [st.nominal for st in stacks]
    times = {ids[i]: np.array(ctrls[i].stats.solve_times_s) for i in range(n_trains)}
    metrics["infeasible_steps"] = int(sum(c.stats.infeasible for c in ctrls))
    fol = np.concatenate([times[i] for i in ids[1:]]) if n_trains > 1 else times[ids[0]]
    metrics["solve_time_median_ms"] = float(np.median(fol) * 1e3)
    metrics["solve_time_mean_ms"] = float(np.mean(fol) * 1e3)
    metrics["solve_time_p99_ms"] = float(np.percentile(fol, 99) * 1e3)
    return RunResult(metrics=metrics, trajectory=traj, solve_times_s=times)


def _wide(frame: pd.DataFrame, ids: list[str], origin_m: float) -> pd.DataFrame:
    """One row per step: time_s, s{i}_m (from the leader's start), v{i}_mps, F{i}_n (applied force),
    u{i}_n (command), infeasible{i}, gap{i}_m (followers)."""
    out = pd.DataFrame({"time_s": frame.loc[frame.train == ids[0], "time_s"].to_numpy()})
    for i, tid in enumerate(ids):
        f = frame[frame.train == tid]
        out[f"s{i}_m"] = f.position_m.to_numpy() - origin_m
        out[f"v{i}_mps"] = f.speed_mps.to_numpy()
        out[f"F{i}_n"] = f.force_n.to_numpy()
        out[f"u{i}_n"] = f.force_cmd_n.to_numpy()
        out[f"infeasible{i}"] = f.infeasible.to_numpy()
        if i > 0:
            out[f"gap{i}_m"] = f.gap_m.to_numpy()
    return out


def _emergency_distance(v: float, a: float, params: TrainParams, dt: float) -> float:
    """Distance to stop from v braking at a after the force lag (≈ v·τ/… + v²/(2a)) plus one step."""
    return v * v / (2.0 * a) + v * (params.traction_lag_s + dt)


def _emergency_command(s: float, v: float, params: TrainParams, a: float, t: float, dt: float, horizon: int) -> Command:
    """Emergency brake: the force giving a total deceleration a (resistance included); the plan
    communicated with it is the constant-deceleration stop (what the leader will do)."""
    u = -(params.mass_kg * a - running_resistance(params, v)) if v > 0 else -params.mass_kg * a
    k = np.arange(horizon + 1)
    tt = np.minimum(k * dt, v / a)
    return Command(force_n=float(u), mode="emergency", emergency=True, plan_times_s=t + k * dt, plan_positions_m=s + v * tt - 0.5 * a * tt * tt,
                   plan_speeds_mps=np.maximum(v - a * k * dt, 0.0), plan_forces_n=np.full(horizon + 1, u))


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
