"""Robust lower and upper proxies of an uncertain train (Terlizzi, Liuzza & Glielmo 2024, §IV).

The train model is eq. 5 with the input constraints eq. 6 and the parameters uncertain in the box
eq. 7 (:meth:`vcsumo.rolling_stock.RollingStock.uncertainty_box`)::

    ẋ1 = x2
    ẋ2 = (−A − B·x2 − C·T_f·x2²)/(ρ·M) − g·σ(x1) + u/(ρ·M)

with σ the *equivalent* gradient of the route (gradient + curve resistance, the paper's
F_e = g·σ + γ/ρ_curve, see :mod:`vcsumo.route_profile`) and T_f the tunnel factor on the
aerodynamic term.  ρ is the rotating-mass factor (nominal, not uncertain; 1 in the paper).

* The **robust lower proxy** RLP (Definition 8, eq. 12) bounds every true trajectory from below,
  component-wise, for every parameter vector in the box.
* The **robust upper proxy** RUP (Definition 9, eq. 13) bounds it from above.

Both freeze the route at its worst value over a window [s_from, s^H] ahead of the train
(σ_sup / σ_inf in eq. 12–13) so that their right-hand side no longer depends on the position and
the comparison principle applies (Lemma IV.1).  The window must contain every position the true
train occupies (its whole length, so it starts at s − L) over the horizon considered; the paper's
choice is s^H = x1 + V^max·T^max (§VI-B).

Implementation notes (all keep the bounds valid, none changes the paper's equations):

* Forces are exogenous in eq. 12–13, but a real train saturates a command at its own (unknown)
  traction/brake envelope eq. 6a–6b.  The RLP therefore uses min(u, U_max^rob(x2)) for u ≥ 0
  (the traction every train in the box can deliver) and the RUP max(u, −U_br^rob(x2)) for u < 0
  (the braking every train in the box can deliver), so that the bounds hold for *any* command,
  including the full-brake demand of the emergency controller.
* The RLP's braking branch of eq. 12 evaluates the aerodynamic term at x2(t0) (the speed at the
  start of the prediction); we use max(x2, x2(t0)) so the bound also holds if the train speeds up
  on a down-grade while braking lightly.
* The proxies take the commanded force as applied (Terlizzi's model has no actuator dynamics).  For
  a train with a force lag or jerk limit (Felez eq. 1c, 4c) the safety layer adds the dead time
  :meth:`BoxBounds.actuation_delay_s` to the follower's braking (see :mod:`vcsumo.control.cbf`).
* :meth:`RobustProxies.rollout` integrates with explicit Euler on the same grid as
  :class:`vcsumo.plant.TrainPlant` (s_{k+1} = s_k + v_k·Δt, eq. 6b of Felez); the Euler map is
  monotone in (s, v) for the step sizes used, so the discrete proxies bound the discrete plant
  step by step (the property :mod:`tests.test_proxies` checks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vcsumo.dynamics import TrainParams, V_EPS_MPS
from vcsumo.rolling_stock import RollingStock, UncertaintyBox
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.separation import brake_range
from vcsumo.units import G
from vcsumo.control.route_bounds import GradeWindow, RouteBounds, StopIntegral  # noqa: F401 - part of this module's interface

"""Speed below which power limits are evaluated at this speed (as :mod:`vcsumo.dynamics`), m/s."""


# -------------------------------------------------------------------------------------------
# The parameter box (eq. 7)


@dataclass(frozen=True)
class BoxBounds:
    """The intervals of eq. 7 in SI units, plus the train's known (certain) data.

    ``*_low``/``*_high`` are the interval ends; braking quantities are magnitudes (positive).
    """

    length_m: float
    max_speed_ms: float
    rotating_mass_factor: float
    mass_low_kg: float
    mass_high_kg: float
    davis_a_low_n: float
    davis_a_high_n: float
    davis_b_low_n_per_mps: float
    davis_b_high_n_per_mps: float
    davis_c_low_n_per_mps2: float
    davis_c_high_n_per_mps2: float
    accel_low_mps2: float
    """a_dr lower end: traction force limit / mass, m/s²."""
    accel_high_mps2: float
    brake_decel_low_mps2: float
    """a_br lower end (service braking force limit / mass), m/s²."""
    brake_decel_high_mps2: float
    power_low_w: float
    power_high_w: float
    brake_power_low_w: float = math.inf
    brake_power_high_w: float = math.inf
    traction_lag_s: float = 0.0
    """First-order force lag τ (eq. 1c of Felez), s; 0 in Terlizzi's model."""
    max_jerk_mps3: float = math.inf
    """Jerk limit (eq. 4c of Felez), m/s³; none in Terlizzi's model."""
    emergency_decel_low_mps2: float = math.nan
    """Emergency-brake deceleration (brake force per mass) the train is sure of: the bottom of the
    separation model's emergency range (:func:`vcsumo.signalling.separation.brake_range`), m/s²;
    NaN when the bounds were built without a rolling stock (the paper's model has no emergency brake)."""
    emergency_decel_high_mps2: float = math.nan
    """The top of that range: the hardest emergency braking the train may show, m/s²."""

    def actuation_delay_s(self, force_n: float | None = None) -> float:
        """Dead time bounding the force lag and jerk limit from ``force_n`` to the full brake, s.

        A first-order lag τ and a jerk-limited ramp of duration ΔF/(M̲·j) each deliver, at every
        time, no less braking impulse than holding the present force for the same time and then
        braking fully.  ``force_n=None`` assumes full traction (ΔF ≤ M̄(ā_dr + ā_br)).  0 for a
        train without actuator dynamics (Terlizzi's model).
        """
        if self.traction_lag_s <= 0 and not math.isfinite(self.max_jerk_mps3):
            return 0.0
        f_full = self.strongest_brake_n(0.0)
        f0 = self.mass_high_kg * self.accel_high_mps2 if force_n is None else force_n
        swing = max(0.0, f0 + f_full)
        if swing <= 0.0:
            return 0.0
        ramp = swing / (self.mass_low_kg * self.max_jerk_mps3) if math.isfinite(self.max_jerk_mps3) and self.max_jerk_mps3 > 0 else 0.0
        return self.traction_lag_s + ramp

    @classmethod
    def from_box(cls, box: UncertaintyBox, nominal: TrainParams) -> "BoxBounds":
        """Bounds from the eq. 7 intervals; certain data (length, V_max, ρ) from the nominal model."""
        bp = box.max_brake_power_w
        bp_low = bp.low if bp is not None else nominal.max_brake_power_w
        bp_high = bp.high if bp is not None else nominal.max_brake_power_w
        return cls(
            length_m=nominal.length_m,
            max_speed_ms=nominal.max_speed_ms,
            rotating_mass_factor=nominal.rotating_mass_factor,
            mass_low_kg=box.mass_kg.low,
            mass_high_kg=box.mass_kg.high,
            davis_a_low_n=box.davis_a_n.low,
            davis_a_high_n=box.davis_a_n.high,
            davis_b_low_n_per_mps=box.davis_b_n_per_mps.low,
            davis_b_high_n_per_mps=box.davis_b_n_per_mps.high,
            davis_c_low_n_per_mps2=box.davis_c_n_per_mps2.low,
            davis_c_high_n_per_mps2=box.davis_c_n_per_mps2.high,
            accel_low_mps2=box.max_accel_mps2.low,
            accel_high_mps2=box.max_accel_mps2.high,
            brake_decel_low_mps2=box.service_brake_decel_mps2.low,
            brake_decel_high_mps2=box.service_brake_decel_mps2.high,
            power_low_w=box.max_power_w.low,
            power_high_w=box.max_power_w.high,
            brake_power_low_w=bp_low,
            brake_power_high_w=bp_high,
            traction_lag_s=nominal.traction_lag_s,
            max_jerk_mps3=nominal.max_jerk_mps3,
        )

    @classmethod
    def from_stock(cls, stock: RollingStock, assumptions: AssumptionSet | None = None) -> "BoxBounds":
        """Bounds of a rolling stock's box, with its emergency-brake range under ``assumptions``
        (the separation model's set; None: the shipped default)."""
        low, high = brake_range(stock, assumptions or load_assumptions(), "emergency")
        return replace(cls.from_box(stock.uncertainty_box(), stock.params()), emergency_decel_low_mps2=low, emergency_decel_high_mps2=high)

    def with_emergency_leader(self) -> "BoxBounds":
        """These bounds with the strongest braking of a leader at the top of its emergency range
        (``leader_braking: emergency`` of the CBF): ā_br ← the emergency top."""
        if not math.isfinite(self.emergency_decel_high_mps2):
            raise ValueError("leader_braking 'emergency' needs the leader's emergency range (BoxBounds.from_stock)")
        return replace(self, brake_decel_high_mps2=max(self.brake_decel_high_mps2, self.emergency_decel_high_mps2))

    def contains(self, p: TrainParams, tol: float = 1e-9) -> bool:
        """True when the parameter vector p lies in the box (eq. 7)."""

        def inside(x: float, lo: float, hi: float) -> bool:
            return lo - tol * max(1.0, abs(lo)) <= x <= hi + tol * max(1.0, abs(hi))

        return (
            inside(p.mass_kg, self.mass_low_kg, self.mass_high_kg)
            and inside(p.davis_a_n, self.davis_a_low_n, self.davis_a_high_n)
            and inside(p.davis_b_n_per_mps, self.davis_b_low_n_per_mps, self.davis_b_high_n_per_mps)
            and inside(p.davis_c_n_per_mps2, self.davis_c_low_n_per_mps2, self.davis_c_high_n_per_mps2)
            and inside(p.max_traction_n / p.mass_kg, self.accel_low_mps2, self.accel_high_mps2)
            and inside(p.service_brake_decel_mps2, self.brake_decel_low_mps2, self.brake_decel_high_mps2)
            and inside(p.max_power_w, self.power_low_w, self.power_high_w)
            and (math.isinf(self.brake_power_low_w) or inside(p.max_brake_power_w, self.brake_power_low_w, self.brake_power_high_w))
        )

    # ---------------------------------------------------------------------------------------
    # Robust input sets (eq. 16, 17)

    def robust_traction_max_n(self, v: float) -> float:
        """Largest traction force every train in the box can deliver at speed v, N (eq. 6a, 6b, 16)."""
        return min(self.mass_low_kg * self.accel_low_mps2, self.power_low_w / max(v, V_EPS_MPS))

    def robust_brake_max_n(self, v: float) -> float:
        """Largest braking force (magnitude) every train in the box can deliver at speed v, N.

        −robust_brake_max_n(v) = min 𝒰(x) of eq. 16–17: the emergency input of Definition 11.
        """
        return min(self.mass_low_kg * self.brake_decel_low_mps2, self.brake_power_low_w / max(v, V_EPS_MPS))

    def strongest_brake_n(self, v: float) -> float:
        """Largest braking force (magnitude) any train in the box may develop at speed v, N."""
        return min(self.mass_high_kg * self.brake_decel_high_mps2, self.brake_power_high_w / max(v, V_EPS_MPS))

    def brake_decel_low(self, v: float) -> float:
        """α̲(x2) = min{a̲_br, P̲_br/(M̄·x2)}: the weakest full-brake deceleration in the box, m/s² (§V).

        A train brought to its full brake (the emergency controller demands at least
        :meth:`strongest_brake_n`, which every train saturates at its own envelope) decelerates by
        min(a_br, P_br/(M·v)) ≥ α̲(v) from braking alone.
        """
        return min(self.brake_decel_low_mps2, self.brake_power_low_w / (self.mass_high_kg * max(v, V_EPS_MPS))) / self.rotating_mass_factor

    def accel_high(self, v: float) -> float:
        """Largest tractive acceleration any train in the box can reach at speed v, m/s² (ā_dr, eq. 22)."""
        return min(self.accel_high_mps2, self.power_high_w / (self.mass_low_kg * max(v, V_EPS_MPS))) / self.rotating_mass_factor


