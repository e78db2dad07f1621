"""Maximum-speed profile v_DP*(s) by dynamic programming (Felez, Kim & Borrelli 2019, eq. 10).

The DP is posed in space: the route is sampled at positions s_0 < … < s_Ns (variable step Δs,
§III-C: Δs ≈ v·0.25 s between Δs_min = e_s/2 = 0.25 m where the train is slow and
Δs_max = 5 m where it is fast; stops and limit changes are grid points), the state is the speed
v_i at s_i, and the stage transition is eq. 10c,

    v_{i+1}² = v_i² + 2·Δs_i·a(v_i, u_i, s_i)                                   (10c)

with a(·) the longitudinal dynamics of eq. 1b (:mod:`vcsumo.dynamics`: running resistance,
gradient force).  The controls tried at each stage are a grid over the force range of
10d/10e, [−:func:`~vcsumo.dynamics.brake_force_limit`, :func:`~vcsumo.dynamics.traction_limit`]
at v_i, plus "hold the speed" and "reach the feasible boundary exactly"; speeds above v_lim(s_i)
are infeasible (10f); the terminal condition is v_Ns ≤ v_f (10g, 10h); the stage cost is eq. 10b

    q(v_i) = K_VDP·(v_i − v_lim(s_i))² + K_LDP·((v_i − v_lim) + |v_i − v_lim|)²   (10b)

(squared norms).  The backward recursion (10a) computes J*_i on a speed grid (vectorised over
grid speeds × controls, J*_{i+1} interpolated linearly; ∞ outside the feasible set); the
forward pass applies the optimal policy from the start speed with continuous speeds, so the
profile is exactly reachable under 10c–10e.  Results (:class:`SpeedProfile`):

* ``v_dp_mps`` — the optimal trajectory v_DP*(s): the "maximum achievable speed profile" of the
  paper's Fig. 6/8 (≈ 23.7 m/s on the §IV-A track);
* ``v_max_mps`` — the boundary of the DP feasible set, the largest speed at s_i with a finite
  cost-to-go (the terminal set of Fig. 7; computed exactly by a backward full-brake recursion of
  10c).  It equals v_DP* wherever v_DP* is not limited by the acceleration from the start.

:func:`vcsumo.control.mpc_terminal.terminal_set` lowers that boundary to the one of the NMPC's own time-discrete model
(explicit Euler in time, eq. 6b, full brake) so that a plan ending on it can follow it; the NMPC
(:mod:`vcsumo.control.mpc`) uses it for the terminal constraints 11i/12k, so a train entering the
route at speed is not forced onto the start-up curve.

The speed limit is the train-length limit (lowest over the whole train [s − L, s], SUMO's rule,
turnout limits included) and the gradient is the mean over the train, from a
:class:`~vcsumo.route_profile.RouteProfile` via :class:`~vcsumo.control.route_lookup.RouteLookup` (vectorised look-ups, used by
the NMPC as well).  Results are cached in memory per (train, route content, arguments): 0.2 s for
the 4 km §IV-A track, a few seconds for an 80 km high-speed line.
"""

from __future__ import annotations

import bisect
import hashlib
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from vcsumo.control.route_lookup import RouteLookup, route_profile_from_arrays, straight_route_profile
from vcsumo.dynamics import TrainParams, brake_force_limit, gradient_force, running_resistance, traction_limit
from vcsumo.route_profile import RouteProfile


# -------------------------------------------------------------------------------------------
# DP settings and result


@dataclass(frozen=True)
class DPSettings:
    """Discretisation and weights of the DP (eq. 10; Table II: K_VDP = 1, K_LDP = 1e5, Δs 0.25–5 m)."""

    ds_min_m: float = 0.25
    ds_max_m: float = 5.0
    ds_time_s: float = 0.25
    """Δs ≈ v·ds_time_s, clipped to [ds_min_m, ds_max_m] (fine grid where the train is slow)."""
    dv_mps: float = 0.1
    """Speed-grid resolution of the cost-to-go J*, m/s (the grid also holds every limit value)."""
    n_controls: int = 11
    """Force grid points over [−brake limit, traction limit] per stage (plus 'hold' and 'edge')."""
    k_vdp: float = 1.0
    k_ldp: float = 1.0e5


