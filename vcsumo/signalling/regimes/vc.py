"""Virtual coupling: moving block between convoys, relative braking inside them."""

from __future__ import annotations

import numpy as np

from vcsumo.signalling.blocking_time import mb_headway_profile
from vcsumo.signalling.regimes.base import AnalyticHeadway, HeadwayInputs, Regime


ROUTE_GAP_STEP_M = 20.0
"""On a route the followers' spacings are evaluated again when the leader has run this far or its
speed has changed by :data:`ROUTE_GAP_STEP_MPS` since the last evaluation (kept in between), m."""
ROUTE_GAP_STEP_MPS = 0.25


def route_gaps(gap_at, v: float, s_lead: float, L: float, convoy_size: int, start: list[float] | None = None) -> list[float]:
    """The gap of each follower (k = 1 … n − 1) behind the train ahead with the leader's front at
    ``s_lead`` and the whole convoy at speed v: follower k at the spacing ``gap_at(v, s_k)`` where
    its front is, s_k = s_(k−1) − L − g_k (a fixed point from ``start`` or the spacing at the
    leader's position), m."""
    out = []
    front = s_lead
    for k in range(1, convoy_size):
        g = start[k - 1] if start is not None and k - 1 < len(start) else gap_at(v, max(front - L, 0.0))
        for _ in range(6):
            g_new = gap_at(v, max(front - L - g, 0.0))
            done = abs(g_new - g) < 0.1
            g = max(g, g_new) if done else g_new
            if done:
                break
        out.append(g)
        front -= L + g
    return out


def convoy_offsets(inp: HeadwayInputs, convoy_size: int) -> np.ndarray:
    """Δ at every sample of the leader's run: how far the last train's front is behind the leader's, m.

    Level track (no ``inp.coupled_gap_at``): Δ(v) = (n − 1)·(L + g(v)).  On the route: the sum of
    the followers' own spacings where each of them is (:func:`route_gaps`)."""
    run = inp.run
    s = run["s_m"].to_numpy()
    v = run["speed_mps"].to_numpy()
    L = inp.stock.length_m
    if inp.coupled_gap_at is None:
        grid = np.arange(0.0, np.ceil(float(v.max())) + 1.0)  # the gap on a 1 m/s grid, interpolated (not at the rounded speed: below it)
        gap_at = inp.coupled_gap or (lambda v: inp.model.vc_gap(inp.stock, inp.stock, v))
        gaps = np.array([gap_at(float(x)) for x in grid])
        return (convoy_size - 1) * (L + np.interp(v, grid, gaps))
    delta = np.empty(len(s))
    last_s, last_v, gaps = -np.inf, -np.inf, None
    for i in range(len(s)):
        if gaps is None or abs(s[i] - last_s) >= ROUTE_GAP_STEP_M or abs(v[i] - last_v) >= ROUTE_GAP_STEP_MPS:
            gaps = route_gaps(inp.coupled_gap_at, float(v[i]), float(s[i]), L, convoy_size, gaps)
            last_s, last_v = s[i], v[i]
        delta[i] = (convoy_size - 1) * L + sum(gaps)
    return delta


def convoy_rear_lag(inp: HeadwayInputs, convoy_size: int):
    """τ_c(z): time between the convoy's leader and its last train passing position z, s.

    From the separation model alone: each follower runs the coupled gap g behind the rear of the
    train ahead (``inp.coupled_gap_at``: the spacing its stack certifies where it is on the route;
    ``inp.coupled_gap``: the same on level track; else ``vc_gap(v)``, relative braking with the
    assumption set's message-age bound), so the last train's front is Δ (:func:`convoy_offsets`;
    level track: (n − 1)·(L + g(v))) behind the leader's front at the leader's speed v; it passes z
    when the leader's front is at z + Δ (first passage; standing still the gap is the margin and
    the position errors).
    """
    run = inp.run
    t = run["time_s"].to_numpy()
    s = run["s_m"].to_numpy()
    delta = convoy_offsets(inp, convoy_size)
    rear_front = np.maximum.accumulate(s - delta)  # where the last train's front is, as the leader runs
    keep = np.concatenate([[True], np.diff(rear_front) > 1e-6])
    s_last, t_last = rear_front[keep], t[keep]
    s_lead = np.maximum.accumulate(s)

    def lag(z):
        z = np.asarray(z, dtype=float)
        return np.interp(z, s_last, t_last) - np.interp(z, s_lead, t)

    return lag


class VirtualCoupling(Regime):
    """VC: moving block (SUMO's moving-block mode) between units; inside a convoy the followers are
    driven by a vcsumo controller stack at the relative-braking spacing of the separation model.

    Between convoys the next leader keeps the moving-block distance to the previous convoy's last
    train: H(y) = t(z) + τ_c(z) − t(y) + P + T_fixed, z = y + D(v(y)) + margin + 2e + L
    (:func:`convoy_rear_lag`).
    """

    name = "vc"
    title = "Virtual coupling (relative braking in convoys)"
    moving_block = True
    supervision = "mb"
    couples = True
    default_step_s = 0.2

    def analytic_headway(self, inp: HeadwayInputs, convoy_size: int = 1) -> AnalyticHeadway:
        a = inp.model.assumptions
        lag = convoy_rear_lag(inp, convoy_size) if convoy_size > 1 else None
        prof = mb_headway_profile(inp.run, inp.stock.length_m, inp.braking(), inp.model.margin_m, rear_lag_at=lag)
        sel = prof[prof.s_m <= inp.s_check_m]
        if sel.empty:
            sel = prof.iloc[:1]
        i = sel.headway_s.idxmax()
        v0 = float(inp.run["speed_mps"].iloc[0])
        level = gap = None
        if convoy_size > 1:
            level = float(inp.coupled_gap(v0)) if inp.coupled_gap is not None else float(inp.model.vc_gap(inp.stock, inp.stock, v0))
            gap = route_gaps(inp.coupled_gap_at, v0, float(inp.run["s_m"].iloc[0]), inp.stock.length_m, 2)[0] if inp.coupled_gap_at is not None else level
        return AnalyticHeadway(float(sel.loc[i, "headway_s"]) + a.position_report_period_s + a.fixed_time_s, float(sel.loc[i, "s_m"]), coupled_gap_m=gap,
                               coupled_gap_level_m=level, reservation=prof[["s_m", "reserved_to_m"]], rear_lag=lag)
