"""Braking-curve supervision of the trains SUMO drives: plan every brake with the guaranteed deceleration.

SUMO's Rail model plans every stop, speed reduction and red signal at the vType's constant
``decel``, while the braking it delivers is ``decel + (R + M·g·i)/(M·ρ)``: on a descent less than it
planned, so trains skip stops, enter restrictions too fast and overrun the end of the track (issue
11).  The supervisor gives every train SUMO drives a *permitted speed* — the lowest braking curve to
its targets ahead — computed with the deceleration it is **guaranteed** to have where it brakes
(:func:`vcsumo.signalling.separation.guaranteed_decel`: brake at the bottom of the box, the
steepest descent between its rear and the target), and the loop commands that speed whenever SUMO
would run faster.  Targets:

* every place where the speed limit drops (the train must be down to the limit when its front gets
  there; SUMO holds the lower limit until the whole train has passed);
* its next scheduled stop: the curve ends at SUMO's stopping point, the train keeps a creep speed
  of 0.3 m/s until SUMO's own discrete stopping rule taken at the guaranteed deceleration is lower,
  and enters the last 10 cm (where SUMO counts the stop reached) at 0.08 m/s, below SUMO's halting
  speed, so SUMO's stop logic takes it whatever braking SUMO plans with (a curve that ends exactly
  there approaches it for ever; one that ends beyond it hands SUMO a train too fast to stop; a
  constant creep carries the train past its stopping point at 0.1 s steps: all seen on the graded
  regional line);
* the end of its route where it has to stop there: the end of the track (less the position
  error, after the dead time), also at an open end of the network, where SUMO ends the trip with
  a stop whose window takes the train held short of the end (``timetable.routes_xml``);
* its **end of movement authority** — a merging junction it has to wait at
  (:mod:`vcsumo.sim.interlocking`), and the regime's: FBS — the last signal at least ``overlap_m``
  behind the rear of the train ahead (ETCS L2 with overlap); MB — the rear of the train ahead as
  of its last position report, minus the safety margin and the position error of both trains
  (ETCS L3).  These use the assumption set's dead time (reaction + half the brake build-up); the
  operational targets (limits, stops) only the simulation step.  ETCS fixed times (route setting,
  MA transmission, reaction; ``fixed_time_s``) make the authority that much older: it is built from
  where the train ahead was ``fixed_time_s`` ago (MB: from its last report sent by then), so every
  headway grows by about that time.

Every curve is planned on the train's guaranteed **service** brake — the brake SUMO brakes the
trains it drives with (speed mode 31) and the normal approach of a train in service (ETCS: the
service-brake curves lie before the emergency-brake intervention) — whatever brake the assumption
set certifies the separation with: an ``absolute_braking: emergency`` set counts the emergency
brake as the reserve behind these curves (the run-health monitor's safe separation), never as the
brake of the approach.

The permitted speed for the next step accounts for the step itself (SUMO's semi-implicit Euler
moves the train ``v·Δt`` at the new speed before it can brake again): the dead time is lengthened by
1.5·Δt, as in :func:`vcsumo.dynamics.discrete_stop_speed`.

What this costs in headway is what the separation model says: the analytic headways of the
regimes (:mod:`vcsumo.signalling.regimes`) use the same decelerations and dead times.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, NamedTuple

from vcsumo.errors import VcsumoError
from vcsumo.dynamics import discrete_stop_speed
from vcsumo.running_time import STOP_CREEP_MPS
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.timetable import PlannedTrain



STOP_REACHED_M = 0.5
"""A train standing this close to its stopping point has reached it: the stop stops being a target
(SUMO holds it for its dwell; it may leave after), m."""
STOP_THRESHOLD_M = 0.1
"""SUMO counts a stop reached from this far before its stopping point (POSITION_EPS), m."""
STOP_ARRIVAL_MPS = 0.08
"""The last centimetres into a stop are run at this speed, below SUMO's halting speed (0.1 m/s), so
SUMO's stop logic takes the train whatever braking it plans with, m/s."""


