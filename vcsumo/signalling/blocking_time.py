"""Blocking-time theory: analytic minimum headways from an unhindered running profile.

For identical trains on the same unhindered profile t(s), v(s) (from
:func:`vcsumo.running_time.unhindered_run`):

* **Fixed block (FBS).**  Block k runs from signal S_k to S_{k+1}.  The follower must find S_k
  clear when it reaches the *approach point* a_k, where a_k + D(v(a_k)) = S_k (it would otherwise
  start braking for the red aspect); the leader releases block k when its tail clears S_{k+1}.
  Blocking time of block k: H_k = t(S_{k+1} + L) − t(a_k).  On a uniform section at speed v this
  is (D(v) + block + L)/v — "braking distance + block + train length over speed".
* **Moving block (MB).**  The follower at position y must stay D(v(y)) + margin behind the
  leader's tail: H(y) = t(y + D(v(y)) + margin + L) − t(y); uniform: (D(v) + margin + L)/v.
* **Virtual coupling (VC, relative braking distance).**  H(y) = (d + L)/v at a coupled gap d.

D(v) = v²/(2b) + v·t_r is the braking distance at the service deceleration b after a reaction
time t_r.  The minimum headway of a train sequence measured at x is the largest blocking time
met between the release point and x (the critical block upstream of x).

SUMO's signalling has no setup, sighting or release times, so none are added here; real ETCS
operation adds them on top (the DATASHEET's 7 s + 14 s), which the capacity study reports
separately as timetable buffer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from vcsumo.dynamics import braking_distance
from vcsumo.running_time import time_at

SUMO_MB_MARGIN_M = 50.0
"""SUMO's Rail model keeps braking distance + 50 m in moving block from 30 km/h (CIR-ELKE)."""
SUMO_MB_SLOW_MARGIN_M = 5.0
"""Below 30 km/h the 50 m margin is dropped and only the train's minGap (5 m) remains."""
SUMO_MB_MARGIN_SPEED_MPS = 30.0 / 3.6


def sumo_mb_margin(speed_mps):
    """The margin SUMO's moving block keeps behind the train ahead at the follower's speed, m:
    50 m from 30 km/h, the train's minGap (5 m) below (scalar or array)."""
    m = np.where(np.asarray(speed_mps) >= SUMO_MB_MARGIN_SPEED_MPS, SUMO_MB_MARGIN_M, SUMO_MB_SLOW_MARGIN_M)
    return float(m) if m.ndim == 0 else m


def sumo_reaction_time(step_s: float) -> float:
    """Equivalent reaction time of SUMO's rail driver, s.

    SUMO's Euler stop speed with a one-step headway gives a braking distance of
    v²/(2b) + ½·Δt·v (measured: 0.505·Δt·v at Δt = 0.5 s and 0.1 s, v = 10 m/s).
    """
    return 0.5 * step_s


@dataclass(frozen=True)
class BrakingRule:
    """How the follower's braking distance is computed."""

    decel_mps2: float
    reaction_time_s: float = 0.0

    def distance(self, v: np.ndarray | float, s: np.ndarray | float | None = None) -> np.ndarray | float:
        """Braking distance at speed v (the position s is not used: constant deceleration), m."""
        return braking_distance(v, self.decel_mps2, self.reaction_time_s)


def _approach_point(s: np.ndarray, v: np.ndarray, rule: BrakingRule, signal_s: float, reach: np.ndarray | None = None) -> float:
    """First position a with a + D(v(a)) >= signal_s on the run."""
    reach = s + rule.distance(v, s) if reach is None else reach
    idx = np.nonzero(reach >= signal_s)[0]
    if len(idx) == 0:
        return float(s[-1])
    i = int(idx[0])
    if i == 0:
        return float(s[0])
    # linear interpolation between samples i-1 and i
    r0, r1 = reach[i - 1], reach[i]
    f = 0.0 if r1 == r0 else (signal_s - r0) / (r1 - r0)
    return float(s[i - 1] + f * (s[i] - s[i - 1]))


