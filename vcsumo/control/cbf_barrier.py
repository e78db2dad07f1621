"""The barrier of the CBF safety layer (Terlizzi, Liuzza & Glielmo 2024, eq. 14–15) and its settings.

Two forms, chosen by :class:`CBFConfig` (``distance``, ``leader_braking``):

* ``distance: fixed`` — the paper's barrier (:class:`BarrierModel`): b = max{b', b''} of eq. 15 with
  a fixed safety distance d (Table II: 1,000 m), the leader's strongest braking the top of its
  service box (``leader_braking: service``, the paper's ā_br) or of its emergency range
  (``emergency``), the follower's weakest ε·α̲ of its service box.  b' is a difference of stopping
  points at one instant: it protects the gap over the whole braking episode only while the follower
  cannot out-brake the leader (the shared note *safe-separation*).
* ``distance: model`` (the default) — the barrier on the one separation model
  (:class:`SeparationBarrier`, :mod:`vcsumo.signalling.separation`): the same safe set eq. 14 with d =
  the assumption set's margin + the position errors of both trains, and b = d + (the worst closing
  of the gap over the braking episode) − (the gap), the closing of
  :class:`~vcsumo.signalling.separation.RelativeBraking` — the follower's guaranteed emergency brake
  (bottom of its range, Davis A, descents where it brakes) after the set's dead time (reaction +
  half the build-up) plus the equivalent dead time of its own force lag and jerk limit from the
  force it applies, against the leader's strongest (top of its emergency range, its whole running
  resistance, up-grades).  When the follower never out-brakes the leader this is eq. 15 with the
  model's stopping points (b = max{b', b''}); when it does (a light follower behind a heavy leader)
  it is the maximum over the episode, never a negative term.  The leader's state is Algorithm 1's
  (its RLP from the newest packet, braking at its strongest since), so the message age and the T^max
  rule of eq. 18 enter as in the paper.

``convention: authors`` (with ``distance: fixed``) replaces eq. 15 by the barrier of the authors'
public code (d front to front, the halved stopping term, fixed brake forces:
:data:`AUTHORS_BRAKE_FORCES_N`), to reproduce the paper's figures; it guarantees nothing.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from vcsumo.config import StrictModel, load_model
from vcsumo.errors import VcsumoError
from vcsumo.control.brake_build_up import BrakeBuildUp
from vcsumo.control.proxies import V_EPS_MPS, BoxBounds, RobustProxies, RouteBounds, StopIntegral
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel, brake_range
from vcsumo.units import G


class CBFConfig(StrictModel):
    """Safety-layer parameters (Table II of the paper where it gives them)."""

    name: str = Field(default="cbf", description="Identifier of the parameter set")
    notes: str = Field(default="", description="Provenance and assumptions")
    distance: Literal["model", "fixed"] = Field(
        default="model",
        description="Safety distance and barrier: 'model' — d = the assumption set's margin + 2 position errors and the separation "
                    "model's relative braking over the whole braking episode (vcsumo.signalling.separation); 'fixed' — the paper's "
                    "eq. 15 with d = safety_distance_m")
    leader_braking: Literal["emergency", "service"] | None = Field(
        default=None,
        description="The leader's strongest braking: 'emergency' — the top of its emergency range under the assumption set (plus its "
                    "resistance and up-grades); 'service' — the top of its service box (the paper's a_br); unset — with distance: model "
                    "the assumption set's relative_braking (the rule the run-health monitor judges the gap with), with distance: fixed "
                    "'emergency'. With distance: model a brake weaker than the set's is refused (the CBF would keep less than the run "
                    "is judged by)")
    safety_distance_m: float = Field(default=1000.0, gt=0, le=50000, description="Safety distance d with distance: fixed, m (Table II: 1,000 m); at most 50 km, the longest block")
    t_max_s: float = Field(default=8.0, gt=0, le=600, description="T^max: longest wait for a leader packet before K_E^F (eq. 18), s (Table II); at most 600 s")
    epsilon: float = Field(default=0.98, gt=0, lt=1, description="ε of §V (slightly below one), - (distance: fixed)")
    packet_loss_probability: float = Field(default=0.01, ge=0, le=1, description="p_loss of Table II, per packet (used for the channel of the reproduction), -")
    lookahead: bool = Field(default=True, description="Check the barrier one control step ahead under the nominal command (sampled-data Algorithm 2)")
    sampled_data_margin: bool = Field(default=True, description="Add the Δt integration margins to b' (false: the paper's continuous formula)")
    actuation_delay_s: float | None = Field(default=None, ge=0, le=30, description="Dead time (0–30 s) before the full brake acts, at full traction, s (None: from the follower's force lag and jerk limit and its applied force)")
    trust_reported_force: bool = Field(default=True, description="The observation's ego force_n is the force the actuator applies (used only for a follower with a force lag or jerk limit); false: bound it by the recent commands")
    stop_model: Literal["profile", "window"] = Field(default="profile", description="distance: fixed — stopping points of b' on the exact route gradient ('profile') or with the worst grade over a window ahead ('window', the paper's literal σ_sup/σ_inf)")
    trigger_margin_m: float = Field(default=0.0, ge=0, le=50000, description="Enforce K_E^F when b ≥ −margin, m, 0–50 km (0: the paper's b ≥ 0)")
    brake_without_leader_data: bool = Field(default=False, description="Hold K_E^F until the first leader packet (false: Algorithm 1 starts with the first packet, as in the paper)")
    position_error_m: float = Field(default=0.0, ge=0, le=100, description="Bound e_s of each train's position error, m (0–100 m); the barrier keeps d + 2·e_s between measured positions (Felez eq. 9), so the true gap stays ≥ d (distance: model — the larger of e_s and the assumption set's error)")
    convention: Literal["paper", "authors"] = Field(default="paper", description="Barrier conventions with distance: fixed: 'paper' (eq. 15 with L^L + d and the box decelerations) or 'authors' (the authors' public code: d front to front, the halved stopping-distance term 0.5·(v²/(2a)), fixed brake forces 315/330/370 kN; see AUTHORS_BRAKE_FORCES_N)")


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
        if (config.leader_braking or "emergency") == "emergency":
            leader = leader.with_emergency_leader()
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
        self.follower_delay_full_s = fb.actuation_delay_s()
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

    def rlp_reset(self, s0: float, v0: float) -> tuple[float, RouteBounds]:
        """Algorithm 1 reset at a packet's state: (e̲^L, its route window).  The window covers the
        leader's path for T^max at up to V_max and its braking from the highest speed it can reach
        meanwhile (:meth:`RobustProxies.leader_path_bounds`)."""
        lead = self.leader
        t_max = self.cfg.t_max_s
        v_hi = min(max(lead.b.max_speed_ms, v0), v0 + lead.b.accel_high(v0) * t_max)
        rb = lead.leader_path_bounds(s0, s0, v_hi, t_max)
        if self.authors:  # the authors' RLP brakes at their fixed emergency force
            return authors_decel(lead.b, "rlp", v0, rb.grade_max), rb
        return lead.leader_decel(v0, rb), rb

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
        stop, v, a = self.follower_stop_parts(s, v, force_n)
        if dt_s > 0 and v > 0.0:
            stop += sampled_stop_margin_m(v, max(a, 0.0), dt_s)
        return stop

    def follower_stop_parts(self, s: float, v: float, force_n: float | None) -> tuple[float, float, float]:
        """(S^F without the sampled-data margin, speed when the full brake acts, ē^F used).

        The speed is ≤ 0 when the follower stops before braking (then S^F is its position and no
        margin applies); :meth:`follower_stop` adds the margin.
        """
        if self.cfg.actuation_delay_s is not None:
            t_act, force_n = self.cfg.actuation_delay_s, None
        elif not self._f_actuated:
            t_act = 0.0
        elif force_n is None:
            t_act = self.follower_delay_full_s
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



# -------------------------------------------------------------------------------------------
# The barrier on the separation model (distance: model)


def level_route(length_m: float = 1.0e7) -> RouteProfile:
    """A straight level open-air route (for a barrier built without the follower's route)."""
    return RouteProfile(edges=["level"], starts_m=np.array([0.0]), lengths_m=np.array([float(length_m)]), speeds_ms=np.array([200.0]),
                        gradients=np.array([0.0]), tunnel_factors=np.array([1.0]), sections=["level"], km_from=np.array([0.0]),
                        km_to=np.array([length_m / 1000.0]), point_limits=[])


def model_leader_braking(model: SeparationModel, config: CBFConfig) -> str:
    """The leader's braking of the barrier on the separation model (``distance: model``): the
    config's ``leader_braking`` if given, else the assumption set's ``relative_braking`` — the brake
    the run-health monitor gives the leader.  A brake weaker than the set's (``service`` under an
    ``emergency`` set) is refused: the CBF would certify a gap the run is judged unsafe at."""
    kind = config.leader_braking or model.assumptions.relative_braking
    if kind == "service" and model.assumptions.relative_braking == "emergency":
        raise VcsumoError(f"CBF parameters '{config.name}': leader_braking 'service' is weaker than the assumption set "
                          f"'{model.assumptions.name}' relative_braking 'emergency' (leave leader_braking out to follow the set)")
    return kind


def model_safety_distance_m(model: SeparationModel, config: CBFConfig) -> float:
    """d of ``distance: model``: the assumption set's margin behind the leader's rear plus the position
    error of both trains (the larger of the set's and the configuration's bound e_s), m."""
    a = model.assumptions
    return a.safety_margin_m + 2.0 * max(a.position_error_m, config.position_error_m)


class SeparationBarrier:
    """Eq. 14–15 on the separation model (``distance: model``, see the module doc).

    b(x^L, x^F) = d + C(x^L, x^F) − (x1^L − L^L − x1^F), with C ≥ 0 the worst closing of the gap over
    the braking episode (:meth:`RelativeBraking.closing`: the leader at its strongest from x^L, the
    follower at its guaranteed emergency brake after the dead time T_F).  C = 0 gives b'' of eq.
    15b; C = S^F − S^L (stopping points) gives b' of eq. 15a; b ≤ 0 keeps the front-to-rear gap ≥ d
    at every moment of the episode, also when the follower out-brakes the leader.

    T_F = the set's dead time (reaction + half the brake build-up) + the equivalent dead time of
    the follower's force lag τ and jerk limit j from the force F it applies (:meth:`actuation_time`:
    τ + (F/M + a_g)/(2j), 0 once the brake is applied), during which it may accelerate with F and
    down the steepest descent of its route.  The second term shrinks at least as fast as time
    passes while K_E^F builds the brake up, so b does not rise along the emergency braking (the
    rule with the set's dead time alone, which the run-health monitor applies at every step, is then
    kept too: its stopping point cannot move forward by more than v·t_act while the brake builds up).
    """

    def __init__(self, leader: RollingStock, follower: RollingStock, follower_box: BoxBounds, config: CBFConfig, model: SeparationModel,
                 profile: RouteProfile | None = None):
        a = model.assumptions
        prof = profile if profile is not None else level_route()
        self.cfg = config
        self.model = model
        self.rule = rule = RelativeBraking(model, follower, leader, prof)
        kind = model_leader_braking(model, config)
        if kind != a.relative_braking:
            rule.leader = RouteBraking(model, leader, prof, kind, strongest=True)
            rule.never_outbrakes = rule.follower.brake_part(0.0) <= brake_range(leader, a, kind)[1]
        self.leader_length_m = leader.length_m
        self.leader_max_speed_ms = leader.max_speed_ms
        self.d_m = model_safety_distance_m(model, config)
        self.dead_time_s = model.dead_time_s
        self.follower = RobustProxies(follower_box, profile)  # the follower's RUP for the one-step look-ahead (eq. 13)
        self.build_up = BrakeBuildUp(follower, a)  # the follower's build-up: the separation guard's, one piece of code
        self._descent = max(0.0, -float(np.min(rule.follower.g_low)))  # the steepest descent of the route (rise/run)
        self.follower_delay_full_s = self.actuation_time(None)

    # ---- the follower's dead time ----------------------------------------------------------
    def actuation_time(self, force_n: float | None) -> float:
        """Equivalent dead time of the follower's force lag and jerk limit from the applied force
        ``force_n`` (None: full traction) to its guaranteed emergency brake, s: the configuration's
        ``actuation_delay_s`` if given, else the build-up's
        (:meth:`vcsumo.control.brake_build_up.BrakeBuildUp.actuation_time`: τ + (F/M + a_g)/(2j), 0 for
        a train without lag and jerk limit, or once the brake is applied)."""
        if self.cfg.actuation_delay_s is not None:
            return self.cfg.actuation_delay_s
        return self.build_up.actuation_time(force_n)

    def follower_dead(self, v_f: float, force_n: float | None, dt_s: float = 0.0) -> tuple[float, float]:
        """(speed held, dead time) of the follower before its guaranteed braking: the set's dead time
        plus :meth:`actuation_time`, at the speed it may reach meanwhile under its applied force and
        the steepest descent of its route (:meth:`~vcsumo.control.brake_build_up.BrakeBuildUp.hold_accel`);
        ``dt_s`` adds the explicit-Euler overshoot of a Δt-sampled braking (Δt/2)."""
        t_act = self.actuation_time(force_n)
        v = v_f
        if t_act > 0.0:
            f = self.build_up.full_traction_n if force_n is None else force_n
            v = v_f + self.build_up.hold_accel(f, self._descent) * t_act
        return v, self.dead_time_s + t_act + 0.5 * dt_s

    def new_step(self) -> None:
        """Start a new control step (nothing is cached between steps)."""

    # ---- the leader --------------------------------------------------------------------------
    def rlp_reset(self, s0: float, v0: float) -> tuple[float, None]:
        """Algorithm 1 reset at a packet's state: the leader's strongest deceleration over its path
        (brake at the top of its range, its whole running resistance at v0 — the highest while it
        slows — and the steepest up-grade under its body from s0 over T^max at up to V_max and its
        braking distance), m/s²; no route window (None)."""
        lead = self.rule.leader
        e_floor = lead.brake_part(0.0)
        reach = max(self.leader_max_speed_ms, v0) * self.cfg.t_max_s + v0 * v0 / (2.0 * e_floor)
        x = lead.x
        i0 = max(int(np.searchsorted(x, s0, side="right")) - 1, 0)
        i1 = max(int(np.searchsorted(x, s0 + reach, side="right")) - 1, i0)
        g = lead.g_low[min(i0, len(lead.g_low) - 1): min(i1, len(lead.g_low) - 1) + 1]
        return lead.brake_part(v0) + G * max(float(np.max(g)), 0.0) / lead.rho, None

    def leader_stop(self, s: float, v: float) -> float:
        """S^L: where a leader in state (s, v) stops at the earliest, m."""
        return s + self.rule.leader.stopping_distance(s, v, 0.0)

    # ---- the barrier -------------------------------------------------------------------------
    def value(self, s_l: float, v_l: float, s_f: float, v_f: float, force_n: float | None = None, dt_s: float = 0.0) -> tuple[float, float]:
        """(b, b'') for the leader's and the follower's fronts and speeds (the follower applying
        ``force_n``); ``dt_s > 0`` adds the sampled-data margins (the Euler overshoot of the follower,
        the leader's position lowered by v^L·Δt for plants that advance with the new speed)."""
        if dt_s > 0.0:
            s_l = s_l - v_l * dt_s
        b2 = self.d_m - (s_l - self.leader_length_m - s_f)
        v_dead, dead = self.follower_dead(v_f, force_n, dt_s)
        return b2 + self.rule.closing(s_f, v_dead, s_l, max(v_l, 0.0), dead), b2

    def required_gap_m(self, s_l: float, v_l: float, s_f: float, v_f: float, force_n: float | None = None) -> float:
        """The front-to-rear gap at which b = 0, m."""
        v_dead, dead = self.follower_dead(v_f, force_n)
        return self.d_m + self.rule.closing(s_f, v_dead, s_l, max(v_l, 0.0), dead)
