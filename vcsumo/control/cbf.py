"""Control-barrier-function safety layer of Terlizzi, Liuzza & Glielmo (2024), §V–§VI-C.

* :func:`barrier` — the CBF b(x) = max{b'(x), b''(x)} of eq. 15 with safety distance d, which
  protects the safe set 𝒮' = {x1^L − x1^F ≥ L^L + d} (eq. 14, Lemma V.1).
* :func:`emergency_force_n` — the follower emergency controller K_E^F (Definition 11).
* :class:`LeaderRLPPredictor` — Algorithm 1: the leader's RLP under an emergency brake, reset at
  every newer packet.
* :class:`DelayEstimator` — Algorithm 3: the p̄-quantile of the last N_Λ packet delays.
* :class:`CBFSupervisor` — Algorithm 2 (safety control) with the T^max rule of eq. 18.  It wraps
  *any* nominal controller through the :class:`~vcsumo.control.base.Supervisor` protocol:
  ``filter(obs, nominal) -> Command`` passes the nominal command through unless the robust barrier
  b(x̲^L(t), x^F(t)) reaches zero or no packet arrived for T^max, and then enforces K_E^F.

Sampled-data implementation (the paper's Algorithm 2 is continuous-time; here it runs once per
control step Δt):

* the check is made on the current state *and* one step ahead, with the leader RLP at t + Δt and
  the follower's RUP (eq. 13) after one step under the nominal command, so the nominal command is
  only applied when it keeps the robust barrier negative until the next check;
* the follower's stopping distance in b' gets the Euler integration error of a Δt-sampled
  braking, x2·Δt/2 + ē·Δt²/8, and the leader's RLP position is lowered by x̲2·Δt (covers plants
  that advance the position with the new speed, like SUMO).  ``sampled_data_margin: false``
  gives the paper's continuous-time formula.

Route model: eq. 15 is evaluated with stopping points (eq. 41–44).  By default
(``stop_model: profile``) they are the exact worst-case stopping points on the route's
train-averaged gradient (:class:`~vcsumo.control.proxies.StopIntegral`), which equal
x1 + x2²/(2e) of eq. 15 on a constant grade but, unlike the worst grade over a window ahead
(σ_sup/σ_inf of eq. 12–13), make b continuous and monotone in the state — Definition 1 asks for a
continuous b, and the proof of Theorem VI.1 needs b(x^L, x^F) ≤ b(x̲^L, x^F) whenever x^L ≥ x̲^L.
With the windowed form b jumps whenever a steeper grade enters the window, and the true barrier
can then exceed the robust one.  ``stop_model: window`` keeps the paper's literal form.

Deviations needed for a plant with grades and a power-limited brake (all on the safe side):
K_E^F demands the strongest brake of the box and holds it at standstill (see
:func:`emergency_force_n`); a force lag or jerk limit of the follower is bounded by a dead time
(:meth:`~vcsumo.control.proxies.BoxBounds.actuation_delay_s`) from the force it may be applying.

``convention: authors`` replaces eq. 15 by the barrier of the authors' public code (d front to
front, the halved stopping term, fixed brake forces: :data:`AUTHORS_BRAKE_FORCES_N`), to reproduce
the paper's figures; it guarantees nothing.

The *true* barrier (eq. 15 on the true states of both trains) is what the safety guarantee is
about (Theorem VI.1); the supervisor records it whenever the observation carries the sensed gap and
speed of the predecessor (it never uses them for control).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from vcsumo.config import StrictModel, load_model
from vcsumo.control.base import Command, Message, Observation
from vcsumo.control.proxies import V_EPS_MPS, BoxBounds, RobustProxies, RouteBounds, StopIntegral
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.units import G


class CBFConfig(StrictModel):
    """Safety-layer parameters (Table II of the paper where it gives them)."""

    name: str = Field(default="cbf", description="Identifier of the parameter set")
    notes: str = Field(default="", description="Provenance and assumptions")
    safety_distance_m: float = Field(default=1000.0, gt=0, le=50000, description="Safety distance d, m (Table II); at most 50 km, the longest block")
    t_max_s: float = Field(default=8.0, gt=0, le=600, description="T^max: longest wait for a leader packet before K_E^F (eq. 18), s (Table II); at most 600 s")
    epsilon: float = Field(default=0.98, gt=0, lt=1, description="ε of §V (slightly below one), -")
    packet_loss_probability: float = Field(default=0.01, ge=0, le=1, description="p_loss of Table II, per packet (used for the channel of the reproduction), -")
    lookahead: bool = Field(default=True, description="Check the barrier one control step ahead under the nominal command (sampled-data Algorithm 2)")
    sampled_data_margin: bool = Field(default=True, description="Add the Δt integration margins to b' (false: the paper's continuous formula)")
    actuation_delay_s: float | None = Field(default=None, ge=0, le=30, description="Dead time (0–30 s) before the full brake acts, at full traction, s (None: from the follower's force lag and jerk limit and its applied force)")
    trust_reported_force: bool = Field(default=True, description="The observation's ego force_n is the force the actuator applies (used only for a follower with a force lag or jerk limit); false: bound it by the recent commands")
    stop_model: Literal["profile", "window"] = Field(default="profile", description="Stopping points of b' on the exact route gradient ('profile') or with the worst grade over a window ahead ('window', the paper's literal σ_sup/σ_inf)")
    trigger_margin_m: float = Field(default=0.0, ge=0, le=50000, description="Enforce K_E^F when b ≥ −margin, m, 0–50 km (0: the paper's b ≥ 0)")
    brake_without_leader_data: bool = Field(default=False, description="Hold K_E^F until the first leader packet (false: Algorithm 1 starts with the first packet, as in the paper)")
    position_error_m: float = Field(default=0.0, ge=0, le=100, description="Bound e_s of each train's position error, m (0–100 m); the barrier keeps d + 2·e_s between measured positions (Felez eq. 9), so the true gap stays ≥ d")
    convention: Literal["paper", "authors"] = Field(default="paper", description="Barrier conventions: 'paper' (eq. 15 with L^L + d and the box decelerations) or 'authors' (the authors' public code: d front to front, the halved stopping-distance term 0.5·(v²/(2a)), fixed brake forces 315/330/370 kN; see AUTHORS_CONVENTION)")


def load_cbf_config(path: str | Path) -> CBFConfig:
    """Read a CBF parameter file (e.g. ``controllers/cbf.yaml``)."""
    return load_model(CBFConfig, path)


# -------------------------------------------------------------------------------------------
# The authors' code conventions (``convention: authors``)

AUTHORS_BRAKE_FORCES_N = {"follower": 315e3, "leader": 330e3, "rlp": 370e3}
"""Fixed brake forces of the authors' public code (github.com/mar4945/tool-RFI, RailwayClasses/Train.py,
for their 490 t leader and 540 t follower), N: the follower's stop in b' (with M̄ and A̲ only), the
leader's stop in b' (with M̲ and Ā + B̄v + C̄v²) and the leader RLP predictor of Algorithm 1
(its emergency braking, with M̲ and the full resistance).  With ``convention: authors`` the barrier
is b' = d − (x1^L − x1^F) − ½·(x2^L²/(2e^L) − x2^F²/(2e^F)), b'' = d − (x1^L − x1^F): d front to
front (no L^L) and the stopping-distance term halved — written as stopping points under twice these
decelerations (on a level track, as the authors', exactly their formula; a grade enters through the
route window as in ``stop_model: window``).  This is not the paper's eq. 15 and guarantees nothing:
it is there to reproduce the paper's figures (~1,300 m coupled at 50 m/s)."""


