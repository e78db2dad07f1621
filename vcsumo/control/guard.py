"""The separation guard: the last filter stage of every VC follower, on forces.

:class:`SeparationGuard` sits between the follower's controller (and its supervisor) and the
train, in the SUMO loop and in the offline loop alike (:class:`~vcsumo.control.stack.FollowerStack`).
``limit(obs, cmd)`` returns the largest force not above ``cmd.force_n`` whose one-step speed
(eq. 1b on the train model, with the gradient and tunnel factor where the train is) stays at or
below the **guard speed** — never below the emergency brake force −M·a_eb.  Interventions (the
command would have exceeded the guard speed) are counted; a limited force beyond the service
brake envelope is flagged ``emergency`` (the offline plant then applies it with the emergency
brake, as the SUMO loop always allows the follower).

What the guard knows of the predecessor is only what is on board (:func:`predecessor_estimate`):
the sensed gap and speed when the Observation carries them (the predecessor is the train seen
ahead), else the state in the latest message the channel delivered (with its age), else nothing —
then the predecessor may be standing at the follower's front.

The guard speed (:meth:`SeparationGuard.speed_limit`) is the relative-braking rule of the one
separation model (:class:`vcsumo.signalling.separation.RelativeBraking`, under the stack's named
assumption set): the predecessor is placed where it is at the least, having braked as hard as it
can (top of its box, its resistance, up-grades) since the time stamp of what the follower knows of
it; from there both trains brake on the route's gradients — the follower with its guaranteed
brake (bottom of its box, descents) after the dead time (reaction + half the brake build-up) and
1.5 steps, the predecessor with its strongest — and the follower's speed for the next step is the
largest that keeps margin + the position errors of both trains (+ the stack's d_min beyond that)
between them at every moment (also when the follower brakes harder than the predecessor can).
Approaching its own stop (``Observation.next_stop_m``) the follower keeps to its guaranteed
service-brake curve to the stop point, and everywhere to the line's permitted speed: the limit under
the whole train and the guaranteed service-brake curve to every lower limit ahead (the same curves
the supervision gives the trains SUMO drives).

By default the guard trusts only what the channel delivered (:class:`GuardConfig` ``sensor``: an
on-board sensor of the train ahead — SUMO's exact gap and speed within its look-ahead, no error
model — may be switched on explicitly).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

from pydantic import Field

from vcsumo.config import StrictModel, load_model
from vcsumo.control.base import Command, Observation
from vcsumo.dynamics import acceleration, brake_force_limit, gradient_force, running_resistance
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel, leader_worst_state


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
# The filter stage


class SeparationGuard:
    """Force filter ``limit(obs, cmd) -> Command`` keeping the guard speed (see the module doc).

    ``follower``/``predecessor``: the two trains' rolling stock (their models and uncertainty boxes);
    ``d_min_m``: the stack's minimum safe gap (kept where it exceeds the model's margin and position
    errors); ``model``: the separation model (its assumption set); ``config``: whether a sensor is
    trusted.  ``interventions`` counts the steps it lowered the command; ``last_speed_mps`` is the
    latest step's guard speed where it bound (else the speed the command reaches: the guard is only
    searched as far as asked) and ``last_force_in_n`` its incoming force."""

    def __init__(self, follower: RollingStock, predecessor: RollingStock, d_min_m: float, config: GuardConfig | None = None,
                 model: SeparationModel | None = None):
        self.follower = follower
        self.predecessor = predecessor
        self.follower_params = follower.params()
        self.predecessor_params = predecessor.params()
        self.d_min_m = float(d_min_m)
        self.cfg = config or GuardConfig()
        self.model = model or SeparationModel(load_assumptions())
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

    def speed_limit(self, obs: Observation, pred: PredecessorEstimate, v_cap_mps: float = math.inf) -> float:
        """The guard speed for the next step, m/s (at most ``v_cap_mps``: only as far as asked)."""
        rule, service = self._rule(obs.profile)
        s, dt = obs.ego.position_m, obs.step_s
        v_max = min(v_cap_mps, 200.0)
        dead = self.model.dead_time_s + 1.5 * dt
        if pred.source == "none":  # nothing known: the predecessor may stand at the follower's front
            v_guard = 0.0
        else:
            a_l = rule.leader.decel_at(pred.front_m, pred.speed_mps)
            moved, v_l = leader_worst_state(pred.speed_mps, a_l, pred.age_s)
            s_l = pred.front_m + moved
            gap = s_l - self.predecessor.length_m - s - max(0.0, self.d_min_m - self.model.margin_m)
            v_guard = rule.max_speed(s, gap, s_l, v_l, dead, v_max)
        if obs.next_stop_m is not None:  # its own stop: the guaranteed service-brake curve to it
            v_guard = min(v_guard, service.permitted_speed(s, obs.next_stop_m, 0.0, 1.5 * dt, obs.ego.speed_mps))
        return min(v_guard, self.limit_speed(obs, service))

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
        v_floor = max(0.0, v + dt * float(acceleration(p, v, f_eb, grad, tf)))
        v_cmd = max(v_floor, v + dt * float(acceleration(p, v, force_in, grad, tf)))
        v_guard = self.speed_limit(obs, predecessor_estimate(obs, self.predecessor_params.length_m, self.cfg.sensor), v_cmd + 1e-6)
        self.last_speed_mps, self.last_force_in_n = v_guard, force_in
        if v_cmd <= v_guard + 1e-9:
            return cmd if force_in >= f_eb else replace(cmd, force_n=f_eb)
        self.interventions += 1
        v_target = max(v_guard, v_floor)
        # the force that gives v_target after one step (eq. 1b solved for u)
        force = p.mass_kg * p.rotating_mass_factor * (v_target - v) / dt + float(running_resistance(p, v, tf)) + float(gradient_force(p, grad))
        force = max(min(force, force_in), f_eb)
        emergency = cmd.emergency or force < -float(brake_force_limit(p, max(v, 0.0))) - 1e-6
        return replace(cmd, force_n=force, emergency=emergency, info={**cmd.info, "guard_speed_mps": v_guard})


__all__ = ["GuardConfig", "load_guard", "PredecessorEstimate", "predecessor_estimate", "SeparationGuard"]
