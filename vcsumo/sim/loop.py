"""The simulation loop: step SUMO, observe trains, let a driver command speeds, record safety.

One loop for every regime:

* ``fbs`` — SUMO rail signals with fixed blocks;
* ``mb`` — the same signals in moving-block mode (``--railsignal-moving-block``: SUMO's Rail model
  keeps the absolute braking distance + 50 m to the train ahead);
* ``vc`` — moving-block signals, and coupled followers driven by a vcsumo driver (controllers plus
  safety supervisor) through ``setSpeed`` with speed mode 30.

Every step the loop switches vTypes at tunnel portals (tunnel drag, the same for every regime),
gives every train SUMO drives its permitted speed on braking curves with its guaranteed
deceleration (:mod:`vcsumo.sim.supervision`: stops, speed restrictions, end of track and the
regime's end of movement authority, so no train plans with more braking than it has), measures
the gap from each train to the train ahead and accounts the run's health at every step from the
first (:mod:`vcsumo.sim.health`: margin to the regime's safe separation from
:mod:`vcsumo.signalling.separation` at every speed, overspeed, braking beyond service, overruns,
collisions with impact speed), and records measuring-point passages.  The separation model's
assumptions are a named set (``Scenario.assumptions``), recorded in the summary.  Everything is
written into the run's folder as tidy CSV plus SUMO's own outputs.

If SUMO fails during the run (an error it stops on, or the simulation closed), :func:`simulate`
raises one :class:`~vcsumo.errors.SumoError` naming the line file, the network file and the time;
the caller's :class:`~vcsumo.results.ResultsFolder` then removes the partial folder.
"""

from __future__ import annotations

import math
import shutil
from bisect import bisect_right
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import pandas as pd

from vcsumo.errors import VcsumoError
from vcsumo.line import Line
from vcsumo.results import write_json
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.regimes import REGIMES, Regime
from vcsumo.signalling.separation import SeparationModel
from vcsumo.sim.health import HealthMonitor
from vcsumo.sim.network import BuiltNetwork
from vcsumo.sim.records import CsvStream, csv_plain
from vcsumo.sim.snapshot import Driver, Snapshot, StepTrains, TrainState  # noqa: F401 (Snapshot, TrainState: the drivers' types, also from here)
from vcsumo.sim.run_results import TRAJECTORY_COLUMNS, TRAJECTORY_FLOATS, SimulationResult, collect_results
from vcsumo.sim.interlocking import MergeLocking
from vcsumo.sim.single_track_lock import OpposingTrains, clearance
from vcsumo.sim.supervision import BrakingCurveSupervisor
from vcsumo.sim.trains_ahead import TrainsAhead
from vcsumo.sim.sumo_backend import SPEED_MODE_VC_FOLLOWER, SumoBackend, sumo_args
from vcsumo.sim.sumo_io import write_sumocfg
from vcsumo.timetable import PlannedTrain, routes_xml
from vcsumo.units import G



@dataclass(frozen=True)
class MeasuringPoint:
    label: str
    section: str
    km: float


