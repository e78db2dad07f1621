"""The junction study's measures, from the outputs of its runs: lost time, formation, junction
headway order, the virtual gap, gap violations in the merge and split windows, signal exposure,
overspeed, and the tables behind the plots (definitions: module doc of :mod:`vcsumo.studies.junction`).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.studies.junction.model import ROLES, Case, RunResult, Setup, link_of

HINDRANCE_ABS_MPS = 0.3
"""Formation start: the follower runs slower than alone by more than max(this, HINDRANCE_REL · v), m/s."""
HINDRANCE_REL = 0.005


def lost_time(run: RunResult, solo: dict[str, RunResult], label: str, role: str) -> float:
    t = run.passages.get(label, {}).get(role)
    t0 = solo[role].passages.get(label, {}).get(role)
    if t is None or t0 is None:
        return math.inf
    return (t - run.departures[role]) - (t0 - solo[role].departures[role])


def virtual_gap(setup: Setup, run: RunResult, leader: str, follower: str, at: str = "key") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time, follower distance to the junction, virtual gap) on the follower's steps."""
    tl, sl, _ = run.traces.get(leader, (np.array([]),) * 3)
    tf, sf, _ = run.traces.get(follower, (np.array([]),) * 3)
    if len(tl) < 2 or len(tf) == 0:
        return np.array([]), np.array([]), np.array([])
    sk = setup.s_merge if (at == "merge" or (at == "key" and setup.merge is not None)) else setup.s_split
    sel = (tf >= tl[0]) & (tf <= tl[-1])
    xl = np.interp(tf[sel], tl, sl) - sk[leader]
    xf = sf[sel] - sk[follower]
    return tf[sel], xf, xl - setup.stock.length_m - xf


def _window_count(viol: pd.DataFrame, run: RunResult, setup: Setup, s_j: dict[str, float], w: float) -> int:
    if viol is None or viol.empty:
        return 0
    n = 0
    for _, v in viol.iterrows():
        tr = run.traces.get(v.train)
        if tr is None:
            continue
        s = float(np.interp(v.time_s, tr[0], tr[1]))
        if abs(s - s_j[v.train]) <= w:
            n += 1
    return n


def signal_exposure(setup: Setup, run: RunResult, follower: str, node: str | None, s_node: dict[str, float], links: dict[tuple[str, str], int],
                    model: SeparationModel | None = None) -> tuple[float, float]:
    """(max deceleration needed to stop at the junction signal while it is red for the follower,
    time red while the signal lay inside its guaranteed service braking distance: the separation
    model's stopping distance on its route, after the dead time, on the grades, with the brake at
    the low end of its box — ``model`` None: the setup's) — nan, 0 without data."""
    if node is None or run.signals.empty or follower not in run.traces:
        return math.nan, 0.0
    li, _ = link_of(setup, follower, node, links)
    sig = run.signals[run.signals.signal == node].sort_values("time_s")
    if li is None or sig.empty:
        return math.nan, 0.0
    times = sig.time_s.to_numpy()
    red = np.array([(s[li] if li < len(s) else "G") in "rs" for s in sig.state])
    t, s, v = run.traces[follower]
    idx = np.searchsorted(times, t, side="right") - 1
    is_red = np.where(idx >= 0, red[np.clip(idx, 0, len(red) - 1)], False)
    d = s_node[follower] - s
    mask = is_red & (d > 0.0)
    if not mask.any():
        return 0.0, 0.0
    model = model or setup.model
    braking = RouteBraking(model, setup.stock, setup.profiles[follower], "service")
    req = v[mask] ** 2 / (2.0 * np.maximum(d[mask], 0.5))
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    inside = sum(braking.stopping_distance(float(sk), float(vk), model.dead_time_s) >= dk for sk, vk, dk in zip(s[mask], v[mask], d[mask])) * dt
    return float(req.max()), float(inside)


