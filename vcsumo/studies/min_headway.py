"""Minimum headway by simulation: the closest release interval at which no train is hindered.

Identical trains (or convoys) are released at a fixed interval h.  The first train runs alone,
so its speed profile is the unhindered one.  A later train is *hindered* up to a measuring point
when, anywhere before that point, it runs slower than the first train did at the same position by
more than a tolerance (it braked for a restrictive signal or for the braking distance to the
train ahead), when its insertion was delayed, when it never reaches the point, or when any
collision or gap violation occurs.  The minimum headway at a point is the smallest h with no hindrance there,
found by bisection on h (each probe is one SUMO run; probes are cached and shared by all
points).  This is "as close as the regime allows" for every regime: SUMO's own insertion is not
used to space the trains (in moving block it inserts trains closer than the braking distance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import pandas as pd


def first_passes(trace: tuple[list[float], list[float]]):
    """A speed trace as a function of position: each step's sample where the train first reaches a
    position beyond every earlier one.  A train inside a junction (SUMO's internal lane, a point of the
    route) or standing keeps its position for some steps while its speed changes; interpolating
    across those samples compared a train's speed at the junction with whichever of them came last."""
    import numpy as np

    s, v = np.asarray(trace[0], dtype=float), np.asarray(trace[1], dtype=float)
    if len(s) < 2:
        return s, v
    keep = np.concatenate(([True], s[1:] > np.maximum.accumulate(s)[:-1]))
    return s[keep], v[keep]


@dataclass
class Probe:
    """The outcome of one simulation at release interval ``h_s``."""

    h_s: float
    passages: pd.DataFrame
    """Columns measuring_point, train, time_s (as written by the simulation loop)."""
    departures: dict[str, float]
    """Scheduled departure of each train, s."""
    summary: dict
    delays: dict[str, float] = field(default_factory=dict)
    """Largest time lost by a train up to each measuring point relative to the first, s (inf: never passed)."""
    speed_deficit: dict[str, float] = field(default_factory=dict)
    """Largest speed deficit (unhindered − actual) before each measuring point, m/s."""

    def compute_speed_deficits(self, points_m: dict[str, float], traces: dict[str, tuple[list[float], list[float]]], order: list[str], start_delays: dict[str, float], rel_tol: float = 0.005, abs_tol_mps: float = 0.3, pairs: list[tuple[str, str]] | None = None, min_speed_mps: float = 0.0,
                               step_s: float = 0.0) -> None:
        """Speed deficit before each point, normalised so that a value above 0 means hindered.

        Positions where the reference runs slower than ``min_speed_mps`` (the last metres of a
        stop, the first of a start, where speed against position is too steep to compare between
        two sampled runs) are left to the lost-time check.

        Each train is compared with its reference (by default the first train of ``order``; for
        convoys ``pairs`` gives (train, same member of the first convoy)).  A train whose start was
        delayed by more than max(0.5 s, ``step_s``) is hindered (SUMO inserts a train at the first step
        at or after its departure: at least one step length, or a coarse step is hindrance itself).
        """
        import numpy as np

        start_tolerance_s = max(0.5, step_s + 1e-6)

        pairs = pairs if pairs is not None else [(tid, order[0]) for tid in order[1:]]
        for lab, x in points_m.items():
            worst = -math.inf
            for tid, ref_id in pairs:
                ref = traces.get(ref_id)
                if ref is None or tid not in traces or start_delays.get(tid, 0.0) > start_tolerance_s:
                    worst = math.inf
                    break
                rs, rv = first_passes(ref)
                fs, fv = first_passes(traces[tid])
                sel = (fs <= x) & (fs >= rs[0])
                if not sel.any():
                    worst = math.inf
                    break
                vref = np.interp(fs[sel], rs, rv)
                excess = (vref - fv[sel]) - np.maximum(abs_tol_mps, rel_tol * vref)
                excess = excess[vref >= min_speed_mps]
                if not excess.size:
                    continue
                worst = max(worst, float(excess.max()))
            self.speed_deficit[lab] = worst

    def compute_delays(self, labels: list[str], order: list[str], pairs: list[tuple[str, str]] | None = None) -> None:
        """Time each train lost up to each point against its reference (as in compute_speed_deficits)."""
        pairs = pairs if pairs is not None else [(tid, order[0]) for tid in order[1:]]
        for lab in labels:
            p = self.passages[self.passages.measuring_point == lab].set_index("train")["time_s"]
            worst = 0.0
            for tid, ref_id in pairs:
                if tid not in p.index or ref_id not in p.index:
                    worst = math.inf
                    break
                worst = max(worst, (p[tid] - self.departures[tid]) - (p[ref_id] - self.departures[ref_id]))
            self.delays[lab] = worst

    def safe(self) -> bool:
        return self.summary.get("collisions", 0) == 0 and self.summary.get("gap_violations", 0) == 0

    def hindrance(self, label: str, tolerance_s: float) -> str:
        """Why this probe is hindered at ``label``, in words ('' when it is not)."""
        why = []
        if not self.safe():
            why.append(f"{self.summary.get('gap_violations', 0)} gap violations, {self.summary.get('collisions', 0)} collisions")
        deficit = self.speed_deficit.get(label, -math.inf)
        if deficit == math.inf:
            why.append("a later train started late or never reached the point")
        elif deficit > 0:
            why.append(f"a later train ran slower than the first at the same place, {deficit:.2f} m/s beyond the tolerance")
        lost = self.delays.get(label, math.inf)
        if lost > tolerance_s:
            why.append("a later train never reached the point" if lost == math.inf else f"a later train lost {lost:.1f} s (tolerance {tolerance_s:g} s)")
        return "; ".join(why)

    def ok(self, label: str, tolerance_s: float) -> bool:
        """Unhindered at ``label``: no speed deficit beyond tolerance (if measured), no lost time beyond ``tolerance_s``."""
        if not self.safe():
            return False
        if label in self.speed_deficit and self.speed_deficit[label] > 0:
            return False
        return self.delays.get(label, math.inf) <= tolerance_s


