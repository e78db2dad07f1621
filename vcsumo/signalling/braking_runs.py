"""Braking runs on a gradient profile and the largest closing of two of them (the relative-braking
rule of a follower that may out-brake its leader, :class:`vcsumo.signalling.separation.RelativeBraking`).

A braking run is a list of pieces of constant deceleration in time — (start time s, distance run
m, speed m/s, deceleration m/s²) — the dead time at constant speed, then one piece per stretch of
the route with one deceleration, until the train stands (after its last piece it stands).  Between
the break points of two runs both decelerations are constant, so their closing x_f(t) − x_l(t) is a
parabola: its largest value lies at a break point or where the speeds are equal — the exact worst
closing, continuous in the trains' states.
"""

from __future__ import annotations

import math
from bisect import bisect_right

from vcsumo.units import G


def braking_run(xs: list[float], grades: list[float], rho: float, brake_mps2: float, s_m: float, v_mps: float, dead_time_s: float,
                name: str = "train") -> list[tuple[float, float, float, float]]:
    """The run from the front at ``s_m`` and ``v_mps``: constant speed for ``dead_time_s``, then the
    deceleration ``brake_mps2`` + G·grade/ρ of the stretch [xs[j], xs[j+1]) the front is on
    (``grades[j]``: the gradient the train's braking counts there; the last one continues beyond)."""
    if v_mps <= 0.0:
        return []
    run: list[tuple[float, float, float, float]] = []
    t = x = 0.0
    v = v_mps
    if dead_time_s > 0.0:
        run.append((0.0, 0.0, v, 0.0))
        t, x = dead_time_s, v * dead_time_s
    n = len(grades)
    j = min(max(bisect_right(xs, s_m + x) - 1, 0), n - 1)
    while True:
        a = brake_mps2 + G * grades[j] / rho
        if a <= 0.0:
            raise ValueError(f"{name}: no braking at {s_m + x:.0f} m")
        run.append((t, x, v, a))
        end = xs[j + 1] - s_m if j + 1 < n else math.inf
        if x + v * v / (2.0 * a) <= end:
            return run
        v_end = math.sqrt(max(v * v - 2.0 * a * (end - x), 0.0))
        t += (v - v_end) / a
        x, v = end, v_end
        j += 1


def _run_at(run: list[tuple[float, float, float, float]], t: float) -> tuple[float, float, float]:
    """(distance run, speed, deceleration) of a braking run at time t (standing after its last piece)."""
    if not run:
        return 0.0, 0.0, 0.0
    i = bisect_right([p[0] for p in run], t) - 1
    t0, x0, v0, a = run[max(i, 0)]
    dt = t - t0
    if a > 0.0 and dt >= v0 / a:  # stood within this piece (only the last piece ends in a stand)
        return x0 + v0 * v0 / (2.0 * a), 0.0, 0.0
    return x0 + v0 * dt - 0.5 * a * dt * dt, v0 - a * dt, a


def run_state(run: list[tuple[float, float, float]], t: float) -> tuple[float, float]:
    """(distance run, speed) of a braking run (:func:`braking_run`) at time t ≥ 0, (m, m/s)."""
    x, v, _ = _run_at(run, t)
    return x, v


def max_closing(follower_run: list[tuple[float, float, float, float]], leader_run: list[tuple[float, float, float, float]]) -> float:
    """The largest closing max_t [x_f(t) − x_l(t)] (≥ 0) of two braking runs
    (:meth:`RouteBraking.braking_run`), m: exact — between consecutive break points of either run
    both decelerations are constant, so the closing is a parabola whose largest value lies at an
    end or where the speeds are equal."""
    def end_time(run):
        if not run:
            return 0.0
        t0, _, v0, a = run[-1]
        return t0 + (v0 / a if a > 0.0 else 0.0)

    times = sorted({p[0] for p in follower_run} | {p[0] for p in leader_run} | {end_time(follower_run), end_time(leader_run)} | {0.0})
    best = 0.0
    for k, t in enumerate(times):
        xf, vf, af = _run_at(follower_run, t)
        xl, vl, al = _run_at(leader_run, t)
        if xf - xl > best:
            best = xf - xl
        if k + 1 < len(times) and vf > vl and af != al:  # closing still grows here: where do the speeds meet?
            t_eq = t + (vf - vl) / (af - al) if af > al else math.inf
            if t_eq < times[k + 1]:
                dt = t_eq - t
                c = (xf - xl) + (vf - vl) * dt - 0.5 * (af - al) * dt * dt
                if c > best:
                    best = c
    return best


__all__ = ["braking_run", "max_closing", "run_state"]
