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
(top of its box, its resistance, up-grades) since the time stamp of what the follower knows of it.
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

**Line** (:meth:`SeparationGuard.line_speed`): approaching its own stop
(``Observation.next_stop_m``) the follower keeps to its guaranteed service-brake curve to the stop
point, and everywhere to the line's permitted speed: the limit under the whole train and the
guaranteed service-brake curve to every lower limit ahead (the same curves the supervision gives
the trains SUMO drives), on the one-step speed of eq. 1b.

By default the guard trusts only what the channel delivered (:class:`GuardConfig` ``sensor``: an
on-board sensor of the train ahead — SUMO's exact gap and speed within its look-ahead, no error
model — may be switched on explicitly).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pydantic import Field

from vcsumo.config import StrictModel, load_model
from vcsumo.control.base import Command, Observation
from vcsumo.dynamics import acceleration, brake_force_limit, gradient_force, running_resistance
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel, brake_range, leader_worst_state
from vcsumo.units import G


class GuardConfig(StrictModel):
    """Settings of the separation guard (the last filter stage of every VC controller)."""

    sensor: bool = Field(default=False, description="Trust an on-board sensor of the train ahead (SUMO's exact gap and speed within its "
                                                     "look-ahead; no error model) besides the channel's messages")


def load_guard(spec: str | Path | None = None, field: str | None = "--guard", base_dir: str | Path | None = None) -> GuardConfig:
    """Guard settings: a YAML file or a name in controllers/ (default ``guard``)."""
    from vcsumo.control.params import resolve_params

    return load_model(GuardConfig, resolve_params(spec, "guard", field, base_dir, kind="guard"))


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
# The follower's brake build-up