@dataclass
class _Curves:
    plan: PlannedTrain
    restrictions: list[tuple[float, float]]
    stops: list[float]
    end_s: float | None
    signals: list[float]
    braking: RouteBraking
    """The train's guaranteed service braking: every target (stops, speed restrictions, the end of
    movement authority and of the track) and every reach bound."""
    restriction_s: list[float] = field(default_factory=list)
    """Positions of ``restrictions`` (for a bisection)."""
    next_stop: int = 0
    platform_from: list[float] = field(default_factory=list)
    """Where each stop's platform begins (the stop's position less the platform's length), m."""
    first_seen_s: float = math.nan
    quiet_from: float = math.inf
    quiet_until: float = -math.inf
    """Front positions [from, until) where no target can come within reach (:meth:`BrakingCurveSupervisor.quiet`), m."""
    quiet_recheck: float = -math.inf
    """The nearest target the window was bounded by: before the front passes it the window is not looked for again, m."""
    quiet_version: int = -1
    """The interlocking's :attr:`~vcsumo.sim.interlocking.MergeLocking.version` the window was found with."""
    quiet_v: float = -math.inf
    """The highest speed the window holds for, m/s."""
    quiet_gap: float = math.inf
    """The window holds while the train ahead is farther than this, m."""
    quiet_stop: int = -1
    """The next stop (``next_stop``) the window was found with."""
    quiet_v_failed: float = math.inf
    """The speed at which the last look found no window (looked for again below 90 % of it), m/s."""


class Permitted(NamedTuple):
    """A train's permitted speed and what set it."""

    speed_mps: float
    reason: str
    """'limit', 'stop', 'end', 'authority' or '' (nothing ahead within reach)."""
    authority_m: float = math.inf
    """Distance from the front to the end of movement authority (inf: none ahead), m."""


