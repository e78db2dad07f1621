"""Control-barrier-function safety layer of Terlizzi, Liuzza & Glielmo (2024), §V–§VI-C.

* :class:`CBFConfig`, the barrier eq. 15 (:class:`BarrierModel`, the paper's form with a fixed d)
  and the barrier on the separation model (:class:`SeparationBarrier`, the default:
  ``distance: model``, ``leader_braking: emergency``) — :mod:`vcsumo.control.cbf_barrier`;
* :class:`LeaderRLPPredictor` (Algorithm 1) and :class:`DelayEstimator` (Algorithm 3) —
  :mod:`vcsumo.control.cbf_rlp`;
* :func:`emergency_force_n` — the follower emergency controller K_E^F (Definition 11);
* :class:`CBFSupervisor` — Algorithm 2 (safety control) with the T^max rule of eq. 18.  It wraps
  *any* nominal controller through the :class:`~vcsumo.control.base.Supervisor` protocol:
  ``filter(obs, nominal) -> Command`` passes the nominal command through unless the robust barrier
  b(x̲^L(t), x^F(t)) reaches zero or no packet arrived for T^max, and then enforces K_E^F.

Sampled-data implementation (the paper's Algorithm 2 is continuous-time; here it runs once per
control step Δt):

* the check is made on the current state *and* one step ahead, with the leader RLP at t + Δt and
  the follower's RUP (eq. 13) after one step under the nominal command, so the nominal command is
  only applied when it keeps the robust barrier negative until the next check;
* the follower's stopping distance gets the Euler integration error of a Δt-sampled braking
  (x2·Δt/2 + ē·Δt²/8 in the paper's form, Δt/2 of dead time in the model's), and the leader's RLP
  position is lowered by x̲2·Δt (covers plants that advance the position with the new speed, like
  SUMO).  ``sampled_data_margin: false`` gives the paper's continuous-time formula.

Route model of the paper's form: eq. 15 is evaluated with stopping points (eq. 41–44).  By default
(``stop_model: profile``) they are the exact worst-case stopping points on the route's
train-averaged gradient (:class:`~vcsumo.control.proxies.StopIntegral`), which equal
x1 + x2²/(2e) of eq. 15 on a constant grade but, unlike the worst grade over a window ahead
(σ_sup/σ_inf of eq. 12–13), make b continuous and monotone in the state — Definition 1 asks for a
continuous b, and the proof of Theorem VI.1 needs b(x^L, x^F) ≤ b(x̲^L, x^F) whenever x^L ≥ x̲^L.
``stop_model: window`` keeps the paper's literal form.  The model's form integrates both trains'
braking over the route's gradient profile (:class:`~vcsumo.signalling.separation.RouteBraking`).

Deviations needed for a plant with grades and a power-limited brake (all on the safe side):
K_E^F demands the strongest brake of the box and holds it at standstill (see
:func:`emergency_force_n`; with ``distance: model`` the strongest emergency brake, flagged
``emergency``); a force lag or jerk limit of the follower is bounded by a dead time from the force
it may be applying.

The *true* barrier (the barrier on the true states of both trains) is what the safety guarantee is
about (Theorem VI.1); the supervisor records it whenever the observation carries the sensed gap and
speed of the predecessor (it never uses them for control).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path

from vcsumo.control.base import Command, Message, Observation
from vcsumo.control.cbf_barrier import (  # noqa: F401 - the barrier's names are part of this module's interface
    BarrierModel, CBFConfig, SeparationBarrier, barrier, barrier_from_stops, level_route, load_cbf_config, model_leader_braking, model_safety_distance_m,
    sampled_stop_margin_m,
)
from vcsumo.control.cbf_rlp import DelayEstimator, LeaderRLPPredictor, RLPBranch  # noqa: F401 - re-exported
from vcsumo.control.proxies import BoxBounds
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel


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


def emergency_brake_force_n(follower: BoxBounds) -> float:
    """K_E^F of ``distance: model``: the strongest emergency brake force of any train in the box,
    N (negative); the command is flagged ``emergency``, so every true train applies its emergency
    brake (the separation model's guaranteed emergency deceleration is the bottom of that range)."""
    return -follower.mass_high_kg * max(follower.emergency_decel_high_mps2, follower.brake_decel_high_mps2)



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
    first_true_barrier_m: float = math.nan
    """The true barrier at the first step the predecessor was sensed, m (kept without the history)."""

    def true_barrier(self, b_true: float) -> None:
        """Count a true barrier value (the first one and the largest)."""
        if math.isnan(self.first_true_barrier_m):
            self.first_true_barrier_m = b_true
        self.max_true_barrier_m = max(self.max_true_barrier_m, b_true)


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

    def __init__(self, leader: RollingStock | BoxBounds, follower: RollingStock | BoxBounds, config: CBFConfig | None = None, leader_id: str | None = None,
                 record: bool = True, keep_resets: int = 2, model: SeparationModel | None = None):
        self.cfg = config or CBFConfig()
        self.separation = model or SeparationModel(load_assumptions())
        """The separation model (its assumption set) of ``distance: model`` and of the leader's emergency range."""
        a = self.separation.assumptions
        self.leader_bounds = leader if isinstance(leader, BoxBounds) else BoxBounds.from_stock(leader, a)
        self.follower_bounds = follower if isinstance(follower, BoxBounds) else BoxBounds.from_stock(follower, a)
        self.leader_stock = leader if isinstance(leader, RollingStock) else None
        self.follower_stock = follower if isinstance(follower, RollingStock) else None
        self.model_mode = self.cfg.distance == "model"
        if self.model_mode and (self.leader_stock is None or self.follower_stock is None):
            raise ValueError("distance 'model' needs the two trains' rolling stock (their braking on the separation model)")
        self.leader_id = leader_id
        self.record = record
        self.keep_resets = keep_resets
        self._models: dict[int, BarrierModel | SeparationBarrier] = {}
        self._predictor: LeaderRLPPredictor | None = None
        self._profile_key: int | None = None
        self._model: BarrierModel | SeparationBarrier | None = None
        self.stats = SupervisorStats()
        self.history = _History()
        self._in_emergency = False
        self._commands: deque[tuple[float, float]] = deque()
        fb = self.follower_bounds
        self._command_horizon_s = 5.0 * fb.traction_lag_s + fb.actuation_delay_s() + 1.0
        self._traction_cap_n = fb.mass_high_kg * fb.accel_high_mps2

    @classmethod
    def from_files(cls, leader: str | Path, follower: str | Path, config: str | Path | None = None, leader_id: str | None = None) -> "CBFSupervisor":
        """Build from rolling-stock names/paths and a CBF YAML file (default ``controllers/cbf.yaml``)."""
        from vcsumo.control.params import resolve_params
        from vcsumo.rolling_stock import load_rolling_stock

        return cls(load_rolling_stock(leader), load_rolling_stock(follower), load_cbf_config(resolve_params(config, "cbf", "config")), leader_id)

    # ---------------------------------------------------------------------------------------
    @property
    def safety_distance_m(self) -> float:
        """d: the distance the barrier keeps between the leader's rear and the follower's front, m."""
        if self.model_mode:
            return model_safety_distance_m(self.separation, self.cfg)
        return self.cfg.safety_distance_m + 2.0 * self.cfg.position_error_m

    def model_for(self, profile: RouteProfile | None) -> BarrierModel | SeparationBarrier:
        """The barrier on a route (one per route, kept)."""
        key = id(profile)
        m = self._models.get(key)
        if m is None:
            if self.model_mode:
                m = SeparationBarrier(self.leader_stock, self.follower_stock, self.follower_bounds, self.cfg, self.separation, profile)
            else:
                m = BarrierModel(self.leader_bounds, self.follower_bounds, self.cfg, profile)
            self._models[key] = m
        return m

    def required_gap_m(self, profile: RouteProfile | None, s_leader_m: float, v_leader_mps: float, s_follower_m: float, v_follower_mps: float,
                       force_n: float | None = None) -> float:
        """Front-to-rear gap at which the barrier on these (true) states is 0, m (bisection for the paper's form)."""
        m = self.model_for(profile)
        if isinstance(m, SeparationBarrier):
            return m.required_gap_m(s_leader_m, v_leader_mps, s_follower_m, v_follower_mps, force_n)
        L = m.leader_length_m
        s_l = s_leader_m

        def b(gap: float) -> float:
            return m.value(s_l, v_leader_mps, s_l - L - gap, v_follower_mps)[0]

        lo, hi = 0.0, max(m.d_m, 1.0)
        while b(hi) > 0.0 and hi < 1e6:
            lo, hi = hi, 2.0 * hi
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if b(mid) > 0.0 else (lo, mid)
        return hi

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
        t = obs.time_s
        msg = self._leader_message(obs)
        pred.update(msg)
        s_f, v_f = obs.ego.position_m, max(0.0, obs.ego.speed_mps)
        stats = self.stats
        stats.steps += 1
        cfg = self.cfg

        b_true = math.nan
        sensed = obs.sensed_gap_m is not None and obs.sensed_speed_mps is not None
        if not pred.branches:
            if sensed:  # before the predecessor's first message: with the force the follower applies, as once it has one
                s_l_true = s_f + obs.sensed_gap_m + self.leader_bounds.length_m
                if isinstance(model, SeparationBarrier):  # (until 2026-11-28 at full traction: a run that never closed in counted a breach)
                    f_now = self._applied_force_bound(t, obs.ego.force_n) if model.follower_delay_full_s > 0 else None
                    b_true = model.value(s_l_true, max(0.0, obs.sensed_speed_mps), s_f, v_f, f_now)[0]
                else:
                    b_true = model.value(s_l_true, max(0.0, obs.sensed_speed_mps), s_f, v_f)[0]
                stats.true_barrier(b_true)
            if cfg.brake_without_leader_data and obs.predecessor is not None:
                return self._emergency(obs, nominal, math.nan, b_true, "no-data", math.nan)
            self._log(t, math.nan, b_true, False, "no-data", math.nan)
            self._in_emergency = False
            self._remember(t, nominal.force_n)
            return nominal

        if isinstance(model, SeparationBarrier):
            b_now, b_chk, b_true = self._barriers_model(obs, nominal, model, pred, s_f, v_f, sensed)
        else:
            b_now, b_chk, b_true = self._barriers_paper(obs, nominal, model, pred, s_f, v_f, sensed)
        stats.max_robust_barrier_m = max(stats.max_robust_barrier_m, b_now)
        if sensed:
            stats.true_barrier(b_true)
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

    def _barriers_paper(self, obs: Observation, nominal: Command, model: BarrierModel, pred: LeaderRLPPredictor, s_f: float, v_f: float,
                        sensed: bool) -> tuple[float, float, float]:
        """(robust barrier now, the larger of now and one step ahead, true barrier) of eq. 15."""
        cfg = self.cfg
        t, dt = obs.time_s, obs.step_s
        b_true = math.nan
        dt_m = dt if cfg.sampled_data_margin else 0.0
        Ld = model.leader_length_m + model.d_m  # L^L + d of eq. 15
        # follower RUP (eq. 13) after one step of the nominal command (with a force lag or jerk limit
        # the applied force lies between the present one and the command)
        actuated = model.follower_delay_full_s > 0 or cfg.actuation_delay_s is not None
        f_now = self._applied_force_bound(t, obs.ego.force_n) if actuated else None
        u_cmd = min(nominal.force_n, self._traction_cap_n)  # no train in the box applies more traction
        u_pred = u_cmd if not actuated else max(u_cmd, f_now)
        f_next = None if not actuated else u_pred
        v_f1 = max(0.0, v_f + model.follower.rup_step_accel(s_f, v_f, u_pred, dt) * dt)
        s_f1 = s_f + max(v_f, v_f1) * dt
        # S^F at the present state once: with the sampled-data margin for the robust barrier, without
        # it for the true one (follower_stop(s_f, v_f, dt_m, f_now) and follower_stop(s_f, v_f, 0, f_now))
        stop_f_cont, v_brake, e_f = model.follower_stop_parts(s_f, v_f, f_now)
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
            stop_f1, v_brake, e_f = model.follower_stop_parts(s_f1, v_f1, f_next)
            if dt_m > 0 and v_brake > 0.0:
                stop_f1 += sampled_stop_margin_m(v_brake, max(e_f, 0.0), dt_m)
            b_next = max(Ld - ((stop_l1 - shift) - stop_f1), Ld - ((pos_l1 - shift) - s_f1))
            b_chk = max(b_now, b_next)
        if sensed:
            # eq. 15 on the true states (Theorem VI.1), continuous-time form
            s_l_true = s_f + obs.sensed_gap_m + self.leader_bounds.length_m
            v_l_true = max(0.0, obs.sensed_speed_mps)
            b_true = max(Ld - (pred.stop_of(s_l_true, v_l_true) - stop_f_cont), Ld - (s_l_true - s_f))
        return b_now, b_chk, b_true

    def _barriers_model(self, obs: Observation, nominal: Command, model: SeparationBarrier, pred: LeaderRLPPredictor, s_f: float, v_f: float,
                        sensed: bool) -> tuple[float, float, float]:
        """(robust barrier now, the larger of now and one step ahead, true barrier) on the separation
        model: the lowest barrier over the kept RLP resets (each a lower bound of the leader)."""
        cfg = self.cfg
        t, dt = obs.time_s, obs.step_s
        dt_m = dt if cfg.sampled_data_margin else 0.0
        actuated = model.follower_delay_full_s > 0
        f_now = self._applied_force_bound(t, obs.ego.force_n) if actuated else None
        u_cmd = min(nominal.force_n, self._traction_cap_n)  # no train in the box applies more traction
        u_pred = u_cmd if not actuated else max(u_cmd, f_now)
        b_now = min(model.value(s_l, v_l, s_f, v_f, f_now, dt_m)[0] for s_l, v_l in pred.states(t))
        b_chk = b_now
        if cfg.lookahead:  # the follower's RUP (eq. 13) after one step of the nominal command
            v_f1 = max(0.0, v_f + model.follower.rup_step_accel(s_f, v_f, u_pred, dt) * dt)
            s_f1 = s_f + max(v_f, v_f1) * dt
            b_next = min(model.value(s_l, v_l, s_f1, v_f1, u_pred if actuated else None, dt_m)[0] for s_l, v_l in pred.states(t + dt))
            b_chk = max(b_now, b_next)
        b_true = math.nan
        if sensed:  # on the true states (Theorem VI.1), continuous-time form
            s_l_true = s_f + obs.sensed_gap_m + self.leader_bounds.length_m
            b_true = model.value(s_l_true, max(0.0, obs.sensed_speed_mps), s_f, v_f, f_now)[0]
        return b_now, b_chk, b_true

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
        return min(max(reported_n, recent), max(reported_n, self._traction_cap_n))

    def _emergency(self, obs: Observation, nominal: Command, b_now: float, b_true: float, reason: str, age: float) -> Command:
        if not self._in_emergency:
            self.stats.emergency_activations += 1
            if reason == "t-max":
                self.stats.tmax_activations += 1
        self._in_emergency = True
        self.stats.interventions += 1
        self.stats.emergency_time_s += obs.step_s
        self._log(obs.time_s, b_now, b_true, True, reason, age)
        u = emergency_brake_force_n(self.follower_bounds) if self.model_mode else emergency_force_n(self.follower_bounds, max(0.0, obs.ego.speed_mps))
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

    def true_barrier(self, profile: RouteProfile | None, s_leader_m: float, v_leader_mps: float, s_follower_m: float, v_follower_mps: float,
                     force_n: float | None = None) -> float:
        """The barrier on given true states, continuous-time form, the follower applying ``force_n``
        (None: full traction) — what Theorem VI.1 keeps ≤ 0 (for analysis and the safety campaign).

        The supervisor keeps d + 2·e_s between *measured* positions (Felez eq. 9, ``position_error_m``);
        between true positions the barrier protects d, so the allowance 2·e_s is taken off here."""
        m = self.model_for(profile)
        if isinstance(m, SeparationBarrier):
            b = m.value(s_leader_m, v_leader_mps, s_follower_m, v_follower_mps, force_n)[0]
        else:
            b = barrier_from_stops(s_leader_m, m.leader_stop(s_leader_m, v_leader_mps), s_follower_m, m.follower_stop(s_follower_m, v_follower_mps, 0.0, force_n),
                                   m.leader_length_m, m.d_m)[0]
        return b - 2.0 * self.cfg.position_error_m