def authors_decel(box: BoxBounds, role: str, v_mps: float, grade: float) -> float:
    """The authors' deceleration under their fixed brake force of ``role`` (follower, leader, rlp), m/s² (positive)."""
    force = AUTHORS_BRAKE_FORCES_N[role]
    if role == "follower":  # e_up: the heaviest train, the least resistance (A̲ only), the flattest grade
        return (force + box.davis_a_low_n) / (box.rotating_mass_factor * box.mass_high_kg) + G * grade
    res = box.davis_a_high_n + box.davis_b_high_n_per_mps * v_mps + box.davis_c_high_n_per_mps2 * v_mps * v_mps
    return (force + res) / (box.rotating_mass_factor * box.mass_low_kg) + G * grade  # e_lp: the lightest, full resistance


# -------------------------------------------------------------------------------------------
# Barrier (eq. 15)


def barrier(s_leader_m: float, v_leader_mps: float, s_follower_m: float, v_follower_mps: float, e_leader_mps2: float, e_follower_mps2: float, leader_length_m: float, safety_distance_m: float, follower_extra_m: float = 0.0) -> tuple[float, float, float]:
    """b(x) = max{b'(x), b''(x)} of eq. 15; returns (b, b', b'').

    b'  = L^L + d − (x1^L − x1^F) − ½·(x2^L²/e̲^L − x2^F²/ē^F)        (15a)
    b'' = L^L + d − (x1^L − x1^F)                                      (15b)

    Positions are train fronts (m), e̲^L and ē^F positive decelerations (m/s²).
    ``follower_extra_m`` lengthens the follower's stopping distance (sampled-data margin).
    b ≤ 0 ⟺ safe set 𝒮; ē^F ≤ 0 (follower cannot stop) gives +inf.
    """
    b2 = leader_length_m + safety_distance_m - (s_leader_m - s_follower_m)
    if e_follower_mps2 <= 0:
        return math.inf, math.inf, b2
    stop_l = v_leader_mps * v_leader_mps / (2.0 * e_leader_mps2)
    stop_f = v_follower_mps * v_follower_mps / (2.0 * e_follower_mps2) + follower_extra_m
    b1 = b2 - (stop_l - stop_f)
    return max(b1, b2), b1, b2


def sampled_stop_margin_m(v_mps: float, decel_mps2: float, dt_s: float) -> float:
    """Extra distance of an explicit-Euler braking at Δt over the continuous v²/(2a): v·Δt/2 + a·Δt²/8."""
    return 0.5 * v_mps * dt_s + decel_mps2 * dt_s * dt_s / 8.0