def beta_curve_scalar(positions: np.ndarray, b2: np.ndarray, end_decel: float, s: float) -> tuple[float, float]:
    """Scalar fast path of :func:`beta_curve` (one look-up per NMPC iteration)."""
    n = len(positions)
    if s > positions[-1]:
        return float(b2[-1] - 2.0 * end_decel * (s - positions[-1])), -2.0 * end_decel
    if s < positions[0]:
        return float(b2[0]), 0.0
    i = min(max(bisect.bisect_right(positions, s) - 1, 0), n - 2)
    p0, p1 = positions[i], positions[i + 1]
    slope = (b2[i + 1] - b2[i]) / (p1 - p0) if p1 > p0 else 0.0
    return float(b2[i] + slope * (s - p0)), float(slope)


def beta_curve(positions: np.ndarray, vmax: np.ndarray, end_decel: float, s) -> tuple[np.ndarray, np.ndarray]:
    """β(s) = v_max(s)² (linear interpolation; v² is nearly linear in s along a braking curve) and
    dβ/ds.  Past the end β keeps falling, β = v_end² − 2·b·(s − s_end), so a state beyond the end of
    the movement is outside the set however slowly it moves."""
    s = np.asarray(s, dtype=float)
    b2 = vmax * vmax
    i = np.clip(np.searchsorted(positions, s, side="right") - 1, 0, len(positions) - 2)
    ds = positions[i + 1] - positions[i]
    slope = (b2[i + 1] - b2[i]) / np.where(ds > 0, ds, 1.0)
    beta = b2[i] + slope * (s - positions[i])
    past = s > positions[-1]
    beta = np.where(past, b2[-1] - 2.0 * end_decel * (s - positions[-1]), beta)
    slope = np.where(past, -2.0 * end_decel, slope)
    before = s < positions[0]
    beta = np.where(before, b2[0], beta)
    slope = np.where(before, 0.0, slope)
    return beta, slope


@dataclass(frozen=True)
class SpeedProfile:
    """Result of the DP (eq. 10) on its position grid; both curves are interpolated linearly."""

    positions_m: np.ndarray
    v_dp_mps: np.ndarray
    """Optimal speed trajectory v_DP*(s) from the start speed (forward pass of eq. 10a)."""
    v_max_mps: np.ndarray
    """Largest speed with a finite cost-to-go J*_i: the DP terminal set (Fig. 7)."""
    v_lim_mps: np.ndarray
    """Train-length speed limit at the grid positions (10f)."""
    force_n: np.ndarray
    """Force u_i applied on [s_i, s_i+1) along v_DP* (len = len(positions) − 1)."""

    def __call__(self, s) -> np.ndarray:
        """v_DP*(s), m/s (zero beyond the end of the grid)."""
        return np.interp(s, self.positions_m, self.v_dp_mps, left=self.v_dp_mps[0], right=0.0)

    def terminal_bound(self, s) -> np.ndarray:
        """Upper bound of the DP terminal set at s, m/s (zero beyond the end of the grid).

        Linear interpolation of a concave braking curve lies below it, so this never exceeds the
        DP's own feasible set between grid points.
        """
        return np.interp(s, self.positions_m, self.v_max_mps, left=self.v_max_mps[0], right=0.0)

    def beta(self, s) -> tuple[np.ndarray, np.ndarray]:
        """(v_max(s)², d/ds) with the extension past the end (see :func:`beta_curve`, b = 1 m/s²)."""
        return beta_curve(self.positions_m, self.v_max_mps, 1.0, s)

    def time_s(self) -> float:
        """Running time along v_DP* (trapezoidal in 1/v), s."""
        v = self.v_dp_mps
        ds = np.diff(self.positions_m)
        vm = 0.5 * (v[:-1] + v[1:])
        return float(np.sum(ds / np.maximum(vm, 1e-3)))


# -------------------------------------------------------------------------------------------
# Grid construction


