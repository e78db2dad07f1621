"""Cruise virtual-coupling control of Terlizzi, Liuzza & Glielmo (2024), §VI-D and §VI-E.

* :class:`PositionReferenceGenerator` — Algorithm 4: at each newer leader packet it computes the
  follower position references z_τ^F(t) of eq. 20–28 (one per τ_i = ω_i·τ̄, eq. 32–34) from the
  leader's robust planned trajectory x̲^L(t_κ) carried by the packet.
* :class:`SwitchedCruiseController` — Algorithm 5: selects K_3^F (x^F ≤ z_τ3, catch up),
  K_2^F (z_τ3 < x^F ≤ z_τ1, normal VC) or K_1^F (x^F > z_τ1, back off) and computes the selected
  mode's finite-horizon optimal control (eq. 35–37).  τ̄ comes from the delay estimator
  (Algorithm 3, :class:`vcsumo.control.cbf.DelayEstimator`) or is fixed.

Each mode's problem (eq. 35–37) is a move-blocked QP on the nominal model, solved every step by a
real-time iteration (:class:`vcsumo.control.cruise_mpc.CondensedMPC`).  The parameters are
:class:`vcsumo.control.cruise_config.CruiseConfig`; Algorithm 4 is
:mod:`vcsumo.control.cruise_reference`; this module holds Algorithm 5.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from vcsumo.control.base import Command, Message, Observation
from vcsumo.control.cbf import BarrierModel, CBFConfig, DelayEstimator
from vcsumo.control.cruise_config import CruiseConfig, load_cruise_config
from vcsumo.control.cruise_mpc import CondensedMPC, DenseQP, MPCSolution, Weights, box_qp
from vcsumo.control.cruise_reference import PositionReferenceGenerator, ReferenceSet, leader_plan_from_message
from vcsumo.control.proxies import BoxBounds, GradeWindow
from vcsumo.dynamics import TrainParams
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile

# -------------------------------------------------------------------------------------------
# Algorithm 5: switched cruise controller


MODES = ("cruise-1", "cruise-2", "cruise-3")


class SwitchedCruiseController:
    """Algorithm 5 with the three modes of eq. 35–37; ``make_step(obs) -> Command``.

    The follower's nominal model is ``obs.params``; the leader's uncertainty box (for e̲^L) comes
    from its rolling stock.  The command's ``info`` carries the mode, τ̄ and z_τ1..3 at t.
    """

    def __init__(self, leader: RollingStock | BoxBounds, follower: RollingStock | BoxBounds, config: CruiseConfig | None = None, cbf: CBFConfig | None = None, leader_id: str | None = None):
        self.leader_bounds = leader if isinstance(leader, BoxBounds) else BoxBounds.from_stock(leader)
        self.follower_bounds = follower if isinstance(follower, BoxBounds) else BoxBounds.from_stock(follower)
        self.cfg = config or CruiseConfig()
        self.cbf = cbf or CBFConfig()
        self.leader_id = leader_id
        self.estimator = DelayEstimator(self.cfg.delay_window, self.cfg.delay_probability, self.cfg.fixed_delay_s)
        self._mpc: CondensedMPC | None = None
        self._mpc_params: TrainParams | None = None
        self._models: dict[int, tuple[BarrierModel, GradeWindow]] = {}
        self.ref: ReferenceSet | None = None
        self._t_last = -math.inf
        self._sol: MPCSolution | None = None
        self._sol_mode: str | None = None
        self._sol_time = -math.inf
        self.mode_counts = {m: 0 for m in (*MODES, "hold")}
        self.solves = 0
        self.failed_solves = 0
        cfg = self.cfg
        self.weights = {
            "cruise-1": Weights(cfg.theta1_s_per_m2, cfg.theta1_v_per_mps2, cfg.theta1_u_per_kn2),
            "cruise-2": Weights(cfg.theta2_s_per_m2, cfg.theta2_v_per_mps2, cfg.theta2_u_per_kn2),
            "cruise-3": Weights(cfg.theta3_s_per_m2, 0.0, cfg.theta3_u_per_kn2),
            "hold": Weights(0.0, cfg.hold_v_per_mps2, cfg.hold_u_per_kn2),
        }

    @classmethod
    def from_files(cls, leader: str | Path, follower: str | Path, config: str | Path | None = None, cbf: str | Path | None = None, leader_id: str | None = None) -> "SwitchedCruiseController":
        """Build from rolling-stock names/paths and YAML files (defaults in ``controllers/``)."""
        from vcsumo.control.cbf import load_cbf_config
        from vcsumo.control.params import resolve_params
        from vcsumo.rolling_stock import load_rolling_stock

        c = load_cruise_config(resolve_params(config, "cruise_terlizzi2024", "config"))
        b = load_cbf_config(resolve_params(cbf, "cbf", "cbf"))
        return cls(load_rolling_stock(leader), load_rolling_stock(follower), c, b, leader_id)

    # ---------------------------------------------------------------------------------------
    @property
    def tau_bar_s(self) -> float:
        return self.estimator.estimate_s if self.cfg.delay_estimator else self.cfg.fixed_delay_s

    def _model(self, profile: RouteProfile | None) -> tuple[BarrierModel, GradeWindow]:
        key = id(profile)
        m = self._models.get(key)
        if m is None:
            m = (BarrierModel(self.leader_bounds, self.follower_bounds, self.cbf, profile), GradeWindow(profile))
            self._models[key] = m
        return m

    def _get_mpc(self, params: TrainParams) -> CondensedMPC:
        if self._mpc is None or self._mpc_params != params:
            self._mpc = CondensedMPC(params, self.cfg.horizon_s, self.cfg.mpc_step_s, self.cfg.blocks)
            self._mpc_params = params
        return self._mpc

    def _leader_message(self, obs: Observation) -> Message | None:
        lid = self.leader_id or obs.predecessor
        if lid is None:
            return next(iter(obs.received.values())) if len(obs.received) == 1 else None
        return obs.received.get(lid)

    def select_mode(self, x_f: float, z: np.ndarray) -> str:
        """Algorithm 5, lines 6–12: z = (z_τ1, z_τ2, z_τ3) at the current time."""
        if x_f <= z[2]:
            return "cruise-3"
        if x_f <= z[0]:
            return "cruise-2"
        return "cruise-1"

    def make_step(self, obs: Observation) -> Command:
        t, s_f, v_f = obs.time_s, obs.ego.position_m, max(0.0, obs.ego.speed_mps)
        model, route = self._model(obs.profile)
        mpc = self._get_mpc(obs.params)
        msg = self._leader_message(obs)
        new_packet = msg is not None and msg.sent_time_s > self._t_last
        if new_packet:
            self.estimator.update_from(msg, t)  # Algorithm 3
            self._t_last = msg.sent_time_s
            v_line = math.inf
            if self.cfg.line_speed_limits and obs.profile is not None:
                s_hi = msg.state.position_m
                v_line = obs.profile.min_speed_over(s_f, max(s_f, s_hi))
            gen = PositionReferenceGenerator(model, self.cfg, obs.step_s)
            self.ref = gen.compute(msg, self.tau_bar_s, s_f, v_f, t, v_line)  # Algorithm 4 / eq. 32-34
        tk = t + mpc.dt * np.arange(1, mpc.N + 1)
        v_lim = self.follower_bounds.max_speed_ms
        if self.ref is None:
            mode = "hold"
            z = np.full(3, math.nan)
            v_target = obs.target_speed_mps if obs.target_speed_mps is not None else v_f
            z_ref = np.zeros(mpc.N)
            v_ref = np.full(mpc.N, v_target)
        else:
            z = self.ref.at(t)
            mode = self.select_mode(s_f, z)
            z_ref = self.ref.over(tk, row=1)  # all modes track z_τ2 (eq. 35-37)
            v_ref = self.ref.speed_over(tk)
        resolve = (
            self._sol is None
            or new_packet
            or mode != self._sol_mode
            or t - self._sol_time >= self.cfg.resolve_period_s - 1e-9
            or t > self._sol.times_s[-2]
        )
        if resolve:
            sol = mpc.solve(t, s_f, v_f, z_ref, v_ref, self.weights[mode], route, v_lim, self.cfg.line_speed_limits)
            self.solves += 1
            self.failed_solves += 0 if sol.ok else 1
            self._sol, self._sol_mode, self._sol_time = sol, mode, t
        sol = self._sol
        k = min(int((t - sol.times_s[0]) / mpc.dt + 1e-9), len(sol.forces_n) - 1)
        force = float(sol.forces_n[k])
        self.mode_counts[mode] += 1
        return Command(
            force_n=force,
            mode=mode,
            infeasible=not sol.ok,
            plan_times_s=sol.times_s,
            plan_positions_m=sol.positions_m,
            plan_speeds_mps=sol.speeds_mps,
            plan_forces_n=np.concatenate((sol.forces_n, sol.forces_n[-1:])),
            info={"tau_bar_s": self.tau_bar_s, "z_tau1_m": float(z[0]), "z_tau2_m": float(z[1]), "z_tau3_m": float(z[2])},
        )


__all__ = [
    "CondensedMPC", "CruiseConfig", "DenseQP", "MODES", "MPCSolution", "PositionReferenceGenerator", "ReferenceSet",
    "SwitchedCruiseController", "Weights", "box_qp", "leader_plan_from_message", "load_cruise_config",
]
