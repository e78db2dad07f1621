"""Algorithm 4 of Terlizzi, Liuzza & Glielmo (2024): the follower's position references z_τ (eq. 20–28,
one per τ_i = ω_i·τ̄, eq. 32–34) from the leader's robust planned trajectory x̲^L carried by its
packets.  The references shape the cruise controller's performance only; safety is the
supervisor's (:mod:`vcsumo.control.cbf`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vcsumo.control.base import Message
from vcsumo.control.cbf import BarrierModel
from vcsumo.control.cruise_config import CruiseConfig
from vcsumo.control.proxies import RobustProxies
from vcsumo.units import G


@dataclass
class ReferenceSet:
    """The trajectories z_τ1, z_τ2, z_τ3 (eq. 32–34) and the leader's robust planned speed."""

    t_last: float
    times_s: np.ndarray
    z_m: np.ndarray
    """Shape (3, n): z_τ1, z_τ2, z_τ3 (z_τ1 ≥ z_τ2 ≥ z_τ3 for ω1 < ω2 < ω3)."""
    leader_speed_mps: np.ndarray
    taus_s: tuple[float, float, float]
    tau_bar_s: float

    def at(self, t: float) -> np.ndarray:
        """(z_τ1, z_τ2, z_τ3) at time t (constant-speed extrapolation past the grid)."""
        out = np.empty(3)
        for i in range(3):
            out[i] = _interp_extrap(t, self.times_s, self.z_m[i])
        return out

    def over(self, times: np.ndarray, row: int = 1) -> np.ndarray:
        return _interp_extrap_vec(times, self.times_s, self.z_m[row])

    def speed_over(self, times: np.ndarray) -> np.ndarray:
        return np.interp(times, self.times_s, self.leader_speed_mps)


def _interp_extrap(t: float, ts: np.ndarray, ys: np.ndarray) -> float:
    if t <= ts[-1]:
        return float(np.interp(t, ts, ys))
    slope = (ys[-1] - ys[-2]) / (ts[-1] - ts[-2]) if len(ts) > 1 else 0.0
    return float(ys[-1] + slope * (t - ts[-1]))


def _interp_extrap_vec(t: np.ndarray, ts: np.ndarray, ys: np.ndarray) -> np.ndarray:
    out = np.interp(t, ts, ys)
    late = t > ts[-1]
    if late.any():
        slope = (ys[-1] - ys[-2]) / (ts[-1] - ts[-2]) if len(ts) > 1 else 0.0
        out[late] = ys[-1] + slope * (t[late] - ts[-1])
    return out