def _position_grid(lookup: RouteLookup, params: TrainParams, s0: float, s1: float, stops: list[float], cfg: DPSettings) -> np.ndarray:
    """Variable-step position grid: Δs ≈ v_env(s)·ds_time_s in [ds_min, ds_max] (§III-C).

    v_env is a quick analytic envelope (limit and v² = v_t² + 2·b·(s_t − s) towards each
    restriction or stop) used only to choose Δs.  Stops, limit changes and the end are grid points.
    """
    b = 0.9 * params.service_brake_decel_mps2
    fine = np.arange(s0, s1, 0.25)
    fine = np.append(fine, s1)
    env = lookup.speed_limit(fine).astype(float)
    targets = [(s, v) for s, v in lookup.restriction_points() if s0 < s <= s1] + [(s, 0.0) for s in stops] + [(s1, 0.0)]
    for st, vt in targets:
        m = fine <= st
        env[m] = np.minimum(env[m], np.sqrt(vt * vt + 2.0 * b * (st - fine[m])))
    ds = np.clip(env * cfg.ds_time_s, cfg.ds_min_m, cfg.ds_max_m)
    # cumulative "step count" and grid points at integer crossings
    steps = np.concatenate([[0.0], np.cumsum(np.diff(fine) / ds[:-1])])
    n = int(math.ceil(steps[-1]))
    pts = np.interp(np.arange(n + 1, dtype=float), steps, fine)
    keys = [s0, s1] + [s for s in stops if s0 < s < s1] + [s for s, _ in lookup.restriction_points() if s0 < s < s1]
    pts = np.unique(np.concatenate([pts, keys]))
    pts = pts[(pts >= s0 - 1e-9) & (pts <= s1 + 1e-9)]
    # drop points closer than 1 cm to a neighbour (keep the key points)
    keep = np.ones(len(pts), dtype=bool)
    keyset = np.array(sorted(keys))
    for i in range(1, len(pts)):
        if pts[i] - pts[i - 1] < 0.01:
            is_key = np.any(np.abs(keyset - pts[i]) < 1e-9)
            keep[i if not is_key else i - 1] = False
    return pts[keep]


def _speed_grid(v_top: float, limits: np.ndarray, dv: float) -> tuple[np.ndarray, int]:
    """Uniform grid 0..v_top plus every limit value; returns (grid, number of inserted values)."""
    g = np.arange(0.0, v_top + 1e-9, dv)
    extra = np.unique(limits[(limits > 0) & (limits <= v_top)])
    extra = extra[np.min(np.abs(extra[:, None] - g[None, :]), axis=1) > 1e-6] if len(extra) else extra
    if len(extra):
        g = g[np.min(np.abs(g[:, None] - extra[None, :]), axis=1) > 0.25 * dv]
    return np.unique(np.concatenate([g, extra])), len(extra)


# -------------------------------------------------------------------------------------------
# The DP


_CACHE: "OrderedDict[str, SpeedProfile]" = OrderedDict()
_CACHE_SIZE = 32


def route_cache_key(params: TrainParams, profile: RouteProfile, *rest) -> str:
    h = hashlib.sha1()
    h.update(repr(params).encode())
    for arr in (profile.starts_m, profile.lengths_m, profile.speeds_ms, profile.gradients, profile.tunnel_factors):
        h.update(np.asarray(arr, dtype=float).tobytes())
    h.update(repr(profile.point_limits).encode())
    h.update(repr(rest).encode())
    return h.hexdigest()


def dp_speed_profile(
    params: TrainParams,
    profile: RouteProfile,
    s_start_m: float = 0.0,
    s_end_m: float | None = None,
    v_start_mps: float = 0.0,
    v_end_mps: float = 0.0,
    stops_m: tuple[float, ...] = (),
    settings: DPSettings | None = None,
    use_cache: bool = True,
) -> SpeedProfile:
    """Solve the maximum-speed DP of eq. 10 on [s_start, s_end] and return v_DP*(s) and the terminal set.

    ``stops_m`` are positions where the train must be at rest (v = 0, e.g. station stops); the
    route end has v ≤ ``v_end_mps`` (10g).  The result is cached per (train, route, arguments).
    """
    cfg = settings or DPSettings()
    s1 = float(profile.length_m if s_end_m is None else s_end_m)
    s0 = float(s_start_m)
    if not s1 > s0:
        raise ValueError(f"s_end_m ({s1}) must be beyond s_start_m ({s0})")
    stops = sorted(float(s) for s in stops_m if s0 < s < s1)
    key = route_cache_key(params, profile, s0, s1, float(v_start_mps), float(v_end_mps), tuple(stops), cfg)
    if use_cache and key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    lookup = RouteLookup(profile, params.length_m)
    res = _solve_dp(params, lookup, s0, s1, float(v_start_mps), float(v_end_mps), stops, cfg)
    if use_cache:
        _CACHE[key] = res
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return res


