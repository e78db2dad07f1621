"""The compiled NMPC (``mpc_qp``/``mpc_solver``) against the numpy formulation it replaced.

:class:`ReferenceNMPC` is the follower/leader NMPC solve as it was before the QP assembly was
compiled into CasADi functions (vcsumo main@4c41627, ``CondensedQP.sqp_iteration`` and
``CondensedNMPC.solve``): the QP built in numpy from the model's Jacobians, the plan checked in
numpy.  Only its CasADi functions (the model, its Jacobians, qpOASES) come from the package; the
tests run the same closed loops with both and compare commands and plans step by step.
"""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np
import pytest

from vcsumo.control.base import Message, Observation, TrainStateMsg
from vcsumo.control.mpc import FollowerMPC, LeaderMPC, MPCSettings, load_mpc_settings
from vcsumo.control.mpc_qp import CondensedQP
from vcsumo.control.mpc_solver import MPCSolution, speed_floor
from vcsumo.control.predictors import LeaderPrediction, lag_alpha
from vcsumo.control.route_lookup import RouteLookup, route_profile_from_arrays, straight_route_profile
from vcsumo.dynamics import TrainParams, brake_force_limit
from vcsumo.line import project_root
from vcsumo.plant import PlantState, TrainPlant
from vcsumo.rolling_stock import load_rolling_stock

_quiet_stdout = contextlib.nullcontext


def _bind(fn, inputs: list, outputs: list):
    buf, ev = fn.buffer()
    for i, a in enumerate(inputs):
        buf.set_arg(i, memoryview(a))
    for i, a in enumerate(outputs):
        buf.set_res(i, memoryview(a))
    return buf, ev


