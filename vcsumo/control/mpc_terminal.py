"""Terminal set of the virtual-coupling NMPC (Felez, Kim & Borrelli 2019, terminal constraints 11i/12k).

The boundary of the DP feasible set (eq. 10, Fig. 7; :func:`vcsumo.control.dp_profile.dp_speed_profile`)
lowered to the same boundary for the NMPC's own time-discrete model (explicit Euler in time, eq. 6b,
full service brake: :func:`discrete_braking_curves`), so that a plan ending on it can follow it;
a train entering the route at speed is thus not forced onto the start-up curve.  Results are cached
in memory per (train, route content, arguments).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from vcsumo.control.dp_profile import SpeedProfile, beta_curve, beta_curve_scalar, route_cache_key
from vcsumo.control.route_lookup import RouteLookup
from vcsumo.dynamics import TrainParams, brake_force_limit, gradient_force, running_resistance
from vcsumo.route_profile import RouteProfile

_CACHE: "OrderedDict[str, TerminalSet]" = OrderedDict()
_CACHE_SIZE = 32


@dataclass(frozen=True)
class TerminalSet:
    """Largest speed v_max(s) from which the train can still obey every later limit and stop.

    The boundary of the DP feasible set (Fig. 7) used by the NMPC terminal constraints 11i/12k.
    ``from_dp_and_model`` takes the lower of the space-DP boundary (eq. 10) and the same boundary
    for the NMPC's own time-discrete model (full service brake, explicit Euler with step Δt), so
    that a plan ending on the boundary with the brake applied can stay on it step after step.
    """

    positions_m: np.ndarray
    v_max_mps: np.ndarray
    end_decel_mps2: float = 1.0
    """Slope of β = v² past the end: β = v_end² − 2·b·(s − s_end)."""

    def terminal_bound(self, s) -> np.ndarray:
        """v_max(s), m/s (zero beyond the end)."""
        return np.interp(s, self.positions_m, self.v_max_mps, left=self.v_max_mps[0], right=0.0)

    def beta(self, s) -> tuple[np.ndarray, np.ndarray]:
        """(v_max(s)², d/ds), extended past the end (see :func:`~vcsumo.control.dp_profile.beta_curve`)."""
        if type(s) is float or np.ndim(s) == 0:  # scalar fast path on lists (one look-up per NMPC iteration)
            lists = self.__dict__.get("_lists")
            if lists is None:
                lists = (self.positions_m.tolist(), (self.v_max_mps * self.v_max_mps).tolist())
                object.__setattr__(self, "_lists", lists)
            return beta_curve_scalar(lists[0], lists[1], self.end_decel_mps2, float(s))
        return beta_curve(self.positions_m, self.v_max_mps, self.end_decel_mps2, s)


def discrete_braking_curves(params: TrainParams, lookup: RouteLookup, targets: list[tuple[float, float]], dt: float, v_top: float, s_min: float,
                            brake_fraction: float = 1.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Full-service-brake curves of the time-discrete model ending at each (position, speed) target.

    Backward in time from the target: v_k − Δt·b(v_k) = v_{k+1}, s_k = s_{k+1} − Δt·v_k (explicit
    Euler as in eq. 6b and :class:`~vcsumo.plant.TrainPlant`), with
    b(v) = (min(M·a_br, P_br/v) + R(v) + F_g(s))/(M·ρ).  Returns one (positions, speeds) curve
    per target, increasing in position, up to ``v_top`` or back to ``s_min``.  Vectorised over
    targets.  ``brake_fraction`` < 1 scales the brake force (a margin for the force lag of eq. 1c,
    which makes the applied force trail a speed-dependent brake limit).
    """
    if not targets:
        return []
    m_eff = params.mass_kg * params.rotating_mass_factor
    S = np.array([t[0] for t in targets], dtype=float)
    V = np.array([t[1] for t in targets], dtype=float)
    curves_s = [[s] for s in S]
    curves_v = [[v] for v in V]
    active = np.ones(len(S), dtype=bool)
    for _ in range(200000):
        if not active.any():
            break
        idx = np.flatnonzero(active)
        s1, v1 = S[idx], V[idx]
        g = lookup.gradient(s1)
        tf = lookup.tunnel_factor(s1)

        def decel(v):
            return (brake_fraction * brake_force_limit(params, v) + running_resistance(params, v, tf) + gradient_force(params, g)) / m_eff

        v0 = v1 + dt * decel(v1)
        for _ in range(4):  # Newton on v0 − Δt·b(v0) − v1 = 0 (b is smooth between regimes)
            h = 1e-4
            f = v0 - dt * decel(v0) - v1
            df = 1.0 - dt * (decel(v0 + h) - decel(v0)) / h
            v0 = v0 - f / np.where(np.abs(df) > 1e-6, df, 1.0)
        v0 = np.maximum(v0, v1)
        s0 = s1 - dt * v0
        S[idx], V[idx] = s0, v0
        for j, k in enumerate(idx):
            curves_s[k].append(s0[j])
            curves_v[k].append(v0[j])
        active[idx] = (v0 < v_top) & (s0 > s_min)
    return [(np.array(cs[::-1]), np.array(cv[::-1])) for cs, cv in zip(curves_s, curves_v)]


def terminal_set(params: TrainParams, profile: RouteProfile, dp: SpeedProfile, dt: float, stops_m: tuple[float, ...] = (), v_end_mps: float = 0.0,
                 brake_fraction: float = 0.98, use_cache: bool = True) -> TerminalSet:
    """Terminal set of the NMPC (11i/12k): min of the DP boundary and the time-discrete braking curves
    (computed with ``brake_fraction`` of the service brake force, see :func:`discrete_braking_curves`)."""
    s0, s1 = float(dp.positions_m[0]), float(dp.positions_m[-1])
    key = "ts" + route_cache_key(params, profile, s0, s1, dt, tuple(stops_m), float(v_end_mps), brake_fraction)
    if use_cache and key in _CACHE:
        return _CACHE[key]
    lookup = RouteLookup(profile, params.length_m)
    v_top = float(np.max(dp.v_lim_mps)) + 1.0
    targets = [(s, v) for s, v in lookup.restriction_points() if s0 < s <= s1] + [(float(s), 0.0) for s in stops_m if s0 < s < s1] + [(s1, v_end_mps)]
    curves = discrete_braking_curves(params, lookup, targets, dt, v_top, s0, brake_fraction)
    grid = np.unique(np.concatenate([dp.positions_m] + [c[0][(c[0] >= s0) & (c[0] <= s1)] for c in curves]))
    vmax = np.minimum(dp.terminal_bound(grid), np.minimum(lookup.speed_limit(grid), params.max_speed_ms))
    for (cs, cv), (st, vt) in zip(curves, targets):
        m = grid <= st
        vmax[m] = np.minimum(vmax[m], np.interp(grid[m], cs, cv, left=cv[0], right=vt))
    ts = TerminalSet(positions_m=grid, v_max_mps=np.maximum(vmax, 0.0), end_decel_mps2=params.service_brake_decel_mps2)
    if use_cache:
        _CACHE[key] = ts
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return ts
