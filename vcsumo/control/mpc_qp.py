"""The condensed Gauss–Newton QP of the virtual-coupling NMPC (one SQP iteration), compiled with CasADi.

Single shooting, condensed: the decision variables are the normalised force increments
z_k = (F_{k+1} − F_k)/(j_max·M·Δt), so the jerk limits are simple bounds.  A compiled CasADi SX
function gives the trajectory over the horizon and its exact Jacobians (forward sensitivities,
lower triangular); :meth:`CondensedQP.sqp_iteration` assembles the QP of the cost and the
constraints of eq. 11/12 (rows: force 4a, power 4b, speed limit, terminal set, and for a follower
d_min and the invariant set 12m; see :mod:`vcsumo.control.mpc`) in numpy and solves it with qpOASES
(``casadi.conic``, dense, hot-started).  CasADi reads and writes preallocated numpy buffers
(``Function.buffer``).  The iteration loop, the plan check and the safe fallback are in
:mod:`vcsumo.control.mpc_solver`.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys

import numpy as np

from vcsumo.control.mpc_settings import MPCSettings
from vcsumo.control.predictors import lag_alpha, model_step
from vcsumo.control.route_lookup import RouteLookup
from vcsumo.dynamics import TrainParams


@contextlib.contextmanager
def _quiet_stdout():
    """Silence C-level stdout (qpOASES prints a licence banner when its memory is created)."""
    try:
        sys.stdout.flush()
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        yield
        return
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


_BUILD_CACHE: dict = {}


def _bind(fn, inputs: list, outputs: list):
    """Bind numpy arrays to a CasADi function's inputs/outputs (``Function.buffer``); returns (buffer, evaluate).

    CasADi keeps raw pointers: the arrays must stay alive (and never be replaced, only written in
    place) as long as the buffer is used."""
    buf, ev = fn.buffer()
    for i, a in enumerate(inputs):
        buf.set_arg(i, memoryview(a))
    for i, a in enumerate(outputs):
        buf.set_res(i, memoryview(a))
    return buf, ev


class CondensedQP:
    """The compiled model and QP of the leader (``follower=False``) or follower NMPC of one train.

    Holds the CasADi functions (shared between instances of the same train and settings), the
    evaluation buffers and qpOASES's working set, which hot-starts the next QP.  Not thread-safe.
    """

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
        key = (params, N, self.dt, follower, settings.stop_smoothing_mps, self.z_scale, self.alpha)
        if key not in _BUILD_CACHE:
            _BUILD_CACHE[key] = self._build()
        lin, sim, qp = _BUILD_CACHE[key]
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
        """A new qpOASES memory: the next QP is a cold start instead of a hot start.

        qpOASES prints a banner when a memory is created and first used; both happen here, with a
        dummy problem, quietly.  The parts of the QP data written here are rewritten by every
        SQP iteration."""
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

    # ---------------------------------------------------------------------------------------
    def _build(self):
        """CasADi functions: the model over the horizon with its exact Jacobians, and the QP solver."""
        import casadi as ca

        p, N, dt, eps = self.p, self.N, self.dt, self.cfg.stop_smoothing_mps
        zs = self.z_scale
        # one step of the model (eq. 6b/7, 1c) and its partial derivatives
        vs, Fn, gs, ts = (ca.SX.sym(n) for n in ("v", "Fn", "g", "tf"))
        _, v_next, _ = model_step(p, 0.0, vs, Fn, Fn, dt, gs, ts, eps)  # u = F = F_{k+1}: force after the lag
        one = ca.Function("one", [vs, Fn, gs, ts], [v_next, ca.jacobian(v_next, vs), ca.jacobian(v_next, Fn)])
        z = ca.SX.sym("z", N)
        x0 = ca.SX.sym("x0", 3)
        grad = ca.SX.sym("grad", N)
        tf = ca.SX.sym("tf", N)
        s, v, F = x0[0], x0[1], x0[2]
        S, V, rowsS, rowsV = [], [], [], []
        zero = ca.SX(1, 1)  # structural zero: the Jacobians are lower triangular
        dv = [zero] * N  # dv_k/dz_j
        ds = [zero] * N
        for k in range(N):
            F = F + z[k] * zs  # F_{k+1} = F_k + ΔF_k  (eq. 1c with u_k = F_k + ΔF_k/α)
            v_new, a_k, b_k = one(v, F, grad[k], tf[k])
            s_new = s + dt * v  # eq. 6b
            # forward sensitivities: ds_{k+1} = ds_k + Δt·dv_k, dv_{k+1} = a_k·dv_k + b_k·dF_{k+1}
            ds = [ds[j] + dt * dv[j] if j < k else zero for j in range(N)]
            dv = [a_k * dv[j] + b_k * zs if j < k else (b_k * zs if j == k else zero) for j in range(N)]
            s, v = s_new, v_new
            S.append(s)
            V.append(v)
            rowsS.append(ca.horzcat(*ds))
            rowsV.append(ca.horzcat(*dv))
        S = ca.vertcat(*S)
        V = ca.vertcat(*V)
        lin = ca.Function("lin", [x0, z, grad, tf], [S, V, ca.densify(ca.vertcat(*rowsS)), ca.densify(ca.vertcat(*rowsV))])
        sim = ca.Function("sim", [x0, z, grad, tf], [S, V])
        opts = {"printLevel": "none", "sparse": False, "error_on_fail": False, "hessian_type": "posdef", "enableRegularisation": True}
        with _quiet_stdout():
            qp = ca.conic("qp", self.cfg.qp_solver, {"h": ca.Sparsity.dense(self.n, self.n), "a": ca.Sparsity.dense(self.m, self.n)}, opts)
        return lin, sim, qp

    def sqp_iteration(self, x0, z, grad, tf, vlim, term, vref, w, srear, fw) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, bool]:
        """One SQP iteration (Gauss-Newton, condensed): linearise at z, solve the QP, re-simulate.

        Returns (z_new, S_new, V_new, slacks, cost at z, QP solved)."""
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
        """Positions and speeds k = 1 … N of the model for increments z (eq. 14 a-priori estimate
        when z is the shifted previous plan); gradient and tunnel factor along the positions."""
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

    def space_terms(self, lookup: RouteLookup | None, s_k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if lookup is None:
            return 0.0, 1.0
        if lookup.uniform:
            return lookup.gradient0, lookup.tunnel0
        return lookup.gradient(s_k), lookup.tunnel_factor(s_k)

    def forces(self, F0: float, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Applied forces F_k (k = 0 … N) and commands u_k (k = 0 … N−1) for increments z."""
        F = np.empty(self.N + 1)
        F[0] = F0
        np.cumsum(z, out=F[1:])
        F[1:] *= self.z_scale
        F[1:] += F0
        u = F[:-1] + (self.z_scale / self.alpha) * z
        return F, u
