"""Run health: every anomaly of every train, counted at every step from the first, never assumed away.

A run is *healthy* when every train arrived, every scheduled stop was served, no train ran above its
permitted speed (+ the assumption set's tolerance), no train passed its end of movement authority
or stopped at the end of the track, nothing collided, no train came closer to the one ahead than the
regime's safe separation, and no train SUMO drives braked beyond its service rate (a sign that its
braking was planned wrong).  Emergency applications of vcsumo's VC controllers and supervisors are
counted separately (they are the safety layer working, reported, not a planning failure).

The safe separation is the one of :mod:`vcsumo.signalling.separation`, evaluated on the true
states: for trains under absolute braking (FBS, MB, convoy leaders) the gap they need to stop
behind the train ahead's rear with their guaranteed brake after the dead time, plus margin and
position errors — on the brake the assumption set certifies the separation with
(``absolute_braking``: service, or emergency, the reserve; the trains are driven on the service
brake either way, so their ends of authority, and the overruns of them, are planned on service);
for virtually coupled followers the relative-braking gap against the leader's strongest brake (the
driver supplies it).  There is no low-speed exemption: standing behind
another train the margin and the position errors remain.

SUMO's own warning "performs emergency braking" (a train's speed fell by more than its vType's
``emergencyDecel`` × step length in one step) is judged one event at a time
(:meth:`HealthMonitor.judge_sumo_emergency_brakings`).  SUMO's deceleration is the speed change, so
it includes the grade: on a steep climb a train braking on its service brake — SUMO's own service
braking, or a VC follower's commanded force — slows by g·i more than its brake gives (0.245 m/s²
on 25 ‰), above an ``emergencyDecel`` set from the brake alone
(:attr:`~vcsumo.rolling_stock.RollingStock.sumo_emergency_decel_mps2`).  The monitor records every
step at which a train decelerated above its vType's ``emergencyDecel`` (whoever drives it) with the
brake its driver may use there, with its running resistance and the steepest up-grade under it: a
train SUMO drives its strongest service brake (the rule of braking beyond service above: it plans
with nothing else), a train vcsumo drives its strongest emergency brake (its safety layers apply the
emergency brake by design and the VC summary counts every application; before, it was judged
against service too, so the same application was real on a climb and unseen on the level).  An
event whose step was within that is *explained* (grade-assisted), every other one — beyond it, or
not matched to a recorded step — is *real* and makes the run unhealthy.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field

from vcsumo.errors import InfeasibleBraking
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel, brake_range, strongest_decel
from vcsumo.sim.sumo_io import SumoEmergencyBraking, SumoLogCounts
from vcsumo.timetable import PlannedTrain

GAP_TOLERANCE_M = 0.01
"""Numerical tolerance of the separation test, m."""
DECEL_TOLERANCE_MPS2 = 0.02
"""Braking counted beyond the service rate above the strongest service deceleration plus this, m/s²."""
SPEED_ROUNDING_MPS = 1e-3
"""Overspeed is counted above the permitted speed + the set's tolerance + this, m/s: SUMO's network
stores lane speeds rounded (16.6667 m/s for 60 km/h), and a train held at its lane's limit is not
overspeeding under a tolerance of 0."""
AUTHORITY_TOLERANCE_M = 0.5
"""A front more than this past its end of movement authority is an overrun, m."""
STANDING_MPS = 0.05
"""Below this a train stands: it cannot start an overrun (it only continues one), m/s."""
SUMO_WARNING_SLACK_MPS2 = 0.01
"""A step is recorded as one SUMO may warn of above the vType's emergencyDecel minus this, m/s²
(SUMO rounds nothing, the slack only makes the recorded steps a superset of its warnings)."""
SUMO_DECEL_MATCH_MPS2 = 0.006
"""A SUMO event matches a recorded step of its train at its time when their decelerations differ by
at most this (SUMO writes two decimals), m/s²."""


@dataclass(frozen=True)
class HardBraking:
    """A step at which a train decelerated above its vType's emergencyDecel (SI units)."""

    time_s: float
    s_m: float
    speed_mps: float
    """The speed at the end of the step, m/s."""
    decel_mps2: float
    service_limit_mps2: float
    """The strongest service deceleration there (brake at the top of its box, running resistance,
    steepest up-grade under the train), m/s²."""
    gradient_permille: float
    """The steepest gradient under the train (+ rising), ‰."""
    driven_by_sumo: bool
    emergency_limit_mps2: float = math.nan
    """A step vcsumo's driver drove: the strongest emergency deceleration there (brake at the top of
    its range, running resistance, steepest up-grade under the train), m/s² (nan: SUMO drove it)."""

    @property
    def beyond_service(self) -> bool:
        return self.decel_mps2 > self.service_limit_mps2 + DECEL_TOLERANCE_MPS2

    @property
    def beyond_its_brake(self) -> bool:
        """Braking the train may not show: a train SUMO drives beyond its service brake (it plans
        with nothing else), one vcsumo drives beyond its emergency brake (its safety layers apply
        the emergency brake by design, counted in the VC summary), whatever the grade."""
        if self.driven_by_sumo:
            return self.beyond_service
        return self.decel_mps2 > self.emergency_limit_mps2 + DECEL_TOLERANCE_MPS2


