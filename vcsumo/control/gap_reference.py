"""Gap references of a virtually coupled convoy (Wu et al. survey §III.A, eq. 3.1–3.6, 3.10).

Frame: positions increase in the direction of travel (vcsumo's route frame), so the gap of train
i behind its predecessor i−1 is  d_i = x_{i−1} − L_{i−1} − x_i  (front-to-rear).  The survey's
eq. 3.8 writes d_i = x_i − x_{i−1} + L_{i−1}, i.e. positions measured against the direction of
travel; the two agree up to that sign.

Steady spacing
    eq. 3.1  d_i^de = D_safe + v_i²/(2 a_b) − v_{i−1}²/(2 a_b)   (relative braking distance);
             at steady convoy speed (v_i = v_{i−1}) it is the constant distance D_safe.
    The constant *time headway* h·v (the h_ij·v_0 term of eq. 4.3) may be added on top:
             d_i^de = D_safe + h·v_i + v_i²/(2 a_b) − v_{i−1}²/(2 a_b).
    With h = 0 and no a_b this is the constant-distance policy, with h > 0 the constant-time-
    headway policy; :class:`SteadyGap` covers all three.

Leader offset
    eq. 3.10  D_i = Σ_{m=1}^{i} (d_m^de + L_{m−1}):  x_i = x_0 − D_i in our frame.

Transitional references for forming (merge: gap shrinks) and leaving (split: gap grows):
    eq. 3.2  d^dy(t) = k1·exp(−k2 t) + d^de(t)                       (:class:`ExpTransition`)
    eq. 3.3  a^dy(t) = k3·k4·exp(−k4 t)                               (:func:`exp_transition_accel_mps2`)
    eq. 3.4  d^dy(x) = k1·sin[k2 (x + k3)] + k4                       (:class:`SinTransition`)
    eq. 3.5  k1 = (d0 − d^de)/2, k2 = π/(x_de − x0), k3 = (x_de − 3 x0)/2, k4 = (d0 + d^de)/2
    eq. 3.6  v(t) = v0 + ½ J t1² + a_max (t − t1)   (one section of a jerk-limited profile with an
             idle phase between traction and braking, :class:`JerkLimitedTransition`)

Note on eq. 3.4: the survey prints ``k1 sin[k2(x + k3) + k4]``; with the eq. 3.5 constants the
reference only starts at d0 (x = x0, phase π/2) and ends at d^de (x = x_de, phase 3π/2) when k4
(a length) is *added outside* the sine, which is what is implemented.

Every reference is evaluated by ``evaluate(time_s, position_m, speed_mps, predecessor_speed_mps)``
returning a :class:`GapSample`: the gap, and the rate and acceleration of its explicit time/position
dependence (the transition), which a controller may use as feed-forward.  The dependence on the
train's own speed (h·v, eq. 3.1) is *not* differentiated: it acts as feedback (the classical
constant-time-headway policy).  All quantities are SI.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, Sequence

from pydantic import Field

from vcsumo.config import StrictModel
from vcsumo.dynamics import V_EPS_MPS


@dataclass(frozen=True)
class GapSample:
    """A gap reference and the derivatives of its transitional part."""

    gap_m: float
    rate_mps: float = 0.0
    """d/dt of the transitional part, m/s (negative while merging)."""
    accel_mps2: float = 0.0
    """d²/dt² of the transitional part, m/s²."""


class GapReference(Protocol):
    """A desired front-to-rear gap of one train behind its predecessor."""

    def evaluate(self, time_s: float, position_m: float, speed_mps: float, predecessor_speed_mps: float) -> GapSample:
        ...


# ---------------------------------------------------------------------------------------------
# eq. 3.1 and the constant time headway


def rbd_gap_m(speed_mps: float, predecessor_speed_mps: float, d_safe_m: float, brake_decel_mps2: float) -> float:
    """Relative-braking-distance gap reference d^de = D_safe + v_i²/(2a_b) − v_{i−1}²/(2a_b) (eq. 3.1), m."""
    if brake_decel_mps2 <= 0:
        raise ValueError("brake_decel_mps2 must be positive")
    return d_safe_m + (speed_mps * speed_mps - predecessor_speed_mps * predecessor_speed_mps) / (2.0 * brake_decel_mps2)


def steady_gap_m(
    speed_mps: float,
    d_min_m: float,
    headway_s: float = 0.0,
    predecessor_speed_mps: float | None = None,
    brake_decel_mps2: float | None = None,
) -> float:
    """Steady convoy spacing D_safe + h·v_i [+ (v_i² − v_{i−1}²)/(2a_b)], m (eq. 3.1 with eq. 4.3's h·v).

    ``headway_s = 0`` and no ``brake_decel_mps2``: constant distance (eq. 3.1 at equal speeds);
    ``headway_s > 0``: constant time headway; ``brake_decel_mps2``: the relative-braking term of eq. 3.1.
    """
    d = d_min_m + headway_s * speed_mps
    if brake_decel_mps2 is not None:
        vp = speed_mps if predecessor_speed_mps is None else predecessor_speed_mps
        d = rbd_gap_m(speed_mps, vp, d, brake_decel_mps2)
    return d


class SteadyGap(StrictModel):
    """Steady gap policy (eq. 3.1 with the time headway of eq. 4.3)."""

    d_min_m: float = Field(default=50.0, ge=0, le=50000, description="Safety margin D_safe (standstill/minimum gap), m (0–50 km)")
    headway_s: float = Field(default=0.0, ge=0, le=600, description="Constant time headway h, s (0: constant distance; at most 600 s)")
    rbd_brake_decel_mps2: float | None = Field(default=None, gt=0, le=5, description="a_b of the relative-braking term of eq. 3.1, m/s², 0 < a ≤ 5 (none: off)")
    certified: bool = Field(default=True, description="Track the certified spacing — the separation model's relative-braking gap under the run's "
                                                      "assumption set (SeparationGap) — instead of eq. 3.1 with the figures above")
    buffer_m: float = Field(default=10.0, ge=0, le=1000, description="Kept beyond the certified spacing, m (so the guard need not step in)")

    def gap_m(self, speed_mps: float, predecessor_speed_mps: float | None = None) -> float:
        """The steady reference at the given speeds (eq. 3.1), m."""
        return steady_gap_m(speed_mps, self.d_min_m, self.headway_s, predecessor_speed_mps, self.rbd_brake_decel_mps2)

    def evaluate(self, time_s: float, position_m: float, speed_mps: float, predecessor_speed_mps: float) -> GapSample:
        return GapSample(self.gap_m(speed_mps, predecessor_speed_mps))


def leader_offset_m(gaps_m: Sequence[float], lengths_m: Sequence[float]) -> float:
    """D_i = Σ_{m=1}^{i} (d_m + L_{m−1}) (eq. 3.10): distance from the leader's front to train i's front, m.

    ``gaps_m`` = [d_1, …, d_i] and ``lengths_m`` = [L_0, …, L_{i−1}] (the trains ahead of each gap).
    """
    if len(gaps_m) != len(lengths_m):
        raise ValueError("need one length per gap (the train ahead of it)")
    return float(sum(gaps_m) + sum(lengths_m))


# ---------------------------------------------------------------------------------------------
# eq. 3.2–3.3: exponential transition


def exp_transition_gap_m(elapsed_s: float, k1_m: float, k2_per_s: float, d_de_m: float) -> float:
    """d^dy = k1·exp(−k2·t) + d^de (eq. 3.2), m; t is the time since the transition started."""
    return k1_m * math.exp(-k2_per_s * max(elapsed_s, 0.0)) + d_de_m


def exp_transition_accel_mps2(elapsed_s: float, k3_mps: float, k4_per_s: float) -> float:
    """Follower acceleration a^dy = k3·k4·exp(−k4·t) (eq. 3.3), m/s² (leader at constant speed)."""
    return k3_mps * k4_per_s * math.exp(-k4_per_s * max(elapsed_s, 0.0))


def exp_accel_coefficients(k1_m: float, k2_per_s: float) -> tuple[float, float]:
    """(k3, k4) of eq. 3.3 consistent with eq. 3.2 behind a constant-speed leader.

    The gap d = x_{i−1} − L − x_i has d̈ = −a_i when the leader does not accelerate, and
    d̈^dy = k1 k2² e^{−k2 t}, so a^dy = −k1 k2² e^{−k2 t} = k3 k4 e^{−k4 t} with k3 = −k1 k2, k4 = k2.
    """
    return -k1_m * k2_per_s, k2_per_s


@dataclass(frozen=True)
class ExpTransition:
    """Exponential transition d^dy(t) = k1·exp(−k2 (t − t0)) + d^de(t) (eq. 3.2).

    ``k1_m`` = d0 − d^de at the start (negative for a split: the gap grows).  Before ``start_time_s``
    the reference holds k1 + d^de.  The value is continuous; the rate jumps from 0 to −k1·k2 at the
    start (the non-zero initial acceleration of Profile 1, Fig. 4, eq. 3.3).
    """

    start_time_s: float
    k1_m: float
    k2_per_s: float
    steady: SteadyGap = field(default_factory=SteadyGap)

    @classmethod
    def between(cls, start_time_s: float, initial_gap_m: float, k2_per_s: float, steady: SteadyGap, speed_mps: float) -> "ExpTransition":
        """The transition from ``initial_gap_m`` at ``start_time_s`` to the steady reference at ``speed_mps``."""
        return cls(start_time_s, initial_gap_m - steady.gap_m(speed_mps), k2_per_s, steady)

    def evaluate(self, time_s: float, position_m: float, speed_mps: float, predecessor_speed_mps: float) -> GapSample:
        d_de = self.steady.gap_m(speed_mps, predecessor_speed_mps)
        t = time_s - self.start_time_s
        if t < 0:
            return GapSample(self.k1_m + d_de)
        e = math.exp(-self.k2_per_s * t)
        return GapSample(self.k1_m * e + d_de, -self.k1_m * self.k2_per_s * e, self.k1_m * self.k2_per_s**2 * e)


# ---------------------------------------------------------------------------------------------
# eq. 3.4–3.5: position-indexed sinusoidal transition


def sin_transition_coefficients(initial_gap_m: float, final_gap_m: float, start_position_m: float, end_position_m: float) -> tuple[float, float, float, float]:
    """(k1, k2, k3, k4) of eq. 3.5."""
    if end_position_m == start_position_m:
        raise ValueError("the transition needs end_position_m != start_position_m")
    k1 = (initial_gap_m - final_gap_m) / 2.0
    k2 = math.pi / (end_position_m - start_position_m)
    k3 = (end_position_m - 3.0 * start_position_m) / 2.0
    k4 = (initial_gap_m + final_gap_m) / 2.0
    return k1, k2, k3, k4


def sin_transition_gap_m(position_m: float, initial_gap_m: float, final_gap_m: float, start_position_m: float, end_position_m: float) -> float:
    """d^dy(x) = k1·sin[k2 (x + k3)] + k4 (eq. 3.4 with eq. 3.5), m; held at d0 before x0 and d^de after x_de."""
    k1, k2, k3, k4 = sin_transition_coefficients(initial_gap_m, final_gap_m, start_position_m, end_position_m)
    x = min(max(position_m, start_position_m), end_position_m)
    return k1 * math.sin(k2 * (x + k3)) + k4


@dataclass(frozen=True)
class SinTransition:
    """Sinusoidal transition indexed by the follower position (eq. 3.4–3.5), from d0 at x0 to d^de at x_de.

    The end value is the steady reference evaluated live (eq. 3.5 uses d^de_{i,t}).  The shape is a
    half cycle of a sine with zero slope at both ends, so the reference is C¹ in position.
    """

    start_position_m: float
    end_position_m: float
    initial_gap_m: float
    steady: SteadyGap = field(default_factory=SteadyGap)

    def evaluate(self, time_s: float, position_m: float, speed_mps: float, predecessor_speed_mps: float) -> GapSample:
        d_de = self.steady.gap_m(speed_mps, predecessor_speed_mps)
        x0, x1 = self.start_position_m, self.end_position_m
        k1, k2, k3, k4 = sin_transition_coefficients(self.initial_gap_m, d_de, x0, x1)
        if position_m <= x0:
            return GapSample(self.initial_gap_m)
        if position_m >= x1:
            return GapSample(d_de)
        ph = k2 * (position_m + k3)
        dd_dx = k1 * k2 * math.cos(ph)
        d2d_dx2 = -k1 * k2 * k2 * math.sin(ph)
        return GapSample(k1 * math.sin(ph) + k4, dd_dx * speed_mps, d2d_dx2 * speed_mps * speed_mps)


# ---------------------------------------------------------------------------------------------
# eq. 3.6: jerk- and acceleration-limited transition with an idle phase


@dataclass(frozen=True)
class JerkProfile:
    """Piecewise-constant-jerk relative motion closing/opening a distance (eq. 3.6, Profile 3 of Fig. 4).

    Seven segments: jerk +J up to a_peak, hold a_peak (eq. 3.6: v = v0 + ½J t1² + a_max (t − t1)),
    jerk −J down to zero, idle (zero acceleration, relative speed Δv), and the mirror image braking
    back to zero relative speed.  Position, speed and acceleration are continuous, |jerk| ≤ J,
    |a| ≤ a_max, relative speed ≤ Δv; the idle phase separates traction from braking.
    """

    distance_m: float
    jerk_mps3: float
    peak_accel_mps2: float
    t1_s: float
    """Time to reach the peak acceleration (eq. 3.6 t1 = a_peak/J)."""
    hold_s: float
    """Time at the peak acceleration."""
    idle_s: float
    peak_speed_mps: float

    @classmethod
    def design(cls, distance_m: float, jerk_mps3: float, max_accel_mps2: float, idle_s: float = 25.0, max_speed_mps: float | None = None) -> "JerkProfile":
        """The shortest such profile covering ``distance_m`` (> 0) with at least ``idle_s`` idling."""
        if distance_m <= 0 or jerk_mps3 <= 0 or max_accel_mps2 <= 0 or idle_s < 0:
            raise ValueError("distance, jerk and acceleration must be positive, idle non-negative")
        J, A, ti = jerk_mps3, max_accel_mps2, idle_s
        t1 = A / J
        if A * t1 * (2 * t1 + ti) >= distance_m:
            lo, hi = 0.0, A  # distance (a²/J)(2a/J + ti) is increasing in a: bisection
            for _ in range(100):
                mid = 0.5 * (lo + hi)
                if mid * mid / J * (2 * mid / J + ti) < distance_m:
                    lo = mid
                else:
                    hi = mid
            a_p, hold = 0.5 * (lo + hi), 0.0
        else:
            a_p = A
            b = 3 * t1 + ti
            c = t1 * (2 * t1 + ti) - distance_m / A
            hold = (-b + math.sqrt(b * b - 4 * c)) / 2.0
        t1 = a_p / J
        dv = a_p * (t1 + hold)
        if max_speed_mps is not None and dv > max_speed_mps:
            dv = max_speed_mps
            if dv >= A * (A / J):
                a_p, t1, hold = A, A / J, dv / A - A / J
            else:
                a_p = math.sqrt(dv * J)
                t1, hold = a_p / J, 0.0
            ti = distance_m / dv - (2 * t1 + hold)
        return cls(distance_m, J, a_p, t1, hold, max(ti, 0.0), dv)

    @property
    def duration_s(self) -> float:
        return 2 * (2 * self.t1_s + self.hold_s) + self.idle_s

    def _segments(self) -> list[tuple[float, float]]:
        J, t1, th, ti = self.jerk_mps3, self.t1_s, self.hold_s, self.idle_s
        return [(t1, J), (th, 0.0), (t1, -J), (ti, 0.0), (t1, -J), (th, 0.0), (t1, J)]

    def state(self, elapsed_s: float) -> tuple[float, float, float]:
        """(distance covered m, relative speed m/s, relative acceleration m/s²) after ``elapsed_s``."""
        s = v = a = 0.0
        t = max(elapsed_s, 0.0)
        for dur, j in self._segments():
            h = min(t, dur)
            s += v * h + a * h * h / 2 + j * h**3 / 6
            v += a * h + j * h * h / 2
            a += j * h
            t -= h
            if t <= 0:
                break
        return s, v, a


def jerk_limited_speed_mps(elapsed_s: float, initial_speed_mps: float, profile: JerkProfile, sign: float = 1.0) -> float:
    """Follower speed during the transition, v0 ± Δv(t) (eq. 3.6 in its constant-acceleration section).

    ``sign`` +1: the follower runs faster than the (constant-speed) predecessor (merge); −1: slower (split).
    """
    return initial_speed_mps + sign * profile.state(elapsed_s)[1]


@dataclass(frozen=True)
class JerkLimitedTransition:
    """Gap reference from d0 to the steady reference along a :class:`JerkProfile` (eq. 3.6).

    The profile is designed for |d0 − d^de(v_design)|; the reference blends d0 → d^de(t) with the
    normalised profile distance φ(t) ∈ [0, 1], so it ends exactly at the live steady value.
    """

    start_time_s: float
    initial_gap_m: float
    profile: JerkProfile
    steady: SteadyGap = field(default_factory=SteadyGap)

    @classmethod
    def design(cls, start_time_s: float, initial_gap_m: float, steady: SteadyGap, speed_mps: float, jerk_mps3: float, max_accel_mps2: float, idle_s: float = 25.0, max_speed_mps: float | None = None) -> "JerkLimitedTransition":
        dist = abs(initial_gap_m - steady.gap_m(speed_mps))
        prof = JerkProfile.design(max(dist, 1e-6), jerk_mps3, max_accel_mps2, idle_s, max_speed_mps)
        return cls(start_time_s, initial_gap_m, prof, steady)

    @property
    def end_time_s(self) -> float:
        return self.start_time_s + self.profile.duration_s

    def evaluate(self, time_s: float, position_m: float, speed_mps: float, predecessor_speed_mps: float) -> GapSample:
        d_de = self.steady.gap_m(speed_mps, predecessor_speed_mps)
        s, v, a = self.profile.state(time_s - self.start_time_s)
        D = self.profile.distance_m
        span = d_de - self.initial_gap_m
        return GapSample(self.initial_gap_m + span * s / D, span * v / D, span * a / D)


# ---------------------------------------------------------------------------------------------
# The certified spacing


class SeparationGap:
    """The certified spacing as a gap reference: the front-to-rear gap the separation model's
    relative-braking rule needs (:class:`vcsumo.signalling.separation.RelativeBraking`, on the
    follower's route when it is known) at the follower's speed, the predecessor at its reported speed
    when that is lower (else at the follower's: the coupled spacing), with the dead time,
    the message age it budgets and ``extra_delay_s`` (e.g. 1.5 loop steps), plus the
    follower's brake build-up from the largest force it may apply there — its full traction at that
    speed (the top of its box: min(M̄·ā, P̄/v)), or the force that holds the speed where that is
    larger — (the separation guard's :class:`~vcsumo.control.brake_build_up.BrakeBuildUp`: its
    equivalent dead time, and the speed it may gain meanwhile), plus ``buffer_m`` — so a controller
    tracking it stays just outside what the guard and the CBF enforce, also while it follows an
    accelerating predecessor at full traction (the CBF's barrier and the guard count the build-up
    from the force applied: from full traction it is ≈ 0.6 s longer than from coasting for a
    regional EMU).

    The message age budgeted is the larger of the assumption set's bound (``t2t_delay_bound_s``: the
    spacing of the analytic capacity) and ``message_age_s``, the age the channel the follower runs on
    keeps (:meth:`vcsumo.control.channel.ChannelConfig.age_budget_s`).  The CBF and the guard act on
    the true age of the newest message: with a channel slower than the set says, a reference on the
    set's bound alone sits inside their boundary whenever a packet is a little late, and the CBF's
    only answer there is its emergency brake (README, *Known gaps*)."""

    def __init__(self, model, follower, leader, profile=None, extra_delay_s: float = 0.0, buffer_m: float = 10.0,
                 message_age_s: float | None = None):
        from vcsumo.control.brake_build_up import BrakeBuildUp
        from vcsumo.signalling.separation import RelativeBraking

        self.model = model
        self.follower, self.leader = follower, leader
        self.params = follower.params()
        self.profile = profile
        self.rule = RelativeBraking(model, follower, leader, profile) if profile is not None else None
        self.message_age_s = max(model.assumptions.t2t_delay_bound_s, message_age_s if message_age_s is not None else 0.0)
        """The age of the predecessor's newest message budgeted, s."""
        self.delay_s = model.dead_time_s + self.message_age_s + extra_delay_s
        self.build_up = BrakeBuildUp(follower, model.assumptions)
        box = follower.uncertainty_box()
        self.power_top_w = box.max_power_w.high if box.max_power_w is not None else self.params.max_power_w
        """The follower's largest traction power (the top of its box), W."""
        self.buffer_m = buffer_m

    def traction_top_n(self, speed_mps: float) -> float:
        """The largest traction any train of the follower's box applies at ``speed_mps``: min(M̄·ā, P̄/v), N."""
        return min(self.build_up.full_traction_n, self.power_top_w / max(speed_mps, V_EPS_MPS))

    def build_up_at(self, speed_mps: float, position_m: float | None = None) -> tuple[float, float]:
        """(speed held, equivalent dead time) of the follower's brake build-up from the largest force
        it may apply at ``speed_mps``: :meth:`traction_top_n`, or the force that holds the speed (its
        running resistance and the gradient where it is; level track without a position) where that
        is larger, m/s and s (:meth:`~vcsumo.control.brake_build_up.BrakeBuildUp.held`)."""
        from vcsumo.dynamics import gradient_force, running_resistance

        p = self.params
        on_route = self.rule is not None and position_m is not None
        grade = self.profile.mean_gradient(position_m, p.length_m) if on_route else 0.0
        tf = self.profile.tunnel_factor_at(position_m) if on_route else 1.0
        force = max(float(running_resistance(p, speed_mps, tf) + gradient_force(p, grade)), self.traction_top_n(speed_mps))
        return self.build_up.held(self.rule.follower if on_route else None, position_m or 0.0, speed_mps, force)

    def gap_m(self, speed_mps: float, predecessor_speed_mps: float | None = None, position_m: float | None = None) -> float:
        """The spacing at the follower's speed with the predecessor at ``predecessor_speed_mps`` when it is
        slower (a braking predecessor needs more room: the rule the guard keeps), else at the follower's
        speed (None: the same speed), m."""
        from vcsumo.signalling.separation import relative_braking_gap

        v = max(speed_mps, 0.0)
        v_l = v if predecessor_speed_mps is None or not math.isfinite(predecessor_speed_mps) else min(v, max(predecessor_speed_mps, 0.0))
        v_dead, t_act = self.build_up_at(v, position_m)
        a_f, a_l = self.model.vc_decels(self.follower, self.leader, v, v_l)
        level = self.model.margin_m + relative_braking_gap(v_dead, v_l, a_f, a_l, self.delay_s + t_act)
        if self.rule is None or position_m is None:
            return level + self.buffer_m
        s_l = position_m + level + self.leader.length_m
        return self.rule.required_gap(position_m, v_dead, s_l, v_l, self.delay_s + t_act) + self.buffer_m

    def evaluate(self, time_s: float, position_m: float, speed_mps: float, predecessor_speed_mps: float) -> GapSample:
        return GapSample(self.gap_m(speed_mps, predecessor_speed_mps, position_m))