class BrakingCurveSupervisor:
    """Permitted speeds of the trains SUMO drives under ``regime`` ('fbs' or 'mb')."""

    def __init__(self, model: SeparationModel, regime: str, trains: list[PlannedTrain], step_s: float, signals: dict[str, list[float]] | None = None,
                 fixed_time_s: float | None = None, locking=None, braking: dict[str, RouteBraking] | None = None,
                 held_at_stop: Callable[[str], bool] | None = None):
        if regime not in ("fbs", "mb"):
            raise ValueError(f"braking-curve supervision of regime '{regime}' (fbs or mb)")
        self.model = model
        self.regime = regime
        self.step_s = step_s
        self.fixed_time_s = model.assumptions.fixed_time_s if fixed_time_s is None else fixed_time_s
        self.curves: dict[str, _Curves] = {}
        a = model.assumptions
        self._keep_s = self.fixed_time_s + a.position_report_period_s + 2.0 * step_s
        """How long an odometer reading is kept, s."""
        self._snap_t: deque = deque()
        self._snap_odo: deque = deque()
        """Times of the odometer readings kept, and each time's readings (train -> odometer, m)."""
        self._odo_now: dict[str, float] = {}
        self._seen: set[str] = set()
        self._dead_s = a.dead_time_s
        self._pos_err = a.position_error_m
        self._overlap = a.overlap_m
        self._margin = a.safety_margin_m
        self._uncertainty = a.position_uncertainty_m
        """The assumption set's figures the per-step rules read (its properties computed once)."""
        self._history = regime == "mb" or self.fixed_time_s > 0.0
        """Odometer readings are kept only when an authority is built from an older position (MB
        reports, fixed times): under FBS without fixed times it is built from the present one."""
        self.locking = locking
        self.held_at_stop = held_at_stop
        """Whether SUMO holds a train at one of its stops (``SumoBackend.at_stop``): a train standing in
        its platform short of the stopping point has been served there only if SUMO says so; None:
        never assumed served short of the stopping point."""
        """Approach locking at merging junctions (:class:`vcsumo.sim.interlocking.MergeLocking`), or None."""
        braking_of = braking
        shared: dict[tuple, RouteBraking] = {}
        for t in trains:
            at = [(x.s_m, x.platform_length_m) for x in t.stops]
            if t.final_stop is not None:
                at.append((t.final_stop.s_m, t.final_stop.platform_length_m))
            at.sort()
            stops = [x for x, _ in at]
            end_s = None
            if t.final_stop is None and t.stop_at_end:
                # the end of the track; at an open end of the network SUMO ends the trip with a stop whose
                # window takes the train held short of it by this rule (timetable.routes_xml)
                end_s = t.profile.length_m if t.end_pos_m is None else float(t.profile.starts_m[-1] + t.end_pos_m)
            try:  # the trains' service braking (``braking``: already built, e.g. the health monitor's)
                service = (braking_of or {}).get(t.id) or shared.get((id(t.stock), id(t.profile))) \
                    or shared.setdefault((id(t.stock), id(t.profile)), RouteBraking(model, t.stock, t.profile, "service"))
            except ValueError:
                g_low, _ = t.profile.gradient_range(0.0, t.profile.length_m)
                raise VcsumoError(f"train {t.id} ({t.stock.name}) has no guaranteed service braking on the steepest descent of its route "
                                  f"({1000 * g_low:.1f} ‰) under the assumption set '{model.assumptions.name}'") from None
            restrictions = t.profile.restriction_targets()
            self.curves[t.id] = _Curves(t, restrictions, stops, end_s, sorted((signals or {}).get(t.id, [])), service,
                                        [x for x, _ in restrictions], platform_from=[x - length if length > 0 else x for x, length in at])

        v_cap = max(t.stock.max_speed_ms for t in trains) * 1.2 + 10.0 if trains else 0.0
        moved = v_cap * (self.fixed_time_s + a.position_report_period_s + 2.0 * step_s) if self._history else 0.0
        if regime == "mb":
            self._gap_slack = moved + self._margin + self._uncertainty + 1.0
        else:
            spacing = {tid: max((b - a_ for a_, b in zip(c.signals, c.signals[1:])), default=0.0) for tid, c in self.curves.items()}
            self._gap_slack_of = {tid: moved + self._overlap + 2.0 * self._pos_err + spacing[tid] + 1.0 for tid in self.curves}
        self._v_window: dict[str, float] = {}
        """Per train: the highest speed a quiet window is looked for at (:meth:`quiet`), m/s."""

    @property
    def reads_odometry(self) -> bool:
        """The authorities are built from the trains' odometer readings (MB reports, fixed times): the
        loop hands :meth:`observe_all` every train's odometer at every step; else nothing reads them."""
        return self._history or self.regime == "mb"

    # ------------------------------------------------------------------------------------------
    def observe_all(self, time_s: float, train_ids: list[str], odometers_m: list[float]) -> None:
        """Every running train's odometer this step, taken before any authority of the step is built
        (kept as long as the fixed time and report period need; a train's history starts when it is
        first seen): every follower's authority is built from the same step's positions."""
        now = dict(zip(train_ids, odometers_m))
        for tid in now.keys() - self._seen:
            c = self.curves.get(tid)
            if c is not None:
                c.first_seen_s = time_s
            self._seen.add(tid)
        self._odo_now = now
        if not self._history:
            return
        ts = self._snap_t
        ts.append(time_s)
        self._snap_odo.append(now)
        oldest = time_s - self._keep_s
        while len(ts) > 2 and ts[1] <= oldest:
            ts.popleft()
            self._snap_odo.popleft()

    def _moved_since(self, train_id: str, c: _Curves, t_ref: float) -> float:
        """How far a train has run since t_ref (from the odometer readings kept; since it was first
        seen if that is later), m."""
        ts, snaps = self._snap_t, self._snap_odo
        now = self._odo_now.get(train_id)
        lo = bisect_left(ts, c.first_seen_s)
        if now is None or lo >= len(ts):
            return 0.0
        i = bisect_right(ts, t_ref)
        if i <= lo:
            return now - snaps[lo][train_id]
        if i >= len(ts):
            return 0.0  # (also every FBS authority without fixed times: t_ref is now)
        t0, t1 = ts[i - 1], ts[i]
        odo0, odo1 = snaps[i - 1][train_id], snaps[i][train_id]
        then = odo0 + (odo1 - odo0) * (t_ref - t0) / max(t1 - t0, 1e-9)
        return now - then

    def information_time(self, leader_id: str, now_s: float) -> float:
        """Time of the train ahead's position the follower's authority is built from, s: ``fixed_time_s``
        ago (FBS), or its last position report sent by then (MB: one every report period)."""
        t_ref = now_s - self.fixed_time_s
        period = self.model.assumptions.position_report_period_s
        lead = self.curves.get(leader_id)
        if self.regime == "mb" and period > 0 and lead is not None and not math.isnan(lead.first_seen_s):
            t_ref = lead.first_seen_s + math.floor((t_ref - lead.first_seen_s) / period + 1e-9) * period
        return t_ref

    def authority_distance(self, train_id: str, s_m: float, gap_m: float, leader_id: str | None, now_s: float, fouling: bool = False) -> float:
        """Distance from the front to the end of movement authority given the train ahead, m.

        ``fouling``: the gap runs to the junction the train ahead still fouls (the loop's fouling gap),
        a fixed point: it does not move back by the run of that train since its last report."""
        if leader_id is None or math.isinf(gap_m):
            return math.inf
        lead = self.curves.get(leader_id)
        # (without a history the authority is built from the present position: nothing moved since)
        moved = 0.0 if lead is None or not self._history or fouling else self._moved_since(leader_id, lead, self.information_time(leader_id, now_s))
        rear = s_m + gap_m - moved
        if self.regime == "mb":
            return rear - s_m - self._margin - self._uncertainty
        # the rear as the interlocking knows it (less the train ahead's position error) must be an
        # overlap beyond the signal that ends the authority; the train stops its own position error
        # short of that signal
        err = self._pos_err
        clear = rear - self._overlap - err
        signals = self.curves[train_id].signals
        k = bisect_right(signals, clear) - 1
        if k < 0 or signals[k] < s_m - 2 * err - 1.0:
            # no signal between the train and the rear of the one ahead: it moves on sight behind it
            return clear - s_m - err
        return signals[k] - s_m - err

    def quiet(self, train_id: str, now_s: float, s_m: float, v_mps: float, gap_m: float = math.inf, leader_id: str | None = None) -> bool:
        """True when :meth:`permitted` would find nothing ahead within reach (permitted speed inf,
        authority beyond the reach), known from bounds without computing a curve.

        A *quiet window* is kept per train: a stretch of route [from, until), a speed and a gap such
        that with the front in the stretch, at most that speed and the train ahead farther than that
        gap, every target — speed restrictions, the next stop, the end, the last signal (FBS), the
        junctions and stretches of single track ahead (:meth:`MergeLocking.authority_floor`), the
        end of authority behind the train ahead (less margin, overlap, position errors, the longest
        block and how far that train can have run since the position the authority is built from) —
        lies beyond the reach at that speed.  Every bound is an upper bound of what
        :meth:`permitted` computes, so the loop skips it only where the answer is known;
        tests/test_supervision_quiet.py checks this against :meth:`permitted` at every step of real
        runs (same arguments as :meth:`permitted`; ``now_s`` and ``leader_id`` are not needed)."""
        c = self.curves.get(train_id)
        if c is None:
            return True
        if c.quiet_stop == c.next_stop and (self.locking is None or c.quiet_version == self.locking.version) and c.quiet_from <= s_m:
            if s_m < c.quiet_until and v_mps <= c.quiet_v:
                return gap_m > c.quiet_gap  # the window holds: only the train ahead decides
            if s_m < c.quiet_recheck and v_mps >= 0.9 * c.quiet_v_failed:
                return False  # nothing that could open a window has changed since the last look found none
        self._quiet_window(train_id, c, s_m, v_mps)
        return c.quiet_from <= s_m < c.quiet_until and gap_m > c.quiet_gap

    def _quiet_window(self, train_id: str, c: _Curves, s_m: float, v_mps: float) -> None:
        """The quiet window from ``s_m`` for speeds up to a little above ``v_mps`` (:meth:`quiet`)."""
        v_cap = self._v_window.get(train_id)
        if v_cap is None:  # the stock's top speed (the bound's braking is constant below it), or the route's
            v_cap = self._v_window[train_id] = min(c.braking.stock.max_speed_ms, c.plan.profile.max_speed() + 1.0)
        c.quiet_from, c.quiet_until, c.quiet_recheck = s_m, -math.inf, 0.0
        c.quiet_stop = c.next_stop
        c.quiet_version = self.locking.version if self.locking is not None else 0
        if v_mps > v_cap or s_m < 0.0:  # (before the start of its route permitted looks at every target: again from 0)
            c.quiet_v_failed = v_mps
            return
        v_q = min(v_cap, 1.1 * v_mps + 5.0)
        reach = 1.3 * c.braking.stopping_bound(v_q, self._dead_s + 2 * self.step_s) + 50.0
        rs = c.restriction_s
        k0 = bisect_right(rs, s_m)
        nearest = rs[k0] if k0 < len(rs) else math.inf
        if c.next_stop < len(c.stops):
            nearest = min(nearest, c.stops[c.next_stop])
        if c.end_s is not None:
            nearest = min(nearest, c.end_s - self._pos_err)
        if self.regime == "fbs" and c.signals:
            nearest = min(nearest, c.signals[-1] - self._pos_err)
        if self.locking is not None:
            nearest = min(nearest, self.locking.authority_floor(train_id, s_m))
        c.quiet_until = nearest - reach - 1.0
        c.quiet_recheck = nearest
        c.quiet_v = v_q
        c.quiet_gap = reach + (self._gap_slack if self.regime == "mb" else self._gap_slack_of[train_id])
        c.quiet_v_failed = v_mps if s_m >= c.quiet_until else math.inf

    def permitted(self, train_id: str, now_s: float, s_m: float, v_mps: float, gap_m: float = math.inf, leader_id: str | None = None,
                  fouling: bool = False) -> Permitted:
        """The lowest braking curve over the train's targets, for the next step, m/s.

        A target matters only within the reach (1.3 × the stopping distance + 50 m); when the nearest
        one is beyond an upper bound of the reach (:meth:`~vcsumo.signalling.separation.RouteBraking.stopping_bound`) no curve is computed — the
        same answer as computing them all."""
        c = self.curves.get(train_id)
        if c is None:
            return Permitted(math.inf, "")
        dt = self.step_s
        dead = self._dead_s
        rs = c.restriction_s
        k0 = bisect_right(rs, s_m)  # the first restriction ahead
        stops = c.stops
        while c.next_stop < len(stops) and (stops[c.next_stop] < s_m - 1.0 or (stops[c.next_stop] < s_m + STOP_REACHED_M and v_mps < 0.05)
                                            or (v_mps < 0.05 and c.platform_from[c.next_stop] <= s_m and self.held_at_stop is not None
                                                and self.held_at_stop(train_id))):
            # passed, standing at it (SUMO holds the train for its dwell), or standing in its platform
            # behind a train stopped ahead in it where SUMO serves the stop (a convoy stands in the
            # platform as one train; SUMO does not run the follower on to the stopping point). Standing
            # in the platform further back (a follower waiting behind its predecessor) is not served:
            # the stop stays the target, or the train would run through it once the one ahead has left
            c.next_stop += 1
        d_ma = self.authority_distance(train_id, s_m, gap_m, leader_id, now_s, fouling) if leader_id is not None else math.inf
        if self.locking is not None:
            d_lock = self.locking.authority_distance(train_id, s_m)
            if d_lock < d_ma:
                d_ma = d_lock
        nearest = d_ma
        if k0 < len(rs) and rs[k0] - s_m < nearest:
            nearest = rs[k0] - s_m
        if c.next_stop < len(stops) and stops[c.next_stop] - s_m < nearest:
            nearest = stops[c.next_stop] - s_m
        end_target = c.end_s - self._pos_err if c.end_s is not None else math.inf  # stopped its position error short of the end
        if end_target - s_m < nearest:
            nearest = end_target - s_m
        if s_m >= 0.0 and nearest > 1.3 * c.braking.stopping_bound(v_mps, dead + 2 * dt) + 50.0:
            return Permitted(math.inf, "", d_ma)
        best, reason = math.inf, ""
        # how far ahead a target can matter: the stopping distance with a generous margin
        br = c.braking
        reach = 1.3 * br.stopping_distance(s_m, v_mps, dead + 2 * dt) + 50.0
        for s_t, v_t in c.restrictions[k0:]:
            if s_t <= s_m:
                continue
            if s_t - s_m > reach:
                break
            vp = br.permitted_speed(s_m, s_t, v_t, 1.5 * dt, v_mps)
            if vp < best:
                best, reason = vp, "limit"
        if c.next_stop < len(c.stops):
            s_t = c.stops[c.next_stop]
            if s_t - s_m <= reach:
                # the creep ends on SUMO's own discrete stopping rule at the guaranteed deceleration, so
                # SUMO's stop logic can always finish the stop
                d = s_t - s_m - STOP_THRESHOLD_M
                creep = min(STOP_CREEP_MPS, max(STOP_ARRIVAL_MPS, discrete_stop_speed(d, br.decel_at(s_m, v_mps), dt))) if d > 0 else STOP_ARRIVAL_MPS
                vp = max(creep, br.permitted_speed(s_m, s_t, 0.0, 1.5 * dt, v_mps))
                if vp < best:
                    best, reason = vp, "stop"
        if end_target - s_m <= reach:
            vp = br.permitted_speed(s_m, end_target, 0.0, dead + 1.5 * dt, v_mps)
            if vp < best:
                best, reason = vp, "end"
        if d_ma <= reach:
            vp = br.permitted_speed(s_m, s_m + d_ma, 0.0, dead + 1.5 * dt, v_mps)
            if vp < best:
                best, reason = vp, "authority"
        return Permitted(best, reason, d_ma)