class BarrierModel:
    """Eq. 15 for a leader/follower pair with their uncertainty boxes on a route.

    Eq. 15a written with stopping points (eq. 41–44): b' = L^L + d − (S^L − S^F) with
    S^L = x1^L + x2^L²/(2e̲^L) the earliest stop of a braking leader and S^F = x1^F + x2^F²/(2ē^F)
    the latest stop of the follower under K_E^F.  The route enters through ``stop_model``:

    * ``"profile"`` (default): S^L and S^F are the exact worst-case stopping points on the route's
      train-averaged gradient (:class:`~vcsumo.control.proxies.StopIntegral`) for a brake-plus-
      resistance deceleration bounded by ā_br + (Ā + B̄V + C̄T̄_fV²)/M̲ (leader, V = V^max so the
      bound does not depend on speed) and by ε·α̲(x2) + A̲/M̄ (follower).  On a constant grade σ
      they equal eq. 15 with e̲^L, ē^F evaluated at σ; on any profile b is continuous and
      monotone in the state, as Definition 1 and the proof of Theorem VI.1 need.
    * ``"window"``: the paper's literal form, e̲^L with σ_sup and ē^F with σ_inf over a window
      ahead (discontinuous where the window meets a new grade).
    """

    def __init__(self, leader: BoxBounds, follower: BoxBounds, config: CBFConfig, profile: RouteProfile | None = None):
        self.leader = RobustProxies(leader, profile)
        self.follower = RobustProxies(follower, profile)
        self.cfg = config
        self.leader_length_m = leader.length_m
        self.d_m = config.safety_distance_m + 2.0 * config.position_error_m  # Felez eq. 9: d_min = d0 + 2·e_s
        self.profile_mode = config.stop_model == "profile"
        self.authors = config.convention == "authors"
        if self.authors:  # d front to front, closed-form stopping points (AUTHORS_BRAKE_FORCES_N)
            self.leader_length_m = 0.0
            self.profile_mode = False
        self.stops_leader = StopIntegral(profile, leader.length_m)
        self.stops_follower = StopIntegral(profile, follower.length_m)
        tf = self.leader.route.global_bounds.tunnel_max
        v = leader.max_speed_ms
        res = leader.davis_a_high_n + leader.davis_b_high_n_per_mps * v + leader.davis_c_high_n_per_mps2 * tf * v * v
        self._leader_brake_mps2 = (leader.brake_decel_high_mps2 + res / leader.mass_low_kg) / leader.rotating_mass_factor
        # per-step constants of the follower (same arithmetic as BoxBounds.actuation_delay_s,
        # brake_decel_low and follower_stop, evaluated once)
        fb = follower
        self._f_actuated = fb.traction_lag_s > 0 or math.isfinite(fb.max_jerk_mps3)
        self._f_brake_full_n = fb.strongest_brake_n(0.0)
        self._f_traction_full_n = fb.mass_high_kg * fb.accel_high_mps2
        self._f_jerk_n_per_s = fb.mass_low_kg * fb.max_jerk_mps3 if math.isfinite(fb.max_jerk_mps3) and fb.max_jerk_mps3 > 0 else 0.0
        self._f_delay_full_s = fb.actuation_delay_s()
        self._f_lag_s = fb.traction_lag_s
        self._f_grade_up = G * max(0.0, -self.follower.route.global_bounds.grade_min)
        self._f_accel_den = fb.rotating_mass_factor * fb.mass_low_kg
        self._f_resist_mps2 = fb.davis_a_low_n / (fb.rotating_mass_factor * fb.mass_high_kg)
        self._f_brake_low = (fb.brake_decel_low_mps2, fb.brake_power_low_w, fb.mass_high_kg, fb.rotating_mass_factor)
        self._f_epsilon = config.epsilon
        # S^L of recent leader states (profile mode: a function of (s, v) only): the supervisor asks
        # for the same RLP states at t + Δt and again at the next step's t.  Two generations, this
        # step's and the last one's (new_step), bounded in size for callers that never call it
        self._leader_stops: dict[tuple[float, float], float] = {}
        self._leader_stops_prev: dict[tuple[float, float], float] = {}

    # ---- decelerations without the grade -------------------------------------------------
    def leader_brake_decel(self, v: float) -> float:
        """Upper bound of a leader's brake-plus-resistance deceleration at speed ≤ max(V^max, v), m/s²."""
        b = self.leader.b
        if v <= b.max_speed_ms:
            return self._leader_brake_mps2
        tf = self.leader.route.global_bounds.tunnel_max
        res = b.davis_a_high_n + b.davis_b_high_n_per_mps * v + b.davis_c_high_n_per_mps2 * tf * v * v
        return (b.brake_decel_high_mps2 + res / b.mass_low_kg) / b.rotating_mass_factor

    def follower_brake_decel(self, v: float) -> float:
        """Lower bound ε·α̲(x2) + A̲/M̄ of the follower's deceleration under K_E^F, without the grade, m/s²."""
        # ε·brake_decel_low(v) + A̲/M̄ with the box constants looked up once (same arithmetic)
        lo, p_lo, m_hi, rho = self._f_brake_low
        vv = V_EPS_MPS if V_EPS_MPS > v else v  # max(v, V_EPS)
        x = p_lo / (m_hi * vv)
        return self._f_epsilon * ((x if x < lo else lo) / rho) + self._f_resist_mps2

    # ---- windowed decelerations of §V (paper-literal; also used by the RLP and the references)
    def leader_bounds(self, s: float, v: float) -> RouteBounds:
        return self.leader.leader_stop_bounds(s, v, self.cfg.t_max_s)

    def leader_decel(self, s: float, v: float, rb: RouteBounds | None = None) -> float:
        """e̲^L at a leader state (window from :meth:`RobustProxies.leader_stop_bounds` unless given)."""
        rb = rb if rb is not None else self.leader_bounds(s, v)
        if self.authors:  # twice the authors' e^L: their halved stopping term
            return 2.0 * authors_decel(self.leader.b, "leader", v, rb.grade_max)
        return self.leader.leader_decel(v, rb)

    def follower_decel(self, s: float, v: float, v_window: float | None = None) -> float:
        """ē^F at a follower state; the route window is that of speed ``v_window`` (≥ v) if given."""
        rb, _ = self.follower.follower_stop_bounds(s, max(v, v_window or 0.0), self.cfg.epsilon)
        if self.authors:  # twice the authors' e^F: their halved stopping term
            return 2.0 * authors_decel(self.follower.b, "follower", v, rb.grade_min)
        return self.follower.follower_decel(v, rb, self.cfg.epsilon)

    def rlp_decel(self, v: float, rb: RouteBounds) -> float:
        """The leader RLP's deceleration of Algorithm 1 from speed v over route window rb, m/s²."""
        if self.authors:
            return authors_decel(self.leader.b, "rlp", v, rb.grade_max)
        return self.leader.leader_decel(v, rb)

    # ---- stopping points ------------------------------------------------------------------
    def leader_stop(self, s: float, v: float, rb: RouteBounds | None = None) -> float:
        """S^L: lower bound of where a leader in state (s, v) can come to a stop, m."""
        if v <= 0.0:
            return s
        if self.profile_mode:
            key = (s, v)
            stop = self._leader_stops.get(key)
            if stop is None:
                stop = self._leader_stops_prev.get(key)
                if stop is None:
                    stop = self.stops_leader.stop_point(s, v, self.leader_brake_decel(v))
                if len(self._leader_stops) >= 256:
                    self.new_step()
                self._leader_stops[key] = stop
            return stop
        return s + v * v / (2.0 * self.leader_decel(s, v, rb))

    def new_step(self) -> None:
        """Start a new control step: S^L remembered from the last step only (a cache, no state)."""
        self._leader_stops_prev = self._leader_stops
        self._leader_stops = {}

    def follower_stop(self, s: float, v: float, dt_s: float = 0.0, force_n: float | None = None) -> float:
        """S^F: upper bound of where the follower stops under K_E^F from (s, v), m.

        ``dt_s > 0`` adds the explicit-Euler overshoot of a Δt-sampled braking (v·Δt/2 + a·Δt²/8).
        A follower with a force lag or jerk limit first keeps (at most) its applied force
        ``force_n`` (None: full traction) for the dead time of
        :meth:`~vcsumo.control.proxies.BoxBounds.actuation_delay_s` (or ``actuation_delay_s`` of
        the configuration, at full traction).
        """
        stop, v, a = self._follower_stop_parts(s, v, force_n)
        if dt_s > 0 and v > 0.0:
            stop += sampled_stop_margin_m(v, max(a, 0.0), dt_s)
        return stop

    def _follower_stop_parts(self, s: float, v: float, force_n: float | None) -> tuple[float, float, float]:
        """(S^F without the sampled-data margin, speed when the full brake acts, ē^F used).

        The speed is ≤ 0 when the follower stops before braking (then S^F is its position and no
        margin applies); :meth:`follower_stop` adds the margin.
        """
        if self.cfg.actuation_delay_s is not None:
            t_act, force_n = self.cfg.actuation_delay_s, None
        elif not self._f_actuated:
            t_act = 0.0
        elif force_n is None:
            t_act = self._f_delay_full_s
        else:  # the follower's BoxBounds.actuation_delay_s(force_n) with its constants precomputed
            swing = force_n + self._f_brake_full_n
            if swing > 0.0:
                t_act = self._f_lag_s + (swing / self._f_jerk_n_per_s if self._f_jerk_n_per_s > 0 else 0.0)
            else:
                t_act = 0.0
        if t_act > 0.0:
            f_up = self._f_traction_full_n if force_n is None else max(force_n, 0.0)
            a_up = f_up / self._f_accel_den + self._f_grade_up
            s = s + v * t_act + 0.5 * a_up * t_act * t_act
            v = v + a_up * t_act
        if v <= 0.0:
            return s, v, 0.0
        if self.profile_mode:
            # follower_brake_decel(v) written out (the hot path of the supervisor)
            lo, p_lo, m_hi, rho = self._f_brake_low
            x = p_lo / (m_hi * (V_EPS_MPS if V_EPS_MPS > v else v))
            a = self._f_epsilon * ((x if x < lo else lo) / rho) + self._f_resist_mps2
            stop = self.stops_follower.stop_point(s, v, a)
        else:
            a = self.follower_decel(s, v)
            stop = s + v * v / (2.0 * a) if a > 0 else math.inf
        return stop, v, a

    def value(self, s_l: float, v_l: float, s_f: float, v_f: float, dt_s: float = 0.0) -> tuple[float, float, float]:
        """b(x) = (b, b', b'') for the given states (eq. 15); ``dt_s > 0`` adds the sampled-data margins."""
        shift = v_l * dt_s if dt_s > 0 else 0.0
        return barrier_from_stops(s_l - shift, self.leader_stop(s_l, v_l) - shift, s_f, self.follower_stop(s_f, v_f, dt_s), self.leader_length_m, self.d_m)


