"""Cruise virtual-coupling control of Terlizzi, Liuzza & Glielmo (2024), §VI-D and §VI-E.

* :class:`PositionReferenceGenerator` — Algorithm 4: at each newer leader packet it computes the
  follower position references z_τ^F(t) of eq. 20–28 (one per τ_i = ω_i·τ̄, eq. 32–34) from the
  leader's robust planned trajectory x̲^L(t_κ) carried by the packet.
* :class:`SwitchedCruiseController` — Algorithm 5: selects K_3^F (x^F ≤ z_τ3, catch up),
  K_2^F (z_τ3 < x^F ≤ z_τ1, normal VC) or K_1^F (x^F > z_τ1, back off) and computes the selected
  mode's finite-horizon optimal control (eq. 35–37).  τ̄ comes from the delay estimator
  (Algorithm 3, :class:`vcsumo.control.cbf.DelayEstimator`) or is fixed.

Each mode's problem (eq. 35–37: ∫_t^{t+H} Θ^s(x1 − z_τ2)² + Θ^v(x2 − x̲2^L)² + Θ^u u² dr subject to
eq. 6) is solved as a real quadratic program, one per control step, by a real-time-iteration
scheme (:class:`CondensedMPC`):

* the nominal follower model eq. 5 is integrated with explicit Euler at ΔT^mpc over H (Table II);
* the running resistance and the gradient force are evaluated along the trajectory predicted at
  the previous step (one Gauss–Newton/SQP iteration per sample, as real-time NMPC does); the
  input enters linearly, so the prediction is affine in the input sequence;
* the input is move-blocked: ``blocks`` piecewise-constant values over H;
* constraints: eq. 6a and 6b as bounds (the power limit at the predicted block speed), eq. 6c
  (0 ≤ x2 ≤ min{V^max, V^line}) at the block ends as linear inequalities;
* the QP is solved to optimality by an exact active-set method: a primal–dual active-set
  iteration on the input bounds (:func:`box_qp`) and, when a speed bound is active, DAQP through
  CasADi's ``conic`` interface on the full problem.

The paper solves the same costs as NMPCs with PANOC; here the nonlinearity (Davis resistance,
gradient) is handled by relinearising every step.  The cost weights are those of Table II; the
input term uses u in kN (Table II gives no unit; kN makes Θ^u commensurate with the tracking
terms).  Table II lists a velocity weight Θ_1^v for K_1 which eq. 35 omits; it is used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import Field

from vcsumo.config import StrictModel, load_model
from vcsumo.control.base import Command, Message, Observation
from vcsumo.control.cbf import BarrierModel, CBFConfig, DelayEstimator
from vcsumo.control.proxies import BoxBounds, GradeWindow, RobustProxies
from vcsumo.dynamics import TrainParams
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.units import G


class CruiseConfig(StrictModel):
    """Parameters of the switched cruise controller (Table II where it gives them)."""

    name: str = Field(default="cruise_terlizzi2024", description="Identifier of the parameter set")
    notes: str = Field(default="", description="Provenance and assumptions")
    horizon_s: float = Field(default=12.0, gt=0, le=300, description="Prediction horizon H, s (Table II); at most 300 s")
    mpc_step_s: float = Field(default=0.06, ge=0.005, le=2, description="Integration step ΔT^mpc of the prediction model, s (Table II); 5 ms–2 s")
    blocks: int = Field(default=12, ge=1, le=60, description="Number of piecewise-constant input moves over H (move blocking), -")
    omega_1: float = Field(default=1.0, gt=0, description="ω1: τ1 = ω1·τ̄ (Table II), -")
    omega_2: float = Field(default=3.0, gt=0, description="ω2: τ2 = ω2·τ̄ (Table II), -")
    omega_3: float = Field(default=6.0, gt=0, description="ω3: τ3 = ω3·τ̄ (Table II), -")
    theta1_s_per_m2: float = Field(default=2.0, ge=0, description="Θ1^s, K1 position weight, 1/m² (Table II)")
    theta1_v_per_mps2: float = Field(default=0.225, ge=0, description="Θ1^v, K1 speed weight, 1/(m/s)² (Table II)")
    theta1_u_per_kn2: float = Field(default=1e-2, ge=0, description="Θ1^u, K1 input weight, 1/kN² (Table II)")
    theta2_s_per_m2: float = Field(default=2e-2, ge=0, description="Θ2^s, K2 position weight, 1/m² (Table II)")
    theta2_v_per_mps2: float = Field(default=10.0, ge=0, description="Θ2^v, K2 speed weight, 1/(m/s)² (Table II)")
    theta2_u_per_kn2: float = Field(default=5e-2, ge=0, description="Θ2^u, K2 input weight, 1/kN² (Table II)")
    theta3_s_per_m2: float = Field(default=1.0, ge=0, description="Θ3^s, K3 position weight, 1/m² (Table II)")
    theta3_u_per_kn2: float = Field(default=4e-3, ge=0, description="Θ3^u, K3 input weight, 1/kN² (Table II)")
    hold_v_per_mps2: float = Field(default=10.0, ge=0, description="Speed weight of the speed-hold mode used before the first packet, 1/(m/s)²")
    hold_u_per_kn2: float = Field(default=5e-2, ge=0, description="Input weight of the speed-hold mode, 1/kN²")
    delay_estimator: bool = Field(default=True, description="Use Algorithm 3 for τ̄ (false: τ̄ = fixed_delay_s)")
    delay_window: int = Field(default=50, ge=1, le=100000, description="N_Λ, number of delays kept by Algorithm 3, - (1–100,000)")
    delay_probability: float = Field(default=0.95, gt=0, le=1, description="p̄ of Algorithm 3, -")
    fixed_delay_s: float = Field(default=1.0, gt=0, le=600, description="τ̄ without the estimator (and before the first packet), s (at most 600)")
    reference_step_s: float = Field(default=0.5, ge=0.005, le=10, description="Time step of the reference trajectories z_τ (eq. 28), s (5 ms–10 s)")
    resolve_period_s: float = Field(default=0.0, ge=0, le=600, description="Re-solve the QP at most every this long unless a packet or a mode switch arrives, s, 0–600 (0: every step)")
    rlp_from_forces: bool = Field(default=True, description="Rebuild the leader's robust plan x̲^L (eq. 12) from the force plan in its packets (false: use the sent trajectory)")
    line_speed_limits: bool = Field(default=True, description="Respect the route's speed limits V^line in eq. 6c/22 (false: V^line = ∞ as the paper's constant 83 m/s)")


def load_cruise_config(path: str | Path) -> CruiseConfig:
    """Read a cruise parameter file (e.g. ``controllers/cruise_terlizzi2024.yaml``)."""
    return load_model(CruiseConfig, path)


# -------------------------------------------------------------------------------------------
# QP solver (CasADi conic interface)


class _QPSolver:
    """min ½uᵀHu + gᵀu s.t. lbx ≤ u ≤ ubx, lba ≤ A·u ≤ uba, for a fixed dense sparsity."""

    def __init__(self, n: int, m: int):
        import casadi as ca

        self.n, self.m = n, m
        hs = ca.Sparsity.dense(n, n)
        as_ = ca.Sparsity.dense(m, n)
        last = None
        for plugin, opts in (("daqp", {"error_on_fail": False}), ("qrqp", {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False})):
            try:
                self.solver = ca.conic("cruise_qp", plugin, {"h": hs, "a": as_}, opts)
                self.plugin = plugin
                break
            except Exception as exc:  # plugin not built into this CasADi
                last = exc
        else:  # pragma: no cover
            raise RuntimeError(f"no QP solver plugin available in CasADi: {last}")

    def solve(self, H: np.ndarray, g: np.ndarray, A: np.ndarray, lba: np.ndarray, uba: np.ndarray, lbx: np.ndarray, ubx: np.ndarray) -> tuple[np.ndarray, bool]:
        r = self.solver(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
        ok = bool(self.solver.stats().get("success", False))
        return np.asarray(r["x"], dtype=float).ravel(), ok


def box_qp(H: np.ndarray, g: np.ndarray, lb: np.ndarray, ub: np.ndarray, max_iter: int = 40, lower: np.ndarray | None = None, upper: np.ndarray | None = None, H_inv: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
    """min ½uᵀHu + gᵀu s.t. lb ≤ u ≤ ub (H positive definite) by a primal–dual active-set method.

    Hintermüller–Ito–Kunisch semismooth-Newton/PDAS iteration: fix the bound-active variables,
    solve the free block exactly, update the active sets from the primal infeasibility and the
    sign of the bound multipliers; stops when the sets repeat (then the KKT conditions hold
    exactly).  Returns (u, converged).
    """
    n = len(g)
    lower = np.zeros(n, dtype=bool) if lower is None else lower.copy()
    upper = np.zeros(n, dtype=bool) if upper is None else upper.copy() & ~lower
    u = np.empty(n)
    for it in range(max_iter):
        fixed = lower | upper
        nfix = int(fixed.sum())
        if nfix == 0:
            u = np.linalg.solve(H, -g) if H_inv is None else -(H_inv @ g)
            if np.all(u >= lb) and np.all(u <= ub):
                return u, True
        else:
            free = ~fixed
            u[lower] = lb[lower]
            u[upper] = ub[upper]
            if nfix < n:
                fi = np.flatnonzero(free)
                xi = np.flatnonzero(fixed)
                rhs = -g[fi] - H[np.ix_(fi, xi)] @ u[xi]
                u[fi] = np.linalg.solve(H[np.ix_(fi, fi)], rhs)
        free = ~fixed
        grad = H @ u + g  # bound multipliers: ≥ 0 at lower, ≤ 0 at upper
        new_lower = (free & (u < lb)) | (lower & (grad > 0))
        new_upper = (free & (u > ub)) | (upper & (grad < 0))
        new_lower &= ~new_upper
        if np.array_equal(new_lower, lower) and np.array_equal(new_upper, upper):
            return u, True
        lower, upper = new_lower, new_upper
    return np.clip(u, lb, ub), False




# -------------------------------------------------------------------------------------------
# Condensed MPC on the nominal model


@dataclass(frozen=True)
class Weights:
    """Running-cost weights: position (1/m²), speed (1/(m/s)²), input (1/kN²)."""

    s: float
    v: float
    u: float


@dataclass
class MPCSolution:
    """One QP solution: block forces and the predicted trajectory on the ΔT^mpc grid."""

    forces_n: np.ndarray
    """Force of each fine step (n_steps values), N."""
    times_s: np.ndarray
    """Absolute times of the predicted states (n_steps + 1 values), s."""
    positions_m: np.ndarray
    speeds_mps: np.ndarray
    ok: bool


class CondensedMPC:
    """Move-blocked linear-quadratic MPC over H on the nominal model eq. 5 (see module doc).

    Prediction (explicit Euler at δ = ΔT^mpc, k = 0 … N−1)::

        v_{k+1} = v_k + δ·(u_{j(k)}/(ρM) − r_k),    s_{k+1} = s_k + δ·v_k,
        r_k = (A + B·v̂_k + C·T_f·v̂_k²)/(ρM) + g·σ(ŝ_k)/ρ

    with (ŝ, v̂) the trajectory predicted at the previous call (shifted), so positions and speeds
    are affine in the block inputs u_j: s = s_free + G_s·u, v = v_free + G_v·u.  The cost
    δ·Σ_k [Θ^s(s_k − z_k)² + Θ^v(v_k − v^ref_k)² + Θ^u u_{j(k)}²] is a QP in u (kN).
    """

    def __init__(self, params: TrainParams, horizon_s: float, step_s: float, blocks: int, force_unit_n: float = 1000.0):
        self.p = params
        self.dt = step_s
        self.N = max(1, int(round(horizon_s / step_s)))
        self.nb = min(blocks, self.N)
        self.unit = force_unit_n
        N, nb = self.N, self.nb
        self.blk = (np.arange(N) * nb) // N
        E = np.zeros((N, nb))
        E[np.arange(N), self.blk] = 1.0
        self.E = E
        self.block_start = np.array([int(np.argmax(self.blk == j)) for j in range(nb)])
        self.block_end = np.array([N - 1 - int(np.argmax(self.blk[::-1] == j)) for j in range(nb)])
        inv_m = force_unit_n / (params.mass_kg * params.rotating_mass_factor)
        Lo = np.tril(np.ones((N, N)))
        Ls = np.tril(np.ones((N, N)), -1)
        d = step_s
        self.Gv = d * Lo @ E * inv_m  # v_1..v_N
        self.Gs = d * d * Lo @ Ls @ E * inv_m  # s_1..s_N
        self.A_speed = np.ascontiguousarray(self.Gv[self.block_end, :])  # speed at each block end
        self.GsT = np.ascontiguousarray(self.Gs.T)
        self.GvT = np.ascontiguousarray(self.Gv.T)
        self._tgrid = step_s * np.arange(N + 1)
        self._inv_mr = 1.0 / (params.mass_kg * params.rotating_mass_factor)
        self._g_r = G / params.rotating_mass_factor
        self._trac_max = params.max_traction_n / force_unit_n
        self._pow_max = params.max_power_w / force_unit_n
        self._brake_max = params.mass_kg * params.service_brake_decel_mps2 / force_unit_n
        self._brake_pow = params.max_brake_power_w / force_unit_n
        self._vmax_const = np.full(nb, params.max_speed_ms)
        self.EtE = E.T @ E
        self.GsTGs = self.Gs.T @ self.Gs
        self.GvTGv = self.Gv.T @ self.Gv
        self._H: dict[Weights, np.ndarray] = {}
        self._H_inv: dict[Weights, np.ndarray] = {}
        self.qp = _QPSolver(nb, nb)
        self.general_solves = 0
        self._active: dict[Weights, tuple[np.ndarray, np.ndarray]] = {}
        self._prev: MPCSolution | None = None

    def hessian(self, w: Weights) -> np.ndarray:
        H = self._H.get(w)
        if H is None:
            H = 2.0 * self.dt * (w.s * self.GsTGs + w.v * self.GvTGv + w.u * self.EtE)
            H = 0.5 * (H + H.T) + 1e-9 * np.eye(self.nb)
            self._H[w] = H
            self._H_inv[w] = np.linalg.inv(H)
        return H

    def reset(self) -> None:
        self._prev = None

    def _guess(self, t: float, s0: float, v0: float) -> tuple[np.ndarray, np.ndarray]:
        """(ŝ_k, v̂_k), k = 0..N−1: the previous prediction shifted to (t, s0, v0), else constant speed."""
        prev = self._prev
        if prev is not None and prev.ok and prev.times_s[0] <= t <= prev.times_s[-1]:
            tk = t + self._tgrid[:-1]
            ts, ps, vs = self._prev_ext
            v_hat = np.interp(tk, ts, vs)
            s_hat = np.interp(tk, ts, ps)
            v_hat += v0 - v_hat[0]
            s_hat += s0 - s_hat[0]
            np.maximum(v_hat, 0.0, out=v_hat)
            return s_hat, v_hat
        return s0 + v0 * self._tgrid[:-1], np.full(self.N, v0)

    def solve(self, t: float, s0: float, v0: float, z_ref: np.ndarray, v_ref: np.ndarray, w: Weights, route: GradeWindow, v_limit_mps: float, line_limits: bool) -> MPCSolution:
        """Solve the mode's QP from state (s0, v0) at time t.

        ``z_ref``, ``v_ref``: position and speed references at t + δ, …, t + N·δ (N values).
        """
        p, d, N = self.p, self.dt, self.N
        s0, v0 = float(s0), float(v0)
        s_hat, v_hat = self._guess(t, s0, v0)
        grade = route.grades_at(s_hat - 0.5 * p.length_m)
        # r_k: resistance and gradient per unit (rotating) mass along the guessed trajectory
        r = (p.davis_a_n + v_hat * (p.davis_b_n_per_mps + p.davis_c_n_per_mps2 * v_hat)) * self._inv_mr + grade * self._g_r
        v_free = np.cumsum(r)
        v_free *= -d
        v_free += v0  # v_1..v_N
        s_free = np.empty(N)
        s_free[0] = 0.0
        np.cumsum(v_free[:-1], out=s_free[1:])
        s_free += v0
        s_free *= d
        s_free += s0  # s_k = s0 + δ·Σ_{i<k} v_i, k = 1..N
        H = self.hessian(w)
        g = (2.0 * d * w.s) * (self.GsT @ (s_free - z_ref))
        if w.v:
            g += (2.0 * d * w.v) * (self.GvT @ (v_free - v_ref))
        vb_eps = v_hat[self.block_start]
        np.maximum(vb_eps, 0.1, out=vb_eps)
        ubx = np.minimum(self._trac_max, self._pow_max / vb_eps)  # eq. 6a, 6b (kN)
        lbx = -np.minimum(self._brake_max, self._brake_pow / vb_eps)
        vmax = self._vmax_const if v_limit_mps >= p.max_speed_ms else np.full(self.nb, v_limit_mps)
        if line_limits and route.profile is not None:
            vmax = np.minimum(vmax, route.speed_limits_at(s_hat[self.block_end]))
        ve = v_free[self.block_end]
        # eq. 6c at the block ends, kept feasible: never ask for more than full braking/traction gives
        uba = np.maximum(vmax - ve, self.A_speed @ lbx + 1e-6)
        lba = np.minimum(-ve, self.A_speed @ ubx - 1e-6)
        # box-constrained QP first; the general solver only when a speed bound (eq. 6c) is active
        warm = self._active.get(w)
        u, ok = box_qp(H, g, lbx, ubx, lower=None if warm is None else warm[0], upper=None if warm is None else warm[1], H_inv=self._H_inv[w])
        if ok:
            self._active[w] = (u <= lbx + 1e-12, u >= ubx - 1e-12)
            dv = self.A_speed @ u
            ok = bool((dv <= uba + 1e-6).all() and (dv >= lba - 1e-6).all())
        if not ok:
            self.general_solves += 1
            u, ok = self.qp.solve(H, g, self.A_speed, lba, uba, lbx, ubx)
            if not ok or not np.isfinite(u).all():
                big = np.full(self.nb, 1e12)
                u, ok2 = self.qp.solve(H, g, self.A_speed, -big, big, lbx, ubx)
                if not ok2 or not np.isfinite(u).all():
                    u = np.zeros(self.nb)
                ok = False
            u = np.minimum(np.maximum(u, lbx), ubx)
        speeds = np.empty(N + 1)
        speeds[0] = v0
        speeds[1:] = v_free + self.Gv @ u
        np.maximum(speeds, 0.0, out=speeds)
        positions = np.empty(N + 1)
        positions[0] = s0
        positions[1:] = s_free + self.Gs @ u
        times = t + self._tgrid
        sol = MPCSolution(forces_n=u[self.blk] * self.unit, times_s=times, positions_m=positions, speeds_mps=speeds, ok=ok)
        self._prev = sol
        far = 1000.0
        self._prev_ext = (np.append(times, times[-1] + far), np.append(positions, positions[-1] + speeds[-1] * far), np.append(speeds, speeds[-1]))
        return sol


# -------------------------------------------------------------------------------------------
# Algorithm 4: position reference generator


@dataclass
class ReferenceSet:
    """The trajectories z_τ1, z_τ2, z_τ3 (eq. 32–34) and the leader's robust planned speed."""

    t_last: float
    times_s: np.ndarray
    z_m: np.ndarray
    """Shape (3, n): z_τ1, z_τ2, z_τ3 (z_τ1 ≥ z_τ2 ≥ z_τ3 for ω1 < ω2 < ω3)."""
    leader_speed_mps: np.ndarray
    taus_s: tuple[float, float, float]
    tau_bar_s: float

    def at(self, t: float) -> np.ndarray:
        """(z_τ1, z_τ2, z_τ3) at time t (constant-speed extrapolation past the grid)."""
        out = np.empty(3)
        for i in range(3):
            out[i] = _interp_extrap(t, self.times_s, self.z_m[i])
        return out

    def over(self, times: np.ndarray, row: int = 1) -> np.ndarray:
        return _interp_extrap_vec(times, self.times_s, self.z_m[row])

    def speed_over(self, times: np.ndarray) -> np.ndarray:
        return np.interp(times, self.times_s, self.leader_speed_mps)


