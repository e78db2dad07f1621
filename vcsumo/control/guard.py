"""The separation guard: the last filter stage of every VC follower, on forces.

:class:`SeparationGuard` sits between the follower's controller (and its supervisor) and the
train, in the SUMO loop and in the offline loop alike (:class:`~vcsumo.control.stack.FollowerStack`).
``limit(obs, cmd)`` returns the command, or the largest force below it that passes two tests —
never below the emergency brake force −M·a_eb.  Interventions are counted; a limited force beyond
the service brake the train is sure of is flagged ``emergency`` (the offline plant then applies
its emergency brake, as the SUMO loop always allows the follower).

What the guard knows of the predecessor is only what is on board (:func:`predecessor_estimate`):
the sensed gap and speed when the Observation carries them (the predecessor is the train seen
ahead), else the state in the latest message the channel delivered (with its age), else nothing —
then the predecessor may be standing at the follower's front.

**Separation** (:class:`NextStepSeparation`): the relative-braking rule of the one separation
model (:class:`vcsumo.signalling.separation.RelativeBraking`, under the stack's named assumption
set), tested on the state one step ahead and on the *force* the train will be applying then.  The
predecessor is placed where it is at the least one step from now, having braked as hard as it can
(top of its box, its resistance, the up-grades it has met on the way) since the time stamp of what
the follower knows of it (:meth:`RouteBraking.state_after`: until 2026-12-01 at the deceleration where
it was, so a climb just ahead of it was left out for the whole age of the message).
The follower's force one step ahead is the largest its plant can apply after the command (a rising
force at most the command, a falling one no lower than the force lag and jerk limit allow from the
force it applies now, ``Observation.ego.force_n``: :meth:`BrakeBuildUp.next_force`); from that force its guaranteed brake needs the build-up
:meth:`BrakeBuildUp.actuation_time` (an equivalent dead time, the CBF's: longest from full
traction — ETR1000 ≈ 1.9 s —, ≈ 1.3 s from coasting, 0 once braking fully), during which it keeps
that force's traction and the steepest descent on its way.  So the follower runs the set's dead
time (reaction + half the brake build-up the set assumes) + that build-up + half a step (the
explicit-Euler overshoot) at the speed it reaches, then brakes at its guaranteed brake (bottom of
its box, descents) on the route's gradients against the predecessor's strongest; the gap less the
margin, the position errors of both trains (the assumption set's, + the odometry bound
``position_error_m`` the guard is told: it works on measured positions and keeps the rule on the
true ones) and the stack's d_min beyond that must hold the worst closing at every moment (also
when the follower brakes harder than the predecessor can).  The test is monotone in the force, so
when the command fails it the guard searches the largest force one step ahead that passes and
commands what gives it (a falling force through the lag inverted, a rising one as it is; the
service brake where the jerk limit makes it as good; else the emergency brake).  Why the build-up from the applied force: the run-health monitor checks
the rule with the set's dead time at *every* step on the true speed, also halfway through a brake
build-up, so a follower at full traction at the rule's boundary cannot stay within it (its speed
still rises while its brake builds up); with the build-up added, the test's stopping point does
not move forward along an emergency braking (the equivalent dead time shrinks as the force falls),
and the monitor's rule — the same with less dead time, at a lower speed — is kept.

**Line** (:class:`NextStepLine`): the limit under the whole train (on speed: back to it in one step,
on the service brake within the set's speed tolerance above it), and the guaranteed service-brake
curves (:class:`RouteBraking`, the same curves the supervision gives the trains SUMO drives) to the
follower's own stop (``Observation.next_stop_m``) and to every lower limit ahead — tested like the
separation, from the same state one step ahead (:class:`NextStep`): the force one step ahead, the
build-up from it to the service brake with its traction held on the steepest descent on the way,
half a step; no reaction time (the train knows its stops and limits).  When the command fails the
curves the guard commands the largest force that keeps them, down to the full service brake
(:meth:`BrakeBuildUp.service_command_n`, M̄·b: any train of the box then brakes at the curves'
guaranteed rate per mass — not an emergency); a train above them already gets the full service
brake, and the emergency brake only above the curves of a brake already applied
(:meth:`SeparationGuard.line_speed`, 1.5 steps of dead time).

By default the guard trusts only what the channel delivered (:class:`GuardConfig` ``sensor``: an
on-board sensor of the train ahead — SUMO's exact gap and speed within its look-ahead, no error
model — may be switched on explicitly).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

from pydantic import Field

from vcsumo.config import StrictModel, load_model
from vcsumo.control.base import Command, Observation
from vcsumo.control.brake_build_up import BrakeBuildUp
from vcsumo.dynamics import acceleration, gradient_force, running_resistance
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel
from vcsumo.units import G


class GuardConfig(StrictModel):
    """Settings of the separation guard (the last filter stage of every VC controller)."""

    sensor: bool = Field(default=False, description="Trust an on-board sensor of the train ahead (SUMO's exact gap and speed within its "
                                                     "look-ahead; no error model) besides the channel's messages")


def load_guard(spec: str | Path | None = None, field: str | None = "--guard", base_dir: str | Path | None = None) -> GuardConfig:
    """Guard settings: a YAML file or a name in controllers/ (default ``guard``)."""
    from vcsumo.control.params import resolve_params

    return load_model(GuardConfig, resolve_params(spec, "guard", field, base_dir, kind="guard"))


def default_guard() -> GuardConfig:
    """The guard settings every stack gets when its caller names none: ``controllers/guard.yaml``
    (``$VCSUMO_HOME/controllers/`` when set) — the same for ``vcsumo run``, the capacity study and the
    safety campaign in both loops (until 2026-11-28 only ``vcsumo run`` and the junction study read the
    file; the others took the built-in defaults, so a ``sensor: true`` there changed the run, not the
    campaign that is to check it)."""
    from vcsumo.control.params import resolve_params

    path = resolve_params(None, "guard", "guard.yaml", kind="guard")
    return _guard_file(str(path), path.stat().st_mtime_ns)


@lru_cache(maxsize=8)
def _guard_file(path: str, _mtime_ns: int) -> GuardConfig:
    return load_model(GuardConfig, path)


@dataclass(frozen=True)
class PredecessorEstimate:
    """What the follower knows of its predecessor: front position (ego route frame, m), speed (m/s)
    and the age of that knowledge (s; 0 for a sensed state, +inf when nothing is known)."""

    front_m: float
    speed_mps: float
    age_s: float
    source: str
    """``sensed``, ``message`` or ``none`` (then: standing at the follower's front)."""


def predecessor_estimate(obs: Observation, predecessor_length_m: float, sensor: bool = True) -> PredecessorEstimate:
    """The best information on board: the sensed gap and speed (when ``sensor``), else the latest
    delivered message, else "the predecessor may be standing at the follower's front"."""
    s = obs.ego.position_m
    if sensor and obs.sensed_gap_m is not None and obs.sensed_speed_mps is not None:
        return PredecessorEstimate(s + obs.sensed_gap_m + predecessor_length_m, obs.sensed_speed_mps, 0.0, "sensed")
    m = obs.received.get(obs.predecessor) if obs.predecessor is not None else None
    if m is not None and math.isfinite(m.state.position_m) and math.isfinite(m.state.speed_mps):
        return PredecessorEstimate(m.state.position_m, m.state.speed_mps, max(0.0, obs.time_s - m.state.time_s), "message")
    return PredecessorEstimate(s, 0.0, math.inf, "none")


# -------------------------------------------------------------------------------------------
# The filter stage


def largest_fitting(fits, lo: float, hi: float) -> float:
    """The largest force in [lo, hi] that passes ``fits`` (monotone: a lower force passes when a higher
    one does), given that ``lo`` passes, to 1/1000 of the interval (it keeps the side that passes), N."""
    tol = 1e-3 * (hi - lo)
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    return lo


class NextStep:
    """The follower one step from now under the force its plant applies then — the state both tests
    of the guard (separation and line) start from: the position after the step (explicit Euler, eq. 6b:
    it advances with the present speed), the speed it may reach in the step (no resistance beyond
    Davis A̲, the lightest mass under traction), and the brake build-up from that force
    (:meth:`BrakeBuildUp.held`: its equivalent dead time and the speed gained meanwhile)."""

    def __init__(self, build: BrakeBuildUp, obs: Observation, braking: RouteBraking):
        self.build = build
        self.braking = braking
        self.dt = obs.step_s
        self.s, self.v = obs.ego.position_m, obs.ego.speed_mps
        self.s1 = self.s + self.v * self.dt
        self.grade = obs.profile.mean_gradient(self.s, obs.params.length_m)

    def state(self, next_force_n: float, brake_mps2: float | None = None) -> tuple[float, float, float]:
        """(speed at the end of the build-up, its equivalent dead time, the speed one step ahead) when the
        plant applies ``next_force_n`` one step from now, building up to the brake ``brake_mps2`` (None:
        the relative-braking rule's), m/s, s, m/s."""
        b = self.build
        net = next_force_n - b.davis_a_low_n
        a1 = net / (b.rho * (b.m_low if net > 0.0 else b.m_high)) - G * self.grade / b.rho
        v1 = max(0.0, self.v + self.dt * a1)
        v_dead, t_act = b.held(self.braking, self.s1, v1, next_force_n, brake_mps2)
        return v_dead, t_act, v1


class NextStepSeparation:
    """The guard's separation test at one step: does a force applied one step from now keep the
    relative-braking rule after the brake build-up from that force?  (See the module doc.)"""

    def __init__(self, guard: "SeparationGuard", obs: Observation, pred: PredecessorEstimate, step: NextStep | None = None):
        self.rule, _ = guard._rule(obs.profile)
        self.step = step if step is not None else NextStep(guard.build_up, obs, self.rule.follower)
        self.dt = obs.step_s
        s, self.v, self.s1 = self.step.s, self.step.v, self.step.s1
        self.dead_s = guard.model.dead_time_s + 0.5 * self.dt  # + the Euler overshoot of a Δt-sampled braking
        if pred.source == "none":  # nothing known: the predecessor may stand at the follower's front
            self.s_l, self.v_l, self.room = s, 0.0, -math.inf
        else:  # where the predecessor is at the least one step from now, having braked as hard as it can since its time stamp
            moved, self.v_l = self.rule.leader.state_after(pred.front_m, pred.speed_mps, pred.age_s + self.dt)  # on the gradients it met
            self.s_l = pred.front_m + moved
            gap = self.s_l - guard.predecessor.length_m - self.s1 - max(0.0, guard.d_min_m - guard.model.margin_m) - 2.0 * guard.position_error_m
            self.room = gap - guard.model.margin_m

    def state(self, next_force_n: float) -> tuple[float, float, float]:
        """(speed, dead time, the follower's speed one step ahead) of the rule's follower when the
        plant applies ``next_force_n`` one step from now: the set's dead time + the build-up from
        that force (:class:`NextStep`) + half a step, at the speed it may reach by then."""
        v_dead, t_act, v1 = self.step.state(next_force_n)
        return v_dead, self.dead_s + t_act, v1

    def closing(self, next_force_n: float) -> float:
        """The rule's worst closing from one step ahead under ``next_force_n``, m."""
        v_dead, dead, _ = self.state(next_force_n)
        return self.rule.closing(self.s1, v_dead, self.s_l, self.v_l, dead)

    def fits(self, next_force_n: float) -> bool:
        return self.room >= 0.0 and self.closing(next_force_n) <= self.room


class NextStepLine:
    """The guard's line test at one step: does a force applied one step from now keep the follower on
    or below its guaranteed service-brake curves — to its own stop and to every lower limit ahead —
    after the build-up from that force to its service brake?  The same state as the separation test
    (:class:`NextStep`: the force one step ahead, the build-up with its traction held on the steepest
    descent on the way) with half a step for the Euler overshoot; no reaction time (the train knows
    its stops and limits in advance).  The curves integrate the guaranteed service brake over the
    route's gradients (:class:`RouteBraking`, as the supervision of the trains SUMO drives)."""

    def __init__(self, guard: "SeparationGuard", obs: Observation, step: NextStep):
        self.service = guard._rule(obs.profile)[1]
        self.step = step
        self.brake = step.build.service_mps2
        self.half_s = 0.5 * step.dt
        s = step.s
        self.targets = []
        targets, positions = guard._restrictions(obs.profile)
        i = bisect_right(positions, s)
        stop = obs.next_stop_m if obs.next_stop_m is not None and obs.next_stop_m > s else math.inf
        nearest = min(positions[i] if i < len(positions) else math.inf, stop)
        if not math.isfinite(nearest):
            return
        # a cheap bound first (the top speed it may reach from full traction on the route's steepest descent)
        t_full, a_hold = guard._hold_bound(obs.profile)
        v_hi = step.v + a_hold * (step.dt + t_full)
        if nearest - s > self.service.stopping_bound(v_hi, t_full + self.half_s) + (step.s1 - s) + 50.0:
            return
        v_top, t_top, _ = step.state(step.build.full_traction_n, self.brake)  # the farthest it may run before it stands
        reach = self.service.stopping_distance(step.s1, v_top, t_top + self.half_s) + (step.s1 - s) + 50.0
        for s_t, v_t in targets[i:]:
            if s_t - s > reach:
                break
            self.targets.append((s_t, v_t))
        if stop - s <= reach:
            self.targets.append((stop, 0.0))

    def fits(self, next_force_n: float) -> bool:
        if not self.targets:
            return True
        v_dead, t_act, _ = self.step.state(next_force_n, self.brake)
        dead, s1 = t_act + self.half_s, self.step.s1
        return all(v_dead <= self.service.permitted_speed(s1, s_t, v_t, dead, v_dead) + 1e-9 for s_t, v_t in self.targets)


class SeparationGuard:
    """Force filter ``limit(obs, cmd) -> Command`` (see the module doc).

    ``follower``/``predecessor``: the two trains' rolling stock (their models and uncertainty boxes);
    ``d_min_m``: the stack's minimum safe gap (kept where it exceeds the model's margin and position
    errors); ``model``: the separation model (its assumption set); ``config``: whether a sensor is
    trusted; ``position_error_m``: the bound e_s of the odometry error of each train's measured
    position (Felez eq. 9) — the positions it works on are measured, and the rule (its margin
    included) is kept on the true ones.  ``interventions`` counts the steps it lowered the command;
    ``last_speed_mps`` is the nominal one-step speed under its output when it bound (else the speed
    the command reaches) and ``last_force_in_n`` its incoming force."""

    def __init__(self, follower: RollingStock, predecessor: RollingStock, d_min_m: float, config: GuardConfig | None = None,
                 model: SeparationModel | None = None, position_error_m: float = 0.0):
        self.follower = follower
        self.predecessor = predecessor
        self.follower_params = follower.params()
        self.predecessor_params = predecessor.params()
        self.d_min_m = float(d_min_m)
        self.position_error_m = float(position_error_m)
        self.cfg = config or GuardConfig()
        self.model = model or SeparationModel(load_assumptions())
        self.build_up = BrakeBuildUp(follower, self.model.assumptions)
        self.interventions = 0
        self.last_speed_mps = math.nan
        self.last_force_in_n = math.nan
        self._rules: dict[int, tuple] = {}
        self._targets: dict[int, tuple] = {}
        self._bounds: dict[int, tuple[float, float]] = {}

    def _rule(self, profile: RouteProfile) -> tuple[RelativeBraking, RouteBraking]:
        r = self._rules.get(id(profile))
        if r is None:
            r = (RelativeBraking(self.model, self.follower, self.predecessor, profile), RouteBraking(self.model, self.follower, profile, "service"))
            self._rules = {id(profile): r}
        return r

    def separation(self, obs: Observation, pred: PredecessorEstimate | None = None) -> NextStepSeparation:
        """The step's separation test (on what the follower knows of its predecessor)."""
        if pred is None:
            pred = predecessor_estimate(obs, self.predecessor_params.length_m, self.cfg.sensor)
        return NextStepSeparation(self, obs, pred)

    def _restrictions(self, profile: RouteProfile) -> tuple[list[tuple[float, float]], list[float]]:
        """(position, speed) of every lower limit of the route, sorted, and their positions (once per route)."""
        targets = self._targets.get(id(profile))
        if targets is None:
            lows = profile.restriction_targets()
            self._targets = {id(profile): (lows, [p for p, _ in lows])}
            targets = self._targets[id(profile)]
        return targets

    def _hold_bound(self, profile: RouteProfile) -> tuple[float, float]:
        """(the build-up from full traction to the service brake, s; the acceleration full traction
        may give meanwhile on the route's steepest descent, m/s²) — bounds of :class:`NextStep` (once per route)."""
        b = self._bounds.get(id(profile))
        if b is None:
            service = self._rule(profile)[1]
            b = self.build_up.actuation_time(None, self.build_up.service_mps2), self.build_up.hold_accel(self.build_up.full_traction_n, max(0.0, -float(min(service.g_low))))
            self._bounds = {id(profile): b}
        return b

    def line(self, obs: Observation, step: NextStep | None = None) -> NextStepLine:
        """The step's line test: the service-brake curves to its stop and the lower limits ahead after
        the build-up from the force one step ahead."""
        return NextStepLine(self, obs, step if step is not None else NextStep(self.build_up, obs, self._rule(obs.profile)[0].follower))

    def present_limit(self, obs: Observation) -> float:
        """The limit under the whole train now and the train's top speed (0 once its front is at or past
        its own stop), m/s."""
        s = obs.ego.position_m
        if obs.next_stop_m is not None and obs.next_stop_m <= s:
            return 0.0
        return min(obs.profile.speed_limit_train(s, self.follower.length_m), self.follower.max_speed_ms)

    def line_speed(self, obs: Observation, v_cap_mps: float = math.inf) -> float:
        """The speed the line allows for the next step to a train whose brake is applied already (no
        build-up), m/s (at most ``v_cap_mps``): approaching its own stop (``Observation.next_stop_m``)
        the guaranteed service-brake curve to it, and everywhere :meth:`limit_speed`.  The guard keeps
        the curves with the build-up (:class:`NextStepLine`); above these it calls the emergency brake."""
        _, service = self._rule(obs.profile)
        s, dt = obs.ego.position_m, obs.step_s
        v = v_cap_mps
        if obs.next_stop_m is not None:
            v = min(v, service.permitted_speed(s, obs.next_stop_m, 0.0, 1.5 * dt, obs.ego.speed_mps))
        return min(v, self.limit_speed(obs, service))

    def limit_speed(self, obs: Observation, service: RouteBraking) -> float:
        """The permitted speed of the line to a train whose brake is applied already: the limit under
        the whole train now, and the guaranteed service-brake curve (1.5 steps of dead time) to every
        lower limit ahead (as the supervision of SUMO-driven trains), m/s."""
        prof, s, v, dt = obs.profile, obs.ego.position_m, obs.ego.speed_mps, obs.step_s
        v_perm = min(prof.speed_limit_train(s, self.follower.length_m), self.follower.max_speed_ms)
        reach = service.stopping_distance(s, v, 2.0 * dt) + 50.0
        for s_t, v_t in self._restrictions(prof)[0]:
            if s_t <= s:
                continue
            if s_t - s > reach:
                break
            v_perm = min(v_perm, service.permitted_speed(s, s_t, v_t, 1.5 * dt, v))
        return v_perm

    def limit(self, obs: Observation, cmd: Command) -> Command:
        p, prof = obs.params, obs.profile
        s, v, dt = obs.ego.position_m, obs.ego.speed_mps, obs.step_s
        grad = prof.mean_gradient(s, p.length_m)
        tf = prof.tunnel_factor_at(s)
        f_eb = -p.mass_kg * p.emergency_brake_decel_mps2  # the train brakes at most with its emergency brake
        force_in = float(cmd.force_n)
        force = max(force_in, f_eb)
        v_floor = max(0.0, v + dt * float(acceleration(p, v, f_eb, grad, tf)))
        v_cmd = max(v_floor, v + dt * float(acceleration(p, v, force, grad, tf)))
        self.last_force_in_n = force_in
        build, f0 = self.build_up, float(obs.ego.force_n)
        service = -build.service_force_n(v)
        step = NextStep(build, obs, self._rule(prof)[0].follower)
        # 1. the line: the limit under the train (on speed), then the service-brake curves to the
        # follower's own stop and every lower limit ahead, after the build-up from the force one step ahead
        # (a command beyond the service force the train is sure of is an emergency command, except the
        # full service command of the line: beyond it, the emergency brake)
        full, beyond = -build.service_command_n(v), service
        v_here = self.present_limit(obs)
        if v_cmd > v_here + 1e-9:  # back to the limit in one step; within the set's speed tolerance on the service brake
            f_here = self._force_for(p, v, max(v_here, v_floor), dt, grad, tf)
            if v <= v_here + self.model.assumptions.speed_tolerance_kmh / 3.6:
                f_here, beyond = max(f_here, full), full
            force = max(min(f_here, force), f_eb)
        line = self.line(obs, step)
        hi = build.next_force(f0, force, dt, cmd.emergency or force < beyond - 1e-6, v)
        if not line.fits(hi):
            floor = build.next_force(f0, full, dt, False, v)
            if line.fits(floor):  # the largest force one step ahead on the curves, and the command that gives it
                u = build.command_for(f0, largest_fitting(line.fits, floor, hi), dt)
                if u <= service + 1e-6:  # as much as the service brake the train is sure of: the full service brake
                    u, beyond = full, full
                force = max(min(u, force), f_eb)
            else:  # above its curves already: the full service brake, and the emergency brake above the curves of a brake applied
                v_line = self.line_speed(obs, v_cmd + 1e-6)
                force, beyond = max(min(full, self._force_for(p, v, max(v_line, v_floor), dt, grad, tf), force), f_eb), full
        # 2. the separation: the force one step ahead keeps the relative-braking rule after its build-up
        sep = NextStepSeparation(self, obs, predecessor_estimate(obs, self.predecessor_params.length_m, self.cfg.sensor), step)
        emergency = cmd.emergency or force < beyond - 1e-6
        if not sep.fits(build.next_force(f0, force, dt, emergency, v)):
            floor = build.next_force(f0, f_eb, dt, True, v)
            if sep.fits(floor):  # the largest force one step ahead that fits, and the command that gives it
                lo = largest_fitting(sep.fits, floor, build.next_force(f0, force, dt, emergency, v))
                u = build.command_for(f0, lo, dt)
                if u < service and build.next_force(f0, service, dt, False, v) <= lo:
                    u = service  # the service brake gets there too (the jerk limit binds): no emergency brake
                if u < force:
                    force, beyond = max(u, f_eb), service
            else:  # outside the rule already: brake as hard as the train can, to a stand (and hold it there)
                force, beyond = max(min(self._force_for(p, v, v_floor, dt, grad, tf), force), f_eb), service
        if force >= force_in - 1e-9:
            self.last_speed_mps = v_cmd
            return cmd if force_in >= f_eb else replace(cmd, force_n=f_eb)
        self.interventions += 1
        self.last_speed_mps = v_out = max(v_floor, v + dt * float(acceleration(p, v, force, grad, tf)))
        emergency = cmd.emergency or force < beyond - 1e-6
        return replace(cmd, force_n=force, emergency=emergency, info={**cmd.info, "guard_speed_mps": v_out})

    @staticmethod
    def _force_for(p, v: float, v_target: float, dt: float, grad: float, tf: float) -> float:
        """The force that gives ``v_target`` after one step (eq. 1b solved for u), N."""
        return p.mass_kg * p.rotating_mass_factor * (v_target - v) / dt + float(running_resistance(p, v, tf)) + float(gradient_force(p, grad))


__all__ = ["GuardConfig", "load_guard", "default_guard", "PredecessorEstimate", "predecessor_estimate", "BrakeBuildUp", "largest_fitting", "NextStep", "NextStepSeparation",
           "NextStepLine", "SeparationGuard"]
