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
  further SQP iterations the current iterate); 0 ≤ v_k holds by construction of the model;
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
function for the trajectory and its exact Jacobians (forward sensitivities, lower triangular),
assembles the Gauss–Newton QP in numpy (N + 3 variables, 4N + 2 rows for a follower) and solves
it with qpOASES (``casadi.conic``, dense, hot-started from the previous step); CasADi reads and
writes preallocated numpy buffers (``Function.buffer``), so no conversion happens per call.
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
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from vcsumo.config import StrictModel, load_model
from vcsumo.control.base import Command, Message, Observation
from vcsumo.control.dp_profile import DPSettings, RouteLookup, SpeedProfile, TerminalSet, dp_speed_profile, terminal_set
from vcsumo.control.predictors import (
    LeaderPrediction,
    lag_alpha,
    model_step,
    np_state_now,
    predict_mb,
    predict_np,
    predict_sh_from_plan,
)
from vcsumo.dynamics import TrainParams, brake_force_limit
from vcsumo.route_profile import RouteProfile

# -------------------------------------------------------------------------------------------
# Settings


class DPModel(StrictModel):
    """DP settings of eq. 10 (Table II: K_VDP, K_LDP, Δs)."""

    ds_min_m: float = Field(default=0.25, ge=0.01, le=1000, description="Smallest position step Δs_min = e_s/2, m (1 cm–1 km)")
    ds_max_m: float = Field(default=5.0, gt=0, le=1000, description="Largest position step Δs_max, m (at most 1 km)")
    ds_time_s: float = Field(default=0.25, gt=0, description="Δs ≈ v·ds_time_s between the two bounds, s")
    dv_mps: float = Field(default=0.1, gt=0, le=1, description="Speed-grid resolution of the cost-to-go, m/s")
    n_controls: int = Field(default=11, ge=3, le=201, description="Force grid points per DP stage (plus hold and boundary), -")
    k_vdp: float = Field(default=1.0, ge=0, description="K_VDP, weight of the deviation from v_lim, -")
    k_ldp: float = Field(default=1.0e5, ge=0, description="K_LDP, weight of exceeding v_lim, -")

    def to_dp(self) -> DPSettings:
        return DPSettings(ds_min_m=self.ds_min_m, ds_max_m=self.ds_max_m, ds_time_s=self.ds_time_s, dv_mps=self.dv_mps,
                          n_controls=self.n_controls, k_vdp=self.k_vdp, k_ldp=self.k_ldp)


class MPCSettings(StrictModel):
    """Parameters of the leader and follower NMPC (Felez et al. 2019, Table II).  SI units."""

    name: str = Field(default="mpc", description="Name of this parameter set")
    notes: str = Field(default="", description="Source and assumptions")
    step_s: float = Field(default=0.1, gt=0, le=2, description="Sample time Δt, s")
    horizon_steps: int = Field(default=40, ge=2, le=400, description="Prediction horizon N_p, steps")
    d_des_m: float = Field(default=10.0, gt=0, le=50000, description="Desired gap d_des (front-to-rear), m (up to 50 km)")
    d0_m: float = Field(default=3.0, ge=0, le=50000, description="Minimum safe distance d_0 of eq. 9, m (0–50 km)")
    position_error_m: float = Field(default=0.5, ge=0, le=1000, description="Location error e_s (±), m; d_min = d_0 + 2·e_s (eq. 9); 0–1 km")
    k_v_leader: float = Field(default=100.0, ge=0, description="K_V^l, weight of (1 − v/v_max)², -")
    k_j_leader: float = Field(default=0.5, ge=0, description="K_J^l, weight of (j/j_max)², -")
    k_d: float = Field(default=100.0, ge=0, description="K_D, weight of (1 − d/d_des)², -")
    k_v_follower: float = Field(default=100.0, ge=0, description="K_V^f, weight of ((v̄^l − v)/v_max)², -")
    k_j_follower: float = Field(default=0.5, ge=0, description="K_J^f, weight of (j/j_max)², -")
    a_leader_mps2: float = Field(default=1.25, gt=0, le=5, description="a^l: leader's assumed (emergency) braking in 12m and eq. 17, m/s² (0 < a ≤ 5: wheel-rail adhesion)")
    a_follower_mps2: float = Field(default=0.75, gt=0, le=5, description="a^f: follower's braking assumed after the horizon in 12m (must be achievable from any speed), m/s² (0 < a ≤ 5)")
    predictor: Literal["SH", "NP", "MB"] = Field(default="SH", description="Preceding-train predictor (eq. 16, 17, 18)")
    v_max_mps: float | None = Field(default=None, gt=0, le=170, description="v_max of 11a/12b (objective speed), m/s, at most 170 m/s (612 km/h); none: Observation.target_speed_mps or the highest route limit")
    jerk_limit_on: Literal["force", "command"] = Field(default="force", description="'force': |F_{k+1} − F_k| ≤ j·M·Δt (eq. 12o, TrainPlant); 'command': |u_k − F_k| ≤ j·M·Δt (a plant that rate-limits the command)")
    stop_smoothing_mps: float = Field(default=0.01, gt=0, le=0.5, description="ε of the smooth max(v, 0) in the prediction model, m/s")
    sqp_max_iterations: int = Field(default=3, ge=1, le=50, description="SQP iterations per step at most (the first is the real-time iteration), -")
    qp_solver: Literal["qpoases"] = Field(default="qpoases", description="Dense QP solver (CasADi conic plugin qpOASES)")
    slack_penalty: float = Field(default=1.0e6, gt=0, description="Exact L1 penalty on constraint slacks, -")
    tol_speed_mps: float = Field(default=0.05, ge=0, description="Accepted speed-limit / terminal-speed violation of a plan, m/s")
    tol_gap_m: float = Field(default=0.05, ge=0, description="Accepted d_min / terminal-set violation of a plan (also as extra stopping distance for 11i/12k), m")
    tol_power_rel: float = Field(default=0.02, ge=0, description="Accepted power-limit violation of a plan, fraction of P")
    terminal_brake_fraction: float = Field(default=0.98, gt=0.5, le=1.0, description="Fraction of the service brake force assumed by the terminal set (margin for the force lag), -")
    terminal_ramp_allowance: bool = Field(default=True, description="Evaluate the terminal bound v_N ≤ v_DP(s̄_N + v̄_N·t_r/2), t_r = time to ramp the force to full brake (jerk, eq. 4c)")
    use_measured_force: bool = Field(default=True, description="Take F_t from Observation.ego.force_n (else the previous plan's F_{t|t−1})")
    dp: DPModel = Field(default_factory=DPModel, description="DP settings (eq. 10)")

    @property
    def d_min_m(self) -> float:
        """d_min = d_0 + 2·e_s (eq. 9), m."""
        return self.d0_m + 2.0 * self.position_error_m

    @model_validator(mode="after")
    def _check(self) -> "MPCSettings":
        if self.d_des_m < self.d_min_m:
            raise ValueError(f"d_des_m ({self.d_des_m}) must not be below d_min = d0_m + 2·position_error_m ({self.d_min_m})")
        return self


