"""The condensed Gauss–Newton QP of the virtual-coupling NMPC (one SQP iteration), compiled with CasADi.

Single shooting, condensed: the decision variables are the normalised force increments
z_k = (F_{k+1} − F_k)/(j_max·M·Δt), so the jerk limits are simple bounds.  The model over the
horizon and its exact Jacobians (forward sensitivities, lower triangular) are CasADi SX
expressions; the QP of the cost and the constraints of eq. 11/12 (rows: force 4a, power 4b, speed
limit, terminal set, and for a follower d_min and the invariant set 12m; see
:mod:`vcsumo.control.mpc`) is assembled by compiled SX functions as well, so one SQP iteration is
three calls into CasADi and one matrix product in numpy:

* ``qpdata`` (x0, z, space terms, v_lim, terminal data, references, weights) → the QP's gradient,
  constraint matrix and bounds, written in place into qpOASES's input buffers, and the weighted
  residual Jacobian J_w with H = J_wᵀ·J_w (the Gauss–Newton Hessian, one BLAS product);
* the QP solver (qpOASES through ``casadi.conic``, dense, hot-started from the previous step);
* ``post`` (x0, z, QP step, …) → the new increments (clipped to the jerk bounds), the re-simulated
  plan, forces, commands and the largest violation of each constraint on that plan.

CasADi reads and writes preallocated numpy buffers (``Function.buffer``); inputs shared by several
functions are one array.  The numpy formulation of the same QP (the form in which it was first
written, kept as the reference the compiled one is tested against) is
``tests/test_mpc_compiled.py``.  The iteration loop, the plan check and the safe fallback are in
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

VIOLATIONS = ("force_n", "power_rel", "speed_mps", "gap_m", "terminal_set_m")
"""Order of the violations computed by the compiled ``post`` function (see :meth:`CondensedQP.post`)."""


def _bind(fn, inputs: list, outputs: list):
    """Bind numpy arrays to a CasADi function's inputs/outputs (``Function.buffer``); returns (buffer, evaluate).

    CasADi keeps raw pointers: the arrays (and the arrays views are taken of) must stay alive and
    never be replaced, only written in place, as long as the buffer is used."""
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

    Input buffers (write in place): ``x0`` (s, v, F), ``z`` (increments), ``grad``/``tf``
    (gradient and tunnel factor at the positions k = 0 … N−1), ``vlim`` (v_lim at k = 1 … N),
    ``term`` (β, dβ/ds, c of the terminal set), ``vref`` (speed reference), ``srear`` (leader rear,
    follower), ``par`` (w_v, w_j, v_scale, c_l, w_d, d_des, d_min, 1/(2a^f)).
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
        key = (params, N, self.dt, follower, settings.stop_smoothing_mps, self.z_scale, self.alpha, self.z_max)  # what _build compiles in
        if key not in _BUILD_CACHE:
            _BUILD_CACHE[key] = self._build()
        self.functions = dict(zip(("lin", "sim", "qpdata", "post", "qp"), _BUILD_CACHE[key]))
        """The compiled CasADi functions (shared): lin, sim, qpdata, post and the QP solver qp."""
        sim, qpdata, post, qp = (self.functions[k] for k in ("sim", "qpdata", "post", "qp"))
        self._qp_fn = qp
        # shared input buffers
        self.x0, self.z, self.grad, self.tf = np.zeros(3), np.zeros(N), np.zeros(N), np.ones(N)
        self.vlim, self.term, self.vref, self.srear, self.par = np.zeros(N), np.zeros(3), np.zeros(N), np.zeros(N), np.zeros(8)
        model_in = [self.x0, self.z, self.grad, self.tf]
        self._sim_out = [np.zeros(N), np.zeros(N)]
        self._sim_buf, self._sim_eval = _bind(sim, model_in, self._sim_out)
        # qpOASES buffers; the constant parts of the QP (slack columns and cost) are written once here
        self._qp_in = {name: np.zeros(qp.nnz_in(i)) for i, name in enumerate(qp.name_in())}
        self._qp_out = [np.zeros(qp.nnz_out(i)) for i in range(qp.n_out())]
        q = self._qp_in
        self._H = q["h"].reshape((n, n), order="F")
        self._A = q["a"].reshape((m, n), order="F")
        self._A[2 * N : 3 * N, N] = -1.0  # speed-limit slack
        self._A[3 * N, N + 1] = -1.0  # terminal slack
        if follower:
            self._A[3 * N + 1 : 4 * N + 1, N + 2] = -1.0  # d_min slack
            self._A[4 * N + 1, N + 1] = 1.0  # terminal set 12m shares the terminal slack
        self._H[N:, N:] = 1e-6 * np.eye(ns)
        q["g"][N:] = settings.slack_penalty
        q["lbx"][N:] = 0.0
        q["ubx"][N:] = np.inf
        q["lba"][2 * N : 3 * N + 1] = -np.inf  # (rewritten by qpdata; set for the first, dummy, QP of _reset_qp)
        if follower:
            q["lba"][3 * N + 1 : 4 * N + 1] = -np.inf
            q["uba"][4 * N + 1] = np.inf
        self.Ju = self.z_scale * (np.tril(np.ones((N, N)), -1) + np.eye(N) / self.alpha)  # du/dz (4a rows)
        # qpdata writes the parts of J_w and of A's decision columns that can be nonzero (column
        # segments, column-major: see _segments), g[:N], the bounds and the cost
        nj = 2 * N if follower else N
        self._Jw = np.zeros(nj * N)
        self._JwT = self._Jw.reshape((N, nj))  # J_wᵀ, C order (J_w is column-major)
        self._A[:N, :N] = self.Ju
        self._Hz = np.zeros((N, N))
        self._cost = np.zeros(1)
        seg_w, seg_a = self._segments()
        self._qpd_buf, self._qpd_eval = _bind(
            qpdata, model_in + [self.vlim, self.term, self.vref, self.srear, self.par],
            [self._Jw[j * nj + r0 : j * nj + r1] for j, r0, r1 in seg_w] + [q["g"][:N]] + [q["a"][j * m + r0 : j * m + r1] for j, r0, r1 in seg_a]
            + [q["lba"], q["uba"], q["lbx"][:N], q["ubx"][:N], self._cost])
        self.dx = self._qp_out[0]  # QP solution: increments' step, then slacks
        self.z_new, self.pos, self.spd = np.zeros(N), np.zeros(N + 1), np.zeros(N + 1)
        self.F, self.u, self.viol = np.zeros(N + 1), np.zeros(N), np.zeros(len(VIOLATIONS) + 1)
        self._post_buf, self._post_eval = _bind(post, model_in + [self.dx, self.vlim, self.srear, self.par],
                                                [self.z_new, self.pos, self.spd, self.F, self.u, self.viol])
        self._eyeN = np.eye(N)
        self._diag, self._w_j = self._eyeN, None
        self._k_dt = self.dt * np.arange(N + 1)
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
            self._A[:N, :N] = self.Ju
            self._H[:N, :N] = self._eyeN
            try:
                self._qp_eval()
            except Exception:
                pass

    def _segments(self) -> tuple[list, list]:
        """(column, first row, end row) of the parts of J_w and of the QP's constraint matrix A
        (decision columns) that can be nonzero; the rest is constant (the force rows 4a, du/dz) or
        zero: V_k depends on z_0 … z_k, S_k and the commands' power on z_0 … z_{k−1}, z_k.
        ``_build`` checks that every entry outside them is a constant zero."""
        N, fol = self.N, self.follower
        seg_w = [(j, j, N) for j in range(N)] + ([(j, N + j + 1, 2 * N) for j in range(N - 1)] if fol else [])
        seg_a = [(j, N + j, 2 * N) for j in range(N)] + [(j, 2 * N + j, 3 * N + 1) for j in range(N)]  # power; v_lim and terminal rows
        if fol:
            seg_a += [(j, 3 * N + 2 + j, 4 * N + 2) for j in range(N)]  # d_min and 12m rows
        return seg_w, seg_a

    # ---------------------------------------------------------------------------------------
    def _build(self):
        """CasADi functions: the model over the horizon with its exact Jacobians (``lin``), the
        model alone (``sim``), the QP data (``qpdata``), the plan after a QP step (``post``) and the
        QP solver."""
        import casadi as ca

        p, N, dt, eps, fol = self.p, self.N, self.dt, self.cfg.stop_smoothing_mps, self.follower
        zs, za, zmax = self.z_scale, self.z_scale / self.alpha, self.z_max
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
        Js, Jv = ca.vertcat(*rowsS), ca.vertcat(*rowsV)
        model_in = [x0, z, grad, tf]
        lin = ca.Function("lin", model_in, [S, V, ca.densify(Js), ca.densify(Jv)])
        sim = ca.Function("sim", model_in, [S, V])

        vlim, term, vref, srear, par = (ca.SX.sym(n, k) for n, k in (("vlim", N), ("term", 3), ("vref", N), ("srear", N), ("par", 8)))
        w_v, w_j, vsc, c_l, w_d, d_des, d_min, inv2af = ca.vertsplit(par)
        inf = ca.inf
        cz = ca.cumsum(z)
        U = x0[2] + zs * (cz - z) + za * z  # u_k = F_k + ΔF_k/α
        vprev = ca.vertcat(x0[1], V[:-1])
        PW = U * vprev
        # Gauss–Newton cost 11a-b / 12a-c: residuals r and Jacobians J; H = 2·Σ w·JᵀJ (= J_wᵀJ_w + (2w_j + 1e-8)·I), g = 2·Σ w·Jᵀr
        rv = (vref - V) / vsc
        Jrv = Jv * (-1.0 / vsc)
        gz = (2.0 * w_v) * ca.mtimes(Jrv.T, rv) + (2.0 * w_j) * z
        cost = w_v * ca.dot(rv, rv) + w_j * ca.dot(z, z)
        Jw = [ca.sqrt(2.0 * w_v) * Jrv]
        if fol:
            rd = 1.0 - (srear - S) / d_des
            Jrd = Js * (1.0 / d_des)
            gz += (2.0 * w_d) * ca.mtimes(Jrd.T, rd)
            cost += w_d * ca.dot(rd, rd)
            Jw.append(ca.sqrt(2.0 * w_d) * Jrd)
        Ju = zs * (np.tril(np.ones((N, N)), -1) + np.eye(N) / self.alpha)
        # power rows 4b: d(u_k·v_k) = v_k·du_k + u_k·dv_k
        Ap = ca.SX(Ju) * ca.repmat(vprev, 1, N) + ca.vertcat(ca.SX(1, N), ca.repmat(U[1:], 1, N) * Jv[:-1, :])
        beta, dbeta, c_sh = term[0], term[1], term[2]
        rows = [ca.SX(Ju), Ap, Jv, (2.0 * V[-1] - dbeta * c_sh) * Jv[-1, :] - dbeta * Js[-1, :]]  # 4a, 4b, v_lim, 11i/12k
        p_lo = -self.p_br if math.isfinite(self.p_br) else -inf
        lba = [self.u_min - U, p_lo - PW, -inf * ca.DM.ones(N + 1)]
        uba = [self.u_max - U, self.p_dr - PW, vlim - V, beta - V[-1] ** 2]
        if fol:  # d_min 12f/12l and the invariant set 12m: d_N + c_l − v_N²/(2a^f) ≥ d_min
            h = srear[-1] - S[-1] + c_l - V[-1] ** 2 * inv2af
            rows += [Js, -Js[-1, :] - (2.0 * V[-1] * inv2af) * Jv[-1, :]]
            lba += [-inf * ca.DM.ones(N), d_min - h]
            uba += [srear - d_min - S, inf]
        Jw, A = ca.vertcat(*Jw), ca.vertcat(*rows)
        seg_w, seg_a = self._segments()
        for M_, segs, r_first in ((Jw, seg_w, 0), (A, seg_a, N)):  # outside the segments: zero (A: below the constant rows 4a)
            inside = {(r, j) for j, r0, r1 in segs for r in range(r0, r1)}
            if any(not M_[r, j].is_zero() for r in range(r_first, M_.size1()) for j in range(N) if (r, j) not in inside):
                raise AssertionError("a QP matrix entry outside the compiled segments is not zero")
        qpdata = ca.Function("qpdata", model_in + [vlim, term, vref, srear, par],
                             [ca.densify(Jw[r0:r1, j]) for j, r0, r1 in seg_w] + [ca.densify(gz)] + [ca.densify(A[r0:r1, j]) for j, r0, r1 in seg_a]
                             + [ca.densify(ca.vertcat(*lba)), ca.densify(ca.vertcat(*uba)), -zmax - z, zmax - z, cost], {"cse": True})

        # after the QP: z + step within the jerk bounds, the plan, and its violations (the reference is _violations)
        dx = ca.SX.sym("dx", N + self.ns)
        zn = ca.fmin(ca.fmax(z + dx[:N], -zmax), zmax)
        Sn, Vn = sim(x0, zn, grad, tf)
        Fn_ = x0[2] + zs * ca.cumsum(zn)  # forces F_k, k = 1 … N
        un = ca.vertcat(x0[2], Fn_[:-1]) + za * zn  # commands u_k = F_k + ΔF_k/α
        uc = x0[2] + zs * (ca.cumsum(zn) - zn) + za * zn  # the same as checked
        pw = uc * ca.vertcat(x0[1], Vn[:-1])
        p_hi = ca.mmax(pw) - self.p_dr
        pr_lo = (-self.p_br - ca.mmin(pw)) / self.p_br if math.isfinite(self.p_br) else 0.0
        viol = [ca.fmax(ca.fmax(ca.mmax(uc) - self.u_max, self.u_min - ca.mmin(uc)), 0.0), ca.fmax(ca.fmax(p_hi / self.p_dr, pr_lo), 0.0),
                ca.fmax(ca.mmax(Vn - vlim), 0.0)]
        if fol:
            d = srear - Sn
            viol += [ca.fmax(d_min - ca.mmin(d), 0.0), ca.fmax(d_min - (d[-1] + c_l - Vn[-1] ** 2 * inv2af), 0.0)]
        else:
            viol += [0.0, 0.0]
        viol.append(ca.sum1(dx))  # finite iff the QP step is
        post = ca.Function("post", model_in + [dx, vlim, srear, par],
                           [zn, ca.vertcat(x0[0], Sn), ca.vertcat(x0[1], Vn), ca.vertcat(x0[2], Fn_), un, ca.densify(ca.vertcat(*viol))], {"cse": True})
        opts = {"printLevel": "none", "sparse": False, "error_on_fail": False, "hessian_type": "posdef", "enableRegularisation": True}
        with _quiet_stdout():
            qp = ca.conic("qp", self.cfg.qp_solver, {"h": ca.Sparsity.dense(self.n, self.n), "a": ca.Sparsity.dense(self.m, self.n)}, opts)
        return lin, sim, qpdata, post, qp

    def sqp_iteration(self) -> bool:
        """One SQP iteration (Gauss–Newton, condensed) on the input buffers: linearise at ``z``, solve
        the QP, re-simulate.  Returns whether the QP was solved; the new plan is then in ``z_new``,
        ``pos``, ``spd`` (k = 0 … N), ``F``, ``u``, ``viol`` (:data:`VIOLATIONS`, computed with
        ``vlim``), the slacks in ``dx[N:]`` and the cost at ``z`` in ``_cost``."""
        N = self.N
        self._qpd_eval()
        Hz = self._Hz
        np.dot(self._JwT, self._JwT.T, out=Hz)
        Hz += self._diag
        self._H[:N, :N] = Hz
        try:
            self._qp_eval()
            self._post_eval()
            solved = self._qp_buf.ret() == 0 and math.isfinite(self.viol[-1])
        except Exception:  # qpOASES failed (its hot start is unusable now)
            solved = False
        if not solved:  # fresh memory, cold start next time
            self._reset_qp()
        return solved

    def set_weights(self, w_v: float, w_j: float, v_scale: float, c_l: float, w_d: float = 0.0, d_des: float = 1.0, d_min: float = 0.0,
                    inv2af: float = 0.0) -> None:
        """Cost weights and follower data of the next QPs (``par``)."""
        self.par[:] = (w_v, w_j, v_scale, c_l, w_d, d_des, d_min, inv2af)
        if w_j != self._w_j:
            self._diag = (2.0 * w_j + 1e-8) * self._eyeN
            self._w_j = w_j

    # ---------------------------------------------------------------------------------------
    def simulate(self, x0, z, lookup: RouteLookup | None) -> tuple[np.ndarray, np.ndarray]:
        """Positions and speeds k = 1 … N of the model for increments z (eq. 14 a-priori estimate
        when z is the shifted previous plan); gradient and tunnel factor along the positions.
        Leaves ``x0``, ``z``, ``grad``, ``tf`` set; returns views of the output buffers."""
        N = self.N
        self.x0[:] = x0
        self.z[:] = z
        S = self._sim_out[0]
        if lookup is None:
            self.grad.fill(0.0)
            self.tf.fill(1.0)
            self._sim_eval()
        elif lookup.uniform:
            self.grad.fill(lookup.gradient0)
            self.tf.fill(lookup.tunnel0)
            self._sim_eval()
        else:
            s_est = x0[0] + x0[1] * self.dt * np.arange(N)
            for _ in range(2):
                self.grad[:], self.tf[:] = lookup.gradient(s_est), lookup.tunnel_factor(s_est)
                self._sim_eval()
                s_est = np.concatenate(([x0[0]], S[:-1]))
        return S, self._sim_out[1]

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
