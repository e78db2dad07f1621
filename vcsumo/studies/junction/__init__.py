"""Junction study: convoys merging and splitting at speed (survey open problem 12), vs FBS and MB.

Scenario
--------
A junction is a branch's ``junction_km``.  A branch that ``leaves_towards: start`` *merges* into the
``up`` direction and *diverges* from ``down`` (``end``: the reverse).  For the studied junction J
(``--junction BRANCH_ID``; default: the first branch of the line file that has a partner junction,
else the first branch) the study runs both directions:

* **merge direction** — the pair merges at J and *splits* at the partner junction, the nearest
  junction downstream where a branch diverges from that direction (none: both trains run on the
  main line to the end of the observation window, ``post_m`` = 20 km after J);
* **split direction** — the pair splits at J after having *merged* at the partner junction, the
  nearest junction upstream where a branch merges into that direction (none: both trains start on
  the main line ``approach_m`` = 12 km before J and run coupled from their release).

Two services of the same train type: the **branch service** enters the merge junction's branch at
its far end at the branch speed (flying start: it comes from the conventional network) and leaves
at the split junction onto that branch; the **main service** runs on the main line, released
``approach_m`` before the first junction at its unhindered speed there (from a standing start at
the main track's start, as in the headway study), and ends 10 km after the split (20 km after a
merge without split).  ``first`` (``--first main|branch|both``) says which service passes the
first junction first: it is the convoy **leader**, the other the **follower** — the *merging
service*, which has to merge in behind.  Under VC the pair is one convoy
(``VCDriver([leader, follower])``); under FBS and MB the same two trains run uncoupled.

**Arrival offset** Δ: with a merge, the time between the two trains reaching the merge junction
when each runs alone (unhindered, in SUMO, same regime and step; release times are set to give Δ;
Δ = 0 is the *simultaneous arrival*); without a merge, the interval between the two releases at the
common release point (the sweep starts at the regime's safe separation there: the relative-braking gap
under VC, the absolute one under FBS and MB, at the release speed).

The interlocking serves the merge in the planned order in every regime, through the loop's one
merge-order mechanism, the approach locking of :mod:`vcsumo.sim.interlocking` with the order fixed
(``Scenario.merge_orders``: leader, then follower): SUMO is told from the start to let the
follower pass the merge signal only after the leader (a rail-signal ``predecessor`` constraint),
and the follower's movement authority ends at the junction (less the margin and the position
errors) until the leader has cleared it — the SUMO-driven follower is supervised to it on its
guaranteed braking curve, the VC follower keeps the same curve through its driver's junction option
(below), released as soon as its own convoy leader's front has passed.  SUMO's own rule (first
come, first served by approach) would let a fast follower claim the junction before its leader.

Definitions (positions are train fronts; the **virtual gap** is the front-to-rear distance from
the follower to the leader along their shared track, computed as the difference of their
distances to the junction — before a merge the two trains are on different tracks)
---------------------------------------------------------------------------------------------
* **lost time** of a train at a point: (passage − scheduled release) − the same for that train
  running alone in SUMO (same regime and step).
* **unhindered through the merge**: follower and leader each lose at most ``tolerance_s`` (2 s) up
  to the merge check point — on the trunk, min(10 km, half-way to the split) after the merge — in
  the planned order, without gap violation (in the merge window) or collision.  **Through the
  split**: the same for the time lost between the merge check point (or the release) and the end
  of each route, with no gap violation in the split window.
* **minimum offset** Δ*: the smallest Δ from which the pair is unhindered at every offset of the
  sweep (``offsets_s``, extended until unhindered), refined by bisection to ``resolution_s``.
* **junction headway** h: the time between the two fronts passing the junction node in the run at
  Δ*; **junction throughput** = 3600/h trains/h (a stream of such pairs, each train merging in
  behind the previous one as closely as the regime allows).  At a merge two offsets are searched:
  ``merge_junction_*`` — both trains unhindered *up to the junction node* (lost time at the node
  within ``tolerance_s``, in order, no violation in the merge window): what the junction costs; and
  ``merge_*`` — unhindered through the merge check point, which adds forming up behind the leader
  on the trunk (a faster follower catching up, a VC follower closing to or opening to its coupled
  spacing: the cost of following and coupling, not of the junction; ``merge_trunk_lost_s`` is the
  follower's lost time between the junction and the check point at the junction's offset).
  ``junction_throughput_trains_per_h`` is the studied junction's in the row's direction
  (``junction_kind``): the merge junction's own, or the split's.  After a merge the spacing at the
  split is set upstream: ``split_is_bottleneck`` says whether the split needed a larger offset than
  the merge (if not, the split throughput is a lower bound).
* **run health** (:mod:`vcsumo.sim.health`) over every simulation of the case (sweep probes and
  analysis runs): ``healthy`` only if every run was, ``unhealthy_runs``, the smallest margin to the
  regime's safe separation (``min_margin_m``), time below it, and the counters summed (gap
  violations and collisions of all runs, stops skipped, overspeed events and the largest excess,
  braking beyond the service rate, overruns of the end of authority, SUMO emergency stops and
  brakings, teleports) with the largest impact speed.  A case that is not healthy is marked on the
  terminal; the sweep plot marks its unhealthy offsets.
* **formation** (Δ = 0 run, with a merge): *start* = where the follower first runs slower than it
  does alone by more than max(0.3 m/s, 0.5 %) — it begins to give way — reported as the distance of
  its front before the merge junction (``formation_start_m_before_merge``: how far before the
  junction the convoy must start forming); *formed* = from where on the follower's lost time stays
  within max(1 s, 5 %) of its value at the end of the trunk (5 km before the split, or the end of
  the window): it no longer drops back.  Time and distance to form are from start to formed (the
  follower's time and travel); ``formed_gap_m``/``formed_speed_mps`` are the virtual gap and speed
  there, ``formed_lost_time_s`` the follower's final lost time.  ``vc_control_start_m_before_merge``:
  where vcsumo first drives the follower.
* **delay to the merging service**: in the Δ = 0 run, the lost time of the second train through the
  first junction, at the merge check point (without a merge: at its route end) and at its route end;
  ``first_service_delay_end_s`` is the other train's.
* **min gap / violations during merge and split**: the smallest virtual gap while the second train's
  front is within ``window_m`` (5 km) of the junction — merge: from the moment the first train
  enters the junction; split: while the first train still occupies the shared track — and the
  simulation loop's gap violations (SUMO's sensed gap below the safe gap that applies) in the window
  of the violating train's front; collisions, SUMO emergency braking (the loop's count and SUMO's
  ``performs emergency braking`` warnings), stops forced by a red signal (SUMO's ``emergency stop
  ... because of a red traffic light``), the largest overspeed of either train over the limit under
  it (turnouts included), and for VC the guard interventions, supervisor emergency activations and
  interventions.
* **junction signal**: the merge and split signals' switches are recorded (SUMO
  ``SaveTLSSwitchStates``, ``junction_signals.csv``).  While the signal is red for the second train
  it would have to stop there: ``*_red_max_required_decel_mps2`` is the largest v²/(2·d) (d: its
  front's distance to the signal) and ``*_red_inside_braking_s`` the time it spends red inside its
  service braking distance.  Above the emergency deceleration a train obeying the signal with its
  brakes could not have stopped.

The VC follower (``VCDriver(..., junction=JunctionPolicy(...))``, :mod:`vcsumo.sim.junction_policy`)
---------------------------------------------------------------------------------------------------
* **link handshake**: it joins its convoy only once the first message of its predecessor has
  arrived and puts the predecessor virtually ahead of it by at least the spacing its stack keeps
  (coupled gap, at least d_min / the CBF's d); before that SUMO drives it, supervised.  Coupled at
  once, a follower virtually a few metres behind a faster leader on the other approach was braked
  to a standstill by its guard (and a cbf-cbc one held until the gap reached the CBF's 1,000 m):
  a flat ~30 s charged at every offset that was the cost of coupling, not of the junction.
* **static speed profile**: its command is capped by its guaranteed braking curve (the separation
  model's :class:`~vcsumo.signalling.separation.RouteBraking`, as the supervision of SUMO-driven
  trains) to every lower limit ahead — turnouts and speed restrictions.
* ``junction_signal`` variant ``braking-curve`` (default): the end of movement authority at the
  merge the loop's approach locking sets, handed to the driver in the ``Snapshot``, is kept on the
  guaranteed braking curve after the assumption set's dead time; steps at which even the
  guaranteed emergency brake could not stop it there are counted (``junction_signal_overruns``).
  Variant ``sumo``: nothing more than speed mode 26, where SUMO enforces a red signal only by
  stopping the train at the signal within one step (kept for the comparison).

Outputs: ``junction.csv`` (one row per line, junction, direction, leader service, regime,
controller, VC variant), ``junction_sweep.csv`` (every simulated offset), ``junction_trajectories.csv``
(1 s samples of the solo, Δ = 0 and Δ* runs: distances to the junctions, speeds, gaps),
``junction_signals.csv`` (junction signal switches), plots ``junction_<regime>.png`` (gap and speed
around the junction, read from ``junction_trajectories.csv``) and ``junction_sweep.png``.

Package layout: :mod:`~vcsumo.studies.junction.model` (junctions of a line, routes, geometry,
release times, one SUMO run), :mod:`~vcsumo.studies.junction.metrics` (the measures of a run) and
:mod:`~vcsumo.studies.junction.study` (cases, sweep and bisection, tables and plots).  SUMO's
files go through :mod:`vcsumo.sim.sumo_io` (the junction signals' recording is an additional file
next to the stations file); the merge order goes through ``Scenario.merge_orders``.
"""

