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
common release point (the sweep starts at the relative braking distance at the release speed).

The interlocking serves the merge in the planned order in every regime: a SUMO rail-signal
``predecessor`` constraint lets the follower pass the merge signal only after the leader has.
SUMO's own rule is first come, first served by approach, which lets a fast VC follower claim the
junction before its convoy leader on the branch; the leader then stops at red and the follower,
coupled behind it, slows down with it (see the study's report).

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
  behind the previous one as closely as the regime allows).  ``junction_throughput_trains_per_h``
  is that of the studied junction in the row's direction (``junction_kind``).  After a merge the
  spacing at the split is set upstream: ``split_is_bottleneck`` says whether the split needed a
  larger offset than the merge (if not, the split throughput is a lower bound).
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

The VC follower (:class:`~vcsumo.sim.junction_policy.JunctionPolicy`: options of the VC driver)
-----------------------------------------------------------------------------------------------
* **link handshake**: it joins its convoy only once the first message of its predecessor has
  arrived (before that SUMO drives it).  ``VCDriver`` couples as soon as the predecessor is in the
  simulation; with no message yet its guard assumes the predecessor stands at the follower's own
  front and commands an emergency brake (a leader inserted on the other approach triggers it).
* **static speed profile**: its command is capped by the braking curve (service deceleration, as
  SUMO's own driver) to every lower limit ahead — turnouts and speed restrictions.  The controllers
  only see the limit under the train: a follower diverging at a split otherwise enters the turnout
  at line speed.
* ``junction_signal`` variant ``sumo`` — nothing more: the follower runs under speed mode 26, where
  SUMO enforces a red signal only by stopping the train at the signal within one step (no braking
  curve).  Variant ``braking-curve`` — while its predecessor's front has not passed the merge
  junction (the time SUMO's moving-block junction signal can be red for it: SUMO turns it green when
  the leader's front passes) the follower must be able to stop at the junction signal with the
  deceleration the guard relies on (``controllers/guard.yaml``); steps at which even that could not
  stop it are counted (``junction_signal_overruns``).

Outputs: ``junction.csv`` (one row per line, junction, direction, leader service, regime,
controller, VC variant), ``junction_sweep.csv`` (every simulated offset), ``junction_trajectories.csv``
(1 s samples of the solo, Δ = 0 and Δ* runs: distances to the junctions, speeds, gaps),
``junction_signals.csv`` (junction signal switches), plots ``junction_<regime>.png`` (gap and speed
around the junction, read from ``junction_trajectories.csv``) and ``junction_sweep.png``.

Package layout: :mod:`~vcsumo.studies.junction.model` (junctions of a line, routes, geometry,
release times, one SUMO run), :mod:`~vcsumo.studies.junction.metrics` (the measures of a run) and
:mod:`~vcsumo.studies.junction.study` (cases, sweep and bisection, tables and plots).  SUMO's
files go through :mod:`vcsumo.sim.sumo_io` (the junction signals' recording and the merge order
constraint are one additional file next to the stations file).
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
