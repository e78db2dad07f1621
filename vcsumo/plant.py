"""Offline plant: eq. 1 integrated for a train without SUMO (offline loop, paper reproductions, tests).

The same equations as :mod:`vcsumo.dynamics`; used where a paper's own simulation is the
reference (Felez et al. integrate eq. 6b with Δt = 0.1 s; Terlizzi et al. eq. 5 with their
uncertain parameters) and by the offline closed loop (:mod:`vcsumo.sim.offline`: the safety
campaign).  The SUMO runs use SUMO's Rail model as the plant instead.

Brakes.  A command is clipped to the traction envelope min(M·a_dr, P_dr/v) above and to the
**service brake** min(M·a_br, P_br/v) below (eq. 4a/4b).  A step with ``emergency=True`` applies
the **emergency brake** instead, whatever the command: the full force of
:func:`emergency_brake_limit`, max(M·a_eb, service envelope) — the emergency deceleration a_eb of
the *true* parameters the plant is given (a train at the top of its uncertainty box brakes at its
top rate), not power-limited; like a real emergency brake it is not modulated.  It builds up like
the service brake: the applied
force follows the command through the first-order lag τ (eq. 1c) and its rate is bounded by the
jerk limit j_max·M (eq. 4c) — e.g. an ETR1000 (τ = 0.5 s, j_max = 0.7 m/s³) goes from cruising
(≈ +0.1 m/s² of force) to its full emergency brake (−1.2 m/s²) in ≈ 1.9 s of jerk-limited ramp
after the lag, an equivalent dead time of ≈ 1.4 s; a train without lag and jerk limit brakes at
once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vcsumo.dynamics import TrainParams, acceleration, brake_force_limit, jerk_limit, lag_step, traction_limit
from vcsumo.route_profile import RouteProfile


def emergency_brake_limit(p: TrainParams, v_mps: float) -> float:
    """Largest emergency braking force, N (positive): max(M·a_eb, service envelope min(M·a_br, P_br/v))."""
    return max(p.mass_kg * p.emergency_brake_decel_mps2, float(brake_force_limit(p, v_mps)))


@dataclass
class PlantState:
    """State x = (s, v, F) of Felez eq. 6 (position m, speed m/s, applied force N)."""

    s_m: float
    v_mps: float
    force_n: float = 0.0
    accel_mps2: float = 0.0


class TrainPlant:
    """One train integrated with explicit Euler (Felez eq. 6b), force lag (1c) and jerk limit (4c).

    The jerk limit bounds the change of the applied force F per step (not of the command), so with
    both lag and jerk the effective jerk is min(lag rate, j_max).

    ``profile`` gives gradient (averaged over the train length) and tunnel factor along position;
    None means level open track.  Speed never goes negative (trains do not reverse).
    """

    def __init__(self, params: TrainParams, state: PlantState, profile: RouteProfile | None = None, apply_lag: bool = True, apply_jerk: bool = True):
        self.p = params
        self.x = state
        self.profile = profile
        self.apply_lag = apply_lag
        self.apply_jerk = apply_jerk

    def step(self, u_cmd_n: float, dt: float, emergency: bool = False) -> PlantState:
        """Advance by ``dt`` under the command ``u_cmd_n`` (N); ``emergency``: apply the full
        emergency brake instead (:func:`emergency_brake_limit`, see the module doc)."""
        p, x = self.p, self.x
        if emergency:
            u = -emergency_brake_limit(p, x.v_mps)
        else:
            u = float(np.clip(u_cmd_n, -brake_force_limit(p, x.v_mps), traction_limit(p, x.v_mps)))
        # the applied force F follows the command with lag τ (eq. 1c); its rate of change is
        # bounded by the jerk limit (eq. 4c / 12o: |F_{k+1} − F_k| ≤ j_max·M·Δt)
        force = lag_step(x.force_n, u, p.traction_lag_s, dt) if self.apply_lag else u
        if self.apply_jerk:
            force = jerk_limit(x.force_n, force, p, dt)
        grad, tf = 0.0, 1.0
        if self.profile is not None:
            grad = self.profile.mean_gradient(x.s_m, p.length_m)
            tf = self.profile.tunnel_factor_at(x.s_m)
        a = float(acceleration(p, x.v_mps, force, grad, tf))
        v_new = max(0.0, x.v_mps + a * dt)
        if v_new == 0.0 and x.v_mps == 0.0 and force <= 0:
            a = 0.0
        s_new = x.s_m + x.v_mps * dt  # explicit Euler, eq. 6b
        self.x = PlantState(s_new, v_new, force, (v_new - x.v_mps) / dt)
        return self.x
