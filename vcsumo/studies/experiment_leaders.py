"""The leader's drivers of an offline experiment (:mod:`vcsumo.studies.experiment`).

* :class:`Schedule` — the leader's target speed over time: (time, speed) points held as steps or
  interpolated, plus the ``speed`` events of the file;
* :class:`SpeedTracker` — a P law on the schedule with the slope as feed-forward
  (:func:`vcsumo.sim.offline.tracking_force`);
* :class:`SpeedMPCLeader` — Terlizzi et al. §VI-D ("any valid MPC embedded on the leader over its
  nominal model"): a move-blocked speed-tracking MPC (:class:`~vcsumo.control.cruise.CondensedMPC`)
  re-planned at each packet it sends, whose packets carry its robust planned trajectory (the RLP of
  eq. 12 under the planned forces);
* :func:`felez_leader` — the leader NMPC of Felez et al. (2019), eq. 11, with its three ways to
  stop (:class:`~vcsumo.studies.experiment_model.FelezLeaderSpec`);
* :class:`LeaderEvents` — the file's emergency brakes (at a time or a position) around any driver:
  from then on the full emergency brake, held, and no plan is sent any more.
"""

from __future__ import annotations

import math

import numpy as np

from vcsumo.control.base import Command, Observation
from vcsumo.control.cruise import CondensedMPC, Weights
from vcsumo.control.mpc import LeaderMPC, load_mpc_settings
from vcsumo.control.params import resolve_params
from vcsumo.control.proxies import GradeWindow, RobustProxies, robust_plan
from vcsumo.dynamics import TrainParams, running_resistance
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.sim.offline import tracking_force
from vcsumo.studies.experiment_model import LeaderSpec


