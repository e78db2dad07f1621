"""The one separation model: how close a train may run behind another, under the worst case.

Every regime and every safety layer takes its braking from here — the FBS and MB movement
authorities, the VC guard, the CBF's safety distance, the run-health monitor and the analytic
headways — so FBS, MB and VC are compared under the same assumptions (a named
:class:`~vcsumo.signalling.assumptions.AssumptionSet`).  The worst case (shared note
*safe-separation*):

* the train ahead brakes as hard as it physically can: its brake at the top of the box, plus its
  whole running resistance, plus an up-grade where it brakes (:func:`strongest_decel`);
* the train behind brakes as weakly as it is guaranteed to: its brake at the bottom of the box,
  only the constant part of its resistance, minus a descent where it brakes, divided by its
  rotating-mass factor (:func:`guaranteed_decel`), after an equivalent dead time (reaction + half
  the brake build-up);
* it knows the leader's state only as of the newest message it holds: the leader may have started
  braking right after sending it (:func:`leader_worst_state`);
* positions are uncertain by the odometry error of both trains, and a margin stays behind the rear.

The rules (positions front of the follower to rear of the leader, m; decelerations > 0, m/s²):

* **relative braking (VC)** — :func:`relative_braking_gap`: the largest closing of the gap while
  the leader brakes at ``a_l`` from ``v_l`` and the follower, after ``T`` at ``v_f``, brakes at
  ``a_f``.  It is the exact maximum over the braking episode, so it stays right when the follower
  brakes harder than the leader can (``a_f > a_l``: the binding moment is then mid-braking, and a
  difference of stopping distances would be negative); with equal speeds and ``a_f ≤ a_l`` it is
  ``v·T + v²/2·(1/a_f − 1/a_l)``;
* **absolute braking (MB, FBS)** — :func:`absolute_braking_gap`: ``v·T + v²/(2·a_f)`` behind a
  point that does not move (the leader's confirmed rear, the end of authority).  Trains are
  *driven* on their guaranteed service brake — every approach (end of authority, end of the track,
  stops, speed limits), so every supervised curve and every analytic headway
  (:class:`RouteBraking`'s default); the set's ``absolute_braking`` is the brake the safe
  separation is *certified* with (:meth:`SeparationModel.absolute_gap`, the run-health check):
  ``emergency`` counts the emergency brake as the reserve that guarantees the stop;
* the permitted speed towards a target (a braking curve): :func:`authority_speed`; the largest
  follower speed a relative-braking rule admits: :func:`relative_braking_speed`.

:class:`SeparationModel` binds an assumption set and the rolling stock and gives the gaps each
regime requires (``vc_gap``, ``mb_gap``, ``absolute_gap``) and the decelerations.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from vcsumo.dynamics import running_resistance
from vcsumo.errors import InfeasibleBraking
from vcsumo.rolling_stock import RollingStock
from vcsumo.running_time import curve_speed as authority_speed  # the braking curve: v·T + (v² − v_t²)/(2a) ≤ distance
from vcsumo.signalling.assumptions import AssumptionSet
from vcsumo.signalling.braking_runs import braking_run, max_closing, run_state
from vcsumo.signalling.train_braking import (  # noqa: F401 (brake_range, guaranteed_decel, strongest_decel: also from here)
    brake_range, guaranteed_decel, guaranteed_decel_of_floats, strongest_decel, strongest_decel_of_floats)
from vcsumo.units import G

# -------------------------------------------------------------------------------------------
# Pure kinematics of the worst case


def _leader_position(t: float, v_l: float, a_l: float) -> float:
    """Distance the leader covers in t braking at a_l from v_l (stopped afterwards), m."""
    if math.isinf(a_l):
        return 0.0
    t_stop = v_l / a_l
    if t >= t_stop:
        return v_l * v_l / (2.0 * a_l)
    return v_l * t - 0.5 * a_l * t * t


def _follower_position(t: float, v_f: float, a_f: float, dead_s: float) -> float:
    """Distance the follower covers in t: ``dead_s`` at v_f, then braking at a_f to a stop, m."""
    if t <= dead_s:
        return v_f * t
    tb = t - dead_s
    t_stop = v_f / a_f
    if tb >= t_stop:
        return v_f * dead_s + v_f * v_f / (2.0 * a_f)
    return v_f * dead_s + v_f * tb - 0.5 * a_f * tb * tb


def relative_braking_gap(v_f: float, v_l: float, a_f: float, a_l: float, dead_time_s: float) -> float:
    """Largest closing of the front-to-rear gap over the braking episode, m (≥ 0).

    The leader brakes at ``a_l`` from ``v_l`` from t = 0; the follower runs ``dead_time_s`` at
    ``v_f`` and then brakes at ``a_f``; both stop and stay stopped.  The gap closes by
    D(t) = x_f(t) − x_l(t), piecewise quadratic, so its maximum is at one of: the end of the dead
    time, the moment the speeds become equal while both brake (a maximum only when a_f > a_l), the
    leader's stop, the follower's stop.  ``a_l = inf`` is a leader that stops at once (absolute
    braking).  A gap at least this large plus the margins keeps the trains apart in every case.
    """
    if v_f < 0 or v_l < 0 or a_f <= 0 or a_l <= 0 or dead_time_s < 0:
        raise ValueError("speeds and dead time must be ≥ 0 and decelerations > 0")
    candidates = [dead_time_s, dead_time_s + v_f / a_f]
    if not math.isinf(a_l):
        candidates.append(v_l / a_l)
        if a_f > a_l:
            t_eq = (v_f - v_l + a_f * dead_time_s) / (a_f - a_l)
            if t_eq > dead_time_s:
                candidates.append(t_eq)
    worst = 0.0
    for t in candidates:
        worst = max(worst, _follower_position(t, v_f, a_f, dead_time_s) - _leader_position(t, v_l, a_l))
    return worst


def absolute_braking_gap(v_f: float, a_f: float, dead_time_s: float) -> float:
    """Distance to stop behind a fixed point: v·T + v²/(2·a), m (numpy arrays accepted)."""
    return v_f * dead_time_s + v_f * v_f / (2.0 * a_f)


def leader_worst_state(v_l: float, a_l: float, age_s: float) -> tuple[float, float]:
    """(distance covered, speed) of a leader that started braking at ``a_l`` ``age_s`` ago, (m, m/s).

    A message says where the leader was and how fast it ran at its time stamp; since then it may
    have braked as hard as it can, which is the least it can have advanced.
    """
    if age_s <= 0.0:
        return 0.0, v_l
    return _leader_position(age_s, v_l, a_l), max(0.0, v_l - a_l * age_s)


def relative_braking_speed(available_gap_m: float, v_l: float, a_f: float, a_l: float, dead_time_s: float, v_max_mps: float,
                           tol_mps: float = 1e-3) -> float:
    """Largest follower speed in [0, v_max] whose relative-braking closing fits ``available_gap_m``, m/s.

    The closing grows with the follower's speed, so the answer is found by bisection; 0 when even a
    standing follower does not fit (the gap is already below the margins).
    """
    if available_gap_m < 0.0:
        return 0.0
    if relative_braking_gap(v_max_mps, v_l, a_f, a_l, dead_time_s) <= available_gap_m:
        return v_max_mps
    # a start value from the absolute rule (the leader stopped): always admissible
    lo = min(v_max_mps, authority_speed(available_gap_m, a_f, dead_time_s))
    hi = v_max_mps
    while hi - lo > tol_mps:
        mid = 0.5 * (lo + hi)
        if relative_braking_gap(mid, v_l, a_f, a_l, dead_time_s) <= available_gap_m:
            lo = mid
        else:
            hi = mid
    return lo


# -------------------------------------------------------------------------------------------
# The rules of the regimes


@dataclass(frozen=True)
class SeparationModel:
    """An assumption set bound to the rules: the gaps FBS, MB and VC require, m."""

    assumptions: AssumptionSet

    @property
    def margin_m(self) -> float:
        """Safety margin behind the leader's rear plus the position error of both trains, m."""
        return self.assumptions.safety_margin_m + self.assumptions.position_uncertainty_m

    @property
    def dead_time_s(self) -> float:
        return self.assumptions.dead_time_s

    def follower_decel(self, stock: RollingStock, v_mps: float, grade_low: float = 0.0, kind: str | None = None):
        """Guaranteed deceleration of a follower with the brake its safe separation is certified with
        (``kind`` None: the set's ``absolute_braking``) or ``kind``."""
        return guaranteed_decel(stock, self.assumptions, kind or self.assumptions.absolute_braking, v_mps, grade_low)

    def vc_decels(self, follower: RollingStock, leader: RollingStock, v_f: float, v_l: float, grade_f: float = 0.0,
                  grade_l: float = 0.0) -> tuple[float, float]:
        """(follower's guaranteed, leader's strongest) deceleration of the relative-braking rule, m/s²."""
        kind = self.assumptions.relative_braking
        if type(v_f) is float and type(v_l) is float and type(grade_f) is float and type(grade_l) is float:  # (the per-step case)
            return (guaranteed_decel_of_floats(follower, self.assumptions, kind, v_f, grade_f),
                    strongest_decel_of_floats(leader, self.assumptions, kind, v_l, grade_l, 1.5))
        return (guaranteed_decel(follower, self.assumptions, kind, v_f, grade_f),
                strongest_decel(leader, self.assumptions, kind, v_l, grade_l))

    def vc_gap(self, follower: RollingStock, leader: RollingStock, v_mps: float, grade_f: float = 0.0, grade_l: float = 0.0,
               message_age_s: float | None = None) -> float:
        """Front-to-rear gap a VC follower needs behind its leader, both at speed v, m.

        Relative braking with the follower's dead time extended by the age of the leader's newest
        message (default: the set's bound ``t2t_delay_bound_s``), plus margin and position errors.
        """
        age = self.assumptions.t2t_delay_bound_s if message_age_s is None else message_age_s
        a_f, a_l = self.vc_decels(follower, leader, v_mps, v_mps, grade_f, grade_l)
        return self.margin_m + relative_braking_gap(v_mps, v_mps, a_f, a_l, self.dead_time_s + age)

    def absolute_gap(self, follower: RollingStock, v_mps, grade_low=0.0, margin_m: float | None = None, kind: str | None = None):
        """Gap a train needs to stop behind a fixed point (the leader's true rear) with the brake the
        set certifies the separation with (``absolute_braking``, or ``kind``), m — the safety check
        of every absolute-braking train (numpy arrays of v and grade accepted)."""
        a_f = self.follower_decel(follower, v_mps, grade_low, kind)
        margin = (self.assumptions.safety_margin_m if margin_m is None else margin_m) + self.assumptions.position_uncertainty_m
        return margin + absolute_braking_gap(np.asarray(v_mps, dtype=float) if np.ndim(v_mps) else v_mps, a_f, self.dead_time_s)

    def mb_gap(self, follower: RollingStock, v_mps, grade_low=0.0):
        """Gap a moving-block follower keeps at steady speed v behind a leader at v, m: the absolute
        rule on the service brake it is driven on, behind the rear as of the last position report,
        which may be a report period old."""
        return self.absolute_gap(follower, v_mps, grade_low, kind="service") + v_mps * self.assumptions.position_report_period_s

    def fbs_braking_distance(self, follower: RollingStock, v_mps, grade_low=0.0):
        """Distance a fixed-block train needs to stop at a signal (its end of authority) on the service
        brake it is driven on, m."""
        a_f = self.follower_decel(follower, v_mps, grade_low, "service")
        return absolute_braking_gap(v_mps, a_f, self.dead_time_s) + self.assumptions.position_error_m


