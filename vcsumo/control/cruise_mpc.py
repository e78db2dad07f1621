"""The finite-horizon problem of each cruise mode (Terlizzi, Liuzza & Glielmo 2024, eq. 35–37) as a
move-blocked quadratic program on the nominal follower model (eq. 5).

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

from dataclasses import dataclass

import numpy as np

from vcsumo.control.proxies import GradeWindow
from vcsumo.dynamics import TrainParams
from vcsumo.units import G

# -------------------------------------------------------------------------------------------
# QP solvers


class DenseQP:
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
        self.qp = DenseQP(nb, nb)
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