from __future__ import annotations

from vcsumo.studies.junction.metrics import (HINDRANCE_ABS_MPS, HINDRANCE_REL, actual_order, formation, lost_time, run_metrics, signal_exposure,
                                             signal_rows, speed_at_trace, trajectory_rows, unhindered, virtual_gap)
from vcsumo.studies.junction.model import (ROLES, SIGNAL_VARIANTS, Case, RunResult, Setup, build_setup, default_junctions, link_of,
                                           measuring_points, merge_direction, partner_junction, resolve_junctions, signal_links, signal_nodes,
                                           simulate_pair, solo_runs, trains_for)
from vcsumo.studies.junction.study import DEFAULT_OFFSETS_S, JUNCTION_COLUMNS, CaseOutcome, cases_for, run_case, run_junction_study

__all__ = [
    "DEFAULT_OFFSETS_S", "HINDRANCE_ABS_MPS", "HINDRANCE_REL", "JUNCTION_COLUMNS", "ROLES", "SIGNAL_VARIANTS", "Case", "CaseOutcome", "RunResult",
    "Setup", "actual_order", "build_setup", "cases_for", "default_junctions", "formation", "link_of", "lost_time", "measuring_points",
    "merge_direction", "partner_junction", "resolve_junctions", "run_case", "run_junction_study", "run_metrics", "signal_exposure", "signal_links",
    "signal_nodes", "signal_rows", "simulate_pair", "solo_runs", "speed_at_trace", "trains_for", "trajectory_rows", "unhindered", "virtual_gap",
]