TUNNEL_FACTOR_FLOOR = 1.5
"""The tunnel factor the strongest braking of a train ahead counts at least (:func:`strongest_decel`'s
default: a route's own tunnels count where they are larger, :class:`RouteBraking`)."""


def _interp(x: float, xp: list[float], fp: list[float], j: int) -> float:
    """``np.interp`` at one point inside [xp[0], xp[-1]] with xp[j] ≤ x < xp[j + 1] given (the same
    operations, so the same number)."""
    if j >= len(xp) - 1:
        return fp[-1]
    if xp[j] == x:
        return fp[j]
    return (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]) * (x - xp[j]) + fp[j]


# -------------------------------------------------------------------------------------------
# Braking curves along a route (gradient profile integrated, as ETCS braking curves are)


class RouteBraking:
    """A train's guaranteed braking along its route, integrated over the gradient profile.

    Braking from v to v_t over a stretch uses the energy budget v²/2 − v_t²/2 = ∫ a(x) dx, with
    a(x) the guaranteed deceleration while the front is at x (brake at the bottom of the box,
    Davis A, the lowest gradient under the train's body there: min over [x − L, x], counted only
    when it is a descent; over ρ).  That is exact for the piecewise-constant gradient profile and
    continuous in position, unlike one worst gradient for the whole distance.  The brake part is
    taken at the speed the braking starts from (a brake-power limit only eases as the train slows).

    * :meth:`permitted_speed` — the braking curve towards a target (supervision, running times);
    * :meth:`stopping_distance` — how far the train runs before it stands (health monitor,
      analytic headways).

    ``kind``: the brake, by default the service brake every train is driven on (the supervision,
    the interlocking's locking distances, the running times and analytic headways); the run-health
    monitor certifies the separation with the set's ``absolute_braking``.
    """

    def __init__(self, model: "SeparationModel", stock: RollingStock, profile, kind: str = "service", strongest: bool = False):
        self.model = model
        self.stock = stock
        self.kind = kind
        self.strongest = strongest
        a = model.assumptions
        low, high = brake_range(stock, a, self.kind)
        box = stock.uncertainty
        self.m_high = stock.mass_kg if box is None else box.mass_kg.high
        self.m_low = stock.mass_kg if box is None else box.mass_kg.low
        self.brake_low = high if strongest else low
        self.power_low = None
        if stock.max_brake_power_w is not None and not strongest and self.kind == "service":  # the emergency brake is not power-limited
            self.power_low = stock.max_brake_power_w if box is None or box.max_brake_power_w is None else box.max_brake_power_w.low
        self.res_low = (stock.davis_a_n if box is None else box.davis_a_n.low) / self.m_high
        self.params_high = stock.params()
        if box is not None:
            self.params_high = self.params_high.with_(davis_a_n=box.davis_a_n.high, davis_b_n_per_mps=box.davis_b_n_per_mps.high, davis_c_n_per_mps2=box.davis_c_n_per_mps2.high)
        self.rho = 1.0 if strongest else stock.rotating_mass_factor
        # the strongest counts the quadratic resistance at the route's largest tunnel factor, at least
        # 1.5 (until 2026-12-01 always 1.5: a leader braking in a tunnel of factor 4.0 beat it)
        self.tunnel_max = max(TUNNEL_FACTOR_FLOOR, float(np.max(profile.tunnel_factors))) if len(profile.tunnel_factors) else TUNNEL_FACTOR_FLOOR
        # pieces: the route's edges, cut also where the rear passes a gradient change (front there + the
        # train's length), so the gradient under the body is the same all along each piece (an edge
        # as long as a long block would otherwise carry a descent its rear left a kilometre before)
        edge_starts = np.asarray(profile.starts_m, dtype=float)
        end = float(edge_starts[-1] + profile.lengths_m[-1])
        grads = np.asarray(profile.gradients, dtype=float)
        rear_cuts = edge_starts[1:][grads[1:] != grads[:-1]] + stock.length_m
        starts = np.unique(np.concatenate([edge_starts, rear_cuts[rear_cuts < end]]))
        lengths = np.diff(np.append(starts, end))
        # the body over [x − L, x) for every front x on the piece (1 µm inside its ends: a rear at a change is past it)
        body = [(x - stock.length_m + 1e-6, x + ln - 1e-6) for x, ln in zip(starts, lengths)]
        if strongest:  # the steepest up-grade under the body helps the train ahead; a descent is not counted
            g_low = np.array([max(profile.gradient_range(a, b)[1], 0.0) for a, b in body])
        else:  # the lowest gradient under the body while the front is on the piece
            g_low = np.array([min(profile.gradient_range(a, b)[0], 0.0) for a, b in body])
        self.x = np.concatenate([starts, [starts[-1] + lengths[-1]]])
        self.g_low = g_low
        self.grade_integral = np.concatenate([[0.0], np.cumsum(g_low * lengths)])
        # plain lists for the scalar look-ups of the per-step loops (the same floating-point
        # operations as numpy's, so the same numbers): positions, gradients, G·∫g/ρ
        self._x = [float(v) for v in self.x]
        self._g = [float(v) for v in g_low]
        self._gi = [float(v) for v in self.grade_integral]
        self._ci = [float(v) for v in G * self.grade_integral / self.rho]
        self._g_min = min(self._g)
        self._floor: float | None = None
        self._v_top = math.inf
        worst = self.brake_part(stock.max_speed_ms) + G * float(g_low.min()) / self.rho
        if worst <= 0.0 and not strongest:
            raise InfeasibleBraking(f"{stock.name}: no guaranteed {self.kind} braking on a {1000 * float(g_low.min()):.1f} ‰ descent")

    def brake_part(self, v_mps: float) -> float:
        """Guaranteed (strongest: hardest) deceleration without the gradient at speed v, m/s²; the
        strongest counts the whole running resistance at v (it only falls as the train slows), in
        the route's largest tunnel (at least :data:`TUNNEL_FACTOR_FLOOR`)."""
        if self.strongest:
            return self.brake_low + float(running_resistance(self.params_high, v_mps, self.tunnel_max)) / self.m_low
        b = self.brake_low
        if self.power_low is not None:
            b = min(b, self.power_low / (self.m_high * max(v_mps, 0.1)))
        return (b + self.res_low) / self.rho

    def _grade_integral_at(self, s: float) -> float:
        x = self._x
        if s <= x[0]:
            return self._g[0] * (s - x[0])
        if s >= x[-1]:
            return self._gi[-1] + self._g[-1] * (s - x[-1])
        return _interp(s, x, self._gi, bisect_right(x, s) - 1)

    def decel_at(self, s: float, v_mps: float) -> float:
        """Guaranteed deceleration with the front at s, m/s²."""
        i = min(max(bisect_right(self._x, s) - 1, 0), len(self._g) - 1)
        return self.brake_part(v_mps) + G * self._g[i] / self.rho

    def energy(self, s0: float, s1: float, v_mps: float) -> float:
        """∫ a(x) dx over [s0, s1] for braking that starts at speed v, m²/s²."""
        return self.brake_part(v_mps) * (s1 - s0) + G * (self._grade_integral_at(s1) - self._grade_integral_at(s0)) / self.rho

    def permitted_speed(self, s_m: float, target_m: float, target_speed_mps: float, dead_time_s: float, v_mps: float) -> float:
        """The braking curve at s: the largest speed from which the train, after the dead time,
        brakes to ``target_speed_mps`` by ``target_m``, m/s (the target speed at or past it)."""
        if target_m <= s_m:
            return target_speed_mps
        e = 0.5 * target_speed_mps * target_speed_mps + self.energy(s_m, target_m, max(v_mps, target_speed_mps))
        # v²/2 + ∫ a over the dead-time run [s, s + v·T] = e, the run charged where it is run (the
        # inverse of stopping_distance): solved on the piece of constant deceleration the run ends in
        x, n = self._x, len(self._g)
        b = self.brake_part(v_mps)
        j = min(max(bisect_right(x, s_m) - 1, 0), n - 1)
        spent = 0.0  # ∫ a from s to the start of piece j (the dead-time run crossed the pieces before)
        x_j = s_m
        while True:
            a = b + G * self._g[j] / self.rho
            k = a * dead_time_s
            rest = e - spent + a * (x_j - s_m)
            v = -k + math.sqrt(k * k + 2.0 * max(rest, 0.0)) if rest > 0.0 else 0.0
            if j + 1 >= n or s_m + v * dead_time_s <= x[j + 1]:
                return max(target_speed_mps, v)
            spent += a * (x[j + 1] - x_j)
            x_j = x[j + 1]
            j += 1

    def stopping_distance(self, s_m: float, v_mps: float, dead_time_s: float) -> float:
        """Distance from the front at s to where the train stands, braking after the dead time, m."""
        if v_mps <= 0.0:
            return 0.0
        x0 = s_m + v_mps * dead_time_s
        b = self.brake_part(v_mps)
        need = 0.5 * v_mps * v_mps
        # F(x) = b·x + g·Gi(x)/ρ is increasing (a > 0 everywhere); invert it past x0
        xs, ci = self._x, self._ci
        f0 = b * x0 + G * self._grade_integral_at(x0) / self.rho
        target = f0 + need
        f_end = b * xs[-1] + ci[-1]
        if target <= f_end:  # the breakpoint at or below the target, walking on from x0 (as np.interp(target, F(xs), xs))
            n = len(xs) - 1
            j = min(max(bisect_right(xs, x0) - 1, 0), n)
            while j > 0 and b * xs[j] + ci[j] > target:
                j -= 1
            if b * xs[0] + ci[0] > target:
                x_stop = xs[0]
            else:
                while j < n and b * xs[j + 1] + ci[j + 1] <= target:
                    j += 1
                x_stop = xs[n] if j == n else _interp(target, [b * xs[j] + ci[j], b * xs[j + 1] + ci[j + 1]], xs[j:j + 2], 0)
        else:  # beyond the route's end the last edge's gradient continues
            x_stop = xs[-1] + (target - f_end) / (b + G * self._g[-1] / self.rho)
        x_stop = max(x_stop, x0)
        return x_stop - s_m

    def braking_run(self, s_m: float, v_mps: float, dead_time_s: float) -> list[tuple[float, float, float, float]]:
        """The braking run from the front at s (:func:`vcsumo.signalling.braking_runs.braking_run`):
        the dead time at constant speed, then this train's deceleration along the route."""
        return braking_run(self._x, self._g, self.rho, self.brake_part(v_mps), s_m, v_mps, dead_time_s, self.stock.name)

    def state_after(self, s_m: float, v_mps: float, t_s: float) -> tuple[float, float]:
        """(distance covered, speed) t after the train at s and v started braking (no dead time), on
        the route's gradients, (m, m/s): with ``strongest`` the least a train ahead can have advanced
        since a message of that state t old (:func:`leader_worst_state` on level track)."""
        if t_s <= 0.0 or v_mps <= 0.0:
            return 0.0, max(v_mps, 0.0)
        return run_state(self.braking_run(s_m, v_mps, 0.0), t_s)

    def stopping_bound(self, v_mps: float, dead_time_s: float) -> float:
        """An upper bound of :meth:`stopping_distance` from anywhere on the route (s ≥ 0), m: v·T + v²/(2·a)
        with a the lowest deceleration of the route (its steepest descent; the brake part at the
        train's top speed, or at v above it), plus a margin for rounding.  Per-step checks use it
        to skip the integration where even this distance cannot matter."""
        if self._floor is None:
            self._v_top = self.stock.max_speed_ms
            self._floor = self.brake_part(self._v_top) + G * self._g_min / self.rho
        a = self._floor if v_mps <= self._v_top else self.brake_part(v_mps) + G * self._g_min / self.rho
        if a <= 0.0:
            return math.inf
        return (v_mps * dead_time_s + v_mps * v_mps / (2.0 * a)) * (1.0 + 1e-6) + 1e-3

    def curve(self, dead_time_s: float):
        """``curve(s, target, target speed, v)`` for :func:`vcsumo.running_time.unhindered_run`."""

        def f(s_m: float, target_m: float, target_speed_mps: float, v_mps: float) -> float:
            return self.permitted_speed(s_m, target_m, target_speed_mps, dead_time_s, v_mps)

        return f


