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

The guard speed (:func:`guard_speed_limit`, the one place of its maths) is today the nominal
relative-braking-distance condition (Felez et al. eq. 12m, Wu et al. eq. 3.1): after one step the
follower must be able to stop, braking at its guaranteed deceleration (:func:`guaranteed_decel`),
at least d_min behind the point where the predecessor would stop braking at its strongest
deceleration (:func:`strongest_decel`) from the state it was last known in.  The decelerations
(emergency or service, for each train) are :class:`GuardConfig` (``controllers/guard.yaml``).
Approaching its own stop (``Observation.next_stop_m``) the follower keeps to its service brake and
the stop point is an obstacle too.  The formula assumes nominal braking of both trains, no brake
build-up and no position error; the robust separation model replaces it in one place
(:meth:`SeparationGuard.speed_limit`: the guard holds both trains' rolling stock, the observation
gives the route, the step and the predecessor's last known state with its age).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

from pydantic import Field

from vcsumo.config import StrictModel, load_model
from vcsumo.control.base import Command, Observation
from vcsumo.dynamics import TrainParams, acceleration, brake_force_limit, gradient_force, running_resistance
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.units import G


class GuardConfig(StrictModel):
    """Decelerations of the relative-braking guard (the last filter stage of every VC controller)."""

    leader_decel: str = Field(default="emergency", pattern="^(emergency|service)$", description="Predecessor's worst case: its emergency or service deceleration")
    follower_decel: str = Field(default="emergency", pattern="^(emergency|service)$", description="Deceleration the follower's guard may rely on (its own emergency or service brake)")


def load_guard(spec: str | Path | None = None, field: str | None = "--guard", base_dir: str | Path | None = None) -> GuardConfig:
    """Guard settings: a YAML file or a name in controllers/ (default ``guard``)."""
    from vcsumo.control.params import resolve_params

    return load_model(GuardConfig, resolve_params(spec, "guard", field, base_dir, kind="guard"))


# -------------------------------------------------------------------------------------------
# The maths (one place)


def guard_speed(s_f_m: float, b_f_mps2: float, dt_s: float, s_l_m: float, v_l_mps: float, leader_length_m: float, a_l_mps2: float, d_min_m: float) -> float:
    """Highest follower speed for the next step that keeps the relative braking distance, m/s.

    Worst case for the predecessor: braking at ``a_l`` from the state (s_l, v_l) it was last known
    in — sensed now or communicated earlier; the stopping point s_l + v_l²/(2·a_l) is the same
    whenever after that moment the braking started, so old information is still a valid bound.
    The follower runs one step (Δt) at the commanded speed v and then brakes at ``b_f`` with
    SUMO's semi-implicit Euler update, which covers v²/(2·b_f) + ½·v·Δt:
    1.5·v·Δt + v²/(2·b_f) ≤ s_l + v_l²/(2·a_l) − L_l − d_min − s_f.
    """
    stop_l = s_l_m + v_l_mps * v_l_mps / (2.0 * a_l_mps2)
    room = stop_l - leader_length_m - d_min_m - s_f_m
    if room <= 0.0:
        return 0.0
    k = 1.5 * dt_s
    return b_f_mps2 * (-k + math.sqrt(k * k + 2.0 * room / b_f_mps2))


def guaranteed_decel(p: TrainParams, v_mps: float, decel_mps2: float, grad_low: float) -> float:
    """Deceleration a train certainly reaches braking with force M·decel (eq. 1b): resistance at
    least A, gradient at worst the steepest downhill ahead, m/s²."""
    return (p.mass_kg * decel_mps2 + p.davis_a_n + p.mass_kg * G * min(grad_low, 0.0)) / (p.mass_kg * p.rotating_mass_factor)


def strongest_decel(p: TrainParams, v_mps: float, decel_mps2: float, grad_high: float, tunnel_factor: float = 1.0) -> float:
    """Hardest deceleration a train may show braking with force M·decel at speed v (eq. 1b):
    its resistance at v and the steepest uphill ahead help it, m/s²."""
    return (p.mass_kg * decel_mps2 + float(running_resistance(p, v_mps, tunnel_factor)) + p.mass_kg * G * max(grad_high, 0.0)) / p.mass_kg


@dataclass(frozen=True)
class PredecessorEstimate:
    """What the follower knows of its predecessor: front position (ego route frame, m), speed (m/s)
    and the age of that knowledge (s; 0 for a sensed state, +inf when nothing is known)."""

    front_m: float
    speed_mps: float
    age_s: float
    source: str
    """``sensed``, ``message`` or ``none`` (then: standing at the follower's front)."""


def predecessor_estimate(obs: Observation, predecessor_length_m: float) -> PredecessorEstimate:
    """The best information on board: the sensed gap and speed, else the latest delivered message,
    else "the predecessor may be standing at the follower's front"."""
    s = obs.ego.position_m
    if obs.sensed_gap_m is not None and obs.sensed_speed_mps is not None:
        return PredecessorEstimate(s + obs.sensed_gap_m + predecessor_length_m, obs.sensed_speed_mps, 0.0, "sensed")
    m = obs.received.get(obs.predecessor) if obs.predecessor is not None else None
    if m is not None and math.isfinite(m.state.position_m) and math.isfinite(m.state.speed_mps):
        return PredecessorEstimate(m.state.position_m, m.state.speed_mps, max(0.0, obs.time_s - m.state.time_s), "message")
    return PredecessorEstimate(s, 0.0, math.inf, "none")


def guard_speed_limit(follower: TrainParams, predecessor: TrainParams, profile: RouteProfile, s_m: float, v_mps: float, pred: PredecessorEstimate,
                      step_s: float, d_min_m: float, cfg: GuardConfig, stop_m: float | None = None) -> float:
    """The guard speed: highest follower speed for the next step, m/s (see the module doc).

    ``follower``/``predecessor``: the trains' nominal models; ``profile``: the follower's route
    (the predecessor is in the same frame); (s_m, v_mps): the follower's front and speed; ``pred``:
    the predecessor's last known state (:func:`predecessor_estimate`); ``stop_m``: the follower's
    own stop when it is near (None: none)."""
    p, pp = follower, predecessor
    near_stop = stop_m is not None
    dec_f = p.emergency_brake_decel_mps2 if (cfg.follower_decel == "emergency" and not near_stop) else p.service_brake_decel_mps2
    dec_l = pp.emergency_brake_decel_mps2 if cfg.leader_decel == "emergency" else pp.service_brake_decel_mps2
    v = v_mps
    s_l, v_l = pred.front_m, pred.speed_mps
    g_low, _ = profile.gradient_range(s_m - p.length_m, s_m + v * v / (2 * dec_f) + 2 * v * step_s + 10.0)
    b_f = guaranteed_decel(p, v, dec_f, g_low)
    _, g_high = profile.gradient_range(s_l - pp.length_m, s_l + v_l * v_l / (2 * dec_l) + 10.0)
    a_l = strongest_decel(pp, v_l, dec_l, g_high, 1.5)
    v_guard = guard_speed(s_m, b_f, step_s, s_l, v_l, pp.length_m, a_l, d_min_m)
    if near_stop:
        b_serv = guaranteed_decel(p, v, p.service_brake_decel_mps2, g_low)
        v_guard = min(v_guard, guard_speed(s_m, b_serv, step_s, stop_m, 0.0, 0.0, 1.0, 1.0))
    return v_guard


# -------------------------------------------------------------------------------------------
# The filter stage


class SeparationGuard:
    """Force filter ``limit(obs, cmd) -> Command`` keeping the guard speed (see the module doc).

    ``follower``/``predecessor``: the two trains' rolling stock (their models and uncertainty boxes);
    ``d_min_m``: the stack's minimum safe gap; ``config``: which decelerations the guard assumes.
    ``interventions`` counts the steps it lowered the command; ``last_speed_mps`` and
    ``last_force_in_n`` are the latest step's guard speed and incoming force."""

    def __init__(self, follower: RollingStock, predecessor: RollingStock, d_min_m: float, config: GuardConfig | None = None):
        self.follower = follower
        self.predecessor = predecessor
        self.follower_params = follower.params()
        self.predecessor_params = predecessor.params()
        self.d_min_m = float(d_min_m)
        self.cfg = config or GuardConfig()
        self.interventions = 0
        self.last_speed_mps = math.nan
        self.last_force_in_n = math.nan

    def speed_limit(self, obs: Observation, pred: PredecessorEstimate) -> float:
        """The guard speed for this step, m/s — the one call into the separation rule (today
        :func:`guard_speed_limit` on the nominal models)."""
        return guard_speed_limit(self.follower_params, self.predecessor_params, obs.profile, obs.ego.position_m, obs.ego.speed_mps, pred,
                                 obs.step_s, self.d_min_m, self.cfg, obs.next_stop_m)

    def limit(self, obs: Observation, cmd: Command) -> Command:
        p, prof = obs.params, obs.profile
        s, v, dt = obs.ego.position_m, obs.ego.speed_mps, obs.step_s
        v_guard = self.speed_limit(obs, predecessor_estimate(obs, self.predecessor_params.length_m))
        grad = prof.mean_gradient(s, p.length_m)
        tf = prof.tunnel_factor_at(s)
        f_eb = -p.mass_kg * p.emergency_brake_decel_mps2  # the train brakes at most with its emergency brake
        force_in = float(cmd.force_n)
        self.last_speed_mps, self.last_force_in_n = v_guard, force_in
        v_floor = max(0.0, v + dt * float(acceleration(p, v, f_eb, grad, tf)))
        v_cmd = max(v_floor, v + dt * float(acceleration(p, v, force_in, grad, tf)))
        if v_cmd <= v_guard + 1e-9:
            return cmd if force_in >= f_eb else replace(cmd, force_n=f_eb)
        self.interventions += 1
        v_target = max(v_guard, v_floor)
        # the force that gives v_target after one step (eq. 1b solved for u)
        force = p.mass_kg * p.rotating_mass_factor * (v_target - v) / dt + float(running_resistance(p, v, tf)) + float(gradient_force(p, grad))
        force = max(min(force, force_in), f_eb)
        emergency = cmd.emergency or force < -float(brake_force_limit(p, max(v, 0.0))) - 1e-6
        return replace(cmd, force_n=force, emergency=emergency, info={**cmd.info, "guard_speed_mps": v_guard})


__all__ = ["GuardConfig", "load_guard", "guard_speed", "guaranteed_decel", "strongest_decel", "PredecessorEstimate", "predecessor_estimate",
           "guard_speed_limit", "SeparationGuard"]