def _interp_extrap(t: float, ts: np.ndarray, ys: np.ndarray) -> float:
    if t <= ts[-1]:
        return float(np.interp(t, ts, ys))
    slope = (ys[-1] - ys[-2]) / (ts[-1] - ts[-2]) if len(ts) > 1 else 0.0
    return float(ys[-1] + slope * (t - ts[-1]))


def _interp_extrap_vec(t: np.ndarray, ts: np.ndarray, ys: np.ndarray) -> np.ndarray:
    out = np.interp(t, ts, ys)
    late = t > ts[-1]
    if late.any():
        slope = (ys[-1] - ys[-2]) / (ts[-1] - ts[-2]) if len(ts) > 1 else 0.0
        out[late] = ys[-1] + slope * (t[late] - ts[-1])
    return out


def leader_plan_from_message(msg: Message, leader: RobustProxies | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The leader's robust planned trajectory x̲^L(t_κ) from a packet: (times, positions, speeds).

    * With ``leader`` proxies and a force plan in the packet: the RLP (eq. 12) of the leader from
      the sent state under the planned forces, held piecewise constant on the plan's time grid
      (the computation of §VI-D, done on the follower side so any sender works).
    * Else the packet's plan as sent (a Terlizzi leader sends its RLP).
    * A packet without a plan is read as "cruising at the sent speed".

    The plan only shapes the references (performance); safety never relies on it.
    """
    st = msg.state
    tp = msg.plan_times_s
    if tp is not None and len(tp) >= 2:
        tp = np.asarray(tp, float)
        if leader is not None and msg.plan_forces_n is not None and len(msg.plan_forces_n) >= len(tp) - 1:
            f = np.asarray(msg.plan_forces_n, float)
            s0, v0 = float(st.position_m), max(0.0, float(st.speed_mps))
            rb = leader.window(s0, v0, float(tp[-1] - tp[0]))
            s = np.empty(len(tp))
            v = np.empty(len(tp))
            s[0], v[0] = s0, v0
            for k in range(len(tp) - 1):
                h = float(tp[k + 1] - tp[k])
                a = leader.rlp_accel(v[k], float(f[k]), rb, v0)
                v[k + 1] = max(0.0, v[k] + a * h)
                s[k + 1] = s[k] + v[k] * h
            return tp, s, v
        if msg.plan_positions_m is not None and msg.plan_speeds_mps is not None:
            return tp, np.asarray(msg.plan_positions_m, float), np.asarray(msg.plan_speeds_mps, float)
    t0 = msg.sent_time_s
    return np.array([t0, t0 + 1.0]), np.array([st.position_m, st.position_m + st.speed_mps]), np.array([st.speed_mps, st.speed_mps])


class PositionReferenceGenerator:
    """Algorithm 4 (eq. 20–28), for several τ at once (eq. 32–34).

    For each grid time t ∈ [t_last, t_last + span) on the leader's robust plan x̲^L(t):

    * s_τ^L (eq. 21): position of the leader RLP after braking at e̲^L for τ (v_τ^L, eq. 20, enters
      through the stop point: s_τ + v_τ²/(2e̲^L) is the leader's earliest stop S^L from x̲^L(t),
      taken on the route profile as in the supervisor's barrier);
    * v_ave^L (eq. 23): mean planned speed over [t, t+τ] (the printed integral lacks the 1/τ);
    * v_τ^{max,F} (eq. 22): min{x2^F + ā_dr·τ, V^{max,F}, V^{line,*}} with ā_dr the largest
      acceleration in the box at the follower's speed (taking ΔT = τ, the span the bound covers);
    * z̃^{F,1}, z̃^{F,2}, z̃^F (eq. 24): follower positions putting b' resp. b'' at zero at t + τ,
      with the follower's stopping distance from v_τ^{max,F} taken at its present position;
    * z̃^{FL} = x̲1^L − z̃^F (eq. 25), its running maximum over [t − τ, t] ∩ [t_last, t] (eq. 26) and
      z_τ^F = x̲1^L − z^{FL} (eq. 27).

    Past the packet's plan horizon the plan is extended at its last speed.  The same sampled-data
    margins as the supervisor are included so that z_τ is consistent with its check.  The
    references shape performance only; safety is the supervisor's.
    """

    def __init__(self, model: BarrierModel, cfg: CruiseConfig, dt_s: float = 0.0):
        self.model = model
        self.cfg = cfg
        self.dt_s = dt_s

    def compute(self, msg: Message, tau_bar_s: float, s_f: float, v_f: float, t_now: float, v_line_max: float = math.inf) -> ReferenceSet:
        cfg, model = self.cfg, self.model
        taus = (cfg.omega_1 * tau_bar_s, cfg.omega_2 * tau_bar_s, cfg.omega_3 * tau_bar_s)
        tp, sp, vp = leader_plan_from_message(msg, model.leader if cfg.rlp_from_forces else None)
        t_last = float(msg.sent_time_s)
        step = cfg.reference_step_s
        span = max(t_now - t_last, 0.0) + cfg.horizon_s + 2.0 * step
        n = int(math.ceil(span / step)) + 1
        tmax = max(taus)
        n_ext = n + int(math.ceil(tmax / step)) + 2
        tg = t_last + step * np.arange(n_ext)
        s_g = np.interp(tg, tp, sp)
        v_g = np.interp(tg, tp, vp)
        late = tg > tp[-1]
        if late.any():
            v_g[late] = vp[-1]
            s_g[late] = sp[-1] + vp[-1] * (tg[late] - tp[-1])
        v_g = np.maximum(v_g, 0.0)
        # leader route window covering the planned stretch and its braking (σ_sup of e̲^L)
        lead = model.leader
        rb_l = lead.leader_path_bounds(float(s_g[0]), float(s_g[n - 1]), float(v_g.max()), model.cfg.t_max_s)
        b = lead.b
        res = b.davis_a_high_n + b.davis_b_high_n_per_mps * v_g + b.davis_c_high_n_per_mps2 * rb_l.tunnel_max * v_g * v_g
        e_l = res / (b.rotating_mass_factor * b.mass_low_kg) + G * rb_l.grade_max + b.brake_decel_high_mps2 / b.rotating_mass_factor
        # cumulative integral of the planned speed (trapezoid) for eq. 23
        P = np.concatenate(([0.0], np.cumsum(0.5 * (v_g[1:] + v_g[:-1]) * step)))
        fol = model.follower
        fb = fol.b
        L, d = model.leader_length_m, model.d_m
        dt = self.dt_s if model.cfg.sampled_data_margin else 0.0
        s0, v0 = s_g[:n], v_g[:n]
        e0 = e_l[:n]
        a_up = fb.accel_high(v_f) - G * min(model.stops_follower.grade_at(s_f), 0.0)
        # earliest stop of the braking leader from each planned state (flow-invariant: s_τ + v_τ²/2e̲)
        stop_l = np.array([model.leader_stop(float(a), float(b), rb_l) for a, b in zip(s0, v0)])
        z = np.empty((3, n))
        for i, tau in enumerate(taus):
            t_stop = v0 / e0
            full = t_stop <= tau
            s_tau = np.where(full, s0 + v0 * v0 / (2 * e0), s0 + v0 * tau - 0.5 * e0 * tau * tau)  # eq. 21
            v_ave = (np.interp(tg[:n] + tau, tg, P) - P[:n]) / tau if tau > 0 else v0  # eq. 23
            v_max_f = max(0.0, min(v_f + a_up * tau, fb.max_speed_ms, v_line_max))  # eq. 22
            stop_f = model.follower_stop(s_f, v_max_f, dt) - s_f  # v^max,F²/(2ē^F) (+ sampled-data margin)
            shift = v_ave * tau
            z1 = stop_l - shift - L - d - stop_f - (v0 * dt if dt > 0 else 0.0)  # eq. 24
            z2 = s_tau - shift - L - d  # eq. 24
            zt = np.minimum(z1, z2)
            zfl = s0 - zt  # eq. 25
            w = max(1, int(round(tau / step)))
            padded = np.concatenate((np.full(w, -np.inf), zfl))
            win = np.lib.stride_tricks.sliding_window_view(padded, w + 1)
            zfl_max = win.max(axis=1)  # eq. 26
            z[i] = s0 - zfl_max  # eq. 27
        return ReferenceSet(t_last=t_last, times_s=tg[:n], z_m=z, leader_speed_mps=v0.copy(), taus_s=taus, tau_bar_s=tau_bar_s)


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