# -------------------------------------------------------------------------------------------
# Relative braking along a route (the VC guard and the run-health monitor of coupled followers)


class RelativeBraking:
    """The relative-braking rule for one follower behind one leader, on the follower's route.

    Both trains brake on the route's gradient profile (:class:`RouteBraking`): the follower with its
    guaranteed relative-braking brake after the dead time, the leader with its strongest, from its
    worst state.  When the follower cannot out-brake the leader anywhere (its best guaranteed
    deceleration on level track is below the leader's hardest brake alone), the closing is largest
    when both stand, and the rule is the stopping-point form — exact on the gradient profile and
    continuous in position.  Otherwise (a light follower behind a heavy leader) the worst moment may
    be mid-braking: the rule is :func:`relative_braking_gap` with the weakest follower and hardest
    leader decelerations over their braking distances.
    """

    def __init__(self, model: SeparationModel, follower: RollingStock, leader: RollingStock, profile):
        kind = model.assumptions.relative_braking
        self.model = model
        self.follower = RouteBraking(model, follower, profile, kind)
        self.leader = RouteBraking(model, leader, profile, kind, strongest=True)
        self.profile = profile
        _, high_l = brake_range(leader, model.assumptions, kind)
        self.never_outbrakes = self.follower.brake_part(0.0) <= high_l

    def closing(self, s_f: float, v_f: float, s_l: float, v_l: float, dead_time_s: float) -> float:
        """How much the front-to-rear gap closes in the worst case from now, m (≥ 0)."""
        if self.never_outbrakes:
            d_f = self.follower.stopping_distance(s_f, v_f, dead_time_s)
            d_l = self.leader.stopping_distance(s_l, v_l, 0.0)
            return max(0.0, d_f - d_l)  # stopping points: the gap is smallest when both stand
        # the follower may out-brake the leader somewhere: the largest closing over the whole episode,
        # both runs integrated on the gradient profile (exact, and continuous in the states: one
        # deceleration per train for the whole run would miss a climb under the leader's run that
        # neither end reaches, and jump when an end crosses onto it)
        return max_closing(self.follower.braking_run(s_f, v_f, dead_time_s), self.leader.braking_run(s_l, v_l, 0.0))

    def required_gap(self, s_f: float, v_f: float, s_l: float, v_l: float, dead_time_s: float) -> float:
        """Front-to-rear gap the follower needs: the closing plus margin and position errors, m."""
        return self.model.margin_m + self.closing(s_f, v_f, s_l, v_l, dead_time_s)

    def max_speed(self, s_f: float, gap_m: float, s_l: float, v_l: float, dead_time_s: float, v_max: float, tol_mps: float = 0.01) -> float:
        """Largest follower speed in [0, v_max] that keeps the rule with ``gap_m`` to the leader's
        rear (``s_l``: the leader's front), m/s."""
        room = gap_m - self.model.margin_m
        if room < 0.0:
            return 0.0
        if self.closing(s_f, v_max, s_l, v_l, dead_time_s) <= room:
            return v_max
        lo, hi = 0.0, v_max
        while hi - lo > tol_mps:
            mid = 0.5 * (lo + hi)
            if self.closing(s_f, mid, s_l, v_l, dead_time_s) <= room:
                lo = mid
            else:
                hi = mid
        return lo