@dataclass
class Scenario:
    """Everything a run needs."""

    line: Line
    network: BuiltNetwork
    trains: list[PlannedTrain]
    regime: str
    step_length_s: float = 0.5
    record_period_s: float = 1.0
    measuring_points: list[MeasuringPoint] = field(default_factory=list)
    assumptions: AssumptionSet | None = None
    """The separation model's assumption set (None: the shipped default, etcs_typical)."""
    seed: int = 42
    end_time_s: float | None = None
    lookahead_m: float = 30000.0
    driver: Driver | None = None
    fixed_time_s: float | None = None
    """ETCS-style fixed times (route setting + MA transmission + reaction) of the movement
    authorities of the trains SUMO drives, s (None: the assumption set's)."""
    rules: Regime | None = field(default=None, init=False, repr=False)
    """The registered regime named by ``regime`` (set on construction)."""
    merge_orders: dict[str, list[str]] = field(default_factory=dict)
    """Junction node -> train ids in the order they must pass it (default: first come, first served)."""
    supervise: bool = True
    """Braking-curve supervision of the trains SUMO drives (off only to show what SUMO alone does)."""
    full_outputs: bool = True
    """Write the trajectory CSV and SUMO's rail-signal output (off for bisection probes and batches)."""
    sumo_fcd: bool = False
    """Also write SUMO's own fcd output (fcd.xml, the same 1 s samples as trajectories.csv; only with full_outputs)."""
    trace_speeds: bool = False
    """Keep every train's (position, speed) at every step in the result (hindrance checks)."""
    additional_files: list[Path] = field(default_factory=list)
    """Further SUMO additional files, loaded after the network's stations file (e.g. signal
    recordings and constraints written by :func:`vcsumo.sim.sumo_io.write_additional`)."""

    def __post_init__(self) -> None:
        if self.regime not in REGIMES:
            raise VcsumoError(f"unknown regime '{self.regime}' (choose from {', '.join(REGIMES)})")
        self.rules = REGIMES[self.regime]
        if not self.trains:
            raise VcsumoError("no trains to simulate")
        if self.assumptions is None:
            self.assumptions = load_assumptions()
        if self.fixed_time_s is not None:
            self.assumptions = self.assumptions.model_copy(update={"fixed_time_s": self.fixed_time_s})


LOOP_PARTS = ("sumo", "observation", "supervision", "health", "recording", "driver", "io")
"""Parts of the loop whose CPU time :func:`simulate` accounts (``summary["loop_cpu_s"]``)."""


@dataclass
class _Track:
    plan: PlannedTrain
    s: float = math.nan
    sync_s: float = math.nan
    sync_odo: float = math.nan
    tf: float = 1.0
    min_gap: float = math.inf
    emergencies: int = 0
    released_s: float = math.nan
    """When the driver last handed the train back to SUMO (nan: never)."""
    controlled: bool = False
    mp_s: dict[str, float] = field(default_factory=dict)
    departed_at: float = math.nan
    arrived_at: float = math.nan
    starts: list[float] = field(default_factory=list)
    """Where each edge of the route starts, m (plain floats for the per-step look-ups)."""
    tunnels: bool = True
    """The route has a tunnel factor other than 1 somewhere (else the vType never changes)."""
    edges: list[str] = field(default_factory=list)
    n_edges: int = 0
    tf_from: float = math.inf
    tf_to: float = -math.inf
    """The stretch of the route around the front with one tunnel factor (the last one looked up), m."""


