"""ETCS-style fixed times in the loop: a movement authority that is ``fixed_time_s`` old.

Blocking-time theory (Pachl, *Railway Operation and Control*; UIC 406) adds to every block
occupation the *fixed times* of the signalling: route setting, movement-authority (MA)
transmission and processing (RBC → on-board), and the driver's / on-board unit's reaction.  Their
sum T is typically 10–20 s for ETCS level 2, e.g. route setting 6 s + MA transmission 4 s +
reaction 3 s = 13 s.  Each one delays the moment a train may use track the train ahead has freed,
so every minimum headway grows by exactly T — in FBS (the block behind the train ahead is
released to the follower T later) and in moving block (the follower's MA ends behind where the
rear of the train ahead was T ago).

SUMO's rail signals and its moving-block driver know no fixed times.  :class:`DelayedAuthority`
adds them on top: for each train SUMO drives it remembers how far the train ahead has run, places
that train's rear where it was T seconds ago, and caps the follower's speed to what it may run
towards that older end of authority:

* FBS: the EoA is the last signal at or behind the delayed rear (the block that rear occupies is
  still occupied for the follower);
* MB: the EoA is the delayed rear minus the moving-block margin (50 m from 30 km/h, 5 m below, as
  SUMO keeps it).

The cap is the largest speed from which the train stops before the EoA with the service
deceleration after SUMO's one-step reaction (:func:`vcsumo.signalling.blocking_time.sumo_reaction_time`):
v²/(2b) + t_r·v ≤ EoA − position.  SUMO still applies its own (fresher) signal or gap logic, so
the result is the stricter of the two.  Trains vcsumo's virtual-coupling controllers drive are not
capped: inside a convoy, authority comes over the train-to-train channel and its delay is the
channel's (:mod:`vcsumo.control.channel`).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, field

from vcsumo.signalling.blocking_time import sumo_mb_margin


def authority_speed(distance_m: float, decel_mps2: float, reaction_s: float) -> float:
    """Largest v with v²/(2b) + t_r·v ≤ distance (0 for no distance), m/s."""
    if distance_m <= 0.0:
        return 0.0
    bt = decel_mps2 * reaction_s
    return -bt + math.sqrt(bt * bt + 2.0 * decel_mps2 * distance_m)


@dataclass
class _History:
    times: deque = field(default_factory=deque)
    positions: deque = field(default_factory=deque)

    def add(self, t: float, s: float, keep_s: float) -> None:
        self.times.append(t)
        self.positions.append(s)
        while len(self.times) > 2 and self.times[1] <= t - keep_s:
            self.times.popleft()
            self.positions.popleft()

    def at(self, t: float) -> float | None:
        """Position at time t (linear between samples); None before the first sample."""
        if not self.times or t < self.times[0] - 1e-9:
            return None
        i = bisect.bisect_right(self.times, t)
        if i >= len(self.times):
            return self.positions[-1]
        t0, t1 = self.times[i - 1], self.times[i]
        s0, s1 = self.positions[i - 1], self.positions[i]
        return s0 + (s1 - s0) * (t - t0) / max(t1 - t0, 1e-9)


class DelayedAuthority:
    """Speed caps that make SUMO's trains see a movement authority ``fixed_time_s`` old.

    ``signals_m``: per train, the route positions of the signals along its route (FBS; empty or
    absent for moving block).  ``decel_mps2``: per train, the service deceleration the cap uses.
    """

    def __init__(self, fixed_time_s: float, regime: str, step_s: float, decel_mps2: dict[str, float], signals_m: dict[str, list[float]] | None = None):
        if fixed_time_s < 0:
            raise ValueError("fixed_time_s must not be negative")
        self.fixed_time_s = fixed_time_s
        self.fbs = regime == "fbs"
        self.step_s = step_s
        self.reaction_s = 0.5 * step_s
        self.decel = decel_mps2
        self.signals = signals_m or {}
        self.history: dict[str, _History] = {}
        self.caps_applied = 0

    def end_of_authority(self, follower_s: float, gap_m: float, leader_s_now: float, leader_s_then: float | None, follower_speed_mps: float, follower: str) -> float:
        """EoA (follower's route frame, m) from the gap to the rear of the train ahead now and
        how far that train has run in the last ``fixed_time_s``."""
        if leader_s_then is None:  # the train ahead has not been seen that long: no older information
            return math.inf
        rear_then = follower_s + gap_m - (leader_s_now - leader_s_then)
        if self.fbs:
            sig = self.signals.get(follower, [])
            i = bisect.bisect_right(sig, rear_then) - 1
            if i < 0 or sig[i] <= follower_s + 1.0:
                return math.inf  # no signal between: SUMO let the train into that block already
            return sig[i]
        return rear_then - sumo_mb_margin(follower_speed_mps)

    def caps(self, time_s: float, trains: dict, skip: set[str] = frozenset()) -> dict[str, float]:
        """Speed caps (m/s) for this step; ``trains``: id → state with ``s_m``, ``speed_mps``,
        ``leader``, ``gap_m`` (the simulation's snapshot).  Trains in ``skip`` are not capped."""
        keep = self.fixed_time_s + 5.0 * self.step_s
        for tid, st in trains.items():
            self.history.setdefault(tid, _History()).add(time_s, st.s_m, keep)
        if self.fixed_time_s <= 0.0:
            return {}
        out: dict[str, float] = {}
        for tid, st in trains.items():
            if tid in skip or st.leader is None or st.leader not in trains or not math.isfinite(st.gap_m):
                continue
            lead = trains[st.leader]
            then = self.history[st.leader].at(time_s - self.fixed_time_s)
            eoa = self.end_of_authority(st.s_m, st.gap_m, lead.s_m, then, st.speed_mps, tid)
            if not math.isfinite(eoa):
                continue
            out[tid] = authority_speed(eoa - st.s_m, self.decel.get(tid, 0.5), self.reaction_s)
        return out