def leader_plan_from_message(msg: Message, leader: RobustProxies | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The leader's robust planned trajectory x̲^L(t_κ) from a packet: (times, positions, speeds).

    * With ``leader`` proxies and a force plan in the packet: the RLP (eq. 12) of the leader from
      the sent state under the planned forces, held piecewise constant on the plan's time grid
      (the computation of §VI-D, done on the follower side so any sender works).
    * Else the packet's plan as sent (a Terlizzi leader sends its RLP).
    * A packet without a plan is read as "cruising at the sent speed".

    The plan only shapes the references (performance); safety never relies on it.
    """
    st = msg.state
    tp = msg.plan_times_s
    if tp is not None and len(tp) >= 2:
        tp = np.asarray(tp, float)
        if leader is not None and msg.plan_forces_n is not None and len(msg.plan_forces_n) >= len(tp) - 1:
            f = np.asarray(msg.plan_forces_n, float)
            s0, v0 = float(st.position_m), max(0.0, float(st.speed_mps))
            rb = leader.window(s0, v0, float(tp[-1] - tp[0]))
            s = np.empty(len(tp))
            v = np.empty(len(tp))
            s[0], v[0] = s0, v0
            for k in range(len(tp) - 1):
                h = float(tp[k + 1] - tp[k])
                a = leader.rlp_accel(v[k], float(f[k]), rb, v0)
                v[k + 1] = max(0.0, v[k] + a * h)
                s[k + 1] = s[k] + v[k] * h
            return tp, s, v
        if msg.plan_positions_m is not None and msg.plan_speeds_mps is not None:
            return tp, np.asarray(msg.plan_positions_m, float), np.asarray(msg.plan_speeds_mps, float)
    t0 = msg.sent_time_s
    return np.array([t0, t0 + 1.0]), np.array([st.position_m, st.position_m + st.speed_mps]), np.array([st.speed_mps, st.speed_mps])


class PositionReferenceGenerator:
    """Algorithm 4 (eq. 20–28), for several τ at once (eq. 32–34).

    For each grid time t ∈ [t_last, t_last + span) on the leader's robust plan x̲^L(t):

    * s_τ^L (eq. 21): position of the leader RLP after braking at e̲^L for τ (v_τ^L, eq. 20, enters
      through the stop point: s_τ + v_τ²/(2e̲^L) is the leader's earliest stop S^L from x̲^L(t),
      taken on the route profile as in the supervisor's barrier);
    * v_ave^L (eq. 23): mean planned speed over [t, t+τ] (the printed integral lacks the 1/τ);
    * v_τ^{max,F} (eq. 22): min{x2^F + ā_dr·τ, V^{max,F}, V^{line,*}} with ā_dr the largest
      acceleration in the box at the follower's speed (taking ΔT = τ, the span the bound covers);
    * z̃^{F,1}, z̃^{F,2}, z̃^F (eq. 24): follower positions putting b' resp. b'' at zero at t + τ,
      with the follower's stopping distance from v_τ^{max,F} taken at its present position;
    * z̃^{FL} = x̲1^L − z̃^F (eq. 25), its running maximum over [t − τ, t] ∩ [t_last, t] (eq. 26) and
      z_τ^F = x̲1^L − z^{FL} (eq. 27).

    Past the packet's plan horizon the plan is extended at its last speed.  The same sampled-data
    margins as the supervisor are included so that z_τ is consistent with its check.  The
    references shape performance only; safety is the supervisor's.
    """

    def __init__(self, model: BarrierModel, cfg: CruiseConfig, dt_s: float = 0.0):
        self.model = model
        self.cfg = cfg
        self.dt_s = dt_s

    def compute(self, msg: Message, tau_bar_s: float, s_f: float, v_f: float, t_now: float, v_line_max: float = math.inf) -> ReferenceSet:
        cfg, model = self.cfg, self.model
        taus = (cfg.omega_1 * tau_bar_s, cfg.omega_2 * tau_bar_s, cfg.omega_3 * tau_bar_s)
        tp, sp, vp = leader_plan_from_message(msg, model.leader if cfg.rlp_from_forces else None)
        t_last = float(msg.sent_time_s)
        step = cfg.reference_step_s
        span = max(t_now - t_last, 0.0) + cfg.horizon_s + 2.0 * step
        n = int(math.ceil(span / step)) + 1
        tmax = max(taus)
        n_ext = n + int(math.ceil(tmax / step)) + 2
        tg = t_last + step * np.arange(n_ext)
        s_g = np.interp(tg, tp, sp)
        v_g = np.interp(tg, tp, vp)
        late = tg > tp[-1]
        if late.any():
            v_g[late] = vp[-1]
            s_g[late] = sp[-1] + vp[-1] * (tg[late] - tp[-1])
        v_g = np.maximum(v_g, 0.0)
        # leader route window covering the planned stretch and its braking (σ_sup of e̲^L)
        lead = model.leader
        rb_l = lead.leader_path_bounds(float(s_g[0]), float(s_g[n - 1]), float(v_g.max()), model.cfg.t_max_s)
        b = lead.b
        res = b.davis_a_high_n + b.davis_b_high_n_per_mps * v_g + b.davis_c_high_n_per_mps2 * rb_l.tunnel_max * v_g * v_g
        e_l = res / (b.rotating_mass_factor * b.mass_low_kg) + G * rb_l.grade_max + b.brake_decel_high_mps2 / b.rotating_mass_factor
        # cumulative integral of the planned speed (trapezoid) for eq. 23
        P = np.concatenate(([0.0], np.cumsum(0.5 * (v_g[1:] + v_g[:-1]) * step)))
        fol = model.follower
        fb = fol.b
        L, d = model.leader_length_m, model.d_m
        dt = self.dt_s if model.cfg.sampled_data_margin else 0.0
        s0, v0 = s_g[:n], v_g[:n]
        e0 = e_l[:n]
        a_up = fb.accel_high(v_f) - G * min(model.stops_follower.grade_at(s_f), 0.0)
        # earliest stop of the braking leader from each planned state (flow-invariant: s_τ + v_τ²/2e̲)
        stop_l = np.array([model.leader_stop(float(a), float(b), rb_l) for a, b in zip(s0, v0)])
        z = np.empty((3, n))
        for i, tau in enumerate(taus):
            t_stop = v0 / e0
            full = t_stop <= tau
            s_tau = np.where(full, s0 + v0 * v0 / (2 * e0), s0 + v0 * tau - 0.5 * e0 * tau * tau)  # eq. 21
            v_ave = (np.interp(tg[:n] + tau, tg, P) - P[:n]) / tau if tau > 0 else v0  # eq. 23
            v_max_f = max(0.0, min(v_f + a_up * tau, fb.max_speed_ms, v_line_max))  # eq. 22
            stop_f = model.follower_stop(s_f, v_max_f, dt) - s_f  # v^max,F²/(2ē^F) (+ sampled-data margin)
            shift = v_ave * tau
            z1 = stop_l - shift - L - d - stop_f - (v0 * dt if dt > 0 else 0.0)  # eq. 24
            z2 = s_tau - shift - L - d  # eq. 24
            zt = np.minimum(z1, z2)
            zfl = s0 - zt  # eq. 25
            w = max(1, int(round(tau / step)))
            padded = np.concatenate((np.full(w, -np.inf), zfl))
            win = np.lib.stride_tricks.sliding_window_view(padded, w + 1)
            zfl_max = win.max(axis=1)  # eq. 26
            z[i] = s0 - zfl_max  # eq. 27
        return ReferenceSet(t_last=t_last, times_s=tg[:n], z_m=z, leader_speed_mps=v0.copy(), taus_s=taus, tau_bar_s=tau_bar_s)
