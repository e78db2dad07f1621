"""Offline plant: eq. 1 integrated for a train without SUMO (for paper reproductions and tests).

The same equations as :mod:`vcsumo.dynamics`; used where a paper's own simulation is the
reference (Felez et al. integrate eq. 6b with Δt = 0.1 s; Terlizzi et al. eq. 5 with their
uncertain parameters).  The SUMO runs use SUMO's Rail model as the plant instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vcsumo.dynamics import TrainParams, acceleration, brake_force_limit, jerk_limit, lag_step, traction_limit
from vcsumo.route_profile import RouteProfile


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

    def step(self, u_cmd_n: float, dt: float) -> PlantState:
        p, x = self.p, self.x
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
