"""The NMPC solve of one step (eq. 11 leader, eq. 12 follower) on the condensed QP.

Real-time iterations: one SQP iteration from the warm start (eq. 14b-c), more (up to
``sqp_max_iterations``) only while the re-simulated plan violates a constraint beyond the
tolerances; a plan that still does is infeasible and the full service brake is commanded.  Nothing
raises out of :meth:`CondensedNMPC.solve` or :meth:`CondensedNMPC.fallback`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from vcsumo.control.mpc_qp import CondensedQP
from vcsumo.control.predictors import LeaderPrediction
from vcsumo.control.route_lookup import RouteLookup
from vcsumo.dynamics import brake_force_limit


@dataclass
class MPCSolution:
    """One solved NMPC problem: the plan k = 0 … N and solver information."""

    ok: bool
    """All constraints hold on the plan within the tolerances."""
    force_n: float
    """Command to apply now: u_0 of the plan, or the full service brake if not ok."""
    times_s: np.ndarray
    positions_m: np.ndarray
    speeds_mps: np.ndarray
    forces_n: np.ndarray
    """Applied force F_k, k = 0 … N (state of eq. 1c)."""
    commands_n: np.ndarray
    """Planned inputs u_k, k = 0 … N−1."""
    z: np.ndarray
    """Normalised force increments (decision variables), k = 0 … N−1."""
    slacks: np.ndarray
    violation: dict
    iterations: int
    solve_time_s: float
    v_limit_mps: np.ndarray
    """v_lim(s̄_k), k = 1 … N, used for the speed constraint."""
    v_terminal_mps: float
    """Terminal speed bound √β used in the last iteration (11i/12k)."""
    leader: LeaderPrediction | None = None
    cost: float = math.nan

    def warm_start(self) -> np.ndarray:
        """Eq. 14b-c: the plan shifted by one step, last increment zero (holds the last force)."""
        return np.append(self.z[1:], 0.0)


class CondensedNMPC(CondensedQP):
    """Compiled one-iteration SQP of the leader (``follower=False``) or follower NMPC for one train.

    The pure entry point is :meth:`solve`: it takes plain arrays (current state, warm start,
    space-dependent data through a :class:`RouteLookup` and a terminal set, the leader
    prediction) and returns an :class:`MPCSolution`; the only state kept between calls is
    qpOASES's working set, which hot-starts the next QP.  One instance per train (not
    thread-safe).
    """

    def solve(
        self,
        x0,
        z_warm: np.ndarray | None,
        lookup: RouteLookup | None,
        terminal,
        v_ref_mps,
        v_scale_mps: float,
        leader: LeaderPrediction | None = None,
        t0_s: float = 0.0,
        max_iterations: int | None = None,
        v_limit_fn=None,
    ) -> MPCSolution:
        """Solve one NMPC problem (eq. 11 for the leader, eq. 12 for a follower) from plain data.

        ``x0`` = (s, v, F) now; ``z_warm`` the warm start (normalised force increments, e.g.
        :meth:`MPCSolution.warm_start` of the previous step; None: hold the current force);
        ``lookup`` gives gradient, tunnel factor and v_lim(s) (None: level track, limit from
        ``v_limit_fn`` or unlimited); ``terminal`` the terminal set (a
        :class:`~vcsumo.control.mpc_terminal.TerminalSet` or :class:`SpeedProfile`; None: no
        terminal speed bound); ``v_ref_mps`` scalar or N-vector: v_max of 11a (leader; a follower
        tracks ``leader.speeds_mps``, 12b); ``v_scale_mps`` the v_max normalising 11a/12b.
        ``max_iterations`` given: iterate the SQP to convergence (at most that many iterations);
        None: real-time iteration (one, more only while the plan violates a constraint).  Never
        raises on an infeasible problem: the solution then has ``ok = False`` and the full brake.
        """
        t_start = time.perf_counter()
        cfg, N, dt = self.cfg, self.N, self.dt
        try:
            x0 = np.array([float(x0[0]), max(float(x0[1]), 0.0), float(x0[2])])
            if not np.all(np.isfinite(x0)):
                raise ValueError("non-finite state")
            if z_warm is None:
                z = np.zeros(N)
            else:
                z = np.minimum(np.maximum(np.asarray(z_warm, dtype=float).ravel()[:N], -self.z_max), self.z_max)
                if len(z) < N:
                    z = np.append(z, np.zeros(N - len(z)))
                z = np.where(np.isfinite(z), z, 0.0)
            if self.follower:
                if leader is None:
                    raise ValueError("the follower NMPC needs a leader prediction")
                srear = np.asarray(leader.rear_m[1 : N + 1], dtype=float)
                vref = np.asarray(leader.speeds_mps[1 : N + 1], dtype=float)
                vl_N = float(leader.speeds_mps[N])
                fw = (cfg.k_d, cfg.d_des_m, cfg.d_min_m, 1.0 / (2.0 * cfg.a_follower_mps2))
                w = (cfg.k_v_follower, cfg.k_j_follower, float(v_scale_mps), vl_N * vl_N / (2.0 * cfg.a_leader_mps2))
                if not (np.all(np.isfinite(srear)) and np.all(np.isfinite(vref))):
                    raise ValueError("non-finite leader prediction")
            else:
                srear, vl_N, fw = None, 0.0, None
                vref = np.broadcast_to(np.asarray(v_ref_mps, dtype=float), (N,))
                w = (cfg.k_v_leader, cfg.k_j_leader, float(v_scale_mps), 0.0)
            converge = max_iterations is not None
            iters = max_iterations or cfg.sqp_max_iterations
            S, V = self.simulate(x0, z, lookup)  # a-priori estimate (eq. 14)
            sol = None
            for it in range(1, iters + 1):
                s_k = np.empty(N)
                s_k[0] = x0[0]
                s_k[1:] = S[:-1]  # positions k = 0..N-1 for the dynamics data
                grad, tf = self.space_terms(lookup, s_k)
                vlim = self._vlim(lookup, v_limit_fn, S)
                term = self._term(terminal, x0, z, S, V)
                z_new, S, V, slacks, cost, solved = self.sqp_iteration(x0, z, grad, tf, vlim, term, vref, w, srear, fw)
                if not solved:
                    break
                step_norm = float(np.max(np.abs(z_new - z)))
                z = z_new
                # check the nonlinear plan against every constraint
                vlim_chk = vlim if it == 1 and not converge else np.minimum(vlim, self._vlim(lookup, v_limit_fn, S))
                beta_N = float(self._term(terminal, x0, z, S, V)[0])
                viol = self._violations(x0, z, S, V, vlim_chk, beta_N, srear, vl_N)
                terminal_ok = viol["terminal_speed_mps"] <= cfg.tol_speed_mps or viol["terminal_overshoot_m"] <= cfg.tol_gap_m
                ok = (viol["speed_mps"] <= cfg.tol_speed_mps and terminal_ok and viol["gap_m"] <= cfg.tol_gap_m
                      and viol["terminal_set_m"] <= cfg.tol_gap_m and viol["power_rel"] <= cfg.tol_power_rel and viol["force_n"] <= 1.0)
                sol = (ok, z, S, V, slacks, viol, it, vlim, term, cost)
                if ok and (not converge or step_norm < 1e-7):
                    break
        except Exception as exc:  # never raise: brake
            return self._fallback(x0, t0_s, None, leader, t_start, f"error: {exc!r}")
        if sol is None:
            return self._fallback(x0, t0_s, lookup, leader, t_start, "the QP solver failed")
        ok, z, S, V, slacks, viol, it, vlim, term, cost = sol
        F, u = self.forces(x0[2], z)
        force_now = float(u[0]) if ok else float(-brake_force_limit(self.p, x0[1]))
        return MPCSolution(ok=ok, force_n=force_now, times_s=t0_s + dt * np.arange(N + 1), positions_m=np.concatenate(([x0[0]], S)),
                           speeds_mps=np.concatenate(([x0[1]], V)), forces_n=F, commands_n=u, z=z, slacks=slacks, violation=viol, iterations=it,
                           solve_time_s=time.perf_counter() - t_start, v_limit_mps=vlim, v_terminal_mps=math.sqrt(max(term[0], 0.0)),
                           leader=leader, cost=cost)

    def _term(self, terminal, x0, z, S, V) -> np.ndarray:
        """Terminal-set data (11i/12k) at the linearisation point: [β, dβ/ds, c] with β = v_DP(s)²
        evaluated at s̄_N + c·v̄_N.  c = t_r/2, t_r the time to ramp the force from F̄_N to the full
        brake at the jerk limit (eq. 4c): a ramp acts as a dead time of half its length
        (``terminal_ramp_allowance``; c = 0 gives the paper's v_N ≤ v_DP(s_N))."""
        if terminal is None:
            return np.array([1e6, 0.0, 0.0])
        c = 0.0
        if self.cfg.terminal_ramp_allowance:
            F_N = x0[2] + self.z_scale * float(z.sum())
            c = 0.5 * max(F_N - self.u_min, 0.0) * self.dt / (self.z_max * self.z_scale)
        beta, slope = terminal.beta(float(S[-1]) + c * float(V[-1]))
        return np.array([float(beta), float(slope), c])

    def _vlim(self, lookup, v_limit_fn, S) -> np.ndarray:
        if v_limit_fn is not None:
            return np.asarray(v_limit_fn(S), dtype=float)
        if lookup is None:
            return np.full(self.N, 1e3)
        return np.minimum(lookup.speed_limit(S), self.p.max_speed_ms)

    def _violations(self, x0, z, S, V, vlim, beta_N, srear, vl_N) -> dict:
        """Largest violation of each constraint on a plan (0 when satisfied)."""
        cfg = self.cfg
        zs = self.z_scale
        u = x0[2] + zs * (np.cumsum(z) - z) + (zs / self.alpha) * z
        vprev = np.empty(self.N)
        vprev[0] = x0[1]
        vprev[1:] = V[:-1]
        pw = u * vprev
        p_hi = float(pw.max()) - self.p_dr
        p_lo = (-self.p_br - float(pw.min())) if math.isfinite(self.p_br) else -1.0
        vb = math.sqrt(max(beta_N, 0.0))
        out = {
            "force_n": max(float(u.max()) - self.u_max, self.u_min - float(u.min()), 0.0),
            "power_rel": max(p_hi / self.p_dr, p_lo / self.p_br if math.isfinite(self.p_br) else 0.0, 0.0),
            "speed_mps": max(float((V - vlim).max()), 0.0),
            # v_N² ≤ β as a speed excess: √(v_N² − β + v_b²) − v_b, v_b = √max(β, 0)
            "terminal_speed_mps": max(math.sqrt(max(V[-1] ** 2 - beta_N, 0.0) + vb * vb) - vb, 0.0),
            # … and as the extra distance it needs to stop, (v_N² − β)/(2·a_br)
            "terminal_overshoot_m": max(V[-1] ** 2 - beta_N, 0.0) / (2.0 * self.p.service_brake_decel_mps2),
            "gap_m": 0.0,
            "terminal_set_m": 0.0,
        }
        if srear is not None:
            d = srear - S
            out["gap_m"] = max(cfg.d_min_m - float(d.min()), 0.0)
            h = d[-1] + vl_N**2 / (2 * cfg.a_leader_mps2) - V[-1] ** 2 / (2 * cfg.a_follower_mps2)
            out["terminal_set_m"] = max(cfg.d_min_m - h, 0.0)
        return out

    def fallback(self, x0, t0_s: float, lookup: RouteLookup | None = None, leader: LeaderPrediction | None = None, reason: str = "") -> MPCSolution:
        """The safe solution: full service brake now (−min(M·a_br, P_br/v)), plan = braking at the jerk limit."""
        return self._fallback(x0, t0_s, lookup, leader, time.perf_counter(), reason)

    def _fallback(self, x0, t0_s, lookup, leader, t_start, reason) -> MPCSolution:
        N = self.N
        try:
            x0 = np.array([float(x0[0]), max(float(x0[1]), 0.0), float(x0[2])])
            t0_s = float(t0_s)
            if not (np.all(np.isfinite(x0)) and math.isfinite(t0_s)):
                raise ValueError("non-finite state")
            z = np.full(N, -self.z_max)
            F, u = self.forces(x0[2], z)
            k = np.flatnonzero(F[1:] < self.u_min)
            if len(k):  # hold the full brake once reached
                z[k[0]:] = 0.0
                z[k[0]] = (self.u_min - F[k[0]]) / self.z_scale
                F, u = self.forces(x0[2], z)
            S, V = self.simulate(x0, z, lookup)
            return MPCSolution(ok=False, force_n=float(-brake_force_limit(self.p, x0[1])), times_s=t0_s + self.dt * np.arange(N + 1),
                               positions_m=np.concatenate(([x0[0]], S)), speeds_mps=np.concatenate(([x0[1]], V)), forces_n=F, commands_n=u, z=z,
                               slacks=np.zeros(self.ns), violation={"reason": reason}, iterations=0,
                               solve_time_s=time.perf_counter() - t_start, v_limit_mps=np.full(N, np.nan), v_terminal_mps=math.nan, leader=leader)
        except Exception:  # not even a state to plan from: full service brake, no plan
            nan = np.full(N + 1, np.nan)
            return MPCSolution(ok=False, force_n=self.u_min, times_s=nan, positions_m=nan, speeds_mps=nan, forces_n=nan, commands_n=nan[:-1],
                               z=np.zeros(N), slacks=np.zeros(self.ns), violation={"reason": reason}, iterations=0,
                               solve_time_s=time.perf_counter() - t_start, v_limit_mps=nan[:-1], v_terminal_mps=math.nan, leader=leader)