def fbs_blocking_times(run: pd.DataFrame, signals_s: list[float], route_end_s: float, length_m: float, rule: BrakingRule,
                       approach_offset_m: float = 0.0, clear_offset_m: float = 0.0) -> pd.DataFrame:
    """Blocking time of every block on the run (one row per block).

    Columns: ``block_start_m, block_end_m, approach_m, t_approach_s, t_clear_s, blocking_time_s``.
    Blocks whose approach point lies before the run's start are approached at the start (the
    follower is released there).  ``approach_offset_m``: the follower must be able to stop this far
    before a signal (its position error); ``clear_offset_m``: the rear of the train ahead must be
    this far beyond the block's end before the block is released (overlap, position error).  A train
    releases every block it still occupies when it leaves the route at ``route_end_s``.
    """
    s = run["s_m"].to_numpy()
    v = run["speed_mps"].to_numpy()
    s0 = float(s[0])
    sig = sorted(x for x in signals_s if x > s0 + 1e-6)
    ends = sig[1:] + [route_end_s]
    reach = s + rule.distance(v, s) + approach_offset_m
    rows = []
    for start, end in zip(sig, ends):
        a = max(_approach_point(s, v, rule, start, reach), s0)
        t_app = float(time_at(run, a)[0])
        # a train leaving the route (its front at the end) releases every block it still occupies
        clear = min(end + clear_offset_m + length_m, route_end_s)
        t_clr = float(time_at(run, min(clear, float(s[-1])))[0])
        if clear > s[-1] + 1e-6:
            # the run ends before the tail clears: extrapolate at the last speed
            t_clr = float(run["time_s"].iloc[-1]) + (clear - s[-1]) / max(float(v[-1]), 0.1)
        rows.append((start, end, a, t_app, t_clr, t_clr - t_app))
    return pd.DataFrame(rows, columns=["block_start_m", "block_end_m", "approach_m", "t_approach_s", "t_clear_s", "blocking_time_s"])


def mb_headway_profile(run: pd.DataFrame, length_m, rule: BrakingRule, margin_m: float | None = None, step_m: float = 50.0,
                       rear_lag_at=None) -> pd.DataFrame:
    """Moving-block headway H(y) along the run; columns ``s_m, speed_mps, headway_s, reserved_to_m``.

    The follower at y keeps D(v(y)) + margin to the rear of the train ahead: H(y) = t(z) − t(y)
    with z = y + D + margin + L.  ``margin_m`` None: SUMO's own margin (50 m from 30 km/h, its
    minGap of 5 m below, :func:`sumo_mb_margin`); a number: that margin at every speed (before,
    a margin of exactly 50 m was taken for SUMO's and dropped to 5 m below 30 km/h: an assumption
    set with a 30 m margin and 10 m position errors got a 3.4 s shorter MB headway at a departure).
    For a VC convoy ahead (``rear_lag_at``: the time between its leader and its last train passing a
    position) the rear passes z ``rear_lag_at(z)`` after the leader: H(y) = t(z) + τ_c(z) − t(y),
    with ``length_m`` then the last train's length.  ``reserved_to_m``: how far the track ahead of a
    front at y is reserved, y + D + margin (the band of the time–distance figure).
    """
    s = run["s_m"].to_numpy()
    v = run["speed_mps"].to_numpy()
    grid = np.arange(float(s[0]), float(s[-1]), step_m)
    vy = np.interp(grid, s, v)
    L = length_m(vy) if callable(length_m) else length_m
    margin = sumo_mb_margin(vy) if margin_m is None else margin_m
    reserved = grid + rule.distance(vy, grid) + margin
    ahead = reserved + L
    t_y = time_at(run, grid)
    t_ahead = time_at(run, np.minimum(ahead, s[-1]))
    over = ahead > s[-1]
    t_ahead[over] = float(run["time_s"].iloc[-1]) + (ahead[over] - s[-1]) / max(float(v[-1]), 0.1)
    if rear_lag_at is not None:
        t_ahead = t_ahead + rear_lag_at(np.minimum(ahead, s[-1]))
    return pd.DataFrame({"s_m": grid, "speed_mps": vy, "headway_s": t_ahead - t_y, "reserved_to_m": reserved})


def fbs_headway_at(blocks: pd.DataFrame, x_m: float) -> tuple[float, float]:
    """(headway s, critical block start m) at measuring point x: max over blocks approached before x."""
    sel = blocks[blocks["approach_m"] <= x_m + 1e-6]
    if sel.empty:
        return float("nan"), float("nan")
    i = sel["blocking_time_s"].idxmax()
    return float(sel.loc[i, "blocking_time_s"]), float(sel.loc[i, "block_start_m"])


def mb_headway_at(profile: pd.DataFrame, x_m: float) -> tuple[float, float]:
    """(headway s, critical position m) at measuring point x: max of H(y) for y ≤ x."""
    sel = profile[profile["s_m"] <= x_m + 1e-6]
    if sel.empty:
        return float("nan"), float("nan")
    i = sel["headway_s"].idxmax()
    return float(sel.loc[i, "headway_s"]), float(sel.loc[i, "s_m"])


def uniform_fbs_headway(v: float, block_m: float, length_m: float, rule: BrakingRule) -> float:
    """(D(v) + block + L)/v, s."""
    return (float(rule.distance(v)) + block_m + length_m) / v


def uniform_mb_headway(v: float, length_m: float, rule: BrakingRule, margin_m: float = SUMO_MB_MARGIN_M) -> float:
    """(D(v) + margin + L)/v, s."""
    return (float(rule.distance(v)) + margin_m + length_m) / v


def vc_headway(v: float, gap_m: float, length_m: float) -> float:
    """(d + L)/v at a coupled gap d, s (relative braking distance)."""
    return (gap_m + length_m) / v