@dataclass
class SumoBrakingVerdict:
    """SUMO's emergency-braking warnings of a run judged against the recorded steps."""

    warnings: int = 0
    """SUMO's total (every warning, written or aggregated)."""
    explained: int = 0
    """Warnings of steps braked within the brake the train's driver may use (:attr:`HardBraking.beyond_its_brake`:
    service for SUMO's, emergency for vcsumo's; the grade made the rest of the deceleration)."""
    real: int = 0
    """The others: braking beyond that brake, or no recorded step to explain them."""
    rows: list[dict] = field(default_factory=list)
    """One row per recorded step and per written warning no step matched (:data:`SUMO_BRAKING_COLUMNS`)."""


SUMO_BRAKING_COLUMNS = ["time_s", "train", "lane", "decel_mps2", "sumo_decel_mps2", "wished_mps2", "severity", "service_limit_mps2",
                        "emergency_limit_mps2", "gradient_permille", "speed_mps", "driven_by_sumo", "in_sumo_log", "verdict", "reason"]
"""Columns of sumo_emergency_brakings.csv: ``time_s`` the loop's time, at the end of the step (SUMO's
warning names its start, one step length earlier); ``decel_mps2`` the loop's, ``sumo_decel_mps2``
SUMO's (two decimals); ``in_sumo_log`` — SUMO wrote this warning one by one
(false: a recorded step SUMO may have counted only in its aggregated total); ``verdict``
``explained``/``real``."""


@dataclass
class TrainHealth:
    """Counters of one train (SI units)."""

    min_margin_m: float = math.inf
    """Smallest gap minus the safe separation, m."""
    below_separation_time_s: float = 0.0
    below_separation_distance_m: float = 0.0
    separation_violations: int = 0
    """Times the gap fell below the safe separation."""
    overspeed_events: int = 0
    overspeed_max_kmh: float = 0.0
    overspeed_time_s: float = 0.0
    beyond_service_events: int = 0
    max_decel_mps2: float = 0.0
    overruns: int = 0
    max_overrun_m: float = 0.0
    collisions: int = 0
    max_impact_kmh: float = 0.0
    _below: bool = field(default=False, repr=False)
    _over: bool = field(default=False, repr=False)
    _beyond: bool = field(default=False, repr=False)
    _overrun: bool = field(default=False, repr=False)
    _cache: dict = field(default_factory=dict, repr=False)
    limit_from_m: float = field(default=math.inf, repr=False)
    limit_to_m: float = field(default=-math.inf, repr=False)
    limit_mps: float = field(default=math.inf, repr=False)
    """The train's permitted speed while its front is in (from, to), where it cannot change (:meth:`HealthMonitor._speed_limit`)."""
    quick_decel_mps2: float = field(default=-math.inf, repr=False)
    """Below this deceleration a step can be neither braking beyond service nor one SUMO may warn of."""
    hard_brakings: list[HardBraking] = field(default_factory=list, repr=False)
    """Steps above the vType's emergencyDecel (what SUMO warns of), judged as braking beyond service or not."""