def simulate(scn: Scenario, out: Path, progress: Callable[[float, float], None] | None = None) -> SimulationResult:
    """Run a scenario in SUMO, writing SUMO outputs and vcsumo's CSVs into ``out``.

    Per step the work is proportional to the trains running: SUMO keeps them in one list
    (:meth:`SumoBackend.running`), their values are read in one pass, the train ahead is found from
    the routes' own index (:class:`~vcsumo.sim.trains_ahead.TrainsAhead`), and the trajectory rows go to disk in chunks
    (:class:`vcsumo.sim.records.CsvStream`).  The CPU time of each part of the loop (SUMO stepping,
    observation, supervision, health, recording, driver, I/O) is in ``summary["loop_cpu_s"]``.
    """
    clock = time.thread_time
    cpu = dict.fromkeys(LOOP_PARTS, 0.0)
    c_mark = clock()
    t_wall = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    netdir = out / "network"
    netdir.mkdir(exist_ok=True)
    shutil.copy2(scn.network.net_file, netdir / "line.net.xml")
    shutil.copy2(scn.network.stations_file, netdir / "stations.add.xml")
    topo = scn.network.topology
    # SUMO leaves the model's margin and position errors behind a standing train (a convoy follower berths that far behind its leader)
    (out / "routes.rou.xml").write_text(routes_xml(scn.trains, topo, SeparationModel(scn.assumptions).margin_m, scn.assumptions.position_error_m))
    begin = math.floor(min(t.depart_s for t in scn.trains))
    if scn.end_time_s is not None:
        end = scn.end_time_s
    else:
        longest = max(t.profile.length_m for t in scn.trains)
        dwell = max(sum(s.dwell_s for s in t.stops) for t in scn.trains)
        end = max(t.depart_s for t in scn.trains) + 4.0 * longest / 10.0 + dwell + 3600.0
    args = sumo_args(
        netdir / "line.net.xml", out / "routes.rou.xml", [netdir / "stations.add.xml", *scn.additional_files], out, scn.step_length_s, end,
        moving_block=scn.rules.moving_block, seed=scn.seed, fcd_period=scn.record_period_s, full_outputs=scn.full_outputs,
        fcd=scn.full_outputs and scn.sumo_fcd,
    ) + ["--begin", str(begin)]
    write_sumocfg(out / "scenario.sumocfg", args, out)

    plans = {t.id: t for t in scn.trains}
    route_starts: dict[int, list[float]] = {}

    def starts_of(plan: PlannedTrain) -> list[float]:
        key = id(plan.profile)
        if key not in route_starts:
            route_starts[key] = [float(x) for x in plan.profile.starts_m]
        return route_starts[key]

    portals: dict[int, list[float]] = {}

    def tunnel_stretch(prof, s_m: float) -> tuple[float, float]:
        """[from, to) of the route around s where the tunnel factor does not change, m."""
        key = id(prof)
        if key not in portals:
            tfs = [float(x) for x in prof.tunnel_factors]
            portals[key] = [float(prof.starts_m[i]) for i in range(1, len(tfs)) if tfs[i] != tfs[i - 1]]
        marks = portals[key]
        k = bisect_right(marks, s_m)
        return (marks[k - 1] if k > 0 else -math.inf), (marks[k] if k < len(marks) else math.inf)
    state: dict[str, _Track] = {}
    # (its rows are built below from SUMO's floats, rounded floats and None: no per-row check)
    traj = CsvStream(out / "trajectories.csv", TRAJECTORY_COLUMNS, TRAJECTORY_FLOATS, floats_checked=True) if scn.full_outputs else None
    # every text a trajectory row can hold needs no quoting (train ids, sections, edges, SUMO's junction lanes ':<node>_<k>'): formatted here, else by csv
    plain_text = all(csv_plain(x) for x in [*plans, *topo.edges, *topo.nodes] + [sec for t in scn.trains for sec in t.profile.sections])
    pass_rows: list[tuple] = []
    collisions: list[tuple[float, str, str]] = []
    teleports: list[tuple[float, str]] = []
    traces: dict[str, tuple[list[float], list[float]]] = {}
    violation_rows: list[tuple] = []
    next_record = begin
    dt = scn.step_length_s
    model = SeparationModel(scn.assumptions)
    health = HealthMonitor(model, scn.trains)
    head_on = OpposingTrains(topo, scn.trains, clearance(scn.assumptions))  # opposing trains meeting on single track: collisions SUMO may not see
    supervisor = locking = None
    if scn.supervise:
        signals = {t.id: t.profile.signal_positions(topo) for t in scn.trains} if scn.rules.supervision == "fbs" else None
        convoys = {t.id: scn.driver.predecessor_of(t.id) for t in scn.trains} if scn.driver is not None else {}
        locking = MergeLocking(model, topo, scn.trains, health.service, scn.merge_orders, signals=signals, convoys={k: v for k, v in convoys.items() if v})
        supervisor = BrakingCurveSupervisor(model, scn.rules.supervision, scn.trains, dt, signals, locking=locking, braking=health.service)
    # the highest speed SUMO can give a train in one step from rest: full traction, no resistance, its route's steepest descent
    start_speed = {t.id: dt * (t.stock.max_traction_n / t.stock.mass_kg - G * min(0.0, t.profile.gradient_range(0.0, t.profile.length_m)[0])) for t in scn.trains}
    driver = scn.driver
    if driver is not None and scn.full_outputs and hasattr(driver, "stream_records"):
        driver.stream_records(out)  # the driver's per-step records go to disk as the run goes
    stop_releases = getattr(driver, "stop_releases", lambda: ())  # a driver that never ends a stop need not say so
    stop_holds = getattr(driver, "stop_holds", dict)  # nor one that never holds a train at its stop
    authority_caps = 0
    touching_before: set[tuple[str, str]] = set()
    emergency_before: set[str] = set()
    capped: set[str] = set()
    timing = {"sumo_s": 0.0, "controller_s": 0.0}
    steps = train_steps = 0
    progress_every = max(dt, (end - begin) / 500.0)
    next_progress = begin
    lookahead = scn.lookahead_m
    label = f"{scn.line.path} ({scn.regime}, network {scn.network.net_file})"
    c = clock()
    cpu["io"] += c - c_mark
    c_mark = c
    stopped_at = (lambda t_s: progress(t_s - begin, end - begin)) if progress is not None else None  # noqa: E731
    with SumoBackend(args, error_log=out / "sumo_errors.log", label=label, on_failure=stopped_at) as sim:
        if supervisor is not None:
            supervisor.held_at_stop = sim.at_stop
            locking.single.attach(sim.hold_insertion, sim.time)  # trains entering on single track wait until given it
        if getattr(driver, "insertion", None) is not None:  # convoy followers enter behind their predecessor
            driver.insertion.attach(sim.hold_insertion, topo)
        t = sim.time
        ahead = TrainsAhead(sim, {p.id: p.profile.edges for p in scn.trains}, lookahead)
        while True:
            # ---------------------------------------------------------------- SUMO
            t0 = time.perf_counter()
            t = sim.step()
            timing["sumo_s"] += time.perf_counter() - t0
            steps += 1
            c = clock()
            cpu["sumo"] += c - c_mark
            c_mark = c
            # ---------------------------------------------------------------- observation
            for vid in sim.departed():
                prof = plans[vid].profile
                tr = _Track(plan=plans[vid], departed_at=t, starts=starts_of(plans[vid]), tunnels=bool((prof.tunnel_factors != 1.0).any()),
                            edges=prof.edges, n_edges=len(prof.edges))
                for mp in scn.measuring_points:
                    try:
                        s_mp = tr.plan.profile.s_of(mp.section, mp.km)
                    except KeyError:
                        continue
                    if s_mp > tr.plan.start_s_m:
                        tr.mp_s[mp.label] = s_mp
                state[vid] = tr
            arrived_now = sim.arrived()
            for vid in filter(state.__contains__, arrived_now):  # (only the trains that arrived, not every train ever departed)
                state[vid].arrived_at = t
            active = [v for v in sim.running() if v in state]
            train_steps += len(active)
            observed = sim.observe_all(active)  # (edge, lane pos, speed, accel, odometer, route index)
            obs = dict(zip(active, observed))
            leads = ahead.leaders(active, observed)  # the train ahead on the route and the gap to its rear
            rows: list[tuple] = []  # (vid, track, s, speed, accel, edge, lead, gap, controlled)
            fouled: set[str] = set()  # trains whose gap runs to a junction the train ahead fouls (a fixed point)
            prev_pos = []
            for vid, (edge, lane_pos, _v, _a, odo, ridx) in zip(active, observed):  # every route position first: the gap checks read the train ahead's
                tr = state[vid]
                prev_pos.append(tr.s)
                if 0 <= ridx < tr.n_edges and tr.edges[ridx] == edge:  # on its route's edge (not inside a junction)
                    tr.s = tr.sync_s = tr.starts[ridx] + lane_pos
                    tr.sync_odo = odo
                else:  # inside a junction: its internal lane (SUMO's, ~24 m at a merge) is a point of the route
                    tr.s = min(tr.sync_s + (odo - tr.sync_odo), tr.starts[ridx + 1] if 0 <= ridx < tr.n_edges - 1 else math.inf)
            for vid, (edge, lane_pos, speed, accel, odo, ridx), lead, prev_s in zip(active, observed, leads, prev_pos):
                tr = state[vid]
                s_now = tr.s
                if s_now != s_now:  # nan: not yet on its route
                    continue
                # tunnel drag: switch the vType when the front passes a portal (looked up off the stretch last found)
                if tr.tunnels and not tr.tf_from <= s_now < tr.tf_to:
                    tf = tr.plan.profile.tunnel_factor_at(s_now)
                    if abs(tf - tr.tf) > 1e-9:
                        sim.set_type(vid, tr.plan.stock.vtype_id(tf))
                        tr.tf = tf
                    tr.tf_from, tr.tf_to = tunnel_stretch(tr.plan.profile, s_now)
                # measuring points
                if tr.mp_s and prev_s == prev_s:
                    for mp_label, s_mp in tr.mp_s.items():
                        if prev_s < s_mp <= s_now:
                            frac = (s_mp - prev_s) / max(s_now - prev_s, 1e-9)
                            pass_rows.append((mp_label, vid, t - dt + frac * dt, speed))
                gap = lead[1] if lead else math.inf
                controlled = tr.controlled and driver is not None
                if driver is not None and not tr.controlled and math.isnan(tr.released_s) and lead is not None:
                    # before the driver's first decision a follower behind its own predecessor counts as coupled
                    controlled = driver.predecessor_of(vid) == lead[0]
                if lead is not None and locking is not None and lead[0] in state and not controlled:
                    # absolute braking stops short of the fouling point; relative braking keeps to SUMO's gap to
                    # the rear projected onto this route (the leader's body clears the junction as that rear moves on)
                    g = locking.fouling_gap(vid, s_now, lead[0], state[lead[0]].s)
                    if g is not None:
                        gap = g
                        fouled.add(vid)
                if gap < tr.min_gap:
                    tr.min_gap = gap
                if scn.trace_speeds:
                    tr_s, tr_v = traces.setdefault(vid, ([], []))
                    tr_s.append(s_now)
                    tr_v.append(speed)
                rows.append((vid, tr, s_now, speed, accel, edge, lead, gap, controlled))
            c = clock()
            cpu["observation"] += c - c_mark
            c_mark = c
            # ---------------------------------------------------------------- supervision (braking curves)
            perms: list = [None] * len(rows)
            if supervisor is not None:
                if supervisor.reads_odometry:  # every train's odometer before any authority of the step is built
                    supervisor.observe_all(t, [r[0] for r in rows], [obs[r[0]][4] for r in rows])
                quiet = supervisor.quiet
                for i, (vid, tr, s_now, speed, _a, _e, lead, gap, controlled) in enumerate(rows):
                    if not controlled:
                        lead_id = lead[0] if lead else None
                        if not quiet(vid, t, s_now, speed, gap, lead_id):
                            perms[i] = supervisor.permitted(vid, t, s_now, speed, gap, lead_id, vid in fouled)
            c = clock()
            cpu["supervision"] += c - c_mark
            c_mark = c
            # ---------------------------------------------------------------- health
            caps: dict[str, float] = {}
            held: dict[str, float] = {}  # trains standing at their stop, left to SUMO: their permitted speed
            for i, (vid, tr, s_now, speed, accel, _e, lead, gap, controlled) in enumerate(rows):
                perm = perms[i]
                coupled = lead is not None and controlled and lead[0] in obs  # relative braking behind the train ahead
                required = health.step(vid, dt, s_now, speed, accel, gap, perm.authority_m if perm else math.inf, not controlled,
                                       lead[0] if coupled else None, obs[lead[0]][2] if coupled else 0.0, t)
                if required is not None:
                    sec, km_v = tr.plan.profile.km_at(s_now)  # the gap just fell below the safe separation
                    violation_rows.append((t, vid, lead[0] if lead else None, sec, round(km_v, 4), speed, gap, required, controlled))
                # a train standing at its stop is left to SUMO where one step of its strongest start stays within its
                # curve; the cap takes it from the step it moves (one standing elsewhere stays capped, and so does one whose
                # end of authority is closer than one step of full traction: SUMO would start it past its curve)
                if perm is not None and perm.speed_mps < speed + 2.0:
                    if speed < 0.01 and perm.speed_mps >= start_speed[vid] and sim.at_stop(vid):
                        held[vid] = perm.speed_mps
                    else:
                        caps[vid] = perm.speed_mps
            c = clock()
            cpu["health"] += c - c_mark
            c_mark = c
            # ---------------------------------------------------------------- supervision: merges, caps
            if locking is not None:  # approach locking at merges (used by the supervision from the next step)
                locking.arrived(arrived_now)
                moving = {r[0]: (r[2], r[3]) for r in rows}
                for sig, train, foe in locking.update(moving):
                    sim.add_constraint(sig, train, sig, foe)
                for sig, train, foe_sig, foe in locking.single.update(moving, t):  # one direction at a time on single track
                    sim.add_constraint(sig, train, foe_sig, foe)
            for r in rows:
                vid = r[0]
                cap = caps.get(vid)
                if cap is not None and not r[1].controlled:
                    sim.set_speed(vid, cap)
                    capped.add(vid)
                    authority_caps += 1
                elif vid in capped:
                    sim.release(vid)
                    capped.discard(vid)
            c = clock()
            cpu["supervision"] += c - c_mark
            c_mark = c
            # ---------------------------------------------------------------- health: SUMO's events
            emergency_now = {vid for vid in sim.emergency_stops() if vid in obs}  # (running trains)
            for vid in emergency_now - emergency_before:  # one emergency stop per episode
                state[vid].emergencies += 1
            emergency_before = emergency_now
            touching = set(sim.collisions())  # SUMO reports a collision at every step the trains overlap
            for collider, victim in touching - touching_before:  # one collision per episode
                collisions.append((t, collider, victim))
                health.collision(t, collider, victim, obs[collider][2] if collider in obs else 0.0, obs[victim][2] if victim in obs else 0.0)
            touching_before = touching
            if head_on.active:
                for a_id, b_id in head_on.step({r[0]: r[2] for r in rows}):
                    if (a_id, b_id) not in touching and (b_id, a_id) not in touching:  # (closing speed as the impact speed)
                        collisions.append((t, a_id, b_id))
                        health.collision(t, a_id, b_id, obs[a_id][2] + obs[b_id][2], 0.0)
                for vid, other, past, (sec, km_v) in head_on.too_close:  # onto single track an opposing train had not cleared
                    violation_rows.append((t, vid, other, sec, round(km_v, 4), obs[vid][2], past, health.clearance(vid, past, head_on.clearance_m), any(r[8] for r in rows if r[0] == vid)))
            teleports += [(t, vid) for vid in sim.teleports()]
            c = clock()
            cpu["health"] += c - c_mark
            c_mark = c
            # ---------------------------------------------------------------- recording
            if t + 1e-9 >= next_record:
                if traj is not None and plain_text:  # (the csv module's bytes, formatted here: see CsvStream.extend_lines)
                    traj.extend_lines([f"{t!r},{vid},{section},{round(km, 6)!r},{round(s_now, 3)!r},{speed!r},{accel!r},"
                                       f"{'' if gap == math.inf else repr(round(gap, 3))},{lead[0] if lead else ''},{edge}\n"
                                       for vid, tr, s_now, speed, accel, edge, lead, gap, _c in rows
                                       for section, km in (tr.plan.profile.km_at(s_now),)])
                elif traj is not None:
                    recs = []
                    for vid, tr, s_now, speed, accel, edge, lead, gap, _c in rows:
                        section, km = tr.plan.profile.km_at(s_now)
                        recs.append((t, vid, section, round(km, 6), round(s_now, 3), speed, accel, None if gap == math.inf else round(gap, 3),
                                     lead[0] if lead else None, edge))
                    traj.extend(recs)
                next_record += scn.record_period_s
            c = clock()
            cpu["recording"] += c - c_mark
            c_mark = c
            # ---------------------------------------------------------------- driver
            if driver is not None:
                t0 = time.perf_counter()
                snap = StepTrains(t, {r[0]: (r[1].plan.profile, r[2], r[3], r[4], r[5], r[6][0] if r[6] else None, r[7]) for r in rows})
                ends, handover = {}, {}
                for r in rows:
                    pred = driver.predecessor_of(r[0])
                    if pred is not None and locking is not None:  # what the approach locking allows each convoy follower at the merges ahead
                        d_ma = locking.authority_distance(r[0], r[2], coupled_to=pred)
                        if d_ma < math.inf:
                            ends[r[0]] = d_ma
                    if pred is not None and supervisor is not None and r[6]:  # the authority it gets if handed to SUMO (report age, fixed times)
                        handover[r[0]] = supervisor.authority_distance(r[0], r[2], r[7], r[6][0], t)
                commands = driver.make_step(Snapshot(t, dt, snap, ends, handover))
                timing["controller_s"] += time.perf_counter() - t0
                for vid, until in stop_holds().items():  # a follower behind it in the platform has not served its dwell
                    if vid in state and sim.at_stop(vid):
                        sim.hold_stop(vid, until)
                for vid in stop_releases():
                    sim.resume(vid)
                    if vid in held:  # off its stop now: its curve holds from this step (SUMO would start it at full acceleration)
                        sim.set_speed(vid, held[vid])
                        capped.add(vid)
                for vid, v_cmd in commands.items():
                    tr = state.get(vid)
                    if tr is None:
                        continue
                    capped.discard(vid)
                    if not tr.controlled:
                        sim.set_speed_mode(vid, SPEED_MODE_VC_FOLLOWER)
                        tr.controlled = True
                    sim.set_speed(vid, max(0.0, v_cmd))
                for vid in active:
                    tr = state[vid]
                    if tr.controlled and vid not in commands and vid in snap:
                        sim.release(vid)
                        tr.controlled = False
                        tr.released_s = t
                        if supervisor is not None:  # supervised from this very step: no step of SUMO alone
                            ts = snap[vid]
                            perm = supervisor.permitted(vid, t, ts.s_m, ts.speed_mps, ts.gap_m, ts.leader, vid in fouled)
                            if perm.speed_mps < ts.speed_mps + 2.0:
                                sim.set_speed(vid, perm.speed_mps)
                                capped.add(vid)
                    elif not tr.controlled and vid not in commands and vid in snap and math.isnan(tr.released_s) and tr.departed_at < t:
                        tr.released_s = t  # the driver decided not to drive it
                c = clock()
                cpu["driver"] += c - c_mark
                c_mark = c
            if progress is not None and t >= next_progress:
                progress(t - begin, end - begin)
                next_progress = t + progress_every
            if sim.min_expected() == 0 or t >= end - 1e-9:
                break
        sim_end = t
    if progress is not None:
        progress(sim_end - begin, end - begin)
    t_io = time.perf_counter()
    if traj is not None:
        traj.close()
    pd.DataFrame(violation_rows, columns=["time_s", "train", "leader", "section", "km", "speed_mps", "gap_m", "safe_separation_m", "driven_by_vcsumo"]).to_csv(out / "violations.csv", index=False)
    pd.DataFrame(health.collision_rows, columns=["time_s", "collider", "victim", "impact_speed_kmh"]).to_csv(out / "collisions.csv", index=False)
    extra = {
        "fixed_time_s": scn.assumptions.fixed_time_s, "authority_caps": authority_caps, "assumptions": scn.assumptions.name,
        "sumo_step_time_s": round(timing["sumo_s"], 3), "controller_time_s": round(timing["controller_s"], 3),
        "steps": steps, "train_steps": train_steps,
    }
    result = collect_results(scn, out, state, health, traj.path if traj is not None else None, pass_rows, collisions, teleports, sim_end, t_io - t_wall, extra)
    result.speed_traces = traces
    cpu["io"] += clock() - c_mark
    result.summary["loop_cpu_s"] = {k: round(v, 3) for k, v in cpu.items()}
    write_json(out / "summary.json", result.summary)
    return result