def barrier_from_stops(pos_leader_m: float, stop_leader_m: float, pos_follower_m: float, stop_follower_m: float, leader_length_m: float, safety_distance_m: float) -> tuple[float, float, float]:
    """Eq. 15 written with stop points (eq. 44): b' = L + d − (S^L − S^F), b'' = L + d − (x1^L − x1^F)."""
    b2 = leader_length_m + safety_distance_m - (pos_leader_m - pos_follower_m)
    b1 = leader_length_m + safety_distance_m - (stop_leader_m - stop_follower_m)
    return max(b1, b2), b1, b2


def emergency_force_n(follower: BoxBounds, v_mps: float) -> float:
    """K_E^F (Definition 11): the full-brake demand, N (negative).

    The demand is the strongest brake force of any train in the box, so every true train saturates
    it at its own envelope min(M·a_br, P_br/v) and decelerates by at least α̲(x2) from braking
    alone — the deceleration ē^F in eq. 15 assumes.  (Definition 11's min 𝒰(x), the brake force
    *every* train can deliver, is weaker than α̲ for a heavy train: M̲·a̲_br/M̄ < a̲_br.)  At standstill
    the brake is held rather than released (Definition 11 sets u = 0 at x2 = 0, which on a falling
    grade would let the stopped train roll away).
    """
    return -follower.strongest_brake_n(max(v_mps, 0.0))


