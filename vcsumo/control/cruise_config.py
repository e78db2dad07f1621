"""Parameters of the switched cruise controller of Terlizzi, Liuzza & Glielmo (2024), Table II
(``controllers/cruise_terlizzi2024.yaml``); the controller is :mod:`vcsumo.control.cruise`.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from vcsumo.config import StrictModel, load_model


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