def _next_speed(params: TrainParams, v, u, ds: float, grad: float, tf: float) -> np.ndarray:
    """Eq. 10c: v_{i+1} = sqrt(v_i² + 2·Δs·a(v_i, u_i)); 0 if the train stops within Δs."""
    m_eff = params.mass_kg * params.rotating_mass_factor
    a = (u - running_resistance(params, v, tf) - gradient_force(params, grad)) / m_eff
    return np.sqrt(np.maximum(v * v + 2.0 * ds * a, 0.0))


def _force_for(params: TrainParams, v, v_next, ds: float, grad: float, tf: float) -> np.ndarray:
    """Force u that takes v to v_next over Δs (inverse of eq. 10c)."""
    m_eff = params.mass_kg * params.rotating_mass_factor
    return m_eff * (v_next * v_next - v * v) / (2.0 * ds) + running_resistance(params, v, tf) + gradient_force(params, grad)


def _braking_envelope(params: TrainParams, S: np.ndarray, vlim: np.ndarray, grad: np.ndarray, tf: np.ndarray, v_end: float) -> np.ndarray:
    """Boundary of the DP feasible set: the largest v_i from which full braking (10d, 10e) keeps
    every later v_j ≤ v_lim(s_j) and ends at v ≤ v_f (backward recursion of eq. 10c)."""
    ns = len(S)
    vmax = np.empty(ns)
    vmax[-1] = min(v_end, vlim[-1])
    for i in range(ns - 2, -1, -1):
        ds = S[i + 1] - S[i]
        target = vmax[i + 1]
        hi = float(vlim[i])

        def nxt(v):
            return float(_next_speed(params, v, -brake_force_limit(params, v), ds, grad[i], tf[i]))

        if nxt(hi) <= target + 1e-12:
            vmax[i] = hi
            continue
        # largest v with next(v) ≤ target: Newton on next(v)² = target² from above, then a check
        v = hi
        for _ in range(8):
            f = nxt(v) ** 2 - target * target
            h = 1e-6 * max(v, 1.0)
            df = (nxt(v + h) ** 2 - nxt(v) ** 2) / h
            if df <= 1e-9:
                break
            v_new = min(max(v - f / df, 0.0), hi)
            if abs(v_new - v) < 1e-10:
                v = v_new
                break
            v = v_new
        if nxt(v) > target + 1e-12:  # Newton did not land inside: bisection
            lo, hi2 = 0.0, v
            for _ in range(50):
                mid = 0.5 * (lo + hi2)
                if nxt(mid) <= target + 1e-12:
                    lo = mid
                else:
                    hi2 = mid
            v = lo
        vmax[i] = v
    return vmax