# -------------------------------------------------------------------------------------------
# Algorithm 1: leader RLP predictor


@dataclass(frozen=True)
class RLPBranch:
    """One reset of Algorithm 1: packet time, leader state, e̲^L at that state and its route window."""

    t0_s: float
    s0_m: float
    v0_mps: float
    e0_mps2: float
    rb: RouteBounds

    def state(self, t_s: float) -> tuple[float, float]:
        """(position, speed) of the RLP under constant deceleration e̲^L (eq. 38, 40, 41)."""
        tau = max(0.0, t_s - self.t0_s)
        v0, e = self.v0_mps, self.e0_mps2
        if tau * e >= v0:
            return self.s0_m + v0 * v0 / (2.0 * e), 0.0
        return self.s0_m + v0 * tau - 0.5 * e * tau * tau, v0 - e * tau


class LeaderRLPPredictor:
    """Algorithm 1: the leader's RLP under emergency braking from the last packet.

    On a packet with t_κ > t_last: t_last ← t_κ, x̲^L(t_last) ← x^L(t_κ).  Between packets the RLP
    (eq. 12) under the leader's strongest brake decelerates by at most e̲^L(x2(t_last)), so the
    prediction is the closed-form flow of eq. 38–41 (constant deceleration e̲^L evaluated at the
    reset state over the leader's route window), which lies below the RLP and hence below every
    true leader trajectory.  Before the first packet t_last = −∞ and x̲^L = +∞.

    The route window of a reset covers the leader's path for T^max at up to V_max and its braking
    from the highest speed it can reach meanwhile.  Every earlier reset stays a valid lower bound,
    so the predictor keeps the last ``keep`` resets and uses the highest of their bounds
    (:meth:`bounds`): a newer packet whose window sees a steeper up-grade then cannot make the
    prediction *more* pessimistic than the older one.  ``keep=1`` is the paper's predictor.
    """

    def __init__(self, model: BarrierModel, keep: int = 2):
        self.model = model
        self.keep = max(1, keep)
        self.branches: list[RLPBranch] = []
        self.resets = 0

    @property
    def has_data(self) -> bool:
        return bool(self.branches)

    @property
    def t_last(self) -> float:
        return self.branches[-1].t0_s if self.branches else -math.inf

    @property
    def latest(self) -> RLPBranch | None:
        return self.branches[-1] if self.branches else None

    def update(self, msg: Message | None) -> bool:
        """Lines 2–6: reset on a newer packet; returns True if reset."""
        if msg is None or not msg.sent_time_s > self.t_last:
            return False
        s0 = float(msg.state.position_m)
        v0 = max(0.0, float(msg.state.speed_mps))
        lead = self.model.leader
        t_max = self.model.cfg.t_max_s
        v_hi = min(max(lead.b.max_speed_ms, v0), v0 + lead.b.accel_high(v0) * t_max)
        rb = lead.leader_path_bounds(s0, s0, v_hi, t_max)
        self.branches.append(RLPBranch(float(msg.sent_time_s), s0, v0, self.model.rlp_decel(v0, rb), rb))
        if len(self.branches) > self.keep:
            del self.branches[0]
        self.resets += 1
        return True

    def predict(self, t_s: float) -> tuple[float, float]:
        """Line 7: x̲^L(t | K_E^L) of the latest reset = (position m, speed m/s) at time t."""
        if not self.branches:
            return math.inf, math.inf
        return self.branches[-1].state(t_s)

    def bounds(self, t_s: float) -> tuple[float, float, float]:
        """(position lower bound, stop-point lower bound, RLP speed) of the leader at time t.

        The stop point S^L (eq. 41, 44) of each kept RLP state; the highest bounds are used.
        """
        pos = stop = -math.inf
        v_out = 0.0
        model = self.model
        cache = model._leader_stops if model.profile_mode and len(model._leader_stops) < 256 else None
        for br in self.branches:
            # br.state(t_s) written out (the hot loop of the supervisor)
            tau = t_s - br.t0_s
            if not tau > 0.0:
                tau = 0.0
            v0, e = br.v0_mps, br.e0_mps2
            if tau * e >= v0:
                s, v = br.s0_m + v0 * v0 / (2.0 * e), 0.0
            else:
                s, v = br.s0_m + v0 * tau - 0.5 * e * tau * tau, v0 - e * tau
            if v <= 0.0:
                st = s
            elif cache is not None:  # model.leader_stop(s, v) with its cache written out
                key = (s, v)
                st = cache.get(key)
                if st is None:
                    st = model._leader_stops_prev.get(key)
                    if st is None:
                        st = model.stops_leader.stop_point(s, v, model.leader_brake_decel(v))
                    cache[key] = st
            else:
                st = model.leader_stop(s, v, br.rb)
            if s > pos:
                pos, v_out = s, v
            if st > stop:  # max(stop, st)
                stop = st
        return pos, stop, v_out

    def stop_of(self, s_m: float, v_mps: float) -> float:
        """S^L of a leader in state (s, v) (with the windows of the kept resets in ``window`` mode)."""
        if self.model.profile_mode or not self.branches:
            return self.model.leader_stop(s_m, v_mps)
        return max(self.model.leader_stop(s_m, v_mps, br.rb) for br in self.branches)

    def decel_at(self, v_mps: float) -> float:
        """e̲^L at an RLP speed over the window of the last reset."""
        return self.model.leader.leader_decel(v_mps, self.branches[-1].rb)


