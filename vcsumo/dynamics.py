"""Longitudinal train dynamics as pure functions (one model for every part of vcsumo).

The point-mass model of Felez, Kim & Borrelli (2019), eq. 1–5, which is also the nominal model of
Terlizzi, Liuzza & Glielmo (2024), eq. 5–6::

    ds/dt = v                                                    (1a)
    M·ρ·dv/dt = u − (A + B·v + T_f·C·v²) − F_g − F_R             (1b)
    dF/dt = (u_cmd − F)/τ                                       (1c)
    F_g = M·g·i          (i: gradient, rise over run)            (2b)
    F_R = M·k_c/R        (curve resistance)                      (2c)
    −min(M·a_br, P_br/v) ≤ u ≤ min(M·a_dr, P_dr/v)               (4a, 4b)
    |du/dt|/M ≤ j_max                                            (4c)

Forces are in N and positive when they resist motion, speeds in m/s.  ρ is the rotating-mass
factor (ρ = 1 in the papers; SUMO's ``massFactor``).

Every function accepts floats, numpy arrays or CasADi symbols (the MPC builds its constraints from
the same expressions): minimum/maximum dispatch on the argument type.

Curve resistance: the papers print F_R = M·6·10⁶/R, which is not dimensionally consistent for R in
m; we use the Röckl/Rochard form 600/R N/kN ≈ M·6/R N (``CURVE_COEFF_M2PS2`` = 6 m²/s²).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from vcsumo.units import G

CURVE_COEFF_M2PS2 = 6.0
"""k_c in F_R = M·k_c/R (eq. 2c): 600/R N/kN, i.e. about 6/R m/s² per unit mass."""

V_EPS_MPS = 0.1
"""Speed below which power limits are evaluated at this speed (avoids P/0), m/s."""


@dataclass(frozen=True)
class TrainParams:
    """Parameters of the train-dynamics model, SI units (built by RollingStock.params)."""

    length_m: float
    mass_kg: float
    rotating_mass_factor: float
    max_speed_ms: float
    max_traction_n: float
    max_power_w: float
    davis_a_n: float
    davis_b_n_per_mps: float
    davis_c_n_per_mps2: float
    service_brake_decel_mps2: float
    emergency_brake_decel_mps2: float
    max_brake_power_w: float = math.inf
    max_jerk_mps3: float = math.inf
    traction_lag_s: float = 0.0

    def with_(self, **changes: Any) -> "TrainParams":
        """A copy with some parameters changed (for sweeps and robust proxies)."""
        return replace(self, **changes)


# -------------------------------------------------------------------------------------------
# Type dispatch so the same expressions work for floats, numpy and CasADi


def _is_casadi(*xs: Any) -> bool:
    return any(type(x).__module__.startswith("casadi") for x in xs)


_SCALARS = (float, int)


def fmin(a: Any, b: Any) -> Any:
    """Element-wise minimum for floats, numpy arrays and CasADi expressions (NaN propagates)."""
    if type(a) in _SCALARS and type(b) in _SCALARS:  # fast path of the per-step scalar loops
        return a if a <= b else (b if a == a else a)
    if _is_casadi(a, b):
        import casadi as ca

        return ca.fmin(a, b)
    return np.minimum(a, b)


def fmax(a: Any, b: Any) -> Any:
    """Element-wise maximum for floats, numpy arrays and CasADi expressions (NaN propagates)."""
    if type(a) in _SCALARS and type(b) in _SCALARS:
        return a if a >= b else (b if a == a else a)
    if _is_casadi(a, b):
        import casadi as ca

        return ca.fmax(a, b)
    return np.maximum(a, b)


# -------------------------------------------------------------------------------------------
# Forces (eq. 1b, 2)


def running_resistance(p: TrainParams, v: Any, tunnel_factor: Any = 1.0) -> Any:
    """Davis running resistance A + B·v + T_f·C·v², N (Felez eq. 1b; Terlizzi eq. 5)."""
    return p.davis_a_n + p.davis_b_n_per_mps * v + tunnel_factor * p.davis_c_n_per_mps2 * v * v


def gradient_force(p: TrainParams, gradient: Any) -> Any:
    """Gravity component along the track, N, positive uphill (Felez eq. 2b, i = rise/run).

    SUMO uses M·g·sin(atan(i)); for |i| ≤ 0.08 the difference to M·g·i is below 0.4 %.
    """
    return p.mass_kg * G * gradient


def curve_force(p: TrainParams, radius_m: Any) -> Any:
    """Curve resistance M·k_c/R, N (Felez eq. 2c with a consistent unit, see module doc)."""
    if isinstance(radius_m, (int, float)) and (radius_m <= 0 or math.isinf(radius_m)):
        return 0.0
    return p.mass_kg * CURVE_COEFF_M2PS2 / radius_m


def curve_equivalent_gradient(radius_m: float) -> float:
    """Curve resistance expressed as the gradient with the same force (rise/run)."""
    if radius_m <= 0 or math.isinf(radius_m):
        return 0.0
    return CURVE_COEFF_M2PS2 / (G * radius_m)


def traction_limit(p: TrainParams, v: Any) -> Any:
    """Maximum tractive force min(M·a_dr, P_dr/v), N (eq. 4a, 4b)."""
    return fmin(p.max_traction_n, p.max_power_w / fmax(v, V_EPS_MPS))


def brake_force_limit(p: TrainParams, v: Any) -> Any:
    """Maximum braking force min(M·a_br, P_br/v), N (eq. 4a, 4b)."""
    f = p.mass_kg * p.service_brake_decel_mps2
    if math.isinf(p.max_brake_power_w):
        return f + 0.0 * v
    return fmin(f, p.max_brake_power_w / fmax(v, V_EPS_MPS))


def acceleration(p: TrainParams, v: Any, u: Any, gradient: Any = 0.0, tunnel_factor: Any = 1.0, curve_n: Any = 0.0) -> Any:
    """dv/dt for a net traction/brake force u (N), m/s² (eq. 1b)."""
    return (u - running_resistance(p, v, tunnel_factor) - gradient_force(p, gradient) - curve_n) / (p.mass_kg * p.rotating_mass_factor)


def max_acceleration(p: TrainParams, v: Any, gradient: Any = 0.0, tunnel_factor: Any = 1.0, curve_n: Any = 0.0) -> Any:
    """Acceleration at full traction, m/s² (eq. 1b with u at the eq. 4 limit)."""
    return acceleration(p, v, traction_limit(p, v), gradient, tunnel_factor, curve_n)


def max_deceleration(p: TrainParams, v: Any, gradient: Any = 0.0, tunnel_factor: Any = 1.0, curve_n: Any = 0.0) -> Any:
    """Deceleration at full service brake plus resistance, m/s² (positive)."""
    return -acceleration(p, v, -brake_force_limit(p, v), gradient, tunnel_factor, curve_n)


def balance_speed(p: TrainParams, gradient: float = 0.0, tunnel_factor: float = 1.0) -> float:
    """Speed at which full traction equals the resistance, m/s (capped at the train's maximum)."""
    lo, hi = 0.0, p.max_speed_ms
    if max_acceleration(p, hi, gradient, tunnel_factor) >= 0:
        return hi
    if max_acceleration(p, 0.0, gradient, tunnel_factor) <= 0:
        return 0.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if max_acceleration(p, mid, gradient, tunnel_factor) > 0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


# -------------------------------------------------------------------------------------------
# Actuator: lag and jerk (eq. 1c, 4c)


def lag_step(force_n: Any, command_n: Any, lag_s: float, dt: float) -> Any:
    """One explicit-Euler step of dF/dt = (u − F)/τ (eq. 1c); τ = 0 means no lag."""
    if lag_s <= 0:
        return command_n
    alpha = min(1.0, dt / lag_s)
    return force_n + alpha * (command_n - force_n)


def jerk_limit(previous_force_n: float, command_n: float, p: TrainParams, dt: float) -> float:
    """Clip a force command so |ΔF|/(M·Δt) ≤ j_max (eq. 4c)."""
    if math.isinf(p.max_jerk_mps3):
        return command_n
    dmax = p.max_jerk_mps3 * p.mass_kg * dt
    return float(np.clip(command_n, previous_force_n - dmax, previous_force_n + dmax))


def clip_force(p: TrainParams, v: float, u: float) -> float:
    """Clip a force command to the traction and brake envelopes (eq. 4a, 4b)."""
    return float(np.clip(u, -brake_force_limit(p, v), traction_limit(p, v)))


# -------------------------------------------------------------------------------------------
# Braking distance


def braking_distance(v: Any, decel: float, reaction_time_s: float = 0.0) -> Any:
    """Distance to stop from speed v at constant deceleration after a reaction time, m.

    v²/(2·b) + v·t_r.  Blocking-time theory uses the service deceleration; SUMO's Rail model plans
    every stop with ``decel`` and reacts one simulation step late.
    """
    return v * v / (2.0 * decel) + v * reaction_time_s


def discrete_stop_speed(gap_m: float, decel: float, dt: float, reaction_steps: float = 0.0) -> float:
    """Highest speed from which a semi-implicit-Euler driver stops within ``gap_m``, m/s.

    Solves v²/(2b) + v·dt·(reaction_steps + ½) = gap.  With ``reaction_steps = 0`` this is how
    SUMO's Rail model approaches a stop, a red signal or (moving block) the braking point behind
    the train ahead: its braking distance is v²/(2b) + ½·Δt·v (measured, see
    :func:`vcsumo.signalling.blocking_time.sumo_reaction_time`).
    """
    if gap_m <= 0:
        return 0.0
    k = dt * (reaction_steps + 0.5)
    return decel * (-k + math.sqrt(k * k + 2.0 * gap_m / decel))


def discrete_approach_speed(gap_m: float, target_ms: float, decel: float, dt: float) -> float:
    """Highest speed from which braking at ``decel`` reaches ``target_ms`` within ``gap_m``, m/s."""
    if gap_m <= 0:
        return target_ms
    k = 0.5 * dt
    return max(target_ms, decel * (-k + math.sqrt(k * k + (target_ms * target_ms + 2.0 * decel * gap_m) / (decel * decel))))
