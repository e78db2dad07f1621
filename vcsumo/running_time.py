"""Offline running-time calculation: one train alone on its route, driven as SUMO drives it.

Integrates eq. 1b (:mod:`vcsumo.dynamics`) with SUMO's semi-implicit Euler scheme
(v ← v + a·Δt, then s ← s + v·Δt) and SUMO's driver rules:

* full traction (eq. 4a, 4b) until the speed limit, gradient averaged over the train length;
* a lower limit ahead is approached braking at the service deceleration, a limit (and a turnout)
  is held until the whole train has passed it;
* stops are approached at the service deceleration with a reaction of one step;
* with ``curve`` given (a braking curve: the permitted speed at s towards a target, e.g.
  :meth:`vcsumo.signalling.separation.RouteBraking.curve` — guaranteed braking integrated over the
  gradient profile), limits and stops are approached on the braking curves of vcsumo's
  supervision (:mod:`vcsumo.sim.supervision`) instead, stops finished at a creep speed — as the
  trains SUMO drives under supervision run;
* SUMO's Rail model keeps a train that has reached its own maximum speed at that speed whatever
  the gradient (``hold_at_vmax``), a SUMO simplification reproduced here.

The result is the *unhindered running profile* used by blocking-time theory, by the capacity
studies' hindrance check, and by the dynamics test against real SUMO.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from typing import Callable

from vcsumo.dynamics import TrainParams, discrete_approach_speed, discrete_stop_speed, max_acceleration

STOP_CREEP_MPS = 0.3
"""Creep speed at the end of a supervised stop approach, m/s (as :mod:`vcsumo.sim.supervision`)."""


def curve_speed(distance_m: float, decel_mps2: float, reaction_s: float, target_mps: float = 0.0) -> float:
    """Largest v with v·t_r + (v² − v_t²)/(2·b) ≤ distance (the target speed at or past it), m/s."""
    if distance_m <= 0.0:
        return target_mps
    k = decel_mps2 * reaction_s
    return max(target_mps, -k + math.sqrt(k * k + target_mps * target_mps + 2.0 * decel_mps2 * distance_m))
from vcsumo.route_profile import RouteProfile


@dataclass(frozen=True)
class Stop:
    """A stop on the route: front position (m from route start) and dwell (s)."""

    s_m: float
    dwell_s: float
    name: str = ""


def unhindered_run(
    p: TrainParams,
    profile: RouteProfile,
    dt: float = 0.5,
    s0: float = 0.0,
    v0: float = 0.0,
    stops: list[Stop] | None = None,
    end_s: float | None = None,
    stop_at_end: bool = True,
    hold_at_vmax: bool = True,
    t_max: float = 36000.0,
    curve: Callable[[float, float, float, float], float] | None = None,
) -> pd.DataFrame:
    """Simulate one train alone; return a DataFrame with ``time_s, s_m, speed_mps, accel_mps2``.

    ``stops`` are served in order of position; ``end_s`` (default: route end) is where the run
    ends, braking to a stop there when ``stop_at_end``.  ``curve(s, target, target speed, v)``:
    the permitted speed of supervised braking curves (None: SUMO's own planning at the service
    deceleration).
    """
    b = p.service_brake_decel_mps2
    L = p.length_m
    end = profile.length_m if end_s is None else end_s
    pending = sorted(stops or [], key=lambda x: x.s_m)
    if stop_at_end:
        pending.append(Stop(end, 0.0, "end"))
    targets = profile.restriction_targets()
    vmax_train = p.max_speed_ms
    t, s, v = 0.0, s0, v0
    ts, ss, vs, accs = [t], [s], [v], [0.0]
    dwell_left = 0.0
    ti = 0
    while t < t_max:
        if dwell_left > 0:
            t += dt
            dwell_left -= dt
            ts.append(t); ss.append(s); vs.append(0.0); accs.append(0.0)
            continue
        if s >= end - 1e-6 and (not stop_at_end or v <= 1e-6):
            break
        # limits at the current position (whole-train rule)
        v_lim = min(profile.speed_limit_train(s, L), vmax_train)
        # lower limits ahead
        while ti < len(targets) and targets[ti][0] <= s:
            ti += 1
        j = ti
        horizon = v * v / (2 * (b if curve is None else min(b, 0.15))) + 2 * v * dt + 10.0
        while j < len(targets) and targets[j][0] - s <= horizon:
            ps, pv = targets[j]
            if curve is None:
                v_lim = min(v_lim, discrete_approach_speed(ps - s, pv, b, dt))
            else:
                v_lim = min(v_lim, curve(s, ps, pv, v))
            j += 1
        # next stop
        if pending:
            gap = pending[0].s_m - s
            if curve is None:
                v_lim = min(v_lim, discrete_stop_speed(gap, b, dt))
            elif gap > 0.0:
                v_lim = min(v_lim, max(STOP_CREEP_MPS, curve(s, pending[0].s_m, 0.0, v)))
            else:
                v_lim = 0.0
        # traction
        if hold_at_vmax and v >= vmax_train - 1e-9:
            v_trac = vmax_train
        else:
            a_max = float(max_acceleration(p, v, profile.mean_gradient(s, L), profile.tunnel_factor_at(s)))
            v_trac = v + a_max * dt
        v_new = max(0.0, min(v_trac, v_lim))
        s_new = s + v_new * dt
        if pending and s_new >= pending[0].s_m - 0.05 and (v_new <= b * dt + 1e-9 or curve is not None):
            # arrive: SUMO stops the train at the stop position
            s_new = max(s, min(s_new, pending[0].s_m))
            v_new = 0.0
        t += dt
        accs.append((v_new - v) / dt)
        s, v = s_new, v_new
        ts.append(t); ss.append(s); vs.append(v)
        if pending and v == 0.0 and s >= pending[0].s_m - 0.5:
            stop = pending.pop(0)
            if stop.name == "end":
                break
            dwell_left = stop.dwell_s
    return pd.DataFrame({"time_s": ts, "s_m": ss, "speed_mps": vs, "accel_mps2": accs})


def time_at(run: pd.DataFrame, s_m: float | np.ndarray) -> np.ndarray:
    """First time the front reaches position(s) s (linear interpolation), s; nan if never."""
    s_arr = run["s_m"].to_numpy()
    t_arr = run["time_s"].to_numpy()
    # positions are non-decreasing; use the first index where s >= target
    q = np.atleast_1d(np.asarray(s_m, dtype=float))
    idx = np.searchsorted(s_arr, q, side="left")
    out = np.full(q.shape, np.nan)
    for k, (i, x) in enumerate(zip(idx, q)):
        if i == 0:
            out[k] = t_arr[0] if abs(s_arr[0] - x) < 1e-9 or x < s_arr[0] else np.nan
            if x < s_arr[0]:
                out[k] = np.nan
        elif i < len(s_arr):
            s0, s1 = s_arr[i - 1], s_arr[i]
            t0, t1 = t_arr[i - 1], t_arr[i]
            out[k] = t0 + (t1 - t0) * (x - s0) / (s1 - s0) if s1 > s0 else t1
    return out


def speed_at(run: pd.DataFrame, s_m: float) -> float:
    """Speed when the front passes s (first passage), m/s."""
    s_arr = run["s_m"].to_numpy()
    i = int(np.searchsorted(s_arr, s_m, side="left"))
    if i >= len(s_arr):
        return math.nan
    return float(run["speed_mps"].iloc[i])


def steepest_start(p: TrainParams, profile: RouteProfile, s0: float, s1: float) -> tuple[float, float, float]:
    """Where between front positions s0 and s1 the train starts hardest from a stand:
    ``(front position m, gradient under the train rise/run, acceleration m/s² at full traction)``.

    The gradient is averaged over the train (SUMO's slope), so the steepest start has an end of the
    train at a gradient change. An acceleration ≤ 0 means the train cannot start there: stopped at
    a signal or a station on that grade it stands for ever, and reaching it at speed it slows to a
    stand (at 0 m/s the traction is the largest and the resistance the smallest it will be).
    """
    ends = [s0, s1] + [x + d for x in profile.starts_m[1:] for d in (0.0, p.length_m)]
    worst = (s0, 0.0, math.inf)
    for s in ends:
        if s0 <= s <= s1:
            g = profile.mean_gradient(s, p.length_m)
            a = float(max_acceleration(p, 0.0, g))
            if a < worst[2]:
                worst = (s, g, a)
    return worst


def stall_problem(p: TrainParams, profile: RouteProfile, s0: float, s1: float, place=None) -> str | None:
    """Why the train cannot run its front from s0 to s1 — it cannot start on a grade under it (it
    would stall there: :func:`steepest_start`) — as words, or None when it can. ``place``: the
    words for a front position (default: the profile's section and km)."""
    s, g, a = steepest_start(p, profile, s0, s1)
    if a > 0.0:
        return None
    where = place(s) if place is not None else "{} km {:.3f}".format(*profile.km_at(s))
    need_kn = (p.max_traction_n - a * p.mass_kg * p.rotating_mass_factor) / 1000.0
    return f"cannot start on the {1000 * g:.1f} ‰ grade under it at {where}: it needs {need_kn:.0f} kN, its tractive effort is {p.max_traction_n / 1000.0:.0f} kN"