def _lost_along(run: RunResult, solo: RunResult, role: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time, route position, lost time) of a train along its route against its solo run."""
    t, ss, _ = run.traces[role]
    t0, s0, _ = solo.traces[role]
    keep = np.concatenate([[True], np.diff(s0) > 1e-6])
    t_solo = np.interp(ss, s0[keep], t0[keep], left=np.nan, right=np.nan)
    return t, ss, (t - run.departures[role]) - (t_solo - solo.departures[role])


def formation(setup: Setup, run: RunResult, solo: dict[str, RunResult], leader: str, follower: str) -> dict:
    """Formation start/end around the merge junction in one run (module doc)."""
    out = {"formation_start_m_before_merge": math.nan, "formed_m_after_merge": math.nan, "formation_time_s": math.nan,
           "formation_distance_m": math.nan, "formed_gap_m": math.nan, "formed_speed_mps": math.nan, "formed_lost_time_s": math.nan}
    if setup.merge is None or follower not in run.traces or leader not in run.traces:
        return out
    tf, sf, vf = run.traces[follower]
    _, ss0, vs0 = solo[follower].traces[follower]
    vref = np.interp(sf, ss0, vs0)
    excess = (vref - vf) - np.maximum(HINDRANCE_ABS_MPS, HINDRANCE_REL * vref)
    bad = np.nonzero(excess > 0)[0]
    if not len(bad):
        return out
    i_start = int(bad[0])
    out["formation_start_m_before_merge"] = round(float(setup.s_merge[follower] - sf[i_start]), 1)
    # formed: from where on the lost time stays within max(1 s, 5 %) of its value at the end of the trunk
    t, s, lost = _lost_along(run, solo[follower], follower)
    s_final = (setup.s_split[follower] - setup.window_m) if setup.split is not None else setup.points["END"][follower]
    s_final = max(s_final, setup.s_merge[follower] + 1000.0)
    ok = np.isfinite(lost) & (s <= s_final)
    if not ok.any():
        return out
    l_final = float(np.interp(s_final, s[ok], lost[ok]))
    tol = max(1.0, 0.05 * abs(l_final))
    idx = np.nonzero(ok)[0]
    after = idx[idx >= i_start]
    if not len(after):
        return out
    dev = np.abs(lost[after] - l_final) > tol
    if not dev.any():
        i_form = int(after[0])
    else:
        last = int(np.nonzero(dev)[0][-1])
        if last + 1 >= len(after):
            return out
        i_form = int(after[last + 1])
    tg, xg, g = virtual_gap(setup, run, leader, follower, "merge")
    out["formed_m_after_merge"] = round(float(s[i_form] - setup.s_merge[follower]), 1)
    out["formed_gap_m"] = round(float(np.interp(t[i_form], tg, g)), 1) if len(tg) else math.nan
    out["formed_speed_mps"] = round(float(vf[i_form]), 2)
    out["formed_lost_time_s"] = round(l_final, 2)
    out["formation_time_s"] = round(float(t[i_form] - tf[i_start]), 1)
    out["formation_distance_m"] = round(float(s[i_form] - sf[i_start]), 1)
    return out


def _max_overspeed(setup: Setup, run: RunResult, role: str) -> float:
    """Largest excess of a train's speed over the limit under the whole train (turnouts included), m/s."""
    if role not in run.traces:
        return 0.0
    _, ss, vv = run.traces[role]
    prof, L = setup.profiles[role], setup.stock.length_m
    step = max(1, len(ss) // 4000)
    return max(0.0, max((float(v) - prof.speed_limit_train(float(x), L) for x, v in zip(ss[::step], vv[::step])), default=0.0))


def actual_order(setup: Setup, run: RunResult, leader: str) -> tuple[str, str]:
    """(first, second) train through the first junction of the scenario; the planned order if unknown."""
    follower = "main" if leader == "branch" else "branch"
    p = run.passages.get("M" if setup.merge is not None else "S", {})
    if leader in p and follower in p and p[follower] < p[leader]:
        return follower, leader
    return leader, follower


def run_metrics(setup: Setup, case: Case, run: RunResult, solo: dict[str, RunResult], links, window_m: float) -> dict:
    """Metrics of one pair run (used for the sweep table and the case row).

    ``follower_*``/``leader_*`` lost times refer to the planned order (the hindrance test);
    gaps, signal exposure and the merging service's delay to the actual order through the junction.
    """
    leader = case.first
    follower = "main" if leader == "branch" else "branch"
    m: dict = {"offset_s": run.offset_s}
    for lab in setup.points:
        m[f"follower_lost_{lab}_s"] = lost_time(run, solo, lab, follower)
        m[f"leader_lost_{lab}_s"] = lost_time(run, solo, lab, leader)
    for lab in ("M", "S"):
        p = run.passages.get(lab, {})
        m[f"headway_{lab}_s"] = (p[follower] - p[leader]) if leader in p and follower in p else math.nan
    key = "M" if setup.merge is not None else "S"
    m["order_kept"] = bool(m.get(f"headway_{key}_s", math.nan) > 0)
    first, second = actual_order(setup, run, leader)
    m["first_through_junction"] = first
    lab_d = "PM" if setup.merge is not None else "END"
    m["merging_service_delay_s"] = lost_time(run, solo, lab_d, second)
    m["merging_service_delay_end_s"] = lost_time(run, solo, "END", second)
    m["first_service_delay_end_s"] = lost_time(run, solo, "END", first)
    s = run.summary
    m.update({"gap_violations": s["gap_violations"], "collisions": s["collisions"], "sumo_emergency_brakes": s["emergency_brakes"],
              "sumo_emergency_warnings": run.log.emergency_braking, "red_signal_stops": run.log.emergency_stops,
              "teleports": s["teleports"], "min_gap_m": s["min_gap_m"]})
    # windows
    for kind, node, sj in (("merge", setup.merge_node, setup.s_merge), ("split", setup.split_node, setup.s_split)):
        if node is None:
            m[f"min_gap_{kind}_m"] = math.nan
            m[f"gap_violations_{kind}"] = 0
            m[f"{kind}_red_max_required_decel_mps2"] = math.nan
            m[f"{kind}_red_inside_braking_s"] = math.nan
            continue
        t, xf, g = virtual_gap(setup, run, first, second, kind)
        sel = np.abs(xf) <= window_m
        if kind == "merge" and len(t):
            tl, sl, _ = run.traces[first]
            sel &= np.interp(t, tl, sl) >= sj[first]  # both in line: the first train has entered the junction
        if kind == "split" and len(t):
            tl, sl, _ = run.traces[first]
            x_rear_l = np.interp(t, tl, sl) - sj[first] - setup.stock.length_m
            sel &= x_rear_l <= 0.0  # the leader still occupies the shared track
        m[f"min_gap_{kind}_m"] = round(float(g[sel].min()), 2) if len(t) and sel.any() else math.nan
        m[f"gap_violations_{kind}"] = _window_count(run.violations, run, setup, sj, window_m)
        req, inside = signal_exposure(setup, run, second, node, sj, links)
        m[f"{kind}_red_max_required_decel_mps2"] = round(req, 3) if not math.isnan(req) else math.nan
        m[f"{kind}_red_inside_braking_s"] = round(inside, 1)
    m["max_overspeed_mps"] = round(max((_max_overspeed(setup, run, r) for r in ROLES), default=0.0), 2)
    m["vc_guard_interventions"] = run.vc.get("guard_interventions", 0) if run.vc else 0
    m["vc_emergency_activations"] = run.vc.get("vc_emergency_activations", 0) if run.vc else 0
    m["vc_supervisor_interventions"] = run.vc.get("supervisor_interventions", 0) if run.vc else 0
    m["junction_signal_caps"] = run.driver_counts.get("signal_caps", 0)
    m["junction_signal_overruns"] = run.driver_counts.get("signal_overruns", 0)
    m["speed_profile_caps"] = run.driver_counts.get("speed_profile_caps", 0)
    return m


def unhindered(m: dict, label: str, tolerance_s: float, setup: Setup) -> bool:
    """The pair passes the merge junction ('junction': up to the junction node), the merge ('merge':
    up to the merge check point) or the split ('split') without hindrance (module doc)."""
    if m["collisions"] or m["teleports"]:
        return False
    if label == "junction":
        if m["gap_violations_merge"]:
            return False
        return m["follower_lost_M_s"] <= tolerance_s and m["leader_lost_M_s"] <= tolerance_s and m["order_kept"]
    if label == "merge":
        if m["gap_violations_merge"]:
            return False
        return m["follower_lost_PM_s"] <= tolerance_s and m["leader_lost_PM_s"] <= tolerance_s and m["order_kept"]
    if m["gap_violations_split"]:
        return False
    base_f = m.get("follower_lost_PM_s", 0.0) if setup.merge is not None else 0.0
    base_l = m.get("leader_lost_PM_s", 0.0) if setup.merge is not None else 0.0
    if math.isinf(base_f) or math.isinf(base_l):
        return False
    return m["follower_lost_END_s"] - base_f <= tolerance_s and m["leader_lost_END_s"] - base_l <= tolerance_s and (
        setup.merge is not None or m["order_kept"])


def speed_at_trace(run: RunResult, role: str, s: float) -> float:
    """A train's speed at route position s in a run (interpolated between steps), m/s; nan without a trace."""
    tr = run.traces.get(role)
    if tr is None or len(tr[1]) == 0:
        return math.nan
    return float(np.interp(s, tr[1], tr[2]))




def trajectory_rows(setup: Setup, case: Case, run_name: str, run: RunResult) -> pd.DataFrame:
    """1 s samples of a run: per train distances to the junctions, speed, virtual and sensed gap."""
    tr = run.trajectories
    if tr is None or tr.empty:
        return pd.DataFrame()
    leader = case.first
    follower = "main" if leader == "branch" else "branch"
    df = tr[["time_s", "train", "s_m", "speed_mps", "gap_m", "leader"]].copy()
    df["role"] = np.where(df.train == leader, "leader", "follower") if run_name != "solo" else "alone"
    df["service"] = df.train
    df["distance_to_merge_m"] = df.apply(lambda r: r.s_m - setup.s_merge[r.train], axis=1) if setup.merge is not None else math.nan
    df["distance_to_split_m"] = df.apply(lambda r: r.s_m - setup.s_split[r.train], axis=1) if setup.split is not None else math.nan
    df["virtual_gap_m"] = math.nan
    if run_name != "solo" and leader in run.traces and follower in run.traces:
        t, _, g = virtual_gap(setup, run, leader, follower)
        if len(t) and setup.split is not None:
            # after the split the two trains are on different tracks: no gap
            tl, sl, _ = run.traces[leader]
            tf, sf, _ = run.traces[follower]
            parted = ((np.interp(t, tl, sl) - setup.stock.length_m) > setup.s_split[leader]) | (np.interp(t, tf, sf) > setup.s_split[follower])
            g = np.where(parted, np.nan, g)
        fsel = df.train == follower
        if len(t):
            df.loc[fsel, "virtual_gap_m"] = np.interp(df.loc[fsel, "time_s"], t, g, left=np.nan, right=np.nan)
    df = df.rename(columns={"gap_m": "sensed_gap_m", "leader": "sensed_leader", "s_m": "route_position_m"})
    df.insert(0, "run", run_name)
    df.insert(0, "offset_s", run.offset_s if run_name != "solo" else math.nan)
    for k, v in (("split_junction", setup.split.id if setup.split else ""), ("merge_junction", setup.merge.id if setup.merge else ""),
                 ("junction_signal", case.variant or ""), ("controller", case.controller or ""), ("regime", case.regime), ("leader_service", case.first),
                 ("direction", setup.direction), ("junction", setup.junction.id), ("line", setup.line.name)):
        df.insert(0, k, v)
    return df.round(3)


def signal_rows(setup: Setup, case: Case, run_name: str, run: RunResult, links) -> pd.DataFrame:
    """The junction signals' aspects for each train at every switch of a run."""
    if run.signals.empty:
        return pd.DataFrame()
    leader = case.first
    rows = []
    for _, s in run.signals.iterrows():
        for role in ROLES:
            li, e_in = link_of(setup, role, s.signal, links)
            if li is None or li >= len(s.state):
                continue
            rows.append({"line": setup.line.name, "junction": setup.junction.id, "direction": setup.direction, "leader_service": leader,
                         "regime": case.regime, "controller": case.controller or "", "junction_signal": case.variant or "", "run": run_name,
                         "offset_s": run.offset_s, "time_s": s.time_s, "signal": s.signal,
                         "junction_kind": "merge" if s.signal == setup.merge_node else "split", "service": role,
                         "role": "leader" if role == leader else "follower", "incoming_edge": e_in, "aspect": "red" if s.state[li] in "rs" else "green"})
    return pd.DataFrame(rows)