class HealthMonitor:
    """Per-step safety and health accounting of a run (see the module doc)."""

    def __init__(self, model: SeparationModel, trains: list[PlannedTrain]):
        self.model = model
        self.plans = {t.id: t for t in trains}
        self.trains: dict[str, TrainHealth] = {t.id: TrainHealth() for t in trains}
        shared: dict[tuple[int, int, str], RouteBraking] = {}  # one per rolling stock, route and brake (a service's trains share them)
        certified = model.assumptions.absolute_braking
        self.braking: dict[str, RouteBraking] = {}
        """Per train: the brake its safe separation is certified with (the set's ``absolute_braking``)."""
        self.service: dict[str, RouteBraking] = {}
        """Per train: the service brake it is driven on (the supervision's and the interlocking's
        curves; the same objects as :attr:`braking` when the set certifies on service)."""
        for t in trains:
            for kind, into in ((certified, self.braking), ("service", self.service)):
                key = (id(t.stock), id(t.profile), kind)
                try:
                    into[t.id] = shared.get(key) or shared.setdefault(key, RouteBraking(model, t.stock, t.profile, kind))
                except InfeasibleBraking as exc:  # its brake does not hold it on a descent of its route: no run of it can be safe
                    raise exc.for_train(t.id, model.assumptions.name) from None
        self.relative: dict[tuple[str, str], RelativeBraking] = {}
        self.tol_mps = model.assumptions.speed_tolerance_kmh / 3.6 + SPEED_ROUNDING_MPS
        self.collision_rows: list[tuple] = []
        # the hardest service braking without resistance and grade: braking at most this is never beyond service
        self._top_speed = {t.id: t.stock.max_speed_ms for t in trains}
        self._starts: dict[int, list[float]] = {}
        self._margin_m = model.margin_m
        self._dead_s = model.dead_time_s
        self._service_floor = {t.id: self._floor_terms(t.stock) for t in trains}
        # SUMO warns above its vType's emergencyDecel (the drawn "true" train's when it runs as a variant)
        self._sumo_warn = {t.id: getattr(t.stock, "true_stock", t.stock).sumo_emergency_decel_mps2 - SUMO_WARNING_SLACK_MPS2 for t in trains}
        for t in trains:
            self.trains[t.id].quick_decel_mps2 = min(self._service_floor[t.id][0] + DECEL_TOLERANCE_MPS2, self._sumo_warn[t.id])

    def _floor_terms(self, stock) -> tuple[float, float, float, float, float]:
        """(hardest service brake, Davis A, B, C at the top of their box, lowest mass) of a train."""
        box = stock.uncertainty
        p = stock.params()
        if box is not None:
            p = p.with_(davis_a_n=box.davis_a_n.high, davis_b_n_per_mps=box.davis_b_n_per_mps.high, davis_c_n_per_mps2=box.davis_c_n_per_mps2.high)
        m_low = stock.mass_kg if box is None else box.mass_kg.low
        return brake_range(stock, self.model.assumptions, "service")[1], p.davis_a_n, p.davis_b_n_per_mps, p.davis_c_n_per_mps2, m_low

    def service_floor(self, train_id: str, v_mps: float) -> float:
        """A lower bound of :meth:`_service_limit` at speed v, m/s²: the hardest service brake and the
        running resistance at the lowest speed of v's 1 m/s band + 1 (the limit is taken there or
        above, on an up-grade or level), a hair below for rounding."""
        high, a, b, c, m_low = self._service_floor[train_id]
        if b < 0.0 or c < 0.0:
            return high
        u = float(int(v_mps)) + 1.0
        return (high + (a + b * u + 1.5 * c * u * u) / m_low) * (1.0 - 1e-9)

    # ------------------------------------------------------------------------------------------
    def absolute_gap(self, train_id: str, s_m: float, v_mps: float) -> float:
        """The safe separation of a train under absolute braking at (s, v), m: margin and position
        errors plus the distance it needs to stop on its route (guaranteed braking on the grades
        between its rear and where it stops, after the dead time)."""
        return self.model.margin_m + self.braking[train_id].stopping_distance(s_m, v_mps, self.model.dead_time_s)

    def relative_gap(self, train_id: str, s_m: float, v_mps: float, leader_id: str, gap_m: float, leader_v_mps: float) -> float:
        """The safe separation of a virtually coupled follower behind ``leader_id`` (the separation
        model's relative braking on the true states, no message age), m."""
        pl = self.plans.get(leader_id)
        if pl is None:
            return self.absolute_gap(train_id, s_m, v_mps)
        rule = self._rule(train_id, leader_id)
        s_l = s_m + gap_m + pl.stock.length_m  # the leader's front in the follower's route frame
        return rule.required_gap(s_m, v_mps, s_l, leader_v_mps, self.model.dead_time_s)

    def _rule(self, train_id: str, leader_id: str) -> RelativeBraking:
        rule = self.relative.get((train_id, leader_id))
        if rule is None:
            p = self.plans[train_id]
            rule = self.relative[(train_id, leader_id)] = RelativeBraking(self.model, p.stock, self.plans[leader_id].stock, p.profile)
        return rule

    def step(self, train_id: str, dt: float, s_m: float, v_mps: float, accel_mps2: float, gap_m: float, authority_m: float = math.inf,
             driven_by_sumo: bool = True, leader_id: str | None = None, leader_v_mps: float = 0.0, time_s: float = math.nan) -> float | None:
        """One step of one train (as :meth:`update`), the safe separation evaluated only where it can
        change a counter: relative braking behind ``leader_id`` (a coupled follower), else absolute.

        The safe separation is at most margin + an upper bound of the stopping distance
        (:meth:`~vcsumo.signalling.separation.RouteBraking.stopping_bound`); where the gap exceeds that by at least the smallest margin seen so
        far (and by more than −tolerance), the margin can neither set a new minimum nor fall below
        the separation, so the rule is not evaluated: every counter and the minimum margin are
        the same as when it is evaluated at every step.  Returns the safe separation when the gap
        has just fallen below it, else None.  ``time_s``: the simulated time (of SUMO's warnings)."""
        h = self.trains[train_id]
        if gap_m < math.inf:
            relative = leader_id is not None and leader_id in self.plans
            br = self._rule(train_id, leader_id).follower if relative else self.braking[train_id]
            floor = h.min_margin_m if h.min_margin_m > -GAP_TOLERANCE_M else -GAP_TOLERANCE_M
            if s_m < 0.0 or gap_m - self._margin_m - br.stopping_bound(v_mps, self._dead_s) < floor:
                required = (self.relative_gap(train_id, s_m, v_mps, leader_id, gap_m, leader_v_mps) if relative
                            else self.absolute_gap(train_id, s_m, v_mps))
                return required if self.update(train_id, dt, s_m, v_mps, accel_mps2, gap_m, required, authority_m, driven_by_sumo, time_s) else None
        # no gap to test this step: the rest of update(), its common case first — below the hardest service brake
        # (and SUMO's warning), within the permitted speed on a stretch where it holds, short of the authority
        decel = -accel_mps2
        if decel <= h.quick_decel_mps2 and h.limit_from_m < s_m < h.limit_to_m and v_mps - h.limit_mps <= self.tol_mps \
                and (authority_m >= -AUTHORITY_TOLERANCE_M or not driven_by_sumo):
            if decel > h.max_decel_mps2:
                h.max_decel_mps2 = decel
            h._below = h._over = h._beyond = h._overrun = False
            return None
        self.update(train_id, dt, s_m, v_mps, accel_mps2, math.inf, math.inf, authority_m, driven_by_sumo, time_s)
        return None

    def _service_limit(self, train_id: str, s_m: float, v_mps: float) -> float:
        """The strongest service deceleration with the front at s at speed v (the brake at the top of
        its box, the running resistance at v + 1 m/s, the steepest up-grade under the train), m/s²."""
        p = self.plans[train_id]
        h = self.trains[train_id]
        _, g_high = p.profile.gradient_range(s_m - p.stock.length_m, s_m)
        key = ("srv", round(g_high, 5), int(v_mps))
        a = h._cache.get(key)
        if a is None:
            a = strongest_decel(p.stock, self.model.assumptions, "service", v_mps + 1.0, g_high)
            h._cache[key] = a
        return a

    def _speed_limit(self, train_id: str, s_m: float) -> float:
        """The train's permitted speed with its front at s: the lowest limit under the whole train
        (SUMO's rule, :meth:`RouteProfile.speed_limit_train`) and its top speed, m/s.  The value is
        kept for the positions where the front and the rear stay on the same edges (1 mm inside
        every boundary) and no turnout is near, where it cannot change."""
        p = self.plans[train_id]
        prof, length = p.profile, p.stock.length_m
        limit = min(prof.speed_limit_train(s_m, length), self._top_speed[train_id])
        starts = self._starts.get(id(prof))
        if starts is None:
            starts = self._starts[id(prof)] = [float(x) for x in prof.starts_m]
        n = len(starts)
        i1 = min(max(bisect_right(starts, s_m) - 1, 0), n - 1)
        i0 = min(max(bisect_right(starts, max(s_m - length, 0.0)) - 1, 0), n - 1)
        lo = max(starts[i1] if i1 > 0 else -math.inf, starts[i0] + length if i0 > 0 else -math.inf) + 1e-3
        hi = min(starts[i1 + 1] if i1 < n - 1 else math.inf, starts[i0 + 1] + length if i0 < n - 1 else math.inf) - 1e-3
        if any(lo - length - 1.0 <= ps <= hi + 1.0 for ps, _ in prof.point_limits):
            lo, hi = math.inf, -math.inf
        h = self.trains[train_id]
        h.limit_from_m, h.limit_to_m, h.limit_mps = lo, hi, limit
        return limit

    def update(self, train_id: str, dt: float, s_m: float, v_mps: float, accel_mps2: float, gap_m: float, required_gap_m: float,
               authority_m: float = math.inf, driven_by_sumo: bool = True, time_s: float = math.nan) -> bool:
        """One step of one train; True when its gap has just fallen below the safe separation."""
        h = self.trains[train_id]
        p = self.plans[train_id]
        # separation, at every speed
        below = started = False
        if math.isfinite(gap_m):
            margin = gap_m - required_gap_m
            h.min_margin_m = min(h.min_margin_m, margin)
            below = margin < -GAP_TOLERANCE_M
            if below:
                h.below_separation_time_s += dt
                h.below_separation_distance_m += v_mps * dt
                if not h._below:
                    h.separation_violations += 1
                    started = True
        h._below = below
        # permitted speed
        limit = h.limit_mps if h.limit_from_m < s_m < h.limit_to_m else self._speed_limit(train_id, s_m)
        excess = v_mps - limit
        over = excess > self.tol_mps
        if over:
            h.overspeed_time_s += dt
            h.overspeed_max_kmh = max(h.overspeed_max_kmh, 3.6 * excess)
            if not h._over:
                h.overspeed_events += 1
        h._over = over
        # braking beyond the service rate (trains SUMO drives plan with service braking)
        decel = -accel_mps2
        if decel > h.max_decel_mps2:
            h.max_decel_mps2 = decel
        # the service limit is at least the hardest service brake and the resistance: below that it is not looked up
        beyond = driven_by_sumo and decel > self._service_floor[train_id][0] + DECEL_TOLERANCE_MPS2 \
            and decel > self.service_floor(train_id, v_mps) + DECEL_TOLERANCE_MPS2 \
            and decel > self._service_limit(train_id, s_m, v_mps) + DECEL_TOLERANCE_MPS2
        if beyond and not h._beyond:
            h.beyond_service_events += 1
        h._beyond = beyond
        if decel > self._sumo_warn[train_id]:  # a step SUMO may warn of: judged against the brake its driver may use
            _, g_high = p.profile.gradient_range(s_m - p.stock.length_m, s_m)
            e_lim = math.nan if driven_by_sumo else strongest_decel(p.stock, self.model.assumptions, "emergency", v_mps + 1.0, g_high)
            h.hard_brakings.append(HardBraking(time_s, s_m, v_mps, decel, self._service_limit(train_id, s_m, v_mps), 1000.0 * g_high, driven_by_sumo, e_lim))
        # end of movement authority: passing it (moving beyond it) is an overrun; a train standing where
        # it was placed (a departure at a platform whose exit signal stands at its front) passed nothing
        past = driven_by_sumo and authority_m < -AUTHORITY_TOLERANCE_M
        if past and (h._overrun or v_mps > STANDING_MPS):
            h.max_overrun_m = max(h.max_overrun_m, -authority_m)
            if not h._overrun:
                h.overruns += 1
            h._overrun = True
        elif not past:
            h._overrun = False
        return started

    def clearance(self, train_id: str, gap_m: float, required_m: float) -> float:
        """A train entered a stretch of single track with an opposing train's rear ``gap_m`` past the
        point where that train left it, short of ``required_m``
        (:attr:`~vcsumo.sim.single_track_lock.OpposingTrains.too_close`): a gap below the safe
        separation.  Returns ``required_m``."""
        h = self.trains[train_id]
        h.min_margin_m = min(h.min_margin_m, gap_m - required_m)
        h.separation_violations += 1
        return required_m

    def collision(self, time_s: float, collider: str, victim: str, collider_speed_mps: float, victim_speed_mps: float) -> None:
        impact = 3.6 * max(0.0, collider_speed_mps - victim_speed_mps)
        self.collision_rows.append((time_s, collider, victim, round(impact, 2)))
        for tid in (collider, victim):
            if tid in self.trains:
                self.trains[tid].collisions += 1
                self.trains[tid].max_impact_kmh = max(self.trains[tid].max_impact_kmh, impact)

    def train_row(self, train_id: str) -> dict:
        """The train's counters as summary columns (units in the names)."""
        h = self.trains[train_id]
        return {
            "min_margin_m": None if math.isinf(h.min_margin_m) else round(h.min_margin_m, 2),
            "below_separation_time_s": round(h.below_separation_time_s, 2),
            "below_separation_distance_m": round(h.below_separation_distance_m, 1),
            "separation_violations": h.separation_violations,
            "overspeed_events": h.overspeed_events, "overspeed_max_kmh": round(h.overspeed_max_kmh, 2),
            "beyond_service_brakings": h.beyond_service_events, "max_decel_mps2": round(h.max_decel_mps2, 3),
            "authority_overruns": h.overruns, "max_overrun_m": round(h.max_overrun_m, 2),
            "collisions": h.collisions, "max_impact_kmh": round(h.max_impact_kmh, 2),
        }

    # ------------------------------------------------------------------------------------------
    def judge_sumo_emergency_brakings(self, log: SumoLogCounts, step_s: float) -> SumoBrakingVerdict:
        """SUMO's 'performs emergency braking' warnings judged one by one against the steps recorded
        at which a train decelerated above its vType's emergencyDecel (see the module doc).

        A written warning is matched to its train's recorded step one step length after its time
        (SUMO stamps the start of the step, the loop observes its end; within half a step,
        decelerations within :data:`SUMO_DECEL_MATCH_MPS2`): explained when that step braked within
        the service brake, real when beyond it or when no step matches.  Warnings SUMO only counted
        (``--aggregate-warnings``: the total exceeds the written ones) are judged by the recorded steps
        no written warning took: real are at least those beyond service and any the steps within
        service cannot account for — the count is never lowered below what the records justify."""
        v = SumoBrakingVerdict(warnings=log.emergency_braking)
        pool = {tid: list(h.hard_brakings) for tid, h in self.trains.items() if h.hard_brakings}
        half = 0.5 * step_s + 1e-6
        written = log.emergency_braking_events
        for ev in written:
            t_end = ev.time_s + step_s  # SUMO stamps the step's start, the loop observes its end
            cands = [r for r in pool.get(ev.vehicle, ()) if abs(r.time_s - t_end) <= half and abs(r.decel_mps2 - ev.decel_mps2) <= SUMO_DECEL_MATCH_MPS2]
            rec = min(cands, key=lambda r: abs(r.time_s - t_end)) if cands else None
            if rec is None:
                v.real += 1
                v.rows.append(_row(t_end, ev.vehicle, None, ev, "real", "no step of the train at that time decelerated above its vType's emergencyDecel"))
                continue
            pool[ev.vehicle].remove(rec)
            verdict = "real" if rec.beyond_its_brake else "explained"
            v.real += verdict == "real"
            v.explained += verdict == "explained"
            v.rows.append(_row(rec.time_s, ev.vehicle, rec, ev, verdict, _reason(rec)))
        rest = [(tid, r) for tid, rs in pool.items() for r in rs]
        within = sum(not r.beyond_its_brake for _, r in rest)
        beyond = len(rest) - within
        n_rest = max(0, v.warnings - len(written))
        real_rest = max(n_rest - within, min(n_rest, beyond))
        v.real += real_rest
        v.explained += n_rest - real_rest
        for tid, r in sorted(rest, key=lambda x: (x[1].time_s, x[0])):
            v.rows.append(_row(r.time_s, tid, r, None, "real" if r.beyond_its_brake else "explained", _reason(r)))
        v.rows.sort(key=lambda row: (row["time_s"], row["train"]))
        return v