def sample_params(stock: RollingStock, rng: np.random.Generator, corner: bool = False) -> TrainParams:
    """A "true" parameter vector drawn uniformly inside the eq. 7 box (or at a random corner).

    Used to build a plant that differs from the nominal model (seeded)."""
    box = stock.uncertainty_box()
    nom = stock.params()

    def draw(iv) -> float:
        if iv is None:
            return math.nan
        if corner:
            return float(iv.low if rng.random() < 0.5 else iv.high)
        return float(rng.uniform(iv.low, iv.high))

    m = draw(box.mass_kg)
    a_dr = draw(box.max_accel_mps2)
    a_br = draw(box.service_brake_decel_mps2)
    p_br = draw(box.max_brake_power_w)
    return nom.with_(
        mass_kg=m,
        davis_a_n=draw(box.davis_a_n),
        davis_b_n_per_mps=draw(box.davis_b_n_per_mps),
        davis_c_n_per_mps2=draw(box.davis_c_n_per_mps2),
        max_traction_n=m * a_dr,
        service_brake_decel_mps2=a_br,
        emergency_brake_decel_mps2=max(nom.emergency_brake_decel_mps2, a_br),
        max_power_w=draw(box.max_power_w),
        max_brake_power_w=nom.max_brake_power_w if math.isnan(p_br) else p_br,
    )


