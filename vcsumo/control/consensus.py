"""Consensus-based control (CBC) of a virtually coupled convoy (Wu et al. survey §IV.A).

Model.  The follower is the third-order "position–velocity–acceleration" model of eq. 2.7–2.8,
ẋ = v, v̇ = a, τ ȧ = u − a, where u is the desired acceleration and τ the traction lag (eq. 1c of
vcsumo's train model).  The desired acceleration is turned into a traction/brake force with the
shared train model (eq. 2.2 / vcsumo eq. 1b inverted): F = M·ρ·u + R(v) + M·g·i  — the low-level
step the survey describes after eq. 2.4 ("once u is determined, the actual T/B force can be
calculated based on the pre-saved track information and resistance characteristics").

Law (``law: consensus``), for follower i with neighbours j ∈ 𝒩_i ∪ {0} (weights a_ij, eq. 4.1)::

    e^x_ij = x_i − x̂_j + δ_ij          δ_ij = desired x_j − x_i (gaps of eq. 3.1, lengths, eq. 3.10)
    e^v_ij = v_i − v_j + δ̇_ij          e^a_ij = a_i − a_j + δ̈_ij
    u_i = c_ff·Σ_j w̄_ij (a_j − δ̈_ij)                          (neighbour acceleration feed-forward)
          − Σ_j w_ij sat_Δ(k_x e^x_ij + k_v e^v_ij + k_a e^a_ij)  (eq. 4.1, K = [k_x, k_v, k_a]; eq. 4.4 Δ)
          − k_v0 (v_i − v_0) − k_a0 a_i                           (eq. 4.3 / 4.5 reference-speed damping)

with w_ij = a_ij / Σ_j a_ij (the normalisation of eq. 4.3; ``normalize: false`` gives eq. 4.1's
plain a_ij), w̄_ij = a_ij / Σ_j a_ij, and x̂_j the neighbour's position *at the message's time
stamp* plus the eq. 4.3 delay compensation τ_ij·v_0 (τ_ij = t − sent time: the age of what the
channel delivered).  sat_Δ (eq. 4.4) is applied per link when ``link_bound_mps2`` is set; the
total is always saturated to the train's traction/brake envelope (eq. 4.4's input bound, here the
speed-dependent limits of ``vcsumo.dynamics.traction_limit``/``brake_force_limit``, survey Fig. 2(a)).

Variants (predecessor–follower laws, ``topology: PF``):

* ``liu_tanh`` (eq. 4.10):  u = k1·e^sp − k2·[k3 + k4·tanh(k5·d_{t−τ} − k6)]
* ``zhou_tanh`` (eq. 4.11): u = k1·tanh(e^sp/ℓ) − k2·tanh(e^sv/ν) + k3·v/(v − v_max)

(signs written for vcsumo's frame, where a gap larger than the reference must make the follower
accelerate and the speed-limit term must brake; see the notes on those functions).

Modules: the settings are in :mod:`vcsumo.control.consensus_params`;
:mod:`vcsumo.control.consensus_stability` evaluates the linearised closed loop (eq. 4.2 with the T2T
delay of eq. 4.3) in the frequency domain (delay margin, string gain); this module holds the
controller and the acceleration → force step.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, MutableMapping

from vcsumo.control.base import Command, Message, Observation
from vcsumo.control.consensus_params import CbcParams, LiuParams, ZhouParams, cbc_params_for, load_cbc_params
from vcsumo.control.gap_reference import GapReference, GapSample
from vcsumo.control.topology_graph import convoy_graph
from vcsumo.dynamics import V_EPS_MPS, TrainParams, acceleration, brake_force_limit, gradient_force, running_resistance, traction_limit
from vcsumo.units import G

# ---------------------------------------------------------------------------------------------
# Low level: acceleration → force (inverse of eq. 1b / survey eq. 2.2)


def force_for_acceleration(p: TrainParams, speed_mps: float, accel_mps2: float, gradient: float = 0.0, tunnel_factor: float = 1.0) -> float:
    """Traction/brake force u giving dv/dt = ``accel_mps2``: M·ρ·a + R(v) + M·g·i (inverse of eq. 1b), N."""
    return float(p.mass_kg * p.rotating_mass_factor * accel_mps2 + running_resistance(p, speed_mps, tunnel_factor) + gradient_force(p, gradient))


def acceleration_envelope(p: TrainParams, speed_mps: float, gradient: float = 0.0, tunnel_factor: float = 1.0) -> tuple[float, float]:
    """(lowest, highest) reachable dv/dt at full brake / full traction (eq. 4a, 4b through eq. 1b), m/s²."""
    lo = float(acceleration(p, speed_mps, -brake_force_limit(p, speed_mps), gradient, tunnel_factor))
    hi = float(acceleration(p, speed_mps, traction_limit(p, speed_mps), gradient, tunnel_factor))
    return lo, hi


def _envelope(p: TrainParams, v: float, tf: float, grad: float) -> tuple[float, float, float]:
    """(traction limit, −brake limit, resistance + gradient force) at speed v, N.

    ``traction_limit``, ``brake_force_limit``, ``running_resistance`` and ``gradient_force`` of
    :mod:`vcsumo.dynamics` written out for Python floats (the same operations in the same order,
    without numpy's per-call overhead on scalars); anything else (NaN, numpy, CasADi) goes through
    those functions.
    """
    if type(v) is not float or type(tf) is not float or type(grad) is not float or v != v:
        return (float(traction_limit(p, v)), -float(brake_force_limit(p, v)),
                float(running_resistance(p, v, tf)) + float(gradient_force(p, grad)))
    v_pos = v if v > V_EPS_MPS else V_EPS_MPS  # max(v, V_EPS) for a number
    f_tr = p.max_power_w / v_pos
    f_max = p.max_traction_n if p.max_traction_n <= f_tr else f_tr
    f_br = p.mass_kg * p.service_brake_decel_mps2
    if math.isinf(p.max_brake_power_w):
        f_br = f_br + 0.0 * v
    else:
        pb = p.max_brake_power_w / v_pos
        f_br = f_br if f_br <= pb else pb
    f_res = (p.davis_a_n + p.davis_b_n_per_mps * v + tf * p.davis_c_n_per_mps2 * v * v) + p.mass_kg * G * grad
    return float(f_max), -float(f_br), float(f_res)


def sat(x: float, bound: float) -> float:
    """sat_Δ(x) = sgn(x)·Δ for |x| > Δ, x otherwise (eq. 4.4)."""
    return max(-bound, min(bound, x))


# ---------------------------------------------------------------------------------------------
# The controller


def _age_s(obs: Observation, m: Message) -> float:
    """τ_ij of eq. 4.3: how old the delivered state is (its time stamp, else the sending time), s."""
    stamp = m.state.time_s if math.isfinite(m.state.time_s) else m.sent_time_s
    return max(0.0, obs.time_s - stamp)


@dataclass
class _Link:
    msg: Message
    index: int
    weight: float
    age_s: float


class ConsensusController:
    """Consensus-based VC controller: ``make_step(obs) -> Command`` (force in N).

    ``gap_schedule`` maps train ids to a :class:`~vcsumo.control.gap_reference.GapReference`
    (a merge/split transition, eq. 3.2–3.6) overriding ``params.gap`` for that train's gap.  Give
    the *same* mapping object to every controller of a convoy so that multi-hop offsets (PLF,
    TPF, BD) agree; it may be mutated while running (start a merge by inserting a transition).
    """

    def __init__(self, params: CbcParams | None = None, gap_schedule: MutableMapping[str, GapReference] | None = None):
        self.params = params or CbcParams()
        self.gap_schedule: MutableMapping[str, GapReference] = gap_schedule if gap_schedule is not None else {}
        self.default_gap: GapReference = self.params.gap
        """The gap reference of trains without a schedule entry (the registry sets the certified spacing)."""
        self._lengths: dict[str, float] = {}
        self._own_history: deque[tuple[float, float]] = deque()
        self._last_pos: dict[str, float] = {}
        self._neighbours: dict[tuple[int, int], dict[int, float]] = {}

    @classmethod
    def from_yaml(cls, spec: str | Path = "cbc", gap_schedule: MutableMapping[str, GapReference] | None = None) -> "ConsensusController":
        return cls(load_cbc_params(spec), gap_schedule)

    # -----------------------------------------------------------------------------------------
    def make_step(self, obs: Observation) -> Command:
        prm = self.params
        ego = obs.ego
        p = obs.params
        grad = obs.profile.mean_gradient(ego.position_m, p.length_m)
        tf = obs.profile.tunnel_factor_at(ego.position_m)
        self._remember(obs)
        convoy = tuple(obs.convoy)
        i = convoy.index(obs.ego_id) if obs.ego_id in convoy else 0
        if i == 0:
            return self._leader_step(obs, grad, tf)
        if prm.law == "consensus":
            u, info = self._consensus(obs, convoy, i)
        else:
            u, info = self._predecessor_law(obs, convoy, i)
        return self._to_command(obs, u, info, grad, tf)

    # -----------------------------------------------------------------------------------------
    def _remember(self, obs: Observation) -> None:
        for m in obs.received.values():
            self._lengths[m.sender] = m.length_m
            self._last_pos[m.sender] = m.state.position_m
        h = self._own_history
        h.append((obs.time_s, obs.ego.position_m))
        horizon = self.params.max_message_age_s + 2 * obs.step_s
        while h and h[0][0] < obs.time_s - horizon:
            h.popleft()

    def _length(self, train: str, obs: Observation) -> float:
        if train == obs.ego_id:
            return obs.params.length_m
        return self._lengths.get(train, obs.params.length_m)  # homogeneous assumption until a message arrives

    def _fresh(self, obs: Observation, train: str) -> Message | None:
        m = obs.received.get(train)
        if m is None or _age_s(obs, m) > self.params.max_message_age_s:
            return None
        return m

    def _gap_sample(self, obs: Observation, convoy: tuple[str, ...], m: int, own_index: int) -> GapSample:
        """Reference gap of train m behind m−1, evaluated with the ego's speed (consensus value)."""
        ref: GapReference = self.gap_schedule.get(convoy[m], self.default_gap)
        v = obs.ego.speed_mps
        if m == own_index:
            pm = self._fresh(obs, convoy[m - 1])
            v_pred = pm.state.speed_mps if pm is not None else v
            return ref.evaluate(obs.time_s, obs.ego.position_m, v, v_pred)
        x_m = self._last_pos.get(convoy[m], obs.ego.position_m)
        return ref.evaluate(obs.time_s, x_m, v, v)

    def _offset(self, obs: Observation, convoy: tuple[str, ...], i: int, j: int, gaps: dict[int, GapSample]) -> tuple[float, float, float]:
        """δ_ij = desired x_j − x_i and its transitional rate/acceleration (eq. 3.10 over the hops i→j)."""
        lo, hi, sign = (j + 1, i, 1.0) if j < i else (i + 1, j, -1.0)
        d = r = a = 0.0
        for m in range(lo, hi + 1):
            g = gaps.get(m)
            if g is None:
                g = gaps[m] = self._gap_sample(obs, convoy, m, i)
            d += g.gap_m + self._length(convoy[m - 1], obs)
            r += g.rate_mps
            a += g.accel_mps2
        return sign * d, sign * r, sign * a

    def _reference_speed(self, obs: Observation, convoy: tuple[str, ...], links: list[_Link]) -> float:
        """v_0 of eq. 4.3: the leader's reported speed, else the weighted mean of the neighbours' speeds (else own)."""
        lead = self._fresh(obs, convoy[0])
        if lead is not None:
            return lead.state.speed_mps
        if links:
            w = sum(lk.weight for lk in links)
            return sum(lk.weight * lk.msg.state.speed_mps for lk in links) / w
        return obs.ego.speed_mps

    def _consensus(self, obs: Observation, convoy: tuple[str, ...], i: int) -> tuple[float, dict[str, Any]]:
        prm = self.params
        key = (len(convoy), i)
        nbrs = self._neighbours.get(key)
        if nbrs is None:
            nbrs = self._neighbours[key] = convoy_graph(prm.topology, len(convoy)).neighbours(i)
        links: list[_Link] = []
        received, max_age_s = obs.received, prm.max_message_age_s
        for j, a_ij in nbrs.items():
            m = received.get(convoy[j])  # as _fresh, with the age computed once
            if m is not None:
                age = _age_s(obs, m)
                if not age > max_age_s:
                    links.append(_Link(m, j, a_ij, age))
        gaps: dict[int, GapSample] = {i: self._gap_sample(obs, convoy, i, i)}
        info: dict[str, Any] = {"gap_ref_m": gaps[i].gap_m, "links": len(links)}
        if not links:
            return self._fallback(obs, gaps[i]), info | {"fallback": True}
        v0 = self._reference_speed(obs, convoy, links)
        x_i, v_i, a_i = obs.ego.position_m, obs.ego.speed_mps, obs.ego.accel_mps2
        eta = sum(lk.weight for lk in links)
        fb = ff = 0.0
        max_age = 0.0
        for lk in links:
            st = lk.msg.state
            delta, d_rate, d_acc = self._offset(obs, convoy, i, lk.index, gaps)
            if prm.delay_compensation == "reference":
                x_hat = st.position_m + lk.age_s * v0  # eq. 4.3: + τ_ij·v_0
            elif prm.delay_compensation == "sender":
                x_hat = st.position_m + lk.age_s * st.speed_mps
            else:
                x_hat = st.position_m
            e_x = x_i - x_hat + delta
            e_v = v_i - st.speed_mps + d_rate
            e_a = a_i - st.accel_mps2 + d_acc
            term = -(prm.k_pos_per_s2 * e_x + prm.k_vel_per_s * e_v + prm.k_acc * e_a)
            if prm.link_bound_mps2 is not None:
                term = sat(term, prm.link_bound_mps2)  # eq. 4.4
            w = lk.weight / eta if prm.normalize else lk.weight
            fb += w * term
            ff += lk.weight / eta * (st.accel_mps2 - d_acc)
            max_age = max(max_age, lk.age_s)
        # reference-speed damping (eq. 4.3 k2, eq. 4.5 k1); the transitional rate of D_i shifts v_0
        _, d0_rate, _ = self._offset(obs, convoy, i, 0, gaps) if prm.k_ref_vel_per_s > 0 else (0.0, 0.0, 0.0)
        u = prm.accel_feedforward * ff + fb - prm.k_ref_vel_per_s * (v_i - v0 + d0_rate) - prm.k_own_acc * a_i
        info.update(max_age_s=max_age, reference_speed_mps=v0)
        pm = self._fresh(obs, convoy[i - 1])
        if pm is not None:
            info["gap_m"] = pm.state.position_m + pm.state.speed_mps * _age_s(obs, pm) - pm.length_m - x_i
        return u, info

    def _fallback(self, obs: Observation, g: GapSample) -> float:
        """No fresh neighbour: on-board ACC on the sensed gap if there is one, else hold speed."""
        prm = self.params
        if obs.sensed_gap_m is not None and obs.sensed_speed_mps is not None:
            return prm.k_pos_per_s2 * (obs.sensed_gap_m - g.gap_m) - prm.k_vel_per_s * (obs.ego.speed_mps - obs.sensed_speed_mps)
        return 0.0

    # -----------------------------------------------------------------------------------------
    def _predecessor_law(self, obs: Observation, convoy: tuple[str, ...], i: int) -> tuple[float, dict[str, Any]]:
        """Eq. 4.10 / 4.11 on the (delayed) predecessor message."""
        prm = self.params
        g = self._gap_sample(obs, convoy, i, i)
        info: dict[str, Any] = {"gap_ref_m": g.gap_m, "links": 0}
        pm = self._fresh(obs, convoy[i - 1])
        if pm is None:
            return self._fallback(obs, g), info | {"fallback": True}
        st = pm.state
        age = _age_s(obs, pm)
        x_i, v_i = obs.ego.position_m, obs.ego.speed_mps
        comp = {"reference": self._reference_speed(obs, convoy, [_Link(pm, i - 1, 1.0, age)]), "sender": st.speed_mps, "none": 0.0}[prm.delay_compensation]
        gap = st.position_m + age * comp - pm.length_m - x_i  # delayed predecessor position compensated as in eq. 4.3
        e_sp = gap - g.gap_m  # eq. 3.9/3.11 (positive: too far behind)
        e_sv = v_i - st.speed_mps + g.rate_mps
        ff = prm.accel_feedforward * (st.accel_mps2 - g.accel_mps2)
        if prm.law == "liu_tanh":
            c = prm.liu
            gap_delayed = st.position_m - pm.length_m - self._own_position_at(obs.time_s - age, x_i)
            k6 = c.k6 if c.k6 is not None else c.k5_per_m * g.gap_m
            k3 = c.k3 if c.k3 is not None else -c.k4 * math.tanh(c.k5_per_m * g.gap_m - k6)
            u = ff + c.k1_per_s2 * e_sp - c.k2_mps2 * (k3 + c.k4 * math.tanh(c.k5_per_m * gap_delayed - k6)) - c.k_rel_speed_per_s * e_sv
        else:
            c = prm.zhou
            v_max = min(obs.profile.speed_limit_train(x_i, obs.params.length_m), obs.params.max_speed_ms)
            barrier = c.k3_mps2 * v_i / (v_i - v_max) if v_i < v_max - 1e-3 else -1e3
            u = ff + c.k1_mps2 * math.tanh(e_sp / c.spacing_scale_m) - c.k2_mps2 * math.tanh(e_sv / c.speed_scale_mps) + barrier
        info.update(gap_m=gap, max_age_s=age, links=1)
        return u, info

    def _own_position_at(self, t: float, default: float) -> float:
        """Own position at time t from the recorded history (for d_{F,t−τ} of eq. 4.10)."""
        best = default
        for tt, x in reversed(self._own_history):
            best = x
            if tt <= t + 1e-9:
                break
        return best

    # -----------------------------------------------------------------------------------------
    def _leader_step(self, obs: Observation, grad: float, tf: float) -> Command:
        """A convoy leader (or a train outside any convoy) tracks its target speed with a P law."""
        p = obs.params
        v_lim = min(obs.profile.speed_limit_train(obs.ego.position_m, p.length_m), p.max_speed_ms)
        target = v_lim if obs.target_speed_mps is None else min(obs.target_speed_mps, v_lim)
        u = self.params.leader_speed_gain_per_s * (target - obs.ego.speed_mps)
        cmd = self._to_command(obs, u, {"target_speed_mps": target}, grad, tf)
        return Command(cmd.force_n, mode="cbc-leader", info=cmd.info)

    def _to_command(self, obs: Observation, u: float, info: dict[str, Any], grad: float, tf: float) -> Command:
        """Speed-limit guard, saturation to the traction/brake envelope (eq. 4.4), force (eq. 2.2 inverted)."""
        p = obs.params
        v = obs.ego.speed_mps
        prm = self.params
        if prm.speed_limit_gain_per_s is not None:
            v_lim = min(obs.profile.speed_limit_train(obs.ego.position_m, p.length_m), p.max_speed_ms)
            u = min(u, prm.speed_limit_gain_per_s * (v_lim - v))
        # eq. 4.4 input bound: the speed-dependent envelope −min(M a_br, P_br/v) ≤ F ≤ min(M a_dr, P_dr/v),
        # mapped to accelerations through eq. 1b (same arithmetic as dynamics.acceleration, computed once)
        f_max, f_min, f_res = _envelope(p, v, tf, grad)
        m_eff = p.mass_kg * p.rotating_mass_factor
        u_sat = min(max(u, (f_min - f_res) / m_eff), (f_max - f_res) / m_eff)
        force = min(max(m_eff * u_sat + f_res, f_min), f_max)
        info.update(u_mps2=u, u_sat_mps2=u_sat, saturated=bool(u_sat != u))
        mode = "cbc" if prm.law == "consensus" else f"cbc-{prm.law}"
        if info.get("fallback"):
            mode = "cbc-fallback"
        return Command(force_n=force, mode=mode, info=info)


__all__ = [
    "CbcParams",
    "ConsensusController",
    "LiuParams",
    "ZhouParams",
    "acceleration_envelope",
    "cbc_params_for",
    "force_for_acceleration",
    "load_cbc_params",
    "sat",
]