def _solve_dp(params: TrainParams, lookup: RouteLookup, s0: float, s1: float, v_start: float, v_end: float, stops: list[float], cfg: DPSettings) -> SpeedProfile:
    S = _position_grid(lookup, params, s0, s1, stops, cfg)
    ns = len(S)
    vlim = np.minimum(lookup.speed_limit(S).astype(float), params.max_speed_ms)
    for st in stops:  # the train is at rest at each stop (10f with v_lim = 0 there)
        vlim[np.argmin(np.abs(S - st))] = 0.0
    grad = lookup.gradient(S)
    tf = lookup.tunnel_factor(S)
    vmax = _braking_envelope(params, S, vlim, grad, tf, v_end)
    V, _ = _speed_grid(float(vlim.max()), vlim, cfg.dv_mps)
    nv = len(V)
    u_hi = traction_limit(params, V)  # (10d, 10e) at the stage speed
    u_lo = -brake_force_limit(params, V)
    theta = np.linspace(-1.0, 1.0, cfg.n_controls)

    def candidates(v, uh, ul, i):
        """Controls tried at stage i: a grid over [u_lo, u_hi], holding speed, and hitting the
        boundary v_max(s_i+1) exactly (clipped to the limits)."""
        ds = S[i + 1] - S[i]
        ug = np.where(theta[None, :] >= 0, theta[None, :] * uh[:, None], -theta[None, :] * ul[:, None])
        hold = _force_for(params, v, v, ds, grad[i], tf[i])
        edge = _force_for(params, v, np.full_like(v, vmax[i + 1]), ds, grad[i], tf[i])
        u = np.concatenate([ug, hold[:, None], edge[:, None]], axis=1)
        return np.clip(u, ul[:, None], uh[:, None])

    def knots(Jn, i1):
        """Interpolation knots of J*_{i+1}: finite grid values, extended to the boundary v_max."""
        fin = np.isfinite(Jn)
        kv, kj = V[fin], Jn[fin]
        if len(kv) and vmax[i1] > kv[-1]:
            kv = np.append(kv, vmax[i1])
            kj = np.append(kj, kj[-1])
        return kv, kj

    def interp_J(kn, vb, i1):
        """J*_{i+1}(v) by linear interpolation on the grid; ∞ above the feasible boundary."""
        kv, kj = kn
        if len(kv) == 0:
            return np.full_like(vb, np.inf)
        return np.where(vb <= vmax[i1] + 1e-9, np.interp(vb, kv, kj), np.inf)

    def q(v, i):  # (10b)
        dev = v - vlim[i]
        return cfg.k_vdp * dev * dev + cfg.k_ldp * (dev + np.abs(dev)) ** 2

    kns = [None] * ns  # interpolation knots of J*_i
    J = np.where(V <= vmax[-1] + 1e-9, q(V, ns - 1), np.inf)  # (10g, 10h)
    kns[-1] = knots(J, ns - 1)
    for i in range(ns - 2, -1, -1):
        ds = S[i + 1] - S[i]
        k = int(np.searchsorted(V, vmax[i] + 1e-9, side="right"))  # speeds above v_max(s_i) are infeasible
        Vi = V[:k]
        u = candidates(Vi, u_hi[:k], u_lo[:k], i)
        vb = _next_speed(params, Vi[:, None], u, ds, grad[i], tf[i])
        cost = interp_J(kns[i + 1], vb.ravel(), i + 1).reshape(vb.shape)
        best = cost.min(axis=1)
        J = np.full(nv, np.inf)
        J[:k] = np.where(np.isfinite(best), q(Vi, i) + best, np.inf)  # (10a, 10f)
        kns[i] = knots(J, i)
    # forward pass of the optimal policy from the start speed (continuous speeds)
    v_dp = np.zeros(ns)
    force = np.zeros(ns - 1)
    v_dp[0] = min(max(v_start, 0.0), vmax[0])
    for i in range(ns - 1):
        v = np.array([v_dp[i]])
        uh, ul = traction_limit(params, v), -brake_force_limit(params, v)
        u = candidates(v, np.atleast_1d(uh), np.atleast_1d(ul), i)[0]
        ds = S[i + 1] - S[i]
        vb = _next_speed(params, v[0], u, ds, grad[i], tf[i])
        cost = interp_J(kns[i + 1], vb, i + 1)  # (10a): J*_{i+1} already holds q at s_i+1
        k = int(np.argmin(cost))
        if not np.isfinite(cost[k]):  # numerical corner: brake as hard as allowed
            k = int(np.argmin(u))
        v_dp[i + 1] = min(vb[k], vmax[i + 1])
        force[i] = u[k]
    return SpeedProfile(positions_m=S, v_dp_mps=v_dp, v_max_mps=vmax, v_lim_mps=vlim, force_n=force)


__all__ = ["DPSettings", "RouteLookup", "SpeedProfile", "beta_curve", "dp_speed_profile", "route_cache_key", "route_profile_from_arrays", "straight_route_profile"]