# -------------------------------------------------------------------------------------------
# Algorithm 3: delay estimator


class DelayEstimator:
    """Algorithm 3: τ̄ = inf{τ : F̂_Λ(τ) ≥ p̄} over the last N_Λ packet delays.

    τ(t_κ) is the elapsed time between the leader's trigger instant t_κ and the packet's reception
    at the follower.  Only packets newer than the last one update the stack (line 3).  Until the
    first packet the estimate is ``initial_delay_s``.
    """

    def __init__(self, window_size: int = 50, probability: float = 0.95, initial_delay_s: float = 1.0):
        if window_size < 1:
            raise ValueError("window_size must be at least 1")
        if not 0.0 < probability <= 1.0:
            raise ValueError("probability must be in (0, 1]")
        self.window_size = window_size
        self.probability = probability
        self.initial_delay_s = initial_delay_s
        self.samples: deque[float] = deque(maxlen=window_size)
        self.t_last = -math.inf
        self._estimate = initial_delay_s

    def update(self, sent_time_s: float, received_time_s: float) -> bool:
        """Store τ for a packet newer than the last one and recompute τ̄; returns True if stored."""
        if not sent_time_s > self.t_last or not math.isfinite(received_time_s):
            return False
        self.t_last = sent_time_s
        self.samples.append(max(0.0, received_time_s - sent_time_s))
        lam = np.sort(np.fromiter(self.samples, dtype=float))
        k = max(0, math.ceil(self.probability * len(lam) - 1e-12) - 1)
        self._estimate = float(lam[k])
        return True

    def update_from(self, msg: Message | None, now_s: float) -> bool:
        """Convenience: the packet's reception time (or ``now_s`` if the channel did not stamp it)."""
        if msg is None:
            return False
        rx = msg.received_time_s if math.isfinite(msg.received_time_s) else now_s
        return self.update(msg.sent_time_s, rx)

    @property
    def estimate_s(self) -> float:
        """τ̄, s."""
        return self._estimate


# -------------------------------------------------------------------------------------------
# Algorithm 2: safety control as a supervisor


@dataclass
class SupervisorStats:
    """Counters of a :class:`CBFSupervisor`."""

    steps: int = 0
    interventions: int = 0
    """Steps in which the nominal command was overridden by K_E^F."""
    emergency_activations: int = 0
    """Rising edges of K_E^F (the paper's sequence {t_κE})."""
    tmax_activations: int = 0
    """Activations caused by the T^max rule (eq. 18) alone."""
    emergency_time_s: float = 0.0
    max_robust_barrier_m: float = -math.inf
    max_true_barrier_m: float = -math.inf


@dataclass
class _History:
    time_s: list = field(default_factory=list)
    robust_barrier_m: list = field(default_factory=list)
    true_barrier_m: list = field(default_factory=list)
    emergency: list = field(default_factory=list)
    reason: list = field(default_factory=list)
    info_age_s: list = field(default_factory=list)


