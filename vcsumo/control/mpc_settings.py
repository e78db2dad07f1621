"""Parameters of the virtual-coupling NMPC (Felez, Kim & Borrelli 2019, Table II): the horizon, the
cost weights, the safe distance of eq. 9, the predictor, the solver tolerances and the DP of eq. 10.

Loaded from ``controllers/mpc*.yaml`` (:func:`load_mpc_settings`); the formulation is described in
:mod:`vcsumo.control.mpc`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from vcsumo.config import StrictModel, load_model
from vcsumo.control.dp_profile import DPSettings


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
