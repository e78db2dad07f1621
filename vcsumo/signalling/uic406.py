"""UIC 406 capacity consumption: the timetable compressed on each line section.

UIC leaflet 406 (2004, 2nd ed. 2013) measures how much of a line's capacity a timetable uses:
on each line section, every train's *blocking-time stairs* are pushed together, in the
timetable's order, until they touch (the timetable is *compressed*); the *occupation time* of
the compressed timetable divided by the observation window is the capacity consumption.  This
module computes that infrastructure occupation from the timetable alone — no simulation.

Line sections
-------------
A line section is the main line's track of one direction between two consecutive *section
boundaries*:

* the two ends of the main line;
* the stopping position of every station on that track (the train front at the platform's exit
  signal);
* every junction (the signal at the turnout).

vcsumo stations have one platform track per direction and junctions are grade-separated, so
trains cannot overtake inside a section: its train order is fixed, and trains start, end, join
or leave only at its boundaries.  A train is counted on a section when it runs over all of it.
Branches are not evaluated.  Sections without trains are not reported.

Running profiles
----------------
Each train runs its scheduled running profile (:func:`vcsumo.signalling.scheduled_run.timetable_run`):
its unhindered run from its scheduled departure braking on its guaranteed, gradient-compensated
curve under the assumption set (as the supervision brakes every train SUMO drives), each stretch
between timing points slowed uniformly to arrive at the scheduled time, dwells extended to the
scheduled departures.

Blocking-time stairs
--------------------
The blocks and the rules are the regimes' own (:mod:`vcsumo.signalling.regimes`, the separation
model of the capacity study and of the runs' supervision and health).  The blocks of a section are
the stretches between consecutive signals in it (the section's end boundary closes the last
block).  A train's blocking time of block k [S_k, S_k+1] runs

* from the moment it passes the *approach point* a_k, where it must be able to stop short of S_k:
  a_k + D(v(a_k), a_k) + e = S_k, with D the supervised braking distance (the set's dead time +
  1.5 steps, then its guaranteed brake over the route's gradients,
  :class:`vcsumo.signalling.regimes.base.SupervisedBraking`) and e the position error —
  :func:`vcsumo.signalling.blocking_time.fbs_blocking_times`; a train standing at a stop approaches
  the blocks ahead of it only once it departs (a block starting at its stop is blocked from the
  departure); the set's fixed times are added before it;
* to the moment its tail clears S_k+1 by the overlap and the position error (front at S_k+1 +
  overlap + e + L); a train ending its run inside the block (terminating at a platform, leaving
  the network) releases it when it arrives.

``regime`` chooses the blocks and the rule:

* ``fbs`` — the line's signals (:meth:`vcsumo.route_profile.RouteProfile.signal_positions`), as above;
* ``mb`` — moving block as *virtual blocks* of ``virtual_block_m`` (default 25 m): approached at
  D(v, s) + the set's margin and both position errors, released one position-report period after the
  tail clears (the authority is built from a report up to that old), fixed times added: the stairs
  become the moving-block headway band of :class:`vcsumo.signalling.regimes.mb.MovingBlock`
  (within ``virtual_block_m``/v);
* ``vc`` — as ``mb``, except that a declared convoy follower approaches its own convoy leader at
  the coupled gap of the separation model (:class:`CoupledGapRule`: relative braking with the set's
  message-age bound, no report period, no fixed times).

Before (up to this version) the stairs took SUMO's nominal service brake and a fixed 50 m margin,
the running profiles SUMO's unsupervised driving, and a follower's coupled gap a fixed 50 m: the
consumption then measured a separation the runs' trains were never allowed to keep.

Beyond the set's fixed times no setup, sighting or release times are added (SUMO's signalling
has none); ``setup_s`` and ``release_s`` add them to every block.

Compression and consumption
---------------------------
Trains keep the order in which they enter the section.  The first train stays; each next train
is moved to the earliest time at which none of its blocks starts before the same block of any
train ahead of it is released.  The *occupation time* is the time from the first blocking-time
start to the last blocking-time end of the compressed timetable — for two identical trains on a
uniform section, one minimum headway plus one train's whole stair,
(D + B + L)/v + (D + n·B + L)/v.  Consumption = occupation / window × 100 %
(``consumption_pct``) in the busiest window of ``window_s`` (3600 s: the peak hour) of the
section: for every train, the trains entering the section within the window from it are compressed
together, and the window with the largest occupation is reported (:func:`peak_windows`;
``peak_window_start_s``, ``trains_in_window``; the cyclic figure its own busiest window).  A
timetable of one hour is compressed whole; before, every train of a longer timetable was compressed
into the one window (italy_av_north ``full_day``: 1,017 % of an hour).

On a long section the occupation time contains one whole passage of a train (76 km of Bologna -
Firenze: about 1,100 s, 30 % of the hour, with a single train), which hides the difference
between regimes.  The *cyclic* occupation (``cycle_s``, ``cyclic_consumption_pct``) closes the
cycle instead, as UIC 406 does for periodic timetables: the first train of the next period is
compressed behind the last one, so it is the sum of the minimum headways around the cycle (two
identical trains: 2·(D + B + L)/v).  Both are reported.

No buffer times are added (UIC 406's K = A + B + C + D: this is A, the infrastructure
occupation; UIC's recommended limits for A + B are 75 % peak on high-speed and mixed lines, 85 %
on suburban lines).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import pandas as pd

from vcsumo.errors import VcsumoError
from vcsumo.line import Line
from vcsumo.running_time import time_at
from vcsumo.rolling_stock import RollingStock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.blocking_time import fbs_blocking_times
from vcsumo.signalling.line_sections import line_sections
from vcsumo.signalling.regimes.base import SupervisedBraking
from vcsumo.signalling.scheduled_run import at_time_zero, departure_index, pattern_key, route_end_s, timetable_run
from vcsumo.signalling.separation import SeparationModel
from vcsumo.timetable import PlannedTrain, TimetableFile
from vcsumo.topology import Topology

UIC_REGIMES = ("fbs", "mb", "vc")
DEFAULT_WINDOW_S = 3600.0
SECTION_COLUMNS = [
    "regime", "direction", "section", "from_km", "to_km", "length_m", "blocks", "trains", "scheduled_span_s",
    "occupation_s", "window_s", "consumption_pct", "cycle_s", "cyclic_consumption_pct", "peak_window_start_s", "trains_in_window",
]


class _Rule(Protocol):
    def distance(self, v: np.ndarray | float, s: np.ndarray | float | None = None) -> np.ndarray | float: ...


@dataclass(frozen=True)
class MarginRule:
    """A braking rule plus a fixed margin: D(v, s) + margin (moving block: the set's margin and both
    position errors)."""

    base: _Rule
    margin_m: float

    def distance(self, v, s=None):
        return self.base.distance(v, s) + self.margin_m


@dataclass(frozen=True)
class CoupledGapRule:
    """The coupled gap of a VC follower behind its own leader at the follower's speed:
    :meth:`vcsumo.signalling.separation.SeparationModel.vc_gap` (relative braking with the set's
    message-age bound, margin and position errors; level track, both trains at that speed), m."""

    model: SeparationModel
    follower: RollingStock
    leader: RollingStock

    def distance(self, v, s=None):
        v_arr = np.atleast_1d(np.asarray(v, dtype=float))
        out = np.array([self.model.vc_gap(self.follower, self.leader, float(x)) for x in v_arr])
        return float(out[0]) if np.ndim(v) == 0 else out


# ---------------------------------------------------------------------------------------------
# Blocking-time stairs


def stairs(
    run: pd.DataFrame, markers_s: list[float], section_end_s: float, length_m: float, rule: _Rule,
    full_run: pd.DataFrame | None = None, setup_s: float = 0.0, release_s: float = 0.0,
    approach_offset_m: float = 0.0, clear_offset_m: float = 0.0,
) -> pd.DataFrame:
    """Blocking-time stairs of one train over consecutive blocks.

    ``markers_s`` are the block starts (route positions, m; sorted), the last block ends at
    ``section_end_s``.  ``run`` is the part of the train's profile from which it approaches these
    blocks (it starts at the train's departure from its last stop before them, or its origin);
    ``full_run`` (default ``run``) gives the times its tail clears each block.  A block is
    approached where the train must be able to stop ``approach_offset_m`` short of its start (the
    position error) and released when the tail is ``clear_offset_m`` beyond its end (overlap and
    position error), as :func:`vcsumo.signalling.blocking_time.fbs_blocking_times`.  Returns
    ``block_start_m, block_end_m, approach_m, t_start_s, t_end_s, blocking_time_s``.
    """
    full = run if full_run is None else full_run
    s0 = float(run["s_m"].iloc[0])
    # a block starting where the train stands (origin, stop) is approached at departure:
    # fbs_blocking_times only takes signals beyond the run's start, so move it 2 mm ahead
    sig = [x + 0.002 if abs(x - s0) < 1e-3 else x for x in markers_s]
    blocks = fbs_blocking_times(run, sig, section_end_s, length_m, rule, approach_offset_m)  # type: ignore[arg-type]
    if len(blocks) != len(markers_s):
        raise VcsumoError(f"blocking-time stairs: {len(markers_s) - len(blocks)} block(s) start before the train's run")
    fs = full["s_m"].to_numpy()
    t_last = float(full["time_s"].iloc[-1])
    ends = np.array(list(markers_s[1:]) + [section_end_s]) + length_m + clear_offset_m
    t_end = time_at(full, np.minimum(ends, fs[-1]))
    t_end = np.where(ends > fs[-1] + 1e-6, t_last, t_end)  # released when the train arrives (leaves the line)
    out = pd.DataFrame({
        "block_start_m": np.asarray(markers_s, dtype=float), "block_end_m": np.array(list(markers_s[1:]) + [section_end_s], dtype=float),
        "approach_m": blocks["approach_m"].to_numpy(), "t_start_s": blocks["t_approach_s"].to_numpy() - setup_s, "t_end_s": t_end + release_s,
    })
    out["blocking_time_s"] = out["t_end_s"] - out["t_start_s"]
    return out


@dataclass(frozen=True)
class Compression:
    """A compressed section timetable."""

    shifts_s: np.ndarray
    """Time each train was moved by (negative: earlier), s."""
    occupation_s: float
    """First blocking-time start to last blocking-time end after compression, s."""
    cycle_s: float
    """Cyclic occupation: the earliest the first train could run again behind the compressed
    timetable (the pattern repeated), i.e. the sum of the minimum headways around the cycle, s."""


def compress(starts: np.ndarray, ends: np.ndarray, pair_starts: dict[tuple[int, int], np.ndarray] | None = None) -> Compression:
    """Compress blocking-time stairs (arrays trains × blocks, rows in train order).

    Train 0 stays; train j moves to the earliest time at which each of its block starts is at or
    after the release of the same block by every train ahead of it.  ``pair_starts[(i, j)]``
    replaces train j's block starts against train i (a convoy follower approaching its own
    leader).  Blocks a train does not use are nan.
    """
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    ends = np.atleast_2d(np.asarray(ends, dtype=float))
    n = starts.shape[0]
    if n == 0 or starts.size == 0:
        return Compression(np.zeros(n), 0.0, 0.0)
    pair_starts = pair_starts or {}

    def need(j_starts_against, upto: int, shift: np.ndarray) -> float:
        best = -math.inf
        for i in range(upto):
            diff = ends[i] + shift[i] - j_starts_against(i)
            if np.any(~np.isnan(diff)):
                best = max(best, float(np.nanmax(diff)))
        return best

    shift = np.zeros(n)
    for j in range(1, n):
        req = need(lambda i, j=j: pair_starts.get((i, j), starts[j]), j, shift)
        shift[j] = req if math.isfinite(req) else 0.0
    occupation = float(np.nanmax(ends + shift[:, None]) - np.nanmin(starts + shift[:, None]))
    cycle = need(lambda i: starts[0], n, shift)
    return Compression(shift, occupation, cycle if math.isfinite(cycle) else occupation)


def peak_windows(S: np.ndarray, E: np.ndarray, pair_starts: dict[tuple[int, int], np.ndarray], entries: np.ndarray,
                 window_s: float) -> tuple[tuple[float, float, int], tuple[float, float, int]]:
    """The busiest window of a section's trains (rows of ``S``, ``E`` in train order, entering the
    section at ``entries``, s): for every train, the trains entering within ``window_s`` from it are
    compressed together (:func:`compress`); returns (occupation s, window start s, trains) of the
    window with the largest occupation and the same of the largest cyclic occupation.  Windows that
    are part of an earlier one are not evaluated (they occupy no more).  A timetable whose trains all
    enter within one window is compressed whole, as before."""
    n = len(entries)
    best_occ, best_cyc = (-math.inf, math.nan, 0), (-math.inf, math.nan, 0)
    last_end = -1
    for i in range(n):
        k = int(np.searchsorted(entries, entries[i] + window_s, side="left"))
        if k <= last_end:
            continue  # within the window from an earlier train
        last_end = k
        sub = {(a - i, b - i): row for (a, b), row in pair_starts.items() if i <= a < k and i <= b < k}
        comp = compress(S[i:k], E[i:k], sub)
        if comp.occupation_s > best_occ[0]:
            best_occ = (comp.occupation_s, float(entries[i]), k - i)
        if comp.cycle_s > best_cyc[0]:
            best_cyc = (comp.cycle_s, float(entries[i]), k - i)
        if k == n:
            break
    return best_occ, best_cyc


# ---------------------------------------------------------------------------------------------
# A whole timetable


def convoy_pairs(tt: TimetableFile, trains: list[PlannedTrain]) -> list[tuple[str, str]]:
    """(leader train, follower train) of every declared convoy: the k-th trains of the services
    listed in ``convoys[].services`` form the k-th convoy, each following the one listed before it."""
    by_service: dict[str, list[str]] = {}
    for t in trains:
        by_service.setdefault(t.service, []).append(t.id)
    pairs = []
    for cv in tt.convoys:
        lists = [by_service.get(s, []) for s in cv.services]
        for a, b in zip(lists, lists[1:]):
            pairs += list(zip(a, b))
    return pairs


def capacity_consumption(
    line: Line, topo: Topology, trains: list[PlannedTrain], regime: str = "fbs", convoys: list[tuple[str, str]] | None = None,
    window_s: float = DEFAULT_WINDOW_S, step_s: float = 0.5, virtual_block_m: float = 25.0,
    setup_s: float = 0.0, release_s: float = 0.0, cache: dict | None = None, model: SeparationModel | None = None,
) -> pd.DataFrame:
    """UIC 406 capacity consumption of a timetable on every line section (one row per section).

    ``topo`` is the built network's topology (its signals give the fixed blocks).  ``model``: the
    separation model whose rules the blocking times follow (None: the shipped default assumption
    set, as the batch's runs).  ``cache`` (a dict, optional) keeps running profiles and stairs
    between calls on the same trains (e.g. one call per regime).

    Columns: ``regime, direction, section, from_km, to_km, length_m, blocks, trains,
    scheduled_span_s`` (first blocking start to last blocking end as scheduled),
    ``occupation_s`` (compressed), ``window_s``, ``consumption_pct``.
    """
    if regime not in UIC_REGIMES:
        raise VcsumoError(f"UIC 406: unknown regime '{regime}' (choose from {', '.join(UIC_REGIMES)})")
    if window_s <= 0:
        raise VcsumoError(f"UIC 406: window {window_s} s must be positive")

    followers = {f: l for l, f in (convoys or [])} if regime == "vc" else {}
    model = SeparationModel(load_assumptions()) if model is None else model
    a = model.assumptions
    by_id = {t.id: t for t in trains}
    cache = {} if cache is None else cache
    set_key = a.model_dump_json()
    patterns: dict[tuple, pd.DataFrame] = cache.setdefault(("patterns", step_s, set_key), {})
    stair_cache: dict[tuple, pd.DataFrame] = cache.setdefault(("stairs", step_s, virtual_block_m, setup_s, release_s, set_key), {})
    # the regime's rule (vcsumo.signalling.regimes): where a block is approached and when it is released
    setup = setup_s + a.fixed_time_s
    if regime == "fbs":
        offsets = {"approach_offset_m": a.position_error_m, "clear_offset_m": a.overlap_m + a.position_error_m}
        release = release_s
    else:  # the confirmed rear of the train ahead is up to one report period old
        offsets = {}
        release = release_s + a.position_report_period_s
    runs: dict[str, pd.DataFrame] = {}
    for t in trains:
        key = pattern_key(t)
        if key not in patterns:
            patterns[key] = timetable_run(at_time_zero(t), step_s, model)
        r = patterns[key].copy()
        r["time_s"] += t.depart_s
        runs[t.id] = r
    rows = []
    for sec in line_sections(line, topo):
        track = f"{sec.main}_{sec.direction}"
        members = []  # (entry time, train, s_A, s_B)
        for t in trains:
            prof = t.profile
            try:
                s_a, s_b = prof.s_of(sec.main, sec.from_km), prof.s_of(sec.main, sec.to_km)
            except KeyError:
                continue
            if s_b <= s_a or topo.edges[prof.edges[prof.index_at(min(s_a + 0.5, s_b))]].track != track:
                continue
            tol_start = t.stock.length_m + 2.0 if sec.from_name in ("start", "end") else 1.0
            if t.start_s_m > s_a + tol_start or route_end_s(t) < s_b - 1.0:
                continue
            entry = float(time_at(runs[t.id], max(s_a, t.start_s_m))[0])
            members.append((entry, t.id, t, s_a, s_b))
        if not members:
            continue
        members.sort(key=lambda m: (m[0], m[1]))
        per_train = []
        vc_starts: dict[str, np.ndarray] = {}
        for entry, tid, t, s_a, s_b in members:
            prof = t.profile
            braking = SupervisedBraking(model, t.stock, prof, step_s)
            if regime == "fbs":
                markers = [x for x in prof.signal_positions(topo) if s_a - 1e-3 <= x < s_b - 1e-3]
                rule: _Rule = braking
            else:
                n = max(1, int(math.ceil((s_b - s_a) / virtual_block_m - 1e-9)))
                markers = [s_a + k * (s_b - s_a) / n for k in range(n)]
                rule = MarginRule(braking, model.margin_m)
            if regime == "fbs":
                keys: list = [round(prof.km_at(x)[1], 3) for x in markers]
            else:
                keys = list(range(len(markers)))
            # a train inserted at the start of the track (origin 'start'/'end') has no blocks behind it; under fbs it
            # stands in the block from the open end (or the signal behind its front) to the next signal, blocked from
            # its departure (until 2026-12-01 left out: a section from an open end without a signal vanished)
            keep = [i for i, x in enumerate(markers) if x >= t.start_s_m - 1e-3]
            standing_in = None if regime != "fbs" or (keep and markers[keep[0]] <= t.start_s_m + 1e-3) else \
                round(prof.km_at(max([x for x in markers if x < t.start_s_m - 1e-3], default=s_a))[1], 3)
            markers, keys = [markers[i] for i in keep], [keys[i] for i in keep]
            if standing_in is not None and s_a - 1e-3 <= t.start_s_m < s_b - 1e-3:
                markers, keys = [t.start_s_m] + markers, [standing_in] + keys
            if not markers:
                continue
            pkey = (pattern_key(t), sec, "fbs" if regime == "fbs" else "mb")
            if pkey not in stair_cache:
                stair_cache[pkey] = _train_stairs(patterns[pattern_key(t)], t, markers, s_b, rule, setup, release, offsets)
            st = stair_cache[pkey]
            per_train.append((tid, keys, st["t_start_s"].to_numpy() + t.depart_s, st["t_end_s"].to_numpy() + t.depart_s, entry))
            if tid in followers and followers[tid] in by_id:
                # a convoy follower approaches its own leader at the coupled gap (relative braking, no report
                # period, no fixed times: its starts are moved by the report period the leader's releases carry)
                lead_stock = by_id[followers[tid]].stock
                vkey = pkey + ("vc", lead_stock.name)
                if vkey not in stair_cache:
                    stair_cache[vkey] = _train_stairs(patterns[pattern_key(t)], t, markers, s_b, CoupledGapRule(model, t.stock, lead_stock),
                                                      setup_s - a.position_report_period_s, release)
                vc_starts[tid] = stair_cache[vkey]["t_start_s"].to_numpy() + t.depart_s
        if not per_train:
            continue
        all_keys = sorted({k for _, ks, _, _, _ in per_train for k in ks})
        col = {k: i for i, k in enumerate(all_keys)}
        S = np.full((len(per_train), len(all_keys)), np.nan)
        E = np.full_like(S, np.nan)
        vc_rows: dict[str, np.ndarray] = {}
        for r, (tid, ks, ts, te, _) in enumerate(per_train):
            idx = [col[k] for k in ks]
            S[r, idx] = ts
            E[r, idx] = te
            if tid in vc_starts:
                row = np.full(len(all_keys), np.nan)
                row[idx] = vc_starts[tid]
                vc_rows[tid] = row
        order = [tid for tid, _, _, _, _ in per_train]
        pos = {tid: i for i, tid in enumerate(order)}
        pair_starts = {}
        for tid, row in vc_rows.items():
            lead = followers[tid]
            if lead in pos and pos[lead] < pos[tid]:
                pair_starts[(pos[lead], pos[tid])] = row
        entries = np.array([x[4] for x in per_train])
        (occ, occ_from, occ_n), (cyc, _, _) = peak_windows(S, E, pair_starts, entries, window_s)
        span = float(np.nanmax(E) - np.nanmin(S))
        rows.append({
            "regime": regime, "direction": sec.direction, "section": sec.label, "from_km": sec.from_km, "to_km": sec.to_km,
            "length_m": round(sec.length_m, 1), "blocks": len(all_keys), "trains": len(per_train),
            "scheduled_span_s": round(span, 2), "occupation_s": round(occ, 2), "window_s": window_s,
            "consumption_pct": round(100.0 * occ / window_s, 2), "cycle_s": round(cyc, 2),
            "cyclic_consumption_pct": round(100.0 * cyc / window_s, 2), "peak_window_start_s": round(occ_from, 2), "trains_in_window": occ_n,
        })
    return pd.DataFrame(rows, columns=SECTION_COLUMNS)


def _train_stairs(pattern_run: pd.DataFrame, t: PlannedTrain, markers: list[float], s_b: float, rule: _Rule, setup_s: float, release_s: float,
                  offsets: dict | None = None) -> pd.DataFrame:
    """Stairs of one train (relative to its departure) over a section's blocks."""
    # the leg from which the blocks are approached: from the departure of the last stop at or
    # before the first block (or the origin)
    first = markers[0]
    i0 = 0
    for st in t.stops:
        if st.s_m <= first + 1e-3:
            i0 = departure_index(pattern_run, st.s_m, i0)
    leg = pattern_run.iloc[i0:].reset_index(drop=True)
    return stairs(leg, markers, s_b, t.stock.length_m, rule, full_run=pattern_run, setup_s=setup_s, release_s=release_s, **(offsets or {}))


def max_consumption(sections: pd.DataFrame) -> float:
    """The largest consumption over the sections, % (nan without sections)."""
    if sections.empty:
        return math.nan
    return float(sections["consumption_pct"].max())
