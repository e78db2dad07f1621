"""The follower's brake build-up: how long a train takes from the force it applies to its guaranteed
brake, and the force its plant applies one step after a command — bounded over its uncertainty box.

One piece of code for every safety layer of a VC follower that must count its own force lag and jerk
limit: the separation guard's two tests (:mod:`vcsumo.control.guard`: the relative-braking rule to
the predecessor, and the service-brake curves to its stop and the line's lower limits), the CBF's
barrier on the separation model (:class:`vcsumo.control.cbf_barrier.SeparationBarrier`) and the
certified spacing cbc tracks (:class:`vcsumo.control.gap_reference.SeparationGap`).
"""

from __future__ import annotations

import math

import numpy as np

from vcsumo.dynamics import brake_force_limit
from vcsumo.rolling_stock import RollingStock
from vcsumo.signalling.assumptions import AssumptionSet
from vcsumo.signalling.separation import RouteBraking, brake_range
from vcsumo.units import G


class BrakeBuildUp:
    """How long a train takes from the force it applies to its guaranteed brake, and its force
    one step ahead — bounded over its uncertainty box (mass, Davis A, brakes).

    :meth:`actuation_time` is the equivalent dead time of the force lag τ and the jerk limit j from
    the applied force F to the guaranteed brake of the relative-braking rule (the assumption set's
    ``relative_braking`` kind at the bottom of its range, b per mass): τ + (F/M + b)/(2j), with M̲
    for a traction force and M̄ for a brake force, 0 once F ≤ −b·M̄ — also the CBF's
    (:meth:`vcsumo.control.cbf_barrier.SeparationBarrier.actuation_time`): a jerk-limited ramp of
    duration R brakes at every moment at least as much as holding F for R/2 and then braking fully,
    a first-order lag τ at least as much as holding F for τ.  From full traction that is the longest
    (ETR1000: 0.5 + (0.94 + 1.08)/1.4 ≈ 1.94 s), from coasting less (≈ 1.27 s).

    :meth:`next_force` is the largest force the plant can apply one step after a command: a rising
    force at most the command (a plant without lag — SUMO's, driven by speed commands — applies it at
    once); a falling one no lower than the eq. 1c lag (Euler step min(1, Δt/τ)) and the eq. 4c jerk
    limit j·M̲·Δt allow (the plant's service envelope never asks less braking than a command above
    the guaranteed service force, its emergency brake at least M̲ times the bottom of the emergency
    range); :meth:`command_for` inverts the lag.
    """

    def __init__(self, stock: RollingStock, assumptions: AssumptionSet):
        p = stock.params()
        box = stock.uncertainty_box()
        self.lag_s = max(float(p.traction_lag_s), 0.0)
        self.jerk_mps3 = float(p.max_jerk_mps3) if math.isfinite(p.max_jerk_mps3) and p.max_jerk_mps3 > 0 else math.inf
        self.m_low, self.m_high = box.mass_kg.low, box.mass_kg.high
        self.rho = p.rotating_mass_factor
        self.davis_a_low_n = box.davis_a_n.low
        self.brake_mps2 = brake_range(stock, assumptions, assumptions.relative_braking)[0]
        """The guaranteed brake of the relative-braking rule, force per mass (bottom of its range), m/s²."""
        self.service_mps2 = brake_range(stock, assumptions, "service")[0]
        """The guaranteed service brake, force per mass (bottom of the set's range), m/s²: the end of the
        build-up of the guard's own service-brake curves."""
        self.emergency_low_n = self.m_low * brake_range(stock, assumptions, "emergency")[0]
        bp = box.max_brake_power_w.low if box.max_brake_power_w is not None else p.max_brake_power_w
        self.service_low = p.with_(mass_kg=self.m_low, service_brake_decel_mps2=brake_range(stock, assumptions, "service")[0], max_brake_power_w=bp)
        """The train with its guaranteed service-brake force (the bottom of mass, rate and power)."""
        self.service_full = self.service_low.with_(mass_kg=self.m_high)
        """The heaviest train of the box with that rate and power: its service force is the full service
        command (:meth:`service_command_n`)."""
        self.full_traction_n = self.m_high * box.max_accel_mps2.high
        self._routes: dict[int, tuple] = {}

    def actuation_time(self, force_n: float | None, brake_mps2: float | None = None) -> float:
        """Equivalent dead time from the applied force ``force_n`` (None: full traction) to the
        guaranteed brake ``brake_mps2`` (force per mass; None: the relative-braking rule's), s (0 for a
        train without lag and jerk limit, or once that brake is applied)."""
        if self.lag_s <= 0.0 and math.isinf(self.jerk_mps3):
            return 0.0
        f = self.full_traction_n if force_n is None else float(force_n)
        per_mass = f / (self.m_low if f > 0.0 else self.m_high) + (self.brake_mps2 if brake_mps2 is None else brake_mps2)
        if per_mass <= 1e-9:
            return 0.0
        return self.lag_s + (0.5 * per_mass / self.jerk_mps3 if math.isfinite(self.jerk_mps3) else 0.0)

    def hold_accel(self, force_n: float, descent: float) -> float:
        """The largest acceleration while the force ``force_n`` (its traction part) is held, on a
        descent of ``descent`` (rise/run ≥ 0), without resistance, m/s²."""
        return max(force_n, 0.0) / (self.rho * self.m_low) + G * max(descent, 0.0) / self.rho

    def held(self, braking: RouteBraking | None, s_m: float, v_mps: float, force_n: float, brake_mps2: float | None = None) -> tuple[float, float]:
        """(speed, dead time) of the build-up from ``force_n`` applied at (s, v) to the brake
        ``brake_mps2`` (None: the relative-braking rule's): the equivalent dead time
        :meth:`actuation_time` and the speed reached by its end with the force's traction part held,
        on the steepest descent under the train over the distance it runs meanwhile (``braking``: the
        train's guaranteed braking on its route, :class:`RouteBraking`; None: level track), m/s and s."""
        t_act = self.actuation_time(force_n, brake_mps2)
        if t_act <= 0.0:
            return v_mps, 0.0
        if braking is None:
            return v_mps + self.hold_accel(force_n, 0.0) * t_act, t_act
        route = self._routes.get(id(braking))
        if route is None or route[0] is not braking:  # the braking's edges, lowest gradients and steepest descent, once
            route = self._routes[id(braking)] = (braking, braking.x, braking.g_low, max(0.0, -float(np.min(braking.g_low))))
        _, x, g, descent_all = route
        reach = v_mps * t_act + 0.5 * self.hold_accel(force_n, descent_all) * t_act * t_act
        n = len(g) - 1
        i0 = min(max(int(np.searchsorted(x, s_m, side="right")) - 1, 0), n)
        i1 = min(max(int(np.searchsorted(x, s_m + reach, side="right")) - 1, i0), n)
        low = float(g[i0]) if i1 == i0 else float(g[i0: i1 + 1].min())
        return v_mps + self.hold_accel(force_n, max(0.0, -low)) * t_act, t_act

    def service_force_n(self, v_mps: float) -> float:
        """The service-brake force the train is sure to have at speed v, N (positive)."""
        return float(brake_force_limit(self.service_low, max(v_mps, 0.0)))

    def service_command_n(self, v_mps: float) -> float:
        """The full service brake as a force command at speed v, N (positive): min(M̄·b, P̲/v) with b the
        bottom of the set's service range — whatever the train's mass in its box, the plant's service
        envelope (its own limit min(M·a_br, P_br/v) ≥ min(M·b, P̲/v)) then brakes it at least at the
        guaranteed service rate per mass of the service curves (:class:`RouteBraking`)."""
        return float(brake_force_limit(self.service_full, max(v_mps, 0.0)))

    def lag_alpha(self, dt: float) -> float:
        return min(1.0, dt / self.lag_s) if self.lag_s > 0.0 else 1.0

    def next_force(self, force_n: float, command_n: float, dt: float, emergency: bool, v_mps: float) -> float:
        """The largest force the plant applies one step after ``command_n`` from ``force_n``, N."""
        target = -self.emergency_low_n if emergency else max(command_n, -self.service_force_n(v_mps))
        if target >= force_n:  # a rising force: at most the command (a plant without lag applies it at once: SUMO's)
            return target
        f = force_n + self.lag_alpha(dt) * (target - force_n)
        if math.isfinite(self.jerk_mps3):
            f = max(f, force_n - self.jerk_mps3 * self.m_low * dt)
        return f

    def command_for(self, force_n: float, next_force_n: float, dt: float) -> float:
        """The command whose force one step later is at most ``next_force_n`` (:meth:`next_force`
        inverted: a falling force through the lag, a rising one the force itself), N."""
        if next_force_n >= force_n:
            return next_force_n
        return force_n + (next_force_n - force_n) / self.lag_alpha(dt)


__all__ = ["BrakeBuildUp"]