class ReferenceNMPC:
    """The numpy NMPC solve of main@4c41627 (unchanged code), on the package's CasADi model and qpOASES."""

    def __init__(self, params: TrainParams, settings: MPCSettings, follower: bool):
        self.p = params
        self.cfg = settings
        self.follower = follower
        self.N = N = settings.horizon_steps
        self.dt = settings.step_s
        self.alpha = lag_alpha(params, self.dt)
        M = params.mass_kg
        self.u_max = float(params.max_traction_n)  # M·a_dr (4a)
        self.u_min = -float(M * params.service_brake_decel_mps2)  # −M·a_br (4a)
        self.p_dr = float(params.max_power_w)
        self.p_br = float(params.max_brake_power_w)
        if math.isfinite(params.max_jerk_mps3):
            self.z_scale = params.max_jerk_mps3 * M * self.dt  # j_max·M·Δt, N
            self.z_max = 1.0 if settings.jerk_limit_on == "force" else min(1.0, self.alpha)
        else:
            self.z_scale = (self.u_max - self.u_min) * self.alpha
            self.z_max = 1.0
        self.ns = ns = 3 if follower else 2  # slacks: speed limit, terminal set, (d_min)
        self.n = n = N + ns
        self.m = m = 3 * N + 1 + (N + 1 if follower else 0)
        lin, sim, qp = (CondensedQP(params, settings, follower).functions[k] for k in ("lin", "sim", "qp"))
        self._qp_fn = qp
        # evaluation buffers: CasADi reads and writes these numpy arrays in place (no conversions)
        self._lin_in = [np.zeros(3), np.zeros(N), np.zeros(N), np.ones(N)]
        self._lin_out = [np.zeros(N), np.zeros(N), np.zeros(N * N), np.zeros(N * N)]
        self._lin_buf, self._lin_eval = _bind(lin, self._lin_in, self._lin_out)
        self._Js = self._lin_out[2].reshape((N, N), order="F")
        self._Jv = self._lin_out[3].reshape((N, N), order="F")
        self._sim_in = [np.zeros(3), np.zeros(N), np.zeros(N), np.ones(N)]
        self._sim_out = [np.zeros(N), np.zeros(N)]
        self._sim_buf, self._sim_eval = _bind(sim, self._sim_in, self._sim_out)
        self._qp_in = {name: np.zeros(qp.nnz_in(i)) for i, name in enumerate(qp.name_in())}
        self._qp_out = [np.zeros(qp.nnz_out(i)) for i in range(qp.n_out())]
        q = self._qp_in
        self._H = q["h"].reshape((n, n), order="F")
        self._A = q["a"].reshape((m, n), order="F")
        # constant parts of the QP: slack columns, slack cost, u = F_k + ΔF_k/α rows (4a)
        self.Ju = self.z_scale * (np.tril(np.ones((N, N)), -1) + np.eye(N) / self.alpha)
        self._A[:N, :N] = self.Ju
        self._A[2 * N : 3 * N, N] = -1.0  # speed-limit slack
        self._A[3 * N, N + 1] = -1.0  # terminal slack
        if follower:
            self._A[3 * N + 1 : 4 * N + 1, N + 2] = -1.0  # d_min slack
            self._A[4 * N + 1, N + 1] = 1.0  # terminal set 12m shares the terminal slack
        self._H[N:, N:] = 1e-6 * np.eye(ns)
        q["g"][N:] = settings.slack_penalty
        q["lbx"][N:] = 0.0
        q["ubx"][N:] = np.inf
        q["lba"][2 * N : 3 * N + 1] = -np.inf
        if follower:
            q["lba"][3 * N + 1 : 4 * N + 1] = -np.inf
            q["uba"][4 * N + 1] = np.inf
        self._eyeN = np.eye(N)
        self._reset_qp()

    def _reset_qp(self) -> None:
        N, q = self.N, self._qp_in
        with _quiet_stdout():
            self._qp_buf, self._qp_eval = _bind(self._qp_fn, [q[k] for k in self._qp_fn.name_in()], self._qp_out)
            q["lbx"][:N], q["ubx"][:N] = -1.0, 1.0
            q["uba"][:N], q["lba"][:N] = 1.0, -1.0
            self._H[:N, :N] = self._eyeN
            try:
                self._qp_eval()
            except Exception:
                pass


    def sqp_iteration(self, x0, z, grad, tf, vlim, term, vref, w, srear, fw) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, bool]:
        N, ns = self.N, self.ns
        li = self._lin_in
        li[0][:] = x0
        li[1][:] = z
        li[2][:] = grad
        li[3][:] = tf
        self._lin_eval()
        S, V = self._lin_out[0], self._lin_out[1]
        Js, Jv = self._Js, self._Jv
        H, A, q = self._H, self._A, self._qp_in
        zs = self.z_scale
        cz = np.cumsum(z)
        U = x0[2] + zs * (cz - z) + (zs / self.alpha) * z  # u_k = F_k + ΔF_k/α
        w_v, w_j, vsc, c_l = w
        # Gauss-Newton cost 11a-b / 12a-c: residuals r and Jacobians J, H = 2·Σ w·JᵀJ, g = 2·Σ w·Jᵀr
        rv = (vref - V) / vsc
        Jrv = Jv * (-1.0 / vsc)
        Hz = (2.0 * w_v) * (Jrv.T @ Jrv)
        gz = (2.0 * w_v) * (Jrv.T @ rv) + (2.0 * w_j) * z
        cost = w_v * float(rv @ rv) + w_j * float(z @ z)
        if self.follower:
            w_d, d_des, d_min, inv2af = fw
            rd = 1.0 - (srear - S) / d_des
            Jrd = Js * (1.0 / d_des)
            Hz += (2.0 * w_d) * (Jrd.T @ Jrd)
            gz += (2.0 * w_d) * (Jrd.T @ rd)
            cost += w_d * float(rd @ rd)
        Hz += (2.0 * w_j + 1e-8) * self._eyeN
        H[:N, :N] = Hz
        q["g"][:N] = gz
        # force rows 4a: constant Jacobian
        q["lba"][:N] = self.u_min - U
        q["uba"][:N] = self.u_max - U
        # power rows 4b: d(u_k·v_k) = v_k·du_k + u_k·dv_k
        vprev = np.empty(N)
        vprev[0] = x0[1]
        vprev[1:] = V[:-1]
        PW = U * vprev
        Ap = A[N : 2 * N, :N]
        np.multiply(self.Ju, vprev[:, None], out=Ap)
        Ap[1:] += U[1:, None] * Jv[:-1]
        q["lba"][N : 2 * N] = (-self.p_br if math.isfinite(self.p_br) else -np.inf) - PW
        q["uba"][N : 2 * N] = self.p_dr - PW
        # speed limit 11e/12g at the a-priori positions (eq. 14)
        A[2 * N : 3 * N, :N] = Jv
        q["uba"][2 * N : 3 * N] = vlim - V
        # terminal set 11i/12k as v_N² ≤ β(s_N + c·v_N), linearised
        beta, dbeta, c_sh = term
        A[3 * N, :N] = (2.0 * V[-1] - dbeta * c_sh) * Jv[-1] - dbeta * Js[-1]
        q["uba"][3 * N] = beta - V[-1] ** 2
        if self.follower:
            # d_min 12f/12l and the invariant set 12m: d_N + c_l − v_N²/(2a^f) ≥ d_min
            A[3 * N + 1 : 4 * N + 1, :N] = Js
            q["uba"][3 * N + 1 : 4 * N + 1] = srear - d_min - S
            h = srear[-1] - S[-1] + c_l - V[-1] ** 2 * inv2af
            A[4 * N + 1, :N] = -Js[-1] - (2.0 * V[-1] * inv2af) * Jv[-1]
            q["lba"][4 * N + 1] = d_min - h
        q["lbx"][:N] = -self.z_max - z
        q["ubx"][:N] = self.z_max - z
        try:
            self._qp_eval()
            x = self._qp_out[0]
            solved = self._qp_buf.ret() == 0 and bool(np.all(np.isfinite(x)))
        except Exception:  # qpOASES failed (its hot start is unusable now): fresh memory, cold start next time
            solved = False
            x = np.zeros(self.n)
        if not solved:
            self._reset_qp()
        z_new = np.minimum(np.maximum(z + x[:N], -self.z_max), self.z_max)
        si = self._sim_in
        si[0][:] = x0
        si[1][:] = z_new
        si[2][:] = grad
        si[3][:] = tf
        self._sim_eval()
        return z_new, self._sim_out[0].copy(), self._sim_out[1].copy(), x[N:].copy(), cost, solved

    # ---------------------------------------------------------------------------------------
    def simulate(self, x0, z, lookup: RouteLookup | None) -> tuple[np.ndarray, np.ndarray]:
        N = self.N
        xi, zi, gi, ti = self._sim_in
        xi[:] = x0
        zi[:] = z
        s_est = x0[0] + x0[1] * self.dt * np.arange(N)
        passes = 1 if lookup is None or lookup.uniform else 2
        for _ in range(passes):
            gi[:], ti[:] = self.space_terms(lookup, s_est)
            self._sim_eval()
            s_est = np.concatenate(([x0[0]], self._sim_out[0][:-1]))
        return self._sim_out[0].copy(), self._sim_out[1].copy()

    def _speeds(self, z) -> np.ndarray:
        """Speeds k = 1 … N for increments z with the gradient of the latest :meth:`simulate` (the speed floor)."""
        zi = self._sim_in[1]
        z_old = zi.copy()
        zi[:] = z
        self._sim_eval()
        zi[:] = z_old
        return self._sim_out[1].copy()

    def space_terms(self, lookup: RouteLookup | None, s_k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if lookup is None:
            return 0.0, 1.0
        if lookup.uniform:
            return lookup.gradient0, lookup.tunnel0
        return lookup.gradient(s_k), lookup.tunnel_factor(s_k)

    def forces(self, F0: float, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        F = np.empty(self.N + 1)
        F[0] = F0
        np.cumsum(z, out=F[1:])
        F[1:] *= self.z_scale
        F[1:] += F0
        u = F[:-1] + (self.z_scale / self.alpha) * z
        return F, u

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
            floor = speed_floor(self, x0, self._speeds)  # the speed limit is relaxed to this floor where it is above
            relax = 0.0
            sol = None
            for it in range(1, iters + 1):
                s_k = np.empty(N)
                s_k[0] = x0[0]
                s_k[1:] = S[:-1]  # positions k = 0..N-1 for the dynamics data
                grad, tf = self.space_terms(lookup, s_k)
                vlim = self._vlim(lookup, v_limit_fn, S)
                relax = max(float((floor - vlim).max()), 0.0)
                vlim = np.maximum(vlim, floor)
                term = self._term(terminal, x0, z, S, V)
                z_new, S, V, slacks, cost, solved = self.sqp_iteration(x0, z, grad, tf, vlim, term, vref, w, srear, fw)
                if not solved:
                    break
                step_norm = float(np.max(np.abs(z_new - z)))
                z = z_new
                # check the nonlinear plan against every constraint
                vlim_chk = vlim if it == 1 and not converge else np.maximum(np.minimum(vlim, self._vlim(lookup, v_limit_fn, S)), floor)
                beta_N = float(self._term(terminal, x0, z, S, V)[0])
                viol = self._violations(x0, z, S, V, vlim_chk, beta_N, srear, vl_N)
                terminal_ok = viol["terminal_speed_mps"] <= cfg.tol_speed_mps or viol["terminal_overshoot_m"] <= cfg.tol_gap_m
                ok = (viol["speed_mps"] <= cfg.tol_speed_mps and terminal_ok and viol["gap_m"] <= cfg.tol_gap_m
                      and viol["terminal_set_m"] <= cfg.tol_gap_m and viol["power_rel"] <= cfg.tol_power_rel and viol["force_n"] <= 1.0)
                sol = (ok, z, S, V, slacks, viol, it, vlim, term, cost, relax)
                if ok and (not converge or step_norm < 1e-7):
                    break
        except Exception as exc:  # never raise: brake
            return self._fallback(x0, t0_s, None, leader, t_start, f"error: {exc!r}")
        if sol is None:
            return self._fallback(x0, t0_s, lookup, leader, t_start, "the QP solver failed")
        ok, z, S, V, slacks, viol, it, vlim, term, cost, relax = sol
        F, u = self.forces(x0[2], z)
        force_now = float(u[0]) if ok else float(-brake_force_limit(self.p, x0[1]))
        return MPCSolution(ok=ok, force_n=force_now, times_s=t0_s + dt * np.arange(N + 1), positions_m=np.concatenate(([x0[0]], S)),
                           speeds_mps=np.concatenate(([x0[1]], V)), forces_n=F, commands_n=u, z=z, slacks=slacks, violation=viol, iterations=it,
                           solve_time_s=time.perf_counter() - t_start, v_limit_mps=vlim, v_terminal_mps=math.sqrt(max(term[0], 0.0)),
                           leader=leader, cost=cost, speed_relaxation_mps=relax)

    def _term(self, terminal, x0, z, S, V) -> np.ndarray:
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


# -------------------------------------------------------------------------------------------
# Closed loops: the compiled solver against the reference, each on its own plants

FORCE_TOL_N = 1e-3
"""Commands may differ by rounding only (the QP data are summed in another order: 1e-7 N measured
over these runs); 1 mN is 1e-8 of the train's traction.  Positions and speeds follow from it."""
STATE_TOL = 1e-8
"""Positions (m) and speeds (m/s) of plans and plants (1e-13 measured)."""


@pytest.fixture(scope="module")
def params() -> TrainParams:
    return load_rolling_stock("felez2019").params()


@pytest.fixture(scope="module")
def settings():
    return load_mpc_settings(project_root() / "controllers" / "mpc.yaml")


def use_reference(ctrl):
    ctrl.ocp = ReferenceNMPC(ctrl.params, ctrl.settings, follower=ctrl.follower)
    return ctrl


def convoy_run(params, cfg, route, steps: int, reference: bool, leader_end_m=None):
    """Leader NMPC + SH follower NMPC on two plants: start from rest at d_min, the leader accelerates
    to 20 m/s under the power limit, cruises and stops at ``leader_end_m``; the follower closes up.
    Returns per step: leader and follower command, follower plan speeds, positions, speeds, infeasible flags."""
    leader, follower = LeaderMPC(params, cfg, route_end_m=leader_end_m), FollowerMPC(params, cfg, predictor="SH")
    if reference:
        use_reference(leader), use_reference(follower)
    lp = TrainPlant(params, PlantState(100.0, 0.0, 0.0), route)
    fp = TrainPlant(params, PlantState(100.0 - params.length_m - cfg.d_min_m, 0.0, 0.0), route)
    out = {k: [] for k in ("u_l", "u_f", "plan_v_f", "plan_f_f", "s_l", "s_f", "v_f", "infeasible", "iterations")}
    dt, last = cfg.step_s, None
    for k in range(steps):
        t = k * dt
        xl, xf = lp.x, fp.x
        obs_l = Observation(time_s=t, step_s=dt, ego_id="L", ego=TrainStateMsg(t, xl.s_m, xl.v_mps, xl.accel_mps2, xl.force_n), params=params,
                            profile=route, target_speed_mps=20.0)
        cl = leader.make_step(obs_l)
        kw = {} if last is None else dict(plan_times_s=last.plan_times_s, plan_positions_m=last.plan_positions_m, plan_speeds_mps=last.plan_speeds_mps)
        msg = Message("L", t, TrainStateMsg(t, xl.s_m, xl.v_mps), params.length_m, **kw)
        obs_f = Observation(time_s=t, step_s=dt, ego_id="F", ego=TrainStateMsg(t, xf.s_m, xf.v_mps, xf.accel_mps2, xf.force_n), params=params,
                            profile=route, received={"L": msg}, predecessor="L", sensed_gap_m=xl.s_m - params.length_m - xf.s_m,
                            sensed_speed_mps=xl.v_mps, target_speed_mps=20.0)
        cf = follower.make_step(obs_f)
        lp.step(cl.force_n, dt)
        fp.step(cf.force_n, dt)
        last = cl
        for key, val in (("u_l", cl.force_n), ("u_f", cf.force_n), ("plan_v_f", cf.plan_speeds_mps), ("plan_f_f", cf.plan_forces_n), ("s_l", lp.x.s_m),
                         ("s_f", fp.x.s_m), ("v_f", fp.x.v_mps), ("infeasible", (cl.infeasible, cf.infeasible)),
                         ("iterations", (cl.info.get("sqp_iterations"), cf.info.get("sqp_iterations")))):
            out[key].append(val)
    return {k: np.array(v) for k, v in out.items()}


def assert_same_run(fast, ref):
    assert np.array_equal(fast["infeasible"], ref["infeasible"])
    assert np.array_equal(fast["iterations"], ref["iterations"])
    np.testing.assert_allclose(fast["u_l"], ref["u_l"], rtol=0, atol=FORCE_TOL_N)
    np.testing.assert_allclose(fast["u_f"], ref["u_f"], rtol=0, atol=FORCE_TOL_N)
    np.testing.assert_allclose(fast["plan_f_f"], ref["plan_f_f"], rtol=0, atol=FORCE_TOL_N)
    for key in ("plan_v_f", "s_l", "s_f", "v_f"):
        np.testing.assert_allclose(fast[key], ref[key], rtol=0, atol=STATE_TOL)


@pytest.mark.parametrize("horizon", [17, 40])
def test_convoy_closed_loop_matches_reference(params, settings, horizon):
    """Start, power-limited acceleration, cruise on 12m, the leader's stop at the end of its
    movement and the follower closing up: the same commands and trajectories as the numpy solver."""
    cfg = settings.model_copy(update={"horizon_steps": horizon, "a_follower_mps2": 0.75})
    route = straight_route_profile(1200.0, 27.78)
    fast = convoy_run(params, cfg, route, 900, reference=False, leader_end_m=700.0)
    ref = convoy_run(params, cfg, route, 900, reference=True, leader_end_m=700.0)
    assert ref["v_f"].max() > 15.0 and ref["v_f"][-1] < 0.5  # the run covers acceleration, cruise and the stop
    assert_same_run(fast, ref)


def test_restricted_route_closed_loop_matches_reference(params, settings):
    """A speed restriction and a climb (space-varying gradient, v_lim and terminal set), jerk on the command."""
    route = route_profile_from_arrays([0.0, 600.0, 800.0], [27.78, 12.0, 27.78], [0.0, 0.0, 0.01], length_m=2000.0)
    cfg = settings.model_copy(update={"horizon_steps": 17, "jerk_limit_on": "command", "a_follower_mps2": 0.75})
    fast = convoy_run(params, cfg, route, 1200, reference=False, leader_end_m=1500.0)
    ref = convoy_run(params, cfg, route, 1200, reference=True, leader_end_m=1500.0)
    assert ref["iterations"].max() > 1  # the restriction needs more than the real-time iteration somewhere
    assert_same_run(fast, ref)


@pytest.mark.parametrize("follower", [False, True])
def test_converged_and_infeasible_solves_match_reference(params, settings, follower):
    """Single solves iterated to convergence (``max_iterations``), from rest, cruising, braking into
    the leader and with the leader too close (infeasible: the fallback): the same plans."""
    cfg = settings.model_copy(update={"horizon_steps": 17})
    route = route_profile_from_arrays([0.0, 300.0, 400.0], [27.78, 12.0, 27.78], [0.0, 0.005, -0.01], length_m=1000.0)
    cls = FollowerMPC if follower else LeaderMPC
    fast, ref = cls(params, cfg), use_reference(cls(params, cfg))
    N, dt = cfg.horizon_steps, cfg.step_s
    cases = [((100.0, 0.0, 0.0), 40.0, 0.0), ((150.0, 20.0, 1e5), 80.0, 20.0), ((200.0, 25.0, 0.0), 20.0, 10.0), ((250.0, 15.0, -1e5), 3.0, 0.0)]
    n_bad = 0
    for x0, gap, vl in cases:
        kw = {}
        if follower:
            s_l = x0[0] + gap + params.length_m + vl * dt * np.arange(N + 1)
            kw["leader"] = LeaderPrediction(times_s=dt * np.arange(N + 1), positions_m=s_l, speeds_mps=np.full(N + 1, vl), length_m=params.length_m,
                                            strategy="SH")
        a = fast.solve_arrays(x0, profile=route, v_max_mps=20.0, max_iterations=10, **kw)
        b = ref.solve_arrays(x0, profile=route, v_max_mps=20.0, max_iterations=10, **kw)
        assert (a.ok, a.iterations) == (b.ok, b.iterations)
        n_bad += not b.ok
        np.testing.assert_allclose(a.commands_n, b.commands_n, rtol=0, atol=FORCE_TOL_N)
        np.testing.assert_allclose(a.speeds_mps, b.speeds_mps, rtol=0, atol=STATE_TOL)
        np.testing.assert_allclose(a.positions_m, b.positions_m, rtol=0, atol=STATE_TOL)
        assert a.force_n == pytest.approx(b.force_n, abs=FORCE_TOL_N)
        for key, val in b.violation.items():
            assert a.violation[key] == pytest.approx(val, abs=1e-9), key
    assert 0 < n_bad < len(cases)  # both paths: feasible plans and the fallback (25 m/s 100 m before a 12 m/s limit, a leader 3 m ahead)
