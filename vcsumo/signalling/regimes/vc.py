"""Virtual coupling: moving block between convoys, relative braking inside them."""

from __future__ import annotations

import numpy as np

from vcsumo.signalling.blocking_time import mb_headway_profile
from vcsumo.signalling.regimes.base import AnalyticHeadway, HeadwayInputs, Regime


def convoy_rear_lag(inp: HeadwayInputs, convoy_size: int):
    """τ_c(z): time between the convoy's leader and its last train passing position z, s.

    From the separation model alone: each follower runs the coupled gap g(v) behind the rear of the
    train ahead (``inp.coupled_gap``: the spacing its stack certifies; else ``vc_gap(v)``, relative
    braking with the assumption set's message-age bound), so the
    last train's front is Δ(v) = (n − 1)·(L + g(v)) behind the leader's front at the leader's speed
    v; it passes z when the leader's front is at z + Δ(v) (first passage; standing still the gap
    is the margin and the position errors).
    """
    run = inp.run
    t = run["time_s"].to_numpy()
    s = run["s_m"].to_numpy()
    v = run["speed_mps"].to_numpy()
    L = inp.stock.length_m
    grid = np.arange(0.0, np.ceil(float(v.max())) + 1.0)  # the gap on a 1 m/s grid, interpolated (not at the rounded speed: below it)
    gap_at = inp.coupled_gap or (lambda v: inp.model.vc_gap(inp.stock, inp.stock, v))
    gaps = np.array([gap_at(float(x)) for x in grid])
    delta = (convoy_size - 1) * (L + np.interp(v, grid, gaps))
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
        gap = (inp.coupled_gap(v0) if inp.coupled_gap is not None else inp.model.vc_gap(inp.stock, inp.stock, v0)) if convoy_size > 1 else None
        return AnalyticHeadway(float(sel.loc[i, "headway_s"]) + a.position_report_period_s + a.fixed_time_s, float(sel.loc[i, "s_m"]), coupled_gap_m=gap)