# -------------------------------------------------------------------------------------------
# The proxies (eq. 12, 13) and the decelerations of §V


class RobustProxies:
    """RLP (eq. 12) and RUP (eq. 13) of one train, plus the decelerations e̲ and ē of §V."""

    def __init__(self, bounds: BoxBounds, profile: RouteProfile | None = None):
        self.b = bounds
        self.route = GradeWindow(profile)
        # the largest acceleration of :meth:`window` (constant)
        self._a_max_window = bounds.accel_high_mps2 / bounds.rotating_mass_factor + G * max(0.0, -self.route.global_bounds.grade_min)

    @classmethod
    def from_stock(cls, stock: RollingStock, profile: RouteProfile | None = None) -> "RobustProxies":
        return cls(BoxBounds.from_stock(stock), profile)

    # ---- one-step accelerations ------------------------------------------------------------
    def rlp_accel(self, v: float, u_n: float, rb: RouteBounds, v_ref: float | None = None) -> float:
        """dx̲2/dt of the RLP, eq. 12, m/s².

        u < 0: (−Ā − B̄·x2 − C̄·T̄_f·max(x2, x2(t0))²)/M̲ − g·σ_sup + u/M̲
        u ≥ 0: (−Ā − B̄·x2 − C̄·T̄_f·x2²)/M̲ − g·σ_sup + min(u, U_max^rob(x2))/M̄
        """
        b = self.b
        rho = b.rotating_mass_factor
        if u_n < 0:
            vc = max(v, v_ref) if v_ref is not None else v
            res = b.davis_a_high_n + b.davis_b_high_n_per_mps * v + b.davis_c_high_n_per_mps2 * rb.tunnel_max * vc * vc
            return (-res + u_n) / (rho * b.mass_low_kg) - G * rb.grade_max
        res = b.davis_a_high_n + b.davis_b_high_n_per_mps * v + b.davis_c_high_n_per_mps2 * rb.tunnel_max * v * v
        return -res / (rho * b.mass_low_kg) - G * rb.grade_max + min(u_n, b.robust_traction_max_n(v)) / (rho * b.mass_high_kg)

    def rup_accel(self, v: float, u_n: float, rb: RouteBounds) -> float:
        """dx̄2/dt of the RUP, eq. 13, m/s².

        u < 0: −A̲/M̄ − g·σ_inf + max(u, −U_br^rob(x2))/M̄
        u ≥ 0: (−A̲ − B̲·x2 − C̲·T̲_f·x2²)/M̄ − g·σ_inf + u/M̲
        """
        b = self.b
        rho = b.rotating_mass_factor
        if u_n < 0:
            return (-b.davis_a_low_n + max(u_n, -b.robust_brake_max_n(v))) / (rho * b.mass_high_kg) - G * rb.grade_min
        res = b.davis_a_low_n + b.davis_b_low_n_per_mps * v + b.davis_c_low_n_per_mps2 * rb.tunnel_min * v * v
        return -res / (rho * b.mass_high_kg) - G * rb.grade_min + u_n / (rho * b.mass_low_kg)

    # ---- integration -----------------------------------------------------------------------
    def window(self, s0: float, v0: float, horizon_s: float) -> RouteBounds:
        """Route bounds over every position the train can occupy within ``horizon_s`` from (s0, v0).

        [s0 − L, s0 + max(V_max, v0)·T + ½·a_max·T²], the paper's s^H = x1 + V^max·T widened by the
        largest acceleration of any train in the box (full traction down the steepest grade), so
        it holds even for a train that exceeds V_max.
        """
        b = self.b
        a_max = self._a_max_window
        reach = max(b.max_speed_ms, v0) * horizon_s + 0.5 * a_max * horizon_s * horizon_s
        return self.route.bounds(s0 - b.length_m, s0 + reach)

    def rup_step_accel(self, s0: float, v0: float, u_n: float, dt: float) -> float:
        """:meth:`rup_accel` at (s0, v0) under u over :meth:`window` (s0, v0, dt): the RUP's first
        step, with the window's two lower bounds only (same arithmetic)."""
        b = self.b
        a_max = self._a_max_window
        reach = max(b.max_speed_ms, v0) * dt + 0.5 * a_max * dt * dt
        grade_min, tunnel_min = self.route.lower_bounds(s0 - b.length_m, s0 + reach)
        rho = b.rotating_mass_factor
        if u_n < 0:
            return (-b.davis_a_low_n + max(u_n, -b.robust_brake_max_n(v0))) / (rho * b.mass_high_kg) - G * grade_min
        res = b.davis_a_low_n + b.davis_b_low_n_per_mps * v0 + b.davis_c_low_n_per_mps2 * tunnel_min * v0 * v0
        return -res / (rho * b.mass_high_kg) - G * grade_min + u_n / (rho * b.mass_low_kg)

    def rollout(self, kind: str, s0: float, v0: float, forces_n: np.ndarray, dt: float, rb: RouteBounds | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Integrate the RLP (``kind="lower"``) or RUP (``"upper"``) under a force sequence.

        ``forces_n[k]`` is held over [t0 + k·Δt, t0 + (k+1)·Δt).  Explicit Euler exactly as
        :class:`vcsumo.plant.TrainPlant` (speed clamped at 0).  Returns positions and speeds at
        t0, t0 + Δt, …, t0 + n·Δt (n + 1 values).  ``rb`` defaults to the window over the whole
        horizon at V_max (eq. 12–13 with s^H = x1 + V^max·n·Δt).
        """
        f = np.asarray(forces_n, dtype=float)
        n = len(f)
        if rb is None:
            rb = self.window(s0, v0, n * dt)
        s = np.empty(n + 1)
        v = np.empty(n + 1)
        s[0], v[0] = s0, v0
        lower = kind == "lower"
        if not lower and kind != "upper":
            raise ValueError("kind must be 'lower' or 'upper'")
        for k in range(n):
            a = self.rlp_accel(v[k], f[k], rb, v0) if lower else self.rup_accel(v[k], f[k], rb)
            v[k + 1] = max(0.0, v[k] + a * dt)
            s[k + 1] = s[k] + v[k] * dt
        return s, v

    # ---- decelerations of §V ---------------------------------------------------------------
    def leader_decel(self, v: float, rb: RouteBounds) -> float:
        """e̲^L(x2): the "large" deceleration of a braking leader (§V), m/s² (positive).

        (Ā + B̄·x2 + C̄·T̄_f·x2²)/M̲ + g·σ_sup + ā_br: resistance at the current speed (the highest
        while braking), the steepest rising grade, the strongest brake in the box.  Under any input
        a true leader starting at speed x2 has speed ≥ x2 − e̲^L·t (eq. 38).
        """
        b = self.b
        res = b.davis_a_high_n + b.davis_b_high_n_per_mps * v + b.davis_c_high_n_per_mps2 * rb.tunnel_max * v * v
        return res / (b.rotating_mass_factor * b.mass_low_kg) + G * rb.grade_max + b.brake_decel_high_mps2 / b.rotating_mass_factor

    def follower_decel(self, v: float, rb: RouteBounds, epsilon: float) -> float:
        """ē^F(x^F): the "small" deceleration of the follower under its emergency brake (§V), m/s².

        A̲/M̄ + g·σ_inf + ε·α̲(x2), with α̲ from :meth:`BoxBounds.brake_decel_low` (it includes the
        braking-power limit, eq. 6b, evaluated at the current – highest – speed).
        """
        b = self.b
        return b.davis_a_low_n / (b.rotating_mass_factor * b.mass_high_kg) + G * rb.grade_min + epsilon * b.brake_decel_low(v)

    def leader_path_bounds(self, s_from: float, s_to: float, v: float, t_max_s: float) -> RouteBounds:
        """Route window for a leader's RLP between s_from and s_to: the train's length behind,
        at least V_max·T^max ahead of s_from (§VI-B, s^H = x1 + V^max·T^max) and the braking
        distance from speed v at the weakest possible e̲^L beyond s_to."""
        b = self.b
        g_glob = self.route.global_bounds
        e_floor = b.brake_decel_high_mps2 / b.rotating_mass_factor + G * g_glob.grade_min
        reach = v * v / (2.0 * e_floor) if e_floor > 0 else 0.0
        end = max(s_to + reach, s_from + max(b.max_speed_ms * t_max_s, 0.0) + reach)
        return self.route.bounds(s_from - b.length_m, end + 1.0)

    def leader_stop_bounds(self, s: float, v: float, t_max_s: float) -> RouteBounds:
        """:meth:`leader_path_bounds` for a single leader state (s, v)."""
        return self.leader_path_bounds(s, s, v, t_max_s)

    def follower_stop_bounds(self, s: float, v: float, epsilon: float, iterations: int = 2) -> tuple[RouteBounds, float]:
        """Route window covering the follower's worst-case stop from (s, v), and ē^F over it.

        Fixed point: start from the whole route's flattest-for-braking grade; each pass narrows the
        window to [s − L, s + D_k] with D_k the stopping distance at the previous ē, which can only
        shrink, so the last window still covers the stop (the ē it yields is valid).  Returns
        (bounds, ē^F); ē^F ≤ 0 (cannot stop) gives an infinite distance to the caller.
        """
        b = self.b
        rb = self.route.global_bounds
        e = self.follower_decel(v, rb, epsilon)
        for _ in range(iterations):
            if e <= 0:
                break
            dist = v * v / (2.0 * e)
            rb_new = self.route.bounds(s - b.length_m, s + dist + 1.0)
            e_new = self.follower_decel(v, rb_new, epsilon)
            if e_new <= e + 1e-12:
                break
            rb, e = rb_new, e_new
        return rb, e


def robust_plan(proxies: RobustProxies, s0: float, v0: float, forces_n: np.ndarray, dt: float, t0: float, every: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The leader's robust predicted trajectory x̲^L(t_κ) sent with each message (§III-C, §VI-D).

    The leader's planned force sequence (from any controller on its nominal model) is applied
    open loop to its own RLP (eq. 12) from the current state.  Returns (times, positions, speeds)
    sub-sampled every ``every`` steps (the last point always included).
    """
    s, v = proxies.rollout("lower", s0, v0, forces_n, dt)
    idx = np.arange(0, len(s), max(1, every))
    if idx[-1] != len(s) - 1:
        idx = np.append(idx, len(s) - 1)
    return t0 + idx * dt, s[idx], v[idx]