def search_min_headway(
    run_at: Callable[[float], Probe], labels: list[str], guess_s: dict[str, float], tolerance_s: float = 2.0,
    resolution_s: float = 0.25, max_expand: int = 10, bracket: float = 0.15, centre: float = 1.0,
) -> dict[str, tuple[float, Probe]]:
    """Bisection on the release interval for every measuring point.

    ``guess_s`` brackets the search (e.g. the analytic headway): c·g ± max(bracket·c·g, resolution/2)
    with c = ``centre`` (where the answer is expected relative to the guess), so a bracket that
    holds the answer is decided by its two ends; the bracket is widened (doubling steps) until its
    lower end is hindered and its upper end is not, so the guess never decides the answer — a good
    guess only saves simulations.  Ten doublings reach about 500 s beyond the guess at the
    capacity study's 0.5 s first step (a convoy that stops member by member at a platform too
    short for it occupies the platform far longer than the analytic one-train convoy assumes:
    Firenze Rifredi up, cbc n=2, ≈ 70 s beyond the guess).
    """
    cache: dict[float, Probe] = {}

    def probe(h: float) -> Probe:
        key = round(h, 3)
        if key not in cache:
            cache[key] = run_at(key)
        return cache[key]

    out: dict[str, tuple[float, Probe]] = {}
    for lab in labels:
        g = max(guess_s.get(lab, 60.0) * centre, 1.0)
        step = max(bracket * g, 0.5 * resolution_s)
        lo, hi = max(g - step, 0.1), g + step
        for _ in range(max_expand):
            if not probe(lo).ok(lab, tolerance_s):
                break
            hi = lo  # lo is unhindered: the answer is at or below it
            step *= 2.0
            lo = max(lo - step, 0.1)
        for _ in range(max_expand):
            if probe(hi).ok(lab, tolerance_s):
                break
            lo = hi
            step *= 2.0
            hi = hi + step
        if not probe(hi).ok(lab, tolerance_s):
            out[lab] = (math.nan, probe(hi))
            continue
        if probe(lo).ok(lab, tolerance_s):
            out[lab] = (lo, probe(lo))
            continue
        while hi - lo > resolution_s:
            mid = 0.5 * (lo + hi)
            if probe(mid).ok(lab, tolerance_s):
                hi = mid
            else:
                lo = mid
        out[lab] = (hi, probe(hi))
    return out
