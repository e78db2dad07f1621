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
    speed_relaxation_mps: float = 0.0
    """How far the speed constraint was raised above v_lim because no plan can keep below it from
    the initial state (:func:`speed_floor`: the present force, the lag and the jerk limit), m/s."""

    def warm_start(self) -> np.ndarray:
        """Eq. 14b-c: the plan shifted by one step, last increment zero (holds the last force)."""
        return np.append(self.z[1:], 0.0)


def speed_floor(ocp, x0, speeds) -> np.ndarray:
    """The lowest speed the prediction model can reach at each step k = 1 … N from x0 = (s, v, F), m/s.

    The applied force comes down as fast as the model allows: at the jerk limit (4c/12o), each
    command u_k = F_k + ΔF_k/α within the service brake (4a) and the braking power (4b, at the
    speeds of this same plan); the force then holds the bound.  Since v_{k+1} grows with v_k and
    with F_{k+1}, no admissible plan is slower at any step, so a plan that starts at or just above
    a speed limit with a force that the lag and the jerk limit cannot reverse in time exceeds the
    limit by at least ``floor − v_lim`` over the first steps: :meth:`CondensedNMPC.solve` relaxes
    the limit to max(v_lim, floor), only where the floor is above it.  ``ocp`` is a
    :class:`CondensedNMPC` (or an object with its ``N``, ``z_scale``, ``z_max``, ``alpha``,
    ``u_min``, ``p_br``); ``speeds(z)`` gives the model's speeds k = 1 … N for increments z (the
    solve evaluates the model with the gradient along its a-priori plan: the floor's own positions
    are a few metres behind, which the gradient averaged over the train barely notices).
    """
    N, zs, zmax, alpha = ocp.N, ocp.z_scale, ocp.z_max, ocp.alpha
    u_lo = np.full(N, ocp.u_min)
    z = np.empty(N)
    V = None
    for _ in range(2 if math.isfinite(ocp.p_br) else 1):
        if V is not None:  # braking power 4b at the speeds of the first pass: −P_br/v_k ≤ u_k
            v_prev = np.concatenate(((x0[1],), V[:-1]))
            np.maximum(u_lo, -ocp.p_br / np.maximum(v_prev, 1e-3), out=u_lo)
            if not np.any(u_lo > ocp.u_min):  # the power bound does not bind: the first pass is the floor
                break
        F = float(x0[2])
        d0, c = F - ocp.u_min, zmax * zs
        if V is None and d0 >= 0.0 and alpha < 1.0:  # closed form: down at the jerk limit, then the lag's approach to u_min
            k = np.arange(N + 1)
            k1 = int(math.floor((d0 - c / alpha) / c)) + 1 if alpha * d0 >= c else 0  # steps at the jerk limit
            d = np.where(k <= k1, d0 - k * c, (d0 - k1 * c) * (1.0 - alpha) ** np.maximum(k - k1, 0))
            np.divide(np.diff(d), zs, out=z)
        else:
            for k in range(N):
                zk = min(max(-zmax, alpha * (u_lo[k] - F) / zs), zmax)
                z[k] = zk
                F += zk * zs
        V = np.array(speeds(z), dtype=float)
    return V


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
        cfg, N = self.cfg, self.N
        try:
            s0, v0, f0 = float(x0[0]), max(float(x0[1]), 0.0), float(x0[2])
            if not (math.isfinite(s0) and math.isfinite(v0) and math.isfinite(f0)):
                raise ValueError("non-finite state")
            x0 = (s0, v0, f0)
            z = self._warm_z(z_warm)
            if self.follower:
                if leader is None:
                    raise ValueError("the follower NMPC needs a leader prediction")
                np.subtract(leader.positions_m[1 : N + 1], leader.length_m, out=self.srear)  # leader rear (eq. 8)
                self.vref[:] = leader.speeds_mps[1 : N + 1]
                vl_N = float(leader.speeds_mps[N])
                if not (math.isfinite(self.srear.sum()) and math.isfinite(self.vref.sum())):
                    raise ValueError("non-finite leader prediction")
                self.set_weights(cfg.k_v_follower, cfg.k_j_follower, float(v_scale_mps), vl_N * vl_N / (2.0 * cfg.a_leader_mps2), cfg.k_d,
                                 cfg.d_des_m, cfg.d_min_m, 1.0 / (2.0 * cfg.a_follower_mps2))
            else:
                self.vref[:] = v_ref_mps
                self.set_weights(cfg.k_v_leader, cfg.k_j_leader, float(v_scale_mps), 0.0)
            converge = max_iterations is not None
            iters = max_iterations or cfg.sqp_max_iterations
            S, V = self.simulate(x0, z, lookup)  # a-priori estimate (eq. 14); sets x0, z, grad, tf
            S, V = S.copy(), V.copy()
            floor = speed_floor(self, x0, self._speeds)  # the speeds no plan can stay below (lag, jerk)
            self.z[:] = z
            relax = 0.0
            F_N = f0 + self.z_scale * float(z.sum())
            varying = lookup is not None and not lookup.uniform
            sol = None
            for it in range(1, iters + 1):
                if varying:  # gradient and tunnel factor at the positions k = 0..N-1 of the latest plan
                    s_k = np.concatenate(((s0,), S[:-1]))
                    self.grad[:], self.tf[:] = lookup.gradient(s_k), lookup.tunnel_factor(s_k)
                self._set_vlim(lookup, v_limit_fn, S, self.vlim)
                relax = max(float((floor - self.vlim).max()), 0.0)
                np.maximum(self.vlim, floor, out=self.vlim)  # relaxed only where unavoidable
                beta, dbeta, c = self._term(terminal, F_N, S[-1], V[-1])
                self.term[:] = (beta, dbeta, c)
                if not self.sqp_iteration():
                    break
                step_norm = float(np.abs(self.z_new - self.z).max()) if converge else 0.0
                S, V, F_N = self.pos[1:], self.spd[1:], float(self.F[-1])
                # check the nonlinear plan against every constraint
                f_v, p_v, sp_v, g_v, ts_v = self.viol[:5].tolist()
                if it > 1 or converge:
                    vlim_chk = np.maximum(np.minimum(self.vlim, self._set_vlim(lookup, v_limit_fn, S, np.empty(N))), floor)
                    sp_v = max(float((V - vlim_chk).max()), 0.0)
                beta_N = self._term(terminal, F_N, S[-1], V[-1])[0]
                v_N = float(V[-1])
                excess = max(v_N * v_N - beta_N, 0.0)
                vb = math.sqrt(max(beta_N, 0.0))
                viol = {"force_n": f_v, "power_rel": p_v, "speed_mps": sp_v,
                        # v_N² ≤ β as a speed excess: √(v_N² − β + v_b²) − v_b, v_b = √max(β, 0)
                        "terminal_speed_mps": max(math.sqrt(excess + vb * vb) - vb, 0.0),
                        # … and as the extra distance it needs to stop, (v_N² − β)/(2·a_br)
                        "terminal_overshoot_m": excess / (2.0 * self.p.service_brake_decel_mps2), "gap_m": g_v, "terminal_set_m": ts_v}
                terminal_ok = viol["terminal_speed_mps"] <= cfg.tol_speed_mps or viol["terminal_overshoot_m"] <= cfg.tol_gap_m
                ok = (sp_v <= cfg.tol_speed_mps and terminal_ok and g_v <= cfg.tol_gap_m
                      and ts_v <= cfg.tol_gap_m and p_v <= cfg.tol_power_rel and f_v <= 1.0)
                plan = (self.z_new, self.pos, self.spd, self.F, self.u, self.dx[N:], self.vlim)
                sol = (ok, viol, it, beta, self._cost[0], relax)
                if ok and (not converge or step_norm < 1e-7):
                    break
                plan = tuple(a.copy() for a in plan)  # the buffers are rewritten by the next iteration
                z[:] = self.z_new
                self.z[:] = z
        except Exception as exc:  # never raise: brake
            return self._fallback(x0, t0_s, None, leader, t_start, f"error: {exc!r}")
        if sol is None:
            return self._fallback(x0, t0_s, lookup, leader, t_start, "the QP solver failed")
        ok, viol, it, beta, cost, relax = sol
        z, pos, spd, F, u, slacks, vlim = (a.copy() for a in plan)
        force_now = float(u[0]) if ok else float(-brake_force_limit(self.p, x0[1]))
        return MPCSolution(ok=ok, force_n=force_now, times_s=t0_s + self._k_dt, positions_m=pos, speeds_mps=spd, forces_n=F, commands_n=u, z=z,
                           slacks=slacks, violation=viol, iterations=it, solve_time_s=time.perf_counter() - t_start, v_limit_mps=vlim,
                           v_terminal_mps=math.sqrt(max(beta, 0.0)), leader=leader, cost=float(cost),
                           speed_relaxation_mps=relax)

    def _speeds(self, z: np.ndarray) -> np.ndarray:
        """The model's speeds k = 1 … N for increments z from ``x0`` with the present ``grad`` and ``tf`` (overwrites ``z``)."""
        self.z[:] = z
        self._sim_eval()
        return self._sim_out[1].copy()

    def _warm_z(self, z_warm) -> np.ndarray:
        """The warm start within the jerk bounds, padded with zeros to N, non-finite entries zero (a new array)."""
        N, zmax = self.N, self.z_max
        if z_warm is None:
            return np.zeros(N)
        zw = np.asarray(z_warm, dtype=float).ravel()[:N]
        z = np.minimum(zw, zmax) if len(zw) == N else np.append(np.minimum(zw, zmax), np.zeros(N - len(zw)))
        np.maximum(z, -zmax, out=z)
        if not math.isfinite(z.sum()):
            z[~np.isfinite(z)] = 0.0
        return z

    def _term(self, terminal, F_N: float, s_N: float, v_N: float) -> tuple[float, float, float]:
        """Terminal-set data (11i/12k) at the linearisation point: (β, dβ/ds, c) with β = v_DP(s)²
        evaluated at s̄_N + c·v̄_N.  c = t_r/2, t_r the time to ramp the force from F̄_N to the full
        brake at the jerk limit (eq. 4c): a ramp acts as a dead time of half its length
        (``terminal_ramp_allowance``; c = 0 gives the paper's v_N ≤ v_DP(s_N))."""
        if terminal is None:
            return 1e6, 0.0, 0.0
        c = 0.0
        if self.cfg.terminal_ramp_allowance:
            c = 0.5 * max(F_N - self.u_min, 0.0) * self.dt / (self.z_max * self.z_scale)
        beta, slope = terminal.beta(float(s_N) + c * float(v_N))
        return float(beta), float(slope), c

    def _set_vlim(self, lookup, v_limit_fn, S, out: np.ndarray) -> np.ndarray:
        """v_lim at the positions S (k = 1 … N), written into ``out``."""
        if v_limit_fn is not None:
            out[:] = v_limit_fn(S)
        elif lookup is None:
            out.fill(1e3)
        else:
            np.minimum(lookup.speed_limit(S), self.p.max_speed_ms, out=out)
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