def _reason(r: HardBraking) -> str:
    if not r.driven_by_sumo:
        terms = f"emergency brake at the top of its range, running resistance and {r.gradient_permille:+.1f} ‰ under the train; vcsumo drove it"
        if r.beyond_its_brake:
            return f"beyond its emergency brake: {r.decel_mps2:.3f} m/s² > {r.emergency_limit_mps2:.3f} m/s² ({terms})"
        return f"within its emergency brake: {r.decel_mps2:.3f} m/s² <= {r.emergency_limit_mps2:.3f} m/s² ({terms})"
    terms = f"service brake at the top of its box, running resistance and {r.gradient_permille:+.1f} ‰ under the train"
    if r.beyond_service:
        return f"beyond the service brake: {r.decel_mps2:.3f} m/s² > {r.service_limit_mps2:.3f} m/s² ({terms})"
    return f"within the service brake: {r.decel_mps2:.3f} m/s² <= {r.service_limit_mps2:.3f} m/s² ({terms})"


def _row(time_s: float, train: str, rec: HardBraking | None, ev: SumoEmergencyBraking | None, verdict: str, reason: str) -> dict:
    return {
        "time_s": time_s, "train": train, "lane": ev.lane if ev else None,
        "decel_mps2": round(rec.decel_mps2, 4) if rec else None, "sumo_decel_mps2": ev.decel_mps2 if ev else None,
        "wished_mps2": ev.wished_mps2 if ev else None, "severity": ev.severity if ev else None,
        "service_limit_mps2": round(rec.service_limit_mps2, 4) if rec else None,
        "emergency_limit_mps2": round(rec.emergency_limit_mps2, 4) if rec and not rec.driven_by_sumo else None,
        "gradient_permille": round(rec.gradient_permille, 2) if rec else None, "speed_mps": round(rec.speed_mps, 3) if rec else None,
        "driven_by_sumo": rec.driven_by_sumo if rec else None, "in_sumo_log": ev is not None, "verdict": verdict, "reason": reason,
    }
