"""The timetable's scheduled running profile of a train: the input to blocking-time stairs and the
arrival a train's delay is measured against.

Each train runs its *scheduled running profile* (:func:`timetable_run`): its unhindered run
(:func:`vcsumo.running_time.unhindered_run`, SUMO's driving rules) from its scheduled departure,
with the recovery margin of every stretch spread over the running: between two timing points
(the departure, then every stop with a scheduled time and the scheduled arrival) the running is
slowed uniformly (time × f, speed ÷ f, f ≥ 1) so that the train arrives at the scheduled time;
it dwells for its dwell or until its scheduled departure, whichever is later.  Stretches without
a scheduled arrival at their end are run unhindered.

Trains repeating a pattern (same route, stock, stops and relative times: :func:`pattern_key`)
share one profile computed at time 0 (:func:`at_time_zero`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pandas as pd

from vcsumo.errors import InfeasibleBraking
from vcsumo.running_time import Stop, unhindered_run
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.timetable import PlannedTrain

def route_end_s(t: PlannedTrain) -> float:
    end_pos = t.end_pos_m if t.end_pos_m is not None else float(t.profile.lengths_m[-1])
    return float(t.profile.starts_m[-1] + end_pos)


def departure_index(run: pd.DataFrame, stop_s: float, from_index: int = 0) -> int:
    """Index of the last sample standing at a stop (the moment of departure)."""
    s = run["s_m"].to_numpy()
    v = run["speed_mps"].to_numpy()
    at = np.nonzero((np.abs(s - stop_s) < 0.6) & (v <= 1e-9))[0]
    at = at[at >= from_index]
    if len(at) == 0:
        return from_index
    # the contiguous standing samples after the first arrival
    i = int(at[0])
    while i + 1 < len(s) and abs(s[i + 1] - stop_s) < 0.6 and v[i + 1] <= 1e-9:
        i += 1
    return i


def timetable_run(train: PlannedTrain, dt: float = 0.5, model: SeparationModel | None = None) -> pd.DataFrame:
    """The train's scheduled running profile in absolute time (``time_s, s_m, speed_mps, accel_mps2``).

    See "Running profiles" in the module docstring: the unhindered run, each stretch between
    timing points slowed uniformly to meet the scheduled arrival at its end, dwells extended to
    the scheduled departures.  ``model``: the run braking on its guaranteed, gradient-compensated
    curve under that assumption set, as the supervision brakes every train SUMO drives (None:
    SUMO's own driving, its nominal service brake).
    """
    p = train.stock.params()
    try:
        curve = RouteBraking(model, train.stock, train.profile).curve(1.5 * dt) if model is not None else None
    except InfeasibleBraking as exc:  # its guaranteed brake does not hold it on a descent of its route (as the run says it)
        raise exc.for_train(train.id, model.assumptions.name) from None
    run = unhindered_run(p, train.profile, dt=dt, s0=train.start_s_m, v0=train.depart_speed_mps,
                         stops=[Stop(s.s_m, s.dwell_s) for s in train.stops], end_s=route_end_s(train), stop_at_end=train.stop_at_end, curve=curve)
    t = run["time_s"].to_numpy()
    s = run["s_m"].to_numpy()
    v = run["speed_mps"].to_numpy().copy()
    acc = run["accel_mps2"].to_numpy().copy()
    # standing intervals [arrival index, departure index] at each stop
    stand: list[tuple[int, int]] = []
    i = 0
    for st in train.stops:
        j = departure_index(run, st.s_m, i)
        a = j
        while a > i and abs(s[a - 1] - st.s_m) < 0.6 and v[a - 1] <= 1e-9:
            a -= 1
        stand.append((a, j))
        i = j
    n = len(train.stops)
    # timing points 1..n (stops) and n+1 (end): scheduled arrival / departure
    sched_arr = [st.arrival_s for st in train.stops] + [train.scheduled_arrival_s]
    sched_dep = [st.departure_s for st in train.stops] + [None]
    # running segments: k = 0..n, from the departure of point k (0 = origin) to the arrival at point k+1
    seg = [((0 if k == 0 else stand[k - 1][1]), (stand[k][0] if k < n else len(t) - 1)) for k in range(n + 1)]
    run_dur = [t[b] - t[a] for a, b in seg]
    dwell_dur = [t[b] - t[a] for a, b in stand]
    factor = [1.0] * (n + 1)
    new_dwell = list(dwell_dur)
    anchor_time, first = train.depart_s, 0
    for k in range(n + 1):
        is_timing = sched_arr[k] is not None or sched_dep[k] is not None or k == n
        if not is_timing:
            continue
        if sched_arr[k] is not None:
            running = sum(run_dur[first : k + 1])
            dwelling = sum(dwell_dur[first:k])
            f = (sched_arr[k] - anchor_time - dwelling) / running if running > 0 else 1.0
            for m in range(first, k + 1):
                factor[m] = max(1.0, f)
        arrival = anchor_time + sum(run_dur[m] * factor[m] for m in range(first, k + 1)) + sum(dwell_dur[first:k])
        if k < n:
            departure = max(arrival + dwell_dur[k], sched_dep[k] if sched_dep[k] is not None else -math.inf)
            new_dwell[k] = departure - arrival
            anchor_time, first = departure, k + 1
    # map every sample onto the new time axis
    t_new = np.empty_like(t)
    clock = train.depart_s
    for k in range(n + 1):
        a, b = seg[k]
        f = factor[k]
        t_new[a : b + 1] = clock + (t[a : b + 1] - t[a]) * f
        v[a + 1 : b + 1] /= f
        acc[a + 1 : b + 1] /= f * f
        clock = t_new[b]
        if k < n:
            a2, b2 = stand[k]
            span = t[b2] - t[a2]
            frac = (t[a2 : b2 + 1] - t[a2]) / span if span > 0 else np.zeros(b2 - a2 + 1)
            t_new[a2 : b2 + 1] = clock + frac * new_dwell[k]
            clock = t_new[b2]
    return pd.DataFrame({"time_s": t_new, "s_m": s, "speed_mps": v, "accel_mps2": acc})


def reference_arrival_s(train: PlannedTrain, dt: float = 0.5, run: pd.DataFrame | None = None) -> float:
    """The arrival a train is measured against: its scheduled arrival, or, without one, the end of
    its timetable profile (:func:`timetable_run`) — plus the 1 s end stop SUMO makes a train
    leaving the network at the end of a track (or a branch) serve before it arrives."""
    if train.scheduled_arrival_s is not None:
        return float(train.scheduled_arrival_s)
    run = timetable_run(train, dt) if run is None else run
    extra = 1.0 if train.final_stop is None and train.stop_at_end and train.end_pos_m is not None else 0.0
    return float(run["time_s"].iloc[-1]) + extra


def reference_arrivals(trains: list[PlannedTrain], dt: float = 0.5, model: SeparationModel | None = None) -> dict[str, float]:
    """:func:`reference_arrival_s` of every train (trains repeating a pattern share one profile);
    ``model``: on the supervision's braking curves under that set (:func:`timetable_run`)."""
    cache: dict[tuple, pd.DataFrame] = {}
    out: dict[str, float] = {}
    for t in trains:
        if t.scheduled_arrival_s is not None:
            out[t.id] = float(t.scheduled_arrival_s)
            continue
        key = pattern_key(t)
        if key not in cache:
            cache[key] = timetable_run(at_time_zero(t), dt, model)
        rel = cache[key]
        extra = 1.0 if t.final_stop is None and t.stop_at_end and t.end_pos_m is not None else 0.0
        out[t.id] = t.depart_s + float(rel["time_s"].iloc[-1]) + extra
    return out


def at_time_zero(t: PlannedTrain) -> PlannedTrain:
    """The same train departing at time 0 (every scheduled time shifted with it)."""
    off = t.depart_s

    def sh(x: float | None) -> float | None:
        return None if x is None else x - off

    stops = [replace(s, arrival_s=sh(s.arrival_s), departure_s=sh(s.departure_s)) for s in t.stops]
    return replace(t, depart_s=0.0, stops=stops, scheduled_arrival_s=sh(t.scheduled_arrival_s))


def pattern_key(t: PlannedTrain) -> tuple:
    return (tuple(t.edges), t.stock.name, round(t.start_s_m, 3), round(t.depart_speed_mps, 3), round(route_end_s(t), 3), t.stop_at_end,
            tuple((round(s.s_m, 3), s.dwell_s, None if s.departure_s is None else round(s.departure_s - t.depart_s, 3)) for s in t.stops))
