"""Whether a convoy forms: each follower's gap against the spacing its stack keeps, and why not.

A follower is **formed** while it runs (above 5 m/s) within 10 % + 10 m of its coupled spacing
(the spacing its stack keeps at its speed: :meth:`vcsumo.sim.vc_driver.VCDriver.coupled_spacing_m`).
Time it runs farther behind is put down to one cause, checked in this order:

* ``its predecessor left <station> without it: the platform (… m) cannot hold both`` — since it
  left a stop where it waited outside the platform until its predecessor had gone (a platform too
  short for the pair, warned before the run), until it is formed again: the gap is the platform's,
  whatever it then runs at (until 2026-11-28 this time was put down to the speed limit or full
  traction the follower then ran at: "at full traction" for a timetable matter);
* ``at its permitted speed`` — it already runs at the limit under its whole train or at its own
  top speed (equal trains at the same line speed cannot close a gap opened behind a speed
  restriction, a station or a descent; a slower train cannot keep up with a faster one);
* ``at full traction`` — its controller asks for all the traction the train has (a leader of the
  same type running at its own performance limit, e.g. power-limited on a climb, cannot be caught);
* ``held by the separation guard`` — the guard commanded less than the controller asked;
* ``the controller did not close it`` — otherwise (its own dynamics, a gap reference above the
  spacing, a lossy channel).

``vc_summary.json`` carries, per follower, when it first formed, the share of its running time
formed, the largest excess gap and the dominant reason when it was formed less than half the time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

FORMED_REL = 0.10
FORMED_ABS_M = 10.0
"""Formed: gap ≤ (1 + 10 %)·spacing + 10 m (a follower that keeps its place within a car length)."""
MOVING_MPS = 5.0
"""Formation is judged only above this speed (standing and starting trains keep standstill gaps), m/s."""
AT_LIMIT_MPS = 0.5
"""A follower within this of its permitted speed (the line's under the train, at most its own top speed) runs at the limit, m/s."""

def within_spacing(gap_m: float, spacing_m: float) -> bool:
    """Whether a follower ``gap_m`` behind its predecessor is formed at a ``spacing_m`` spacing."""
    return gap_m <= (1.0 + FORMED_REL) * spacing_m + FORMED_ABS_M


PLATFORM_REASON = "its predecessor left {station} without it: the platform ({length}) cannot hold both"
"""The reason for the time behind after a stop where the follower waited outside the platform."""
REASONS = ("at its permitted speed", "at full traction", "held by the separation guard", "the controller did not close it")


@dataclass
class Formation:
    """A follower's formation account (times in s, gaps in m)."""

    formed_at_s: float = math.nan
    running_s: float = 0.0
    formed_s: float = 0.0
    at_limit_s: float = 0.0
    traction_s: float = 0.0
    held_s: float = 0.0
    other_s: float = 0.0
    max_excess_m: float = 0.0
    platform_s: float = 0.0
    outside: tuple = ()
    """Per stop of the follower (the driver's order): "station (length)" where it waits outside the
    platform until its predecessor has left, else None."""
    left_without: str | None = None
    """The stop its predecessor left without it, while it has not formed since."""
    platform_at: str | None = None
    """The last such stop it ran behind from."""

    def passed_stop(self, k: int) -> None:
        """The follower has passed its ``k``-th stop (it leaves it)."""
        if k < len(self.outside) and self.outside[k] is not None:
            self.left_without = self.platform_at = self.outside[k]

    def update(self, time_s: float, dt_s: float, speed_mps: float, gap_m: float, spacing_m: float, limit_mps: float,
               nominal_speed_mps: float, guard_speed_mps: float, at_full_traction: bool = False) -> None:
        """One sample every ``dt_s`` of a coupled follower (``at_full_traction``: its controller asks
        for the most traction force the train has at this speed)."""
        if speed_mps < MOVING_MPS or not math.isfinite(gap_m):
            return
        self.running_s += dt_s
        if within_spacing(gap_m, spacing_m):
            self.formed_s += dt_s
            if math.isnan(self.formed_at_s):
                self.formed_at_s = time_s
            self.left_without = None
            return
        self.max_excess_m = max(self.max_excess_m, gap_m - spacing_m)
        if self.left_without is not None:
            self.platform_s += dt_s
        elif speed_mps >= limit_mps - AT_LIMIT_MPS:
            self.at_limit_s += dt_s
        elif at_full_traction:
            self.traction_s += dt_s
        elif math.isfinite(guard_speed_mps) and guard_speed_mps < nominal_speed_mps - 0.01:
            self.held_s += dt_s
        else:
            self.other_s += dt_s

    @property
    def formed_share(self) -> float:
        return self.formed_s / self.running_s if self.running_s > 0 else math.nan

    def reason(self) -> str:
        """Why the follower was formed less than half its running time ('' when it was formed)."""
        if self.running_s <= 0:
            return "never ran coupled above 5 m/s"
        if self.formed_share >= 0.5:
            return ""
        times = (self.at_limit_s, self.traction_s, self.held_s, self.other_s)
        k = max(range(len(times)), key=lambda k: times[k])
        if self.platform_s > times[k] and self.platform_at is not None:
            station, _, length = self.platform_at.partition(" (")
            return PLATFORM_REASON.format(station=station, length=length.rstrip(")"))
        return REASONS[k]

    def row(self) -> dict:
        share = self.formed_share
        return {"formed_at_s": None if math.isnan(self.formed_at_s) else round(self.formed_at_s, 1),
                "formed_share": None if math.isnan(share) else round(share, 3), "running_coupled_s": round(self.running_s, 1),
                "max_gap_excess_m": round(self.max_excess_m, 1), "not_formed_reason": self.reason()}