def load_mpc_settings(path: str | Path) -> MPCSettings:
    """Load an MPC parameter set (``controllers/mpc*.yaml``); unknown keys are errors."""
    return load_model(MPCSettings, path)


# -------------------------------------------------------------------------------------------
# The condensed SQP step (compiled CasADi function)


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


class CondensedNMPC:
    """Compiled one-iteration SQP of the leader (``follower=False``) or follower NMPC for one train.

    The pure entry point is :meth:`solve`: it takes plain arrays (current state, warm start,
    space-dependent data through a :class:`RouteLookup` and a terminal set, the leader
    prediction) and returns an :class:`MPCSolution`; the only state kept between calls is
    qpOASES's working set, which hot-starts the next QP.  One instance per train (not
    thread-safe).
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

    def _sqp_iteration(self, x0, z, grad, tf, vlim, term, vref, w, srear, fw) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, bool]:
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
            gi[:], ti[:] = self._space_terms(lookup, s_est)
            self._sim_eval()
            s_est = np.concatenate(([x0[0]], self._sim_out[0][:-1]))
        return self._sim_out[0].copy(), self._sim_out[1].copy()

    def _space_terms(self, lookup: RouteLookup | None, s_k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
        :class:`~vcsumo.control.dp_profile.TerminalSet` or :class:`SpeedProfile`; None: no
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
                grad, tf = self._space_terms(lookup, s_k)
                vlim = self._vlim(lookup, v_limit_fn, S)
                term = self._term(terminal, x0, z, S, V)
                z_new, S, V, slacks, cost, solved = self._sqp_iteration(x0, z, grad, tf, vlim, term, vref, w, srear, fw)
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

    def _x0(self, obs: Observation) -> np.ndarray:
        F = obs.ego.force_n
        if not self.settings.use_measured_force and self._last is not None:
            F = float(self._last.forces_n[1])
        return np.array([obs.ego.position_m, obs.ego.speed_mps, F])

    def _warm(self, obs: Observation) -> np.ndarray | None:
        """The previous plan shifted by the elapsed steps (eq. 14b-c), None without one."""
        if self._last is None or self._last_time is None:
            return None
        shift = int(round((obs.time_s - self._last_time) / self.settings.step_s))
        if shift <= 0:
            return self._last.z.copy()
        z = self._last.z[shift:]
        return np.append(z, np.zeros(self.settings.horizon_steps - len(z))) if len(z) else None

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
                "plan_commands_n": sol.commands_n, "infeasible_count": self.stats.infeasible}
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
