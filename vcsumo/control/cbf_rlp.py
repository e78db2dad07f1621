"""Algorithms 1 and 3 of Terlizzi, Liuzza & Glielmo (2024): the leader's RLP predictor and the delay estimator.

* :class:`LeaderRLPPredictor` — Algorithm 1: the leader's robust lower proxy under its strongest
  braking from the newest packet, reset at every newer packet; the deceleration comes from the
  barrier (:meth:`BarrierModel.rlp_reset` — the paper's e̲^L over a route window — or
  :meth:`SeparationBarrier.rlp_reset` — the separation model's strongest braking).
* :class:`DelayEstimator` — Algorithm 3: the p̄-quantile of the last N_Λ packet delays.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from vcsumo.control.base import Message
from vcsumo.control.cbf_barrier import BarrierModel, SeparationBarrier
from vcsumo.control.proxies import RouteBounds

# -------------------------------------------------------------------------------------------
# Algorithm 1: leader RLP predictor


@dataclass(frozen=True)
class RLPBranch:
    """One reset of Algorithm 1: packet time, leader state, e̲^L at that state and its route window."""

    t0_s: float
    s0_m: float
    v0_mps: float
    e0_mps2: float
    rb: RouteBounds | None
    """The route window of e̲^L (None: the separation model's strongest braking over the path)."""

    def state(self, t_s: float) -> tuple[float, float]:
        """(position, speed) of the RLP under constant deceleration e̲^L (eq. 38, 40, 41)."""
        tau = max(0.0, t_s - self.t0_s)
        v0, e = self.v0_mps, self.e0_mps2
        if tau * e >= v0:
            return self.s0_m + v0 * v0 / (2.0 * e), 0.0
        return self.s0_m + v0 * tau - 0.5 * e * tau * tau, v0 - e * tau


class LeaderRLPPredictor:
    """Algorithm 1: the leader's RLP under emergency braking from the last packet.

    On a packet with t_κ > t_last: t_last ← t_κ, x̲^L(t_last) ← x^L(t_κ).  Between packets the RLP
    (eq. 12) under the leader's strongest brake decelerates by at most e̲^L(x2(t_last)), so the
    prediction is the closed-form flow of eq. 38–41 (constant deceleration e̲^L evaluated at the
    reset state over the leader's route window), which lies below the RLP and hence below every
    true leader trajectory.  Before the first packet t_last = −∞ and x̲^L = +∞.

    The route window of a reset covers the leader's path for T^max at up to V_max and its braking
    from the highest speed it can reach meanwhile.  Every earlier reset stays a valid lower bound,
    so the predictor keeps the last ``keep`` resets and uses the highest of their bounds
    (:meth:`bounds`): a newer packet whose window sees a steeper up-grade then cannot make the
    prediction *more* pessimistic than the older one.  ``keep=1`` is the paper's predictor.
    """

    def __init__(self, model: BarrierModel | SeparationBarrier, keep: int = 2):
        self.model = model
        self.keep = max(1, keep)
        self.branches: list[RLPBranch] = []
        self.resets = 0

    @property
    def has_data(self) -> bool:
        return bool(self.branches)

    @property
    def t_last(self) -> float:
        return self.branches[-1].t0_s if self.branches else -math.inf

    @property
    def latest(self) -> RLPBranch | None:
        return self.branches[-1] if self.branches else None

    def update(self, msg: Message | None) -> bool:
        """Lines 2–6: reset on a newer packet; returns True if reset."""
        if msg is None or not msg.sent_time_s > self.t_last:
            return False
        s0 = float(msg.state.position_m)
        v0 = max(0.0, float(msg.state.speed_mps))
        e0, rb = self.model.rlp_reset(s0, v0)
        self.branches.append(RLPBranch(float(msg.sent_time_s), s0, v0, e0, rb))
        if len(self.branches) > self.keep:
            del self.branches[0]
        self.resets += 1
        return True

    def predict(self, t_s: float) -> tuple[float, float]:
        """Line 7: x̲^L(t | K_E^L) of the latest reset = (position m, speed m/s) at time t."""
        if not self.branches:
            return math.inf, math.inf
        return self.branches[-1].state(t_s)

    def states(self, t_s: float) -> list[tuple[float, float]]:
        """(position, speed) at time t of every kept reset's RLP (each a lower bound of the leader)."""
        return [br.state(t_s) for br in self.branches]

    def bounds(self, t_s: float) -> tuple[float, float, float]:
        """(position lower bound, stop-point lower bound, RLP speed) of the leader at time t.

        The stop point S^L (eq. 41, 44) of each kept RLP state; the highest bounds are used.
        """
        pos = stop = -math.inf
        v_out = 0.0
        model = self.model
        for br in self.branches:
            # br.state(t_s) written out (the hot loop of the supervisor)
            tau = t_s - br.t0_s
            if not tau > 0.0:
                tau = 0.0
            v0, e = br.v0_mps, br.e0_mps2
            if tau * e >= v0:
                s, v = br.s0_m + v0 * v0 / (2.0 * e), 0.0
            else:
                s, v = br.s0_m + v0 * tau - 0.5 * e * tau * tau, v0 - e * tau
            st = s if v <= 0.0 else model.leader_stop(s, v, br.rb)
            if s > pos:
                pos, v_out = s, v
            if st > stop:  # max(stop, st)
                stop = st
        return pos, stop, v_out

    def stop_of(self, s_m: float, v_mps: float) -> float:
        """S^L of a leader in state (s, v) (with the windows of the kept resets in ``window`` mode)."""
        if self.model.profile_mode or not self.branches:
            return self.model.leader_stop(s_m, v_mps)
        return max(self.model.leader_stop(s_m, v_mps, br.rb) for br in self.branches)

    def decel_at(self, v_mps: float) -> float:
        """e̲^L at an RLP speed over the window of the last reset."""
        return self.model.leader.leader_decel(v_mps, self.branches[-1].rb)


# -------------------------------------------------------------------------------------------
# Algorithm 3: delay estimator


class DelayEstimator:
    """Algorithm 3: τ̄ = inf{τ : F̂_Λ(τ) ≥ p̄} over the last N_Λ packet delays.

    τ(t_κ) is the elapsed time between the leader's trigger instant t_κ and the packet's reception
    at the follower.  Only packets newer than the last one update the stack (line 3).  Until the
    first packet the estimate is ``initial_delay_s``.
    """

    def __init__(self, window_size: int = 50, probability: float = 0.95, initial_delay_s: float = 1.0):
        if window_size < 1:
            raise ValueError("window_size must be at least 1")
        if not 0.0 < probability <= 1.0:
            raise ValueError("probability must be in (0, 1]")
        self.window_size = window_size
        self.probability = probability
        self.initial_delay_s = initial_delay_s
        self.samples: deque[float] = deque(maxlen=window_size)
        self.t_last = -math.inf
        self._estimate = initial_delay_s

    def update(self, sent_time_s: float, received_time_s: float) -> bool:
        """Store τ for a packet newer than the last one and recompute τ̄; returns True if stored."""
        if not sent_time_s > self.t_last or not math.isfinite(received_time_s):
            return False
        self.t_last = sent_time_s
        self.samples.append(max(0.0, received_time_s - sent_time_s))
        lam = np.sort(np.fromiter(self.samples, dtype=float))
        k = max(0, math.ceil(self.probability * len(lam) - 1e-12) - 1)
        self._estimate = float(lam[k])
        return True

    def update_from(self, msg: Message | None, now_s: float) -> bool:
        """Convenience: the packet's reception time (or ``now_s`` if the channel did not stamp it)."""
        if msg is None:
            return False
        rx = msg.received_time_s if math.isfinite(msg.received_time_s) else now_s
        return self.update(msg.sent_time_s, rx)

    @property
    def estimate_s(self) -> float:
        """τ̄, s."""
        return self._estimate