class BrakeBuildUp:
    """How long a train takes from the force it applies to its guaranteed brake, and its force
    one step ahead — bounded over its uncertainty box (mass, Davis A, brakes).

    :meth:`actuation_time` is the equivalent dead time of the force lag τ and the jerk limit j from
    the applied force F to the guaranteed brake of the relative-braking rule (the assumption set's
    ``relative_braking`` kind at the bottom of its range, b per mass): τ + (F/M + b)/(2j), with M̲
    for a traction force and M̄ for a brake force, 0 once F ≤ −b·M̄ — the CBF's
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
        self.emergency_low_n = self.m_low * brake_range(stock, assumptions, "emergency")[0]
        bp = box.max_brake_power_w.low if box.max_brake_power_w is not None else p.max_brake_power_w
        self.service_low = p.with_(mass_kg=self.m_low, service_brake_decel_mps2=brake_range(stock, assumptions, "service")[0], max_brake_power_w=bp)
        """The train with its guaranteed service-brake force (the bottom of mass, rate and power)."""
        self.full_traction_n = self.m_high * box.max_accel_mps2.high
        self._routes: dict[int, tuple] = {}

    def actuation_time(self, force_n: float | None) -> float:
        """Equivalent dead time from the applied force ``force_n`` (None: full traction) to the
        guaranteed brake, s (0 for a train without lag and jerk limit, or once the brake is applied)."""
        if self.lag_s <= 0.0 and math.isinf(self.jerk_mps3):
            return 0.0
        f = self.full_traction_n if force_n is None else float(force_n)
        per_mass = f / (self.m_low if f > 0.0 else self.m_high) + self.brake_mps2
        if per_mass <= 1e-9:
            return 0.0
        return self.lag_s + (0.5 * per_mass / self.jerk_mps3 if math.isfinite(self.jerk_mps3) else 0.0)

    def hold_accel(self, force_n: float, descent: float) -> float:
        """The largest acceleration while the force ``force_n`` (its traction part) is held, on a
        descent of ``descent`` (rise/run ≥ 0), without resistance, m/s²."""
        return max(force_n, 0.0) / (self.rho * self.m_low) + G * max(descent, 0.0) / self.rho

    def held(self, braking: RouteBraking | None, s_m: float, v_mps: float, force_n: float) -> tuple[float, float]:
        """(speed, dead time) of the build-up from ``force_n`` applied at (s, v): the equivalent dead
        time :meth:`actuation_time` and the speed reached by its end with the force's traction part
        held, on the steepest descent under the train over the distance it runs meanwhile
        (``braking``: the train's guaranteed braking on its route, :class:`RouteBraking`; None: level
        track), m/s and s."""
        t_act = self.actuation_time(force_n)
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


# -------------------------------------------------------------------------------------------
# The filter stage


class NextStepSeparation:
    """The guard's separation test at one step: does a force applied one step from now keep the
    relative-braking rule after the brake build-up from that force?  (See the module doc.)"""

    def __init__(self, guard: "SeparationGuard", obs: Observation, pred: PredecessorEstimate):
        self.rule, _ = guard._rule(obs.profile)
        self.build = guard.build_up
        self.dt = obs.step_s
        p = obs.params
        s, self.v = obs.ego.position_m, obs.ego.speed_mps
        self.s1 = s + self.v * self.dt  # explicit Euler (eq. 6b): the position advances with the present speed
        self.grade = obs.profile.mean_gradient(s, p.length_m)
        self.dead_s = guard.model.dead_time_s + 0.5 * self.dt  # + the Euler overshoot of a Δt-sampled braking
        if pred.source == "none":  # nothing known: the predecessor may stand at the follower's front
            self.s_l, self.v_l, self.room = s, 0.0, -math.inf
        else:  # where the predecessor is at the least one step from now, having braked as hard as it can since its time stamp
            a_l = self.rule.leader.decel_at(pred.front_m, pred.speed_mps)
            moved, self.v_l = leader_worst_state(pred.speed_mps, a_l, pred.age_s + self.dt)
            self.s_l = pred.front_m + moved
            gap = self.s_l - guard.predecessor.length_m - self.s1 - max(0.0, guard.d_min_m - guard.model.margin_m) - 2.0 * guard.position_error_m
            self.room = gap - guard.model.margin_m

    def state(self, next_force_n: float) -> tuple[float, float, float]:
        """(speed, dead time, the follower's speed one step ahead) of the rule's follower when the
        plant applies ``next_force_n`` one step from now: the set's dead time + the build-up from
        that force (:meth:`BrakeBuildUp.held`) + half a step, at the speed it may reach by then (no
        resistance beyond Davis A̲)."""
        b = self.build
        net = next_force_n - b.davis_a_low_n
        a1 = net / (b.rho * (b.m_low if net > 0.0 else b.m_high)) - G * self.grade / b.rho
        v1 = max(0.0, self.v + self.dt * a1)
        v_dead, t_act = b.held(self.rule.follower, self.s1, v1, next_force_n)
        return v_dead, self.dead_s + t_act, v1

    def closing(self, next_force_n: float) -> float:
        """The rule's worst closing from one step ahead under ``next_force_n``, m."""
        v_dead, dead, _ = self.state(next_force_n)
        return self.rule.closing(self.s1, v_dead, self.s_l, self.v_l, dead)

    def fits(self, next_force_n: float) -> bool:
        return self.room >= 0.0 and self.closing(next_force_n) <= self.room


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
        self._targets: dict[int, list] = {}

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

    def line_speed(self, obs: Observation, v_cap_mps: float = math.inf) -> float:
        """The speed the line allows for the next step, m/s (at most ``v_cap_mps``): approaching its own
        stop (``Observation.next_stop_m``) the guaranteed service-brake curve to it, and everywhere
        :meth:`limit_speed`."""
        _, service = self._rule(obs.profile)
        s, dt = obs.ego.position_m, obs.step_s
        v = v_cap_mps
        if obs.next_stop_m is not None:
            v = min(v, service.permitted_speed(s, obs.next_stop_m, 0.0, 1.5 * dt, obs.ego.speed_mps))
        return min(v, self.limit_speed(obs, service))

    def limit_speed(self, obs: Observation, service: RouteBraking) -> float:
        """The permitted speed of the line: the limit under the whole train now, and the guaranteed
        service-brake curve to every lower limit ahead (as the supervision of SUMO-driven trains), m/s."""
        prof, s, v, dt = obs.profile, obs.ego.position_m, obs.ego.speed_mps, obs.step_s
        v_perm = min(prof.speed_limit_train(s, self.follower.length_m), self.follower.max_speed_ms)
        targets = self._targets.get(id(prof))
        if targets is None:
            targets = self._targets = {id(prof): prof.restriction_targets()}
            targets = self._targets[id(prof)]
        reach = service.stopping_distance(s, v, 2.0 * dt) + 50.0
        for s_t, v_t in targets:
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
        # 1. the line: its limits and the follower's own stop (braking curves on speed)
        v_line = self.line_speed(obs, v_cmd + 1e-6)
        if v_cmd > v_line + 1e-9:
            force = max(min(self._force_for(p, v, max(v_line, v_floor), dt, grad, tf), force), f_eb)
        # 2. the separation: the force one step ahead keeps the relative-braking rule after its build-up
        build, f0 = self.build_up, float(obs.ego.force_n)
        sep = self.separation(obs)
        emergency = cmd.emergency or force < -build.service_force_n(v) - 1e-6
        if not sep.fits(build.next_force(f0, force, dt, emergency, v)):
            floor = build.next_force(f0, f_eb, dt, True, v)
            if sep.fits(floor):  # the largest force one step ahead that fits, and the command that gives it
                lo, hi = floor, build.next_force(f0, force, dt, emergency, v)
                tol = 1e-3 * (hi - lo)  # the search's resolution (it keeps the side that passes)
                while hi - lo > tol:
                    mid = 0.5 * (lo + hi)
                    lo, hi = (mid, hi) if sep.fits(mid) else (lo, mid)
                u = build.command_for(f0, lo, dt)
                service = -build.service_force_n(v)
                if u < service and build.next_force(f0, service, dt, False, v) <= lo:
                    u = service  # the service brake gets there too (the jerk limit binds): no emergency brake
                force = max(min(u, force), f_eb)
            else:  # outside the rule already: brake as hard as the train can, to a stand (and hold it there)
                force = max(min(self._force_for(p, v, v_floor, dt, grad, tf), force), f_eb)
        if force >= force_in - 1e-9:
            self.last_speed_mps = v_cmd
            return cmd if force_in >= f_eb else replace(cmd, force_n=f_eb)
        self.interventions += 1
        self.last_speed_mps = v_out = max(v_floor, v + dt * float(acceleration(p, v, force, grad, tf)))
        emergency = cmd.emergency or force < -build.service_force_n(v) - 1e-6
        return replace(cmd, force_n=force, emergency=emergency, info={**cmd.info, "guard_speed_mps": v_out})

    @staticmethod
    def _force_for(p, v: float, v_target: float, dt: float, grad: float, tf: float) -> float:
        """The force that gives ``v_target`` after one step (eq. 1b solved for u), N."""
        return p.mass_kg * p.rotating_mass_factor * (v_target - v) / dt + float(running_resistance(p, v, tf)) + float(gradient_force(p, grad))


__all__ = ["GuardConfig", "load_guard", "PredecessorEstimate", "predecessor_estimate", "BrakeBuildUp", "NextStepSeparation", "SeparationGuard"]