class Schedule:
    """Target speed of the leader: points (time s, speed m/s) as steps or linear (constant outside)."""

    def __init__(self, points: list[tuple[float, float]], kind: str = "steps"):
        pts = sorted(points) if points else [(0.0, 0.0)]
        self.t = np.array([a for a, _ in pts], dtype=float)
        self.v = np.array([b for _, b in pts], dtype=float)
        self.kind = kind

    @classmethod
    def from_spec(cls, spec: LeaderSpec) -> "Schedule":
        pts = dict((float(t), float(v)) for t, v in spec.schedule)
        for e in spec.events:
            if e.action == "speed":
                pts[float(e.at_s)] = float(e.speed_mps)
        return cls(sorted(pts.items()), spec.schedule_kind)

    def at(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        if self.kind == "linear":
            return np.interp(t, self.t, self.v)
        return self.v[np.maximum(np.searchsorted(self.t, t, side="right") - 1, 0)]

    def __call__(self, t: float) -> float:
        return float(self.at(np.array([t]))[0])

    def slope(self, t: float) -> float:
        """dv/dt of a linear schedule (0 for steps), m/s²."""
        if self.kind != "linear":
            return 0.0
        k = int(np.searchsorted(self.t, t, side="right")) - 1
        if k < 0 or k >= len(self.t) - 1:
            return 0.0
        return float((self.v[k + 1] - self.v[k]) / (self.t[k + 1] - self.t[k]))


class SpeedTracker:
    """P law on the schedule (with the slope as feed-forward), holding the brake at a standstill target."""

    def __init__(self, schedule: Schedule, gain_per_s: float = 0.5):
        self.schedule, self.gain = schedule, gain_per_s

    def make_step(self, obs: Observation) -> Command:
        t = obs.time_s
        v_ref = self.schedule(t)
        if v_ref <= 0.0 and obs.ego.speed_mps < 0.5:
            return Command(-obs.params.mass_kg * obs.params.service_brake_decel_mps2, mode="leader")
        return Command(tracking_force(obs, v_ref, self.schedule.slope(t), self.gain), mode="leader")


class SpeedMPCLeader:
    """The leader's own speed-tracking MPC on its nominal model (see the module doc)."""

    def __init__(self, stock: RollingStock, profile: RouteProfile, schedule: Schedule, dt_s: float, horizon_steps: int, step_s: float, blocks: int,
                 speed_weight: float, force_weight: float, replan_period_s: float = 1.0, send_robust_plan: bool = True):
        self.nominal = stock.params()
        self.mpc = CondensedMPC(self.nominal, horizon_steps * step_s, step_s, blocks)
        self.route = GradeWindow(profile)
        self.proxies = RobustProxies.from_stock(stock, profile)
        self.schedule = schedule
        self.weights = Weights(0.0, speed_weight, force_weight)
        self.dt = dt_s
        self.replan_period_s = replan_period_s
        self.send_robust_plan = send_robust_plan
        self.sol = None
        self.solves = 0

    def plan(self, t: float, s: float, v: float) -> None:
        tk = t + self.mpc.dt * np.arange(1, self.mpc.N + 1)
        self.sol = self.mpc.solve(t, s, v, np.zeros(self.mpc.N), self.schedule.at(tk), self.weights, self.route, self.nominal.max_speed_ms, False)
        self.solves += 1

    def broadcast_plan(self, t: float, s: float, v: float) -> tuple | None:
        """At every packet: plan, and the trajectory sent with it (times, positions, speeds, forces)."""
        self.plan(t, s, v)
        if not self.send_robust_plan:
            return None
        sol = self.sol
        n = int(round((sol.times_s[-1] - t) / self.dt))
        tt = t + self.dt * np.arange(n)
        idx = np.minimum(((tt - sol.times_s[0]) / self.mpc.dt + 1e-9).astype(int), len(sol.forces_n) - 1)
        pt, ps, pv = robust_plan(self.proxies, s, v, sol.forces_n[idx], self.dt, t, every=max(1, int(round(0.5 / self.dt))))
        return pt, ps, pv, np.interp(pt, sol.times_s[:-1], sol.forces_n)

    def make_step(self, obs: Observation) -> Command:
        t, v = obs.time_s, obs.ego.speed_mps
        if self.schedule(t) <= 0.0 and v < 0.5:
            return Command(-self.nominal.mass_kg * self.nominal.service_brake_decel_mps2, mode="leader")  # holding brake at a stop
        if self.sol is None or t - self.sol.times_s[0] >= self.replan_period_s - 1e-9:
            self.plan(t, obs.ego.position_m, v)
        sol = self.sol
        k = min(int((t - sol.times_s[0]) / self.mpc.dt + 1e-9), len(sol.forces_n) - 1)
        return Command(float(sol.forces_n[max(k, 0)]), mode="leader")


class UnannouncedStop:
    """Felez's leader that stops without announcing it: its NMPC drives until, from the point from
    which it must stop at ``stop_m``, it brakes at a^l; its plan is then the constant-deceleration stop."""

    def __init__(self, mpc: LeaderMPC, params: TrainParams, a_mps2: float, stop_m: float, horizon: int):
        self.mpc, self.p, self.a, self.stop_m, self.horizon = mpc, params, a_mps2, stop_m, horizon
        self.braking = False
        self.stats = mpc.stats

    def make_step(self, obs: Observation) -> Command:
        x = obs.ego
        p, a, dt = self.p, self.a, obs.step_s
        self.braking = self.braking or x.position_m + x.speed_mps ** 2 / (2.0 * a) + x.speed_mps * (p.traction_lag_s + dt) >= self.stop_m
        if not self.braking:
            return self.mpc.make_step(obs)
        s, v, t = x.position_m, x.speed_mps, obs.time_s
        u = -(p.mass_kg * a - running_resistance(p, v)) if v > 0 else -p.mass_kg * a
        k = np.arange(self.horizon + 1)
        tt = np.minimum(k * dt, v / a)
        return Command(force_n=float(u), mode="emergency", emergency=True, plan_times_s=t + k * dt, plan_positions_m=s + v * tt - 0.5 * a * tt * tt,
                       plan_speeds_mps=np.maximum(v - a * k * dt, 0.0), plan_forces_n=np.full(self.horizon + 1, u))


def felez_leader(spec: LeaderSpec, stock: RollingStock, profile: RouteProfile, objective_mps: float, base_dir, step_s: float) -> tuple[object, TrainParams]:
    """(driver, the leader plant's parameters) of Felez et al.'s leader (eq. 11).

    ``planned-emergency``: its NMPC plans the stop with the emergency brake — no brake-power limit
    and a brake force giving a^l in total (brake + running resistance at the objective speed) — so
    the braking is in the plan it sends, and the plant brakes likewise (one brake, as the paper's);
    ``service``: the same with the service brake; ``unannounced-emergency``: :class:`UnannouncedStop`.
    """
    fz = spec.felez
    cfg = load_mpc_settings(resolve_params(fz.params, "mpc_felez2019", "leader.felez.params", base_dir))
    if abs(cfg.step_s - step_s) > 1e-9:
        cfg = cfg.model_copy(update={"step_s": step_s})
    if fz.horizon_steps is not None:
        cfg = cfg.model_copy(update={"horizon_steps": fz.horizon_steps})
    params = stock.params()
    stop_m = fz.stop_at_m if fz.stop_at_m is not None else profile.length_m
    if fz.braking == "planned-emergency":
        a_brake = cfg.a_leader_mps2 - float(running_resistance(params, objective_mps)) / params.mass_kg
        plant = params.with_(service_brake_decel_mps2=a_brake, max_brake_power_w=math.inf)
        return LeaderMPC(plant, cfg, route_end_m=stop_m), plant
    if fz.braking == "service":
        return LeaderMPC(params, cfg, route_end_m=stop_m), params
    plant = params.with_(service_brake_decel_mps2=params.emergency_brake_decel_mps2 + 0.5, max_brake_power_w=math.inf)
    return UnannouncedStop(LeaderMPC(params, cfg, route_end_m=None), params, cfg.a_leader_mps2, stop_m, cfg.horizon_steps), plant


class LeaderEvents:
    """The file's emergency brakes around a leader driver: the full emergency brake (−inf N, flagged
    emergency) from the first event reached (time or front position) on, held; no plan is sent then."""

    def __init__(self, driver, at_s: list[float], at_m: list[float], plan=None):
        self.driver = driver
        self.at_s = min(at_s, default=math.inf)
        self.at_m = min(at_m, default=math.inf)
        self._plan = plan
        self.braking_since_s: float | None = None
        self.stats = getattr(driver, "stats", None)

    def make_step(self, obs: Observation) -> Command:
        if self.braking_since_s is None and (obs.time_s >= self.at_s - 1e-9 or obs.ego.position_m >= self.at_m):
            self.braking_since_s = obs.time_s
        if self.braking_since_s is not None:
            return Command(-math.inf, mode="emergency", emergency=True)
        return self.driver.make_step(obs)

    def plan(self, t: float, s: float, v: float):
        if self.braking_since_s is not None or self._plan is None:
            return None
        return self._plan(t, s, v)


__all__ = ["Schedule", "SpeedTracker", "SpeedMPCLeader", "UnannouncedStop", "felez_leader", "LeaderEvents"]