class CBFSupervisor:
    """Algorithm 2 (with Algorithm 1 inside) as a safety filter for any nominal controller.

    ``filter(obs, nominal)``: update the leader RLP from the predecessor's latest packet, evaluate
    the robust barrier b(x̲^L(t), x^F(t)) (and one step ahead under the nominal command) and the
    rule c = t − t_last − T^max (eq. 18); if either is ≥ 0 enforce K_E^F, otherwise pass the
    nominal command through.  The returned command's ``info`` carries the barrier values.
    """

    def __init__(self, leader: RollingStock | BoxBounds, follower: RollingStock | BoxBounds, config: CBFConfig | None = None, leader_id: str | None = None, record: bool = True, keep_resets: int = 2):
        self.leader_bounds = leader if isinstance(leader, BoxBounds) else BoxBounds.from_stock(leader)
        self.follower_bounds = follower if isinstance(follower, BoxBounds) else BoxBounds.from_stock(follower)
        self.cfg = config or CBFConfig()
        self.leader_id = leader_id
        self.record = record
        self.keep_resets = keep_resets
        self._models: dict[int, BarrierModel] = {}
        self._predictor: LeaderRLPPredictor | None = None
        self._profile_key: int | None = None
        self._model: BarrierModel | None = None
        self.stats = SupervisorStats()
        self.history = _History()
        self._in_emergency = False
        self._commands: deque[tuple[float, float]] = deque()
        fb = self.follower_bounds
        self._command_horizon_s = 5.0 * fb.traction_lag_s + fb.actuation_delay_s() + 1.0

    @classmethod
    def from_files(cls, leader: str | Path, follower: str | Path, config: str | Path | None = None, leader_id: str | None = None) -> "CBFSupervisor":
        """Build from rolling-stock names/paths and a CBF YAML file (default ``controllers/cbf.yaml``)."""
        from vcsumo.control.params import resolve_params
        from vcsumo.rolling_stock import load_rolling_stock

        return cls(load_rolling_stock(leader), load_rolling_stock(follower), load_cbf_config(resolve_params(config, "cbf", "config")), leader_id)

    # ---------------------------------------------------------------------------------------
    def model_for(self, profile: RouteProfile | None) -> BarrierModel:
        key = id(profile)
        m = self._models.get(key)
        if m is None:
            m = BarrierModel(self.leader_bounds, self.follower_bounds, self.cfg, profile)
            self._models[key] = m
        return m

    @property
    def predictor(self) -> LeaderRLPPredictor | None:
        return self._predictor

    def _leader_message(self, obs: Observation) -> Message | None:
        lid = self.leader_id or obs.predecessor
        if lid is None:
            if len(obs.received) == 1:
                return next(iter(obs.received.values()))
            return None
        return obs.received.get(lid)

    def filter(self, obs: Observation, nominal: Command) -> Command:
        prof_key = id(obs.profile)
        if self._predictor is None or self._profile_key != prof_key:
            # a new route frame: positions of older packets are not comparable, start Algorithm 1 again
            self._model = self.model_for(obs.profile)
            self._predictor = LeaderRLPPredictor(self._model, self.keep_resets)
            self._profile_key = prof_key
        model = self._model
        pred = self._predictor
        model.new_step()
        t, dt = obs.time_s, obs.step_s
        msg = self._leader_message(obs)
        pred.update(msg)
        s_f, v_f = obs.ego.position_m, max(0.0, obs.ego.speed_mps)
        stats = self.stats
        stats.steps += 1
        cfg = self.cfg

        b_true = math.nan
        sensed = obs.sensed_gap_m is not None and obs.sensed_speed_mps is not None
        if not pred.branches:
            if sensed:
                s_l_true = s_f + obs.sensed_gap_m + self.leader_bounds.length_m
                b_true = model.value(s_l_true, max(0.0, obs.sensed_speed_mps), s_f, v_f)[0]
                stats.max_true_barrier_m = max(stats.max_true_barrier_m, b_true)
            if cfg.brake_without_leader_data and obs.predecessor is not None:
                return self._emergency(obs, nominal, math.nan, b_true, "no-data", math.nan)
            self._log(t, math.nan, b_true, False, "no-data", math.nan)
            self._in_emergency = False
            self._remember(t, nominal.force_n)
            return nominal

        dt_m = dt if cfg.sampled_data_margin else 0.0
        Ld = model.leader_length_m + model.d_m  # L^L + d of eq. 15
        # follower RUP (eq. 13) after one step of the nominal command (with a force lag or jerk limit
        # the applied force lies between the present one and the command)
        actuated = model._f_delay_full_s > 0 or cfg.actuation_delay_s is not None
        f_now = self._applied_force_bound(t, obs.ego.force_n) if actuated else None
        u_pred = nominal.force_n if not actuated else max(nominal.force_n, f_now)
        f_next = None if not actuated else u_pred
        v_f1 = max(0.0, v_f + model.follower.rup_step_accel(s_f, v_f, u_pred, dt) * dt)
        s_f1 = s_f + max(v_f, v_f1) * dt
        # S^F at the present state once: with the sampled-data margin for the robust barrier, without
        # it for the true one (follower_stop(s_f, v_f, dt_m, f_now) and follower_stop(s_f, v_f, 0, f_now))
        stop_f_cont, v_brake, e_f = model._follower_stop_parts(s_f, v_f, f_now)
        stop_f0 = stop_f_cont
        if dt_m > 0 and v_brake > 0.0:
            stop_f0 += sampled_stop_margin_m(v_brake, max(e_f, 0.0), dt_m)
        # robust barrier b(x̲^L(t), x^F(t)) (Algorithm 2, line 2) and one step ahead; eq. 15 with stop
        # points as barrier_from_stops: b = max(b', b''), b' = L + d − (S^L − S^F), b'' = L + d − (x^L − x^F)
        pos_l, stop_l, v_l = pred.bounds(t)
        shift = v_l * dt_m
        b_now = max(Ld - ((stop_l - shift) - stop_f0), Ld - ((pos_l - shift) - s_f))
        b_chk = b_now
        if cfg.lookahead:
            pos_l1, stop_l1, v_l1 = pred.bounds(t + dt)
            shift = v_l1 * dt_m
            stop_f1, v_brake, e_f = model._follower_stop_parts(s_f1, v_f1, f_next)
            if dt_m > 0 and v_brake > 0.0:
                stop_f1 += sampled_stop_margin_m(v_brake, max(e_f, 0.0), dt_m)
            b_next = max(Ld - ((stop_l1 - shift) - stop_f1), Ld - ((pos_l1 - shift) - s_f1))
            b_chk = max(b_now, b_next)
        stats.max_robust_barrier_m = max(stats.max_robust_barrier_m, b_now)
        if sensed:
            # eq. 15 on the true states (Theorem VI.1), continuous-time form
            s_l_true = s_f + obs.sensed_gap_m + self.leader_bounds.length_m
            v_l_true = max(0.0, obs.sensed_speed_mps)
            b_true = max(Ld - (pred.stop_of(s_l_true, v_l_true) - stop_f_cont), Ld - (s_l_true - s_f))
            stats.max_true_barrier_m = max(stats.max_true_barrier_m, b_true)
        age = t - pred.branches[-1].t0_s
        c = age - cfg.t_max_s  # eq. 18
        if b_chk >= -cfg.trigger_margin_m:
            return self._emergency(obs, nominal, b_now, b_true, "barrier", age)
        if c >= 0.0:
            return self._emergency(obs, nominal, b_now, b_true, "t-max", age)
        self._in_emergency = False
        self._remember(t, nominal.force_n)
        self._log(t, b_now, b_true, False, "", age)
        info = {**nominal.info, "cbf_barrier_m": b_now, "cbf_true_barrier_m": b_true, "cbf_info_age_s": age}
        if type(nominal) is Command:  # dataclasses.replace without its per-call field introspection
            return Command(nominal.force_n, nominal.mode, nominal.emergency, nominal.infeasible, nominal.plan_times_s, nominal.plan_positions_m,
                           nominal.plan_speeds_mps, nominal.plan_forces_n, info)
        return replace(nominal, info=info)

    def _remember(self, t: float, force_n: float) -> None:
        """Keep the commands of the last 5 lag time constants plus a full jerk ramp."""
        self._commands.append((t, force_n))
        horizon = self._command_horizon_s
        while self._commands and self._commands[0][0] < t - horizon:
            self._commands.popleft()

    def _applied_force_bound(self, t: float, reported_n: float) -> float:
        """Upper bound of the force the actuator applies now: the reported one, or (untrusted) the
        maximum of the recent commands, of which a lagged/jerk-limited force is a mix.  The
        reported force makes the dead time shrink while K_E^F ramps the brake in, so b decreases
        along the emergency braking; the command bound is safe step by step but not monotone."""
        if self.cfg.trust_reported_force:
            return reported_n
        recent = max((f for _, f in self._commands), default=reported_n)
        return max(reported_n, recent)

    def _emergency(self, obs: Observation, nominal: Command, b_now: float, b_true: float, reason: str, age: float) -> Command:
        if not self._in_emergency:
            self.stats.emergency_activations += 1
            if reason == "t-max":
                self.stats.tmax_activations += 1
        self._in_emergency = True
        self.stats.interventions += 1
        self.stats.emergency_time_s += obs.step_s
        self._log(obs.time_s, b_now, b_true, True, reason, age)
        u = emergency_force_n(self.follower_bounds, max(0.0, obs.ego.speed_mps))
        self._remember(obs.time_s, u)
        return Command(
            force_n=u,
            mode="emergency",
            emergency=True,
            info={**nominal.info, "nominal_mode": nominal.mode, "nominal_force_n": nominal.force_n, "cbf_reason": reason, "cbf_barrier_m": b_now, "cbf_true_barrier_m": b_true, "cbf_info_age_s": age},
        )

    def _log(self, t: float, b: float, bt: float, em: bool, reason: str, age: float) -> None:
        if not self.record:
            return
        h = self.history
        h.time_s.append(t)
        h.robust_barrier_m.append(b)
        h.true_barrier_m.append(bt)
        h.emergency.append(em)
        h.reason.append(reason)
        h.info_age_s.append(age)

    def history_frame(self):
        """The recorded barrier history as a pandas DataFrame."""
        import pandas as pd

        h = self.history
        return pd.DataFrame({"time_s": h.time_s, "robust_barrier_m": h.robust_barrier_m, "true_barrier_m": h.true_barrier_m, "emergency": h.emergency, "reason": h.reason, "info_age_s": h.info_age_s})

    def true_barrier(self, profile: RouteProfile | None, s_leader_m: float, v_leader_mps: float, s_follower_m: float, v_follower_mps: float) -> float:
        """b(x) of eq. 15 on given (true) states, continuous-time form (for analysis)."""
        return self.model_for(profile).value(s_leader_m, v_leader_mps, s_follower_m, v_follower_mps)[0]
