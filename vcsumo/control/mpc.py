"""Nonlinear MPC for virtual coupling: leader (eq. 11) and follower (eq. 12) of Felez, Kim & Borrelli (2019).

Problem (per train, horizon N = N_p, step Δt)
---------------------------------------------
State x = (s, v, F), input u (commanded force).  Prediction model: eq. 6b/7 with the force lag
1c, :func:`vcsumo.control.predictors.model_step`, built from :mod:`vcsumo.dynamics` and
integrated exactly as :class:`vcsumo.plant.TrainPlant` does (the force after the lag acts in the
step; v ≥ 0 as a smooth max).  Constraints, k = 0 … N−1 unless noted:

* force 4a/11g/12i: −M·a_br ≤ u_k ≤ M·a_dr;
* power 4b/11h/12j: −P_br ≤ u_k·v_k ≤ P_dr (traction *and* braking power);
* jerk 4c/11f/12h with 11j/12o: |F_{k+1} − F_k| ≤ j_max·M·Δt, on the applied force as in the
  paper and in :class:`~vcsumo.plant.TrainPlant`.  With ``jerk_limit_on = "command"`` the bound is
  |u_k − F_k| ≤ j_max·M·Δt instead (it implies 12o), for a plant that rate-limits the command
  against the lagged force;
* speed limit 11e/12g, k = 1 … N: v_k ≤ v_lim(s̄_k), the train-length limit at the a-priori
  positions s̄ of eq. 14 (the previous plan shifted and simulated from the measured state; in
  further SQP iterations the current iterate); 0 ≤ v_k holds by construction of the model.  Where
  no plan can keep below it — the train starts at or just above the limit with a force that the
  lag and the jerk limit cannot bring down in time, e.g. at the limit on a steep descent, or after
  a plant that applied the last command at once — the limit is raised to the speed floor of
  :func:`~vcsumo.control.mpc_solver.speed_floor` (the force brought down at the jerk limit), only
  at the steps where that floor is above it; ``MPCSolution.speed_relaxation_mps`` reports by how much;
* terminal set 11i/12k: v_N ≤ v_DP(s_N), imposed as v_N² ≤ β(s_N) with β = v_DP² (nearly linear
  in s near a stop, and extended below zero past the end of the movement so that a train beyond
  it is outside the set).  v_DP is the boundary of the DP feasible set (eq. 10, Fig. 7) from
  :mod:`vcsumo.control.dp_profile`, lowered to the same boundary for this time-discrete model
  with ``terminal_brake_fraction`` of the brake; with ``terminal_ramp_allowance`` it is
  evaluated at s_N + v_N·t_r/2, t_r the time the force needs to ramp from F_N to the full brake
  at the jerk limit (the paper's set assumes the brake is already applied at s_N);
* follower only — d_min 12f/12l (eq. 9): d_k = s̄^l_k − s_k − L ≥ d_min, k = 1 … N, and the
  invariant terminal set 12m: d_N + (v̄^l_N)²/(2a^l) − v_N²/(2a^f) ≥ d_min.

Cost (squared weighted norms):

* leader 11a-b: Σ K_V^l·(1 − v_k/v_max)² + Σ K_J^l·(j_k/j_max)²;
* follower 12a-c: Σ K_D·(1 − d_k/d_des)² + Σ K_V^f·((v̄^l_k − v_k)/v_max)² + Σ K_J^f·(j_k/j_max)²;

with j_k = (F_{k+1} − F_k)/(M·Δt) (11j/12o; the paper prints ·M/Δt, a typo).

Solution method
---------------
Single shooting, condensed: the decision variables are the normalised force increments
z_k = (F_{k+1} − F_k)/(j_max·M·Δt), so the jerk limits are simple bounds, and
u_k = F_k + (F_{k+1} − F_k)/α (α = Δt/τ).  One SQP iteration evaluates a compiled CasADi SX
function that gives the Gauss–Newton QP (N + 3 variables, 4N + 2 rows for a follower) from the
trajectory and its exact Jacobians (forward sensitivities, lower triangular), the Hessian as one
numpy product, solves the QP with qpOASES (``casadi.conic``, dense, hot-started from the previous
step) and evaluates a second SX function for the new plan and its constraint violations; CasADi
reads and writes preallocated numpy buffers (``Function.buffer``), so no conversion happens per
call.  (The numpy assembly the compiled one replaced is kept in ``tests/test_mpc_compiled.py`` as
the reference it is tested against.)
In closed loop the controller runs real-time iterations: one SQP iteration from the warm start
(previous solution shifted by one step, last increment zero: eq. 14b-c), more (up to
``sqp_max_iterations``) only while the re-simulated plan violates a constraint beyond the
tolerances.  The state constraints carry slacks with an exact L1 penalty so the QP is always
solvable; a plan that still violates a constraint beyond the tolerances is *infeasible*: the
controller commands the full service brake (−min(M·a_br, P_br/v)), sets ``Command.infeasible``
and counts it (``stats.infeasible``).  Nothing raises out of :meth:`make_step` or
:meth:`CondensedNMPC.solve`.

Public API: :class:`MPCSettings` (``controllers/mpc*.yaml``), :class:`LeaderMPC`,
:class:`FollowerMPC` (``make_step(obs) -> Command``, ``solve_arrays(...) -> MPCSolution``),
:class:`CondensedNMPC` (the pure solver), :func:`fallback_force`.

Modules: this one holds the controllers (``make_step``, predictors, warm start, route data);
:mod:`vcsumo.control.mpc_settings` the parameters, :mod:`vcsumo.control.mpc_qp` the compiled model
and the condensed QP, :mod:`vcsumo.control.mpc_solver` the SQP solve, plan check and fallback.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vcsumo.control.base import Command, Message, Observation
from vcsumo.control.dp_profile import SpeedProfile, dp_speed_profile
from vcsumo.control.mpc_terminal import TerminalSet, terminal_set
from vcsumo.control.mpc_settings import DPModel, MPCSettings, load_mpc_settings
from vcsumo.control.mpc_solver import CondensedNMPC, MPCSolution
from vcsumo.control.predictors import LeaderPrediction, np_state_now, predict_mb, predict_np, predict_sh_from_plan
from vcsumo.control.route_lookup import RouteLookup
from vcsumo.dynamics import TrainParams, brake_force_limit
from vcsumo.route_profile import RouteProfile

# -------------------------------------------------------------------------------------------
# Controllers (make_step interface)


class _RouteCache:
    """Per-route look-up, DP profile (eq. 10) and terminal set, computed once per route + train + end."""

    def __init__(self):
        self._key = None
        self.lookup: RouteLookup | None = None
        self.dp: SpeedProfile | None = None
        self.terminal: TerminalSet | None = None

    def get(self, profile: RouteProfile, params: TrainParams, settings: MPCSettings, end_m: float | None):
        key = (id(profile), end_m)
        if key != self._key:
            end = None if end_m is None else min(float(end_m), profile.length_m)
            self.lookup = RouteLookup(profile, params.length_m)
            self.dp = dp_speed_profile(params, profile, 0.0, end, 0.0, 0.0, (), settings.dp.to_dp())
            self.terminal = terminal_set(params, profile, self.dp, settings.step_s, (), 0.0, settings.terminal_brake_fraction)
            self._key = key
        return self.lookup, self.terminal


@dataclass
class ControllerStats:
    """Counters of one controller."""

    steps: int = 0
    infeasible: int = 0
    sqp_iterations: int = 0
    solve_times_s: list = field(default_factory=list)


class _MPCBase:
    follower: bool = False

    def __init__(self, params: TrainParams, settings: MPCSettings | None = None, route_end_m: float | None = None):
        self.params = params
        self.settings = settings or MPCSettings()
        self.ocp = CondensedNMPC(params, self.settings, follower=self.follower)
        self.route_end_m = route_end_m
        self._route = _RouteCache()
        self._last: MPCSolution | None = None
        self._last_time: float | None = None
        self.stats = ControllerStats()

    @property
    def last_solution(self) -> MPCSolution | None:
        """The plan of the latest step (None before the first)."""
        return self._last

    def set_route_end(self, end_m: float | None) -> None:
        """Move the end of the train's movement (where it must be at rest, e.g. the next stop or
        the end of its movement authority), m along the ego route; None: the route end."""
        self.route_end_m = end_m

    def reset(self) -> None:
        """Forget the warm start (e.g. after a teleport or a long pause)."""
        self._last = None
        self._last_time = None

    def share_route_data(self, other: "_MPCBase") -> None:
        """Use ``other``'s route cache (look-up, DP profile of eq. 10, terminal set): for controllers
        of the same train with the same settings and route end, the DP is then computed once."""
        if other.params != self.params or other.settings != self.settings or other.route_end_m != self.route_end_m:
            raise ValueError("route data can only be shared between controllers of the same train, settings and route end")
        self._route = other._route

    def route_data(self, profile: RouteProfile) -> tuple[RouteLookup, TerminalSet]:
        """The vectorised route look-up and the terminal set (DP of eq. 10) for ``profile`` (cached)."""
        return self._route.get(profile, self.params, self.settings, self.route_end_m)

    def _x0(self, obs: Observation) -> tuple:
        F = obs.ego.force_n
        if not self.settings.use_measured_force and self._last is not None:
            F = float(self._last.forces_n[1])
        return (obs.ego.position_m, obs.ego.speed_mps, F)

    def _warm(self, obs: Observation) -> np.ndarray | None:
        """The previous plan shifted by the elapsed steps (eq. 14b-c), None without one."""
        if self._last is None or self._last_time is None:
            return None
        shift = int(round((obs.time_s - self._last_time) / self.settings.step_s))
        if shift <= 0:
            return self._last.z.copy()
        z = self._last.z[shift:]
        if not len(z):
            return None
        w = np.zeros(self.settings.horizon_steps)
        w[: len(z)] = z
        return w

    def _v_scale(self, obs: Observation) -> float:
        if self.settings.v_max_mps is not None:
            return float(self.settings.v_max_mps)
        if obs.target_speed_mps is not None and obs.target_speed_mps > 0:
            return float(obs.target_speed_mps)
        return float(min(obs.profile.max_speed(), self.params.max_speed_ms))

    def _safe_fallback(self, obs: Observation, reason: str) -> MPCSolution:
        """Full service brake whatever went wrong (also with a malformed observation)."""
        try:
            x0, t0 = (obs.ego.position_m, obs.ego.speed_mps, obs.ego.force_n), obs.time_s
        except Exception:
            x0, t0 = (math.nan, math.nan, math.nan), math.nan
        return self.ocp.fallback(x0, t0, None, None, reason)

    def _command(self, obs: Observation, sol: MPCSolution, mode: str) -> Command:
        self.stats.steps += 1
        self.stats.sqp_iterations += sol.iterations
        self.stats.solve_times_s.append(sol.solve_time_s)
        if not sol.ok:
            self.stats.infeasible += 1
        if sol.ok or np.all(np.isfinite(sol.positions_m)):
            self._last = sol
            try:
                self._last_time = float(obs.time_s)
            except Exception:
                self._last = None
        info = {"solve_time_s": sol.solve_time_s, "sqp_iterations": sol.iterations, "violation": sol.violation,
                "plan_commands_n": sol.commands_n, "infeasible_count": self.stats.infeasible,
                "speed_relaxation_mps": sol.speed_relaxation_mps}
        if sol.leader is not None:
            info["predictor"] = sol.leader.strategy
        return Command(force_n=sol.force_n, mode=mode if sol.ok else "fallback", infeasible=not sol.ok, plan_times_s=sol.times_s,
                       plan_positions_m=sol.positions_m, plan_speeds_mps=sol.speeds_mps, plan_forces_n=sol.forces_n, info=info)


class LeaderMPC(_MPCBase):
    """Leader NMPC (eq. 11): as fast as allowed (v → v_max) under v_lim(s), the DP terminal set and
    the force, power and jerk limits.

    ``route_end_m`` (or :meth:`set_route_end`) is where the train must be at rest (next stop or
    end of movement authority); None: the end of the route.  v_max is ``settings.v_max_mps``,
    else ``Observation.target_speed_mps``, else the highest limit of the route.
    """

    follower = False

    def make_step(self, obs: Observation) -> Command:
        """One control step (the :class:`~vcsumo.control.base.Controller` interface)."""
        try:
            lookup, terminal = self.route_data(obs.profile)
            vsc = self._v_scale(obs)
            sol = self.ocp.solve(self._x0(obs), self._warm(obs), lookup, terminal, vsc, vsc, t0_s=obs.time_s)
        except Exception as exc:  # never crash the loop: brake
            sol = self._safe_fallback(obs, f"error: {exc!r}")
        return self._command(obs, sol, "mpc-leader")

    def solve_arrays(self, x0, profile: RouteProfile | None = None, v_max_mps: float = 20.0, z_warm=None, t0_s: float = 0.0,
                     max_iterations: int | None = None) -> MPCSolution:
        """Pure solve of eq. 11 from plain data: state x0 = (s, v, F), the route (None: level, unlimited)."""
        lookup, terminal = self.route_data(profile) if profile is not None else (None, None)
        return self.ocp.solve(x0, z_warm, lookup, terminal, v_max_mps, v_max_mps, t0_s=t0_s, max_iterations=max_iterations)


class FollowerMPC(_MPCBase):
    """Follower NMPC (eq. 12) with the SH, NP or MB predictor of its predecessor (eq. 16–18).

    The predecessor's state comes from on-board sensing (``Observation.sensed_gap_m`` /
    ``sensed_speed_mps``, §III-A) when given, else from its latest message.  SH uses the
    communicated plan (``Message.plan_*``); without one it degrades to NP, as in the paper.  With
    no information at all about the predecessor the follower brakes (mode ``fallback``).
    """

    follower = True

    def __init__(self, params: TrainParams, settings: MPCSettings | None = None, predictor: str | None = None, route_end_m: float | None = None):
        super().__init__(params, settings, route_end_m)
        self.predictor = (predictor or self.settings.predictor).upper()
        if self.predictor not in ("SH", "NP", "MB"):
            raise ValueError(f"unknown predictor '{predictor}' (SH, NP or MB)")

    def predict_leader(self, obs: Observation) -> LeaderPrediction | None:
        """The predecessor's predicted trajectory on this controller's horizon (eq. 16, 17 or 18)."""
        cfg = self.settings
        N, dt = cfg.horizon_steps, cfg.step_s
        msg: Message | None = obs.received.get(obs.predecessor) if obs.predecessor else None
        length = msg.length_m if msg is not None else self.params.length_m
        meas = None
        if obs.sensed_gap_m is not None:
            meas = (obs.ego.position_m + obs.sensed_gap_m + length,
                    obs.sensed_speed_mps if obs.sensed_speed_mps is not None else (msg.state.speed_mps if msg else 0.0))
        times = obs.time_s + dt * np.arange(N + 1)
        strategy = self.predictor
        if strategy == "SH" and (msg is None or msg.plan_times_s is None or msg.plan_positions_m is None or msg.plan_speeds_mps is None):
            strategy = "NP"  # communication of the plan lost: degraded mode (§III-F)
        if strategy == "SH":
            s, v = predict_sh_from_plan(msg.plan_times_s, msg.plan_positions_m, msg.plan_speeds_mps, obs.time_s, dt, N, measured=meas)
        elif strategy == "NP":
            if meas is None:
                if msg is None:
                    return None
                meas = np_state_now(msg.state.position_m, msg.state.speed_mps, cfg.a_leader_mps2, obs.time_s - msg.state.time_s)
            s, v = predict_np(meas[0], meas[1], cfg.a_leader_mps2, dt, N)
        else:
            if meas is None:
                if msg is None:
                    return None
                meas = (msg.state.position_m, 0.0)
            s, v = predict_mb(meas[0], N)
        return LeaderPrediction(times_s=times, positions_m=s, speeds_mps=v, length_m=length, strategy=strategy)

    def make_step(self, obs: Observation) -> Command:
        """One control step (the :class:`~vcsumo.control.base.Controller` interface)."""
        try:
            lookup, terminal = self.route_data(obs.profile)
            x0 = self._x0(obs)
            leader = self.predict_leader(obs)
            if leader is None:
                sol = self.ocp.fallback(x0, obs.time_s, lookup, None, "no information about the predecessor")
            else:
                vsc = self._v_scale(obs)
                sol = self.ocp.solve(x0, self._warm(obs), lookup, terminal, None, vsc, leader=leader, t0_s=obs.time_s)
        except Exception as exc:  # never crash the loop: brake
            sol = self._safe_fallback(obs, f"error: {exc!r}")
        return self._command(obs, sol, f"mpc-{self.predictor.lower()}")

    def solve_arrays(self, x0, leader: LeaderPrediction, profile: RouteProfile | None = None, v_max_mps: float = 20.0, z_warm=None,
                     t0_s: float = 0.0, max_iterations: int | None = None) -> MPCSolution:
        """Pure solve of eq. 12 from plain data: state x0 = (s, v, F), the leader prediction, the route."""
        lookup, terminal = self.route_data(profile) if profile is not None else (None, None)
        return self.ocp.solve(x0, z_warm, lookup, terminal, None, v_max_mps, leader=leader, t0_s=t0_s, max_iterations=max_iterations)


def fallback_force(params: TrainParams, speed_mps: float) -> float:
    """The safe command: full service brake −min(M·a_br, P_br/v), N (eq. 4a, 4b)."""
    return float(-brake_force_limit(params, speed_mps))


__all__ = [
    "MPCSettings", "DPModel", "load_mpc_settings", "CondensedNMPC", "MPCSolution", "LeaderMPC", "FollowerMPC", "fallback_force",
]
