"""Virtual coupling in the SUMO loop: convoys, messages, controllers and the safety filter.

:class:`VCDriver` is the :class:`~vcsumo.sim.loop.Driver` of the ``vc`` regime.  Each step it

1. lets every convoy member send a train-to-train message through the seeded
   :class:`~vcsumo.control.channel.Channel` (state, and a predicted trajectory: the convoy leader's
   is its unhindered running profile from its current state — the plan its ATO would follow; a
   follower's is its controller's last plan);
2. builds, for every coupled follower, an :class:`~vcsumo.control.base.Observation` with what the
   channel delivered mapped into the follower's own route frame, the on-board sensed gap and
   speed of the predecessor (once it is the train SUMO sees ahead), and its route profile;
3. steps the follower's stack, built by name in :mod:`vcsumo.control.registry` — the same stack
   the offline loop and the safety campaign run: the nominal controller (MPC, consensus,
   Terlizzi's switched cruise controller), the CBF supervisor for ``cbf-`` names, the separation
   guard (:class:`~vcsumo.control.guard.SeparationGuard`: the largest force whose one-step speed
   keeps the relative braking distance, on the best information on board; its interventions are
   counted), all inside the follower's :class:`~vcsumo.control.faults.FaultStage`: a stage that
   raises, returns a non-finite force or reports an infeasible problem without a usable fallback,
   or an observation with a non-finite state, gives the follower the emergency brake until data
   and controller have been valid for ``fault_recovery_s`` (events in ``faults.csv``, counted as
   ``fault_events`` / ``fault_emergency_steps`` in the summary);
4. turns the final force into the speed the train reaches after one step under eq. 1b (the shared
   train model, the force bounded below by the emergency brake), which the loop sends to SUMO with
   speed mode 26 (traction limit and red signals still enforced by SUMO; SUMO's own
   braking-distance rule and service-brake cap off).  Approaching its own stop the follower's
   guard keeps to the service brake (``Observation.next_stop_m``), so SUMO can take over there.

Convoy leaders and trains outside convoys stay with SUMO (moving block).  A follower is coupled while
its predecessor is on the part of its route they share (through a merge, the gap is the difference of
their distances to the merge point; before its predecessor has reached the merge only once that puts
it virtually ahead by its stack's spacing and the safe separation); split: to SUMO.

Stations.  Convoy members leaving the same platform together depart at the leader's time, the
follower standing behind the leader at its standstill gap (the convoy stands in the platform as
one train, as in Felez et al. §IV-B); one the platform does not hold enters behind its predecessor
(:attr:`VCDriver.insertion`, :mod:`~vcsumo.sim.convoy_insertion`).  The controllers know nothing
of stops: a follower is handed to SUMO for its own station stop once its stop is within braking
distance and either its speed is below 30 km/h (SUMO's on-sight moving-block rule lets it close up
behind the standing leader) or the moving-block distance to its predecessor is kept; it is coupled
again once it has left the stop.

Controller names are the registry's (:func:`~vcsumo.control.registry.controller_names`), a parameter
file after a colon (``cbc:cbc_plf``); plans are broadcast only when the controller reads them.  Before
its first command a moving follower applies the force holding its speed (the offline loop's start;
until 2026-11-28 0 N, so on a descent its CBF braked at once), a standing one 0 N.
"""

from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vcsumo.control.base import Command, Message, Observation, TrainStateMsg
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.faults import FAULT_KINDS, faults_frame
from vcsumo.control.guard import GuardConfig, default_guard, load_guard
from vcsumo.control.registry import StackContext, build_follower_stack, controller_spec, parse_controller
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel
from vcsumo.control.stack import FollowerStack
from vcsumo.dynamics import acceleration, gradient_force, running_resistance
from vcsumo.results import write_json
from vcsumo.running_time import unhindered_run
from vcsumo.sim.convoy_formation import MOVING_MPS, Formation
from vcsumo.sim.convoy_insertion import ConvoyInsertion
from vcsumo.sim.convoy_plan import (MIN_CONVOY_DWELL_S, Frame, align_convoy_stops, arrange_convoy_departures, convoy_stop_holds, convoys_from_timetable,
                                    follower_dwells, follower_stops, frame, load_channel, platform_queues, stops_outside, warn_short_platforms)
from vcsumo.sim.junction_policy import JunctionPolicy
from vcsumo.sim.loop import Snapshot
from vcsumo.sim.records import VC_RECORD_COLUMNS, VC_RECORD_FLOATS, CsvStream, RunningStats
from vcsumo.timetable import PlannedTrain, TimetableFile

# -------------------------------------------------------------------------------------------
# The convoy leader's plan


def leader_plan(t: PlannedTrain, s_m: float, v_mps: float, now_s: float, horizon_s: float, dt: float, stops_after: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The convoy leader's predicted trajectory: its unhindered running profile from its state."""
    from vcsumo.running_time import Stop

    run = unhindered_run(t.stock.params(), t.profile, dt=dt, s0=s_m, v0=v_mps, stops=[Stop(x.s_m, x.dwell_s) for x in stops_after],
                         end_s=t.profile.length_m if t.end_pos_m is None else float(t.profile.starts_m[-1] + t.end_pos_m),
                         stop_at_end=t.stop_at_end, t_max=horizon_s)
    p = t.stock.params()
    v = run.speed_mps.to_numpy()
    a = run.accel_mps2.to_numpy()
    s = run.s_m.to_numpy()
    grads = np.array([t.profile.mean_gradient(x, p.length_m) for x in s])
    tfs = np.array([t.profile.tunnel_factor_at(x) for x in s])
    force = p.mass_kg * p.rotating_mass_factor * a + running_resistance(p, v, tfs) + gradient_force(p, grads)
    return now_s + run.time_s.to_numpy(), s, v, force


@dataclass
class _Follower:
    plan: PlannedTrain
    pred: PlannedTrain
    convoy: tuple[str, ...]
    stack: FollowerStack
    d_min: float
    frames: dict[str, Frame]
    coupled: bool = False
    last_cmd: Command | None = None
    steps: int = 0
    infeasible: int = 0
    emergency_steps: int = 0
    emergency_episodes: int = 0
    in_emergency: bool = False
    interventions: int = 0
    solve_ms: RunningStats = field(default_factory=RunningStats)
    """The stack's CPU time per step, ms (running statistics: no per-step list)."""
    modes: dict[str, int] = field(default_factory=dict)
    coupled_since_s: float = math.nan
    released_at_s: float = math.nan
    stops_m: list[float] = field(default_factory=list)
    platforms_m: list[float] = field(default_factory=list)
    dwells_s: list[float | None] = field(default_factory=list)
    """Per stop: its own minimum dwell (None where its run ends), s."""
    pred_stands_m: list[float | None] = field(default_factory=list)
    """Per stop: where the predecessor's front will stand when it stops in the same platform (this
    follower's route frame; None: it does not stop there), m."""
    params: object = None
    rule: RelativeBraking | None = None
    """The relative-braking rule behind its predecessor (the run-health monitor's), on its route."""
    next_stop: int = 0
    stop_handovers: int = 0
    at_stop: bool = False
    linked: bool = False
    """The link to the predecessor is up (set at the first step both run)."""
    braking: RouteBraking | None = None
    """The follower's guaranteed service braking on its route, the supervision's (stop hand-over)."""
    stood_since_s: float = math.nan
    """Since when it stands at a shared stop behind its predecessor, s."""
    formation: Formation = field(default_factory=Formation)

    @property
    def stage(self):
        """The stack's fault stage (controller → supervisor → guard, with fault handling)."""
        return self.stack.stage

    @property
    def guard_interventions(self) -> int:
        return self.stack.guard_interventions


class VCDriver:
    """The vc-regime driver: convoys, channel, controllers, CBF filter (see module doc)."""

    def __init__(self, convoys: list[list[PlannedTrain]], controller: str, step_s: float, seed: int = 42, channel: ChannelConfig | None = None,
                 cbf_config: str | None = None, plan_horizon_s: float = 8.0, record_every_s: float = 1.0, guard: GuardConfig | None = None,
                 plan_step_s: float = 0.5, fault_recovery_s: float = 1.0, assumptions: AssumptionSet | None = None,
                 junction: JunctionPolicy | None = None, message_age_s: float | None = None):
        self.name, self.params_spec = parse_controller(controller)
        self.junction = junction  # link handshake, braking curves to lower limits and to the end of authority at merges
        self.assumptions = assumptions or load_assumptions()
        self.model = SeparationModel(self.assumptions)
        self.step_s = step_s
        self.channel = Channel((channel or ChannelConfig(model="ideal", period_s=step_s)).model_copy(update={"seed": seed}))
        self.plan_horizon_s = plan_horizon_s
        self.plan_step_s = plan_step_s
        # predicted trajectories are sent only to controllers that use them (SH predictor, RLP)
        self.send_plans = controller_spec(controller).uses_plans
        self._plans: dict[str, tuple] = {}
        self.guard = guard or default_guard()
        self.trains: dict[str, PlannedTrain] = {}
        self.convoy_of: dict[str, tuple[str, ...]] = {}
        self.followers: dict[str, _Follower] = {}
        self.record_every_s = record_every_s
        self._next_record = -math.inf
        self._records, self._streaming = CsvStream(Path("vc_followers.csv"), VC_RECORD_COLUMNS, VC_RECORD_FLOATS, chunk_rows=1 << 62), False
        # the message age the stacks' spacing budgets: what the channel keeps, or the caller's (a campaign's nominal channel)
        stack_age = self.channel.cfg.age_budget_s() if message_age_s is None else message_age_s
        for members in convoys:
            ids = tuple(m.id for m in members)
            for m in members:
                self.trains[m.id] = m
                self.convoy_of[m.id] = ids
            for k in range(1, len(members)):
                ego, pred = members[k], members[k - 1]
                ego.shares_platforms = True
                stack = build_follower_stack(controller, StackContext(
                    ego=ego.stock, predecessor=pred.stock, step_s=step_s, profile=ego.profile, supervisor_params=cbf_config, guard=self.guard,
                    ego_id=ego.id, predecessor_id=pred.id, recovery_s=fault_recovery_s, assumptions=self.assumptions, message_age_s=stack_age))
                if getattr(stack.supervisor, "record", None):
                    stack.supervisor.record = False  # its barrier history is read by no output of a SUMO run (the records carry the barrier)
                frames = {}
                for other in members:
                    if other.id != ego.id:
                        f = frame(other, ego)
                        if f is not None:
                            frames[other.id] = f
                stops, plats, stands = follower_stops(ego, pred, frames[pred.id].offset_m if pred.id in frames else None)
                self.followers[ego.id] = _Follower(ego, pred, ids, stack, stack.d_min_m, frames, stops_m=stops, platforms_m=plats, params=ego.stock.params(),
                                                   braking=RouteBraking(self.model, ego.stock, ego.profile), pred_stands_m=stands,
                                                   rule=RelativeBraking(self.model, ego.stock, pred.stock, ego.profile))
        self.min_safe_gap_m = max(f.d_min for f in self.followers.values())
        margin = self.model.margin_m  # standing behind a train: margin and position errors
        standstill = {fid: max(f.d_min, margin) + 2.0 for fid, f in self.followers.items()}
        queues = {tid: q for members in convoys for tid, q in platform_queues(members, standstill).items()}
        for fid, f in self.followers.items():  # where its predecessor waits for it to serve its dwell (the platform holds them all)
            f.dwells_s = follower_dwells(f.plan, f.pred, len(f.stops_m), standstill[fid], queues[f.pred.id])
            f.formation.outside = stops_outside(f.plan, f.pred, f.dwells_s)  # where it waits outside until its predecessor has left
        arrange_convoy_departures(convoys, standstill, self.model)
        self.insertion = ConvoyInsertion(convoys, standstill)  # nor does SUMO insert one in front of its predecessor
        warn_short_platforms(convoys, standstill)
        self.aligned_stops = align_convoy_stops(convoys)
        self.releases: set[str] = set()
        self.holds: dict[str, float] = {}
        """Trains a follower standing behind them in a shared platform holds there: train -> until, s."""

    # -----------------------------------------------------------------------------------
    def _send(self, snap: Snapshot) -> None:
        t = snap.time_s
        for tid in snap.trains:
            if tid not in self.convoy_of or not self.channel.due(tid, t):
                continue
            st = snap.trains[tid]
            plan = self.trains[tid]
            f = self.followers.get(tid)
            times = pos = spd = frc = None
            if f is None:  # convoy leader: its unhindered profile from its state
                if self.send_plans:
                    times, pos, spd, frc = self._leader_plan(tid, plan, st, t)
            elif f.last_cmd is not None and f.last_cmd.plan_times_s is not None:
                times, pos, spd, frc = f.last_cmd.plan_times_s, f.last_cmd.plan_positions_m, f.last_cmd.plan_speeds_mps, f.last_cmd.plan_forces_n
            force = f.last_cmd.force_n if f is not None and f.last_cmd is not None else (float(frc[0]) if frc is not None else 0.0)
            for other in self.convoy_of[tid]:
                if other == tid or other not in self.followers:
                    continue
                fr = self.followers[other].frames.get(tid)
                if fr is None:
                    continue
                off = fr.offset_m
                msg = Message(
                    sender=tid, sent_time_s=t, length_m=plan.stock.length_m,
                    state=TrainStateMsg(t, st.s_m + off, st.speed_mps, st.accel_mps2, force),
                    plan_times_s=times, plan_positions_m=None if pos is None else pos + off, plan_speeds_mps=spd, plan_forces_n=frc,
                )
                self.channel.send(msg, [other], t)

    def _leader_plan(self, tid: str, plan: PlannedTrain, st, t: float):
        """The leader's plan over the next ``plan_horizon_s``: computed for twice the horizon and
        reused while the leader runs on it (within 2 m and 0.3 m/s) — an unhindered SUMO leader
        does, so the plan is recomputed about once per horizon instead of at every message."""
        c = self._plans.get(tid)
        if c is not None:
            times, pos, spd, frc, complete = c
            if (complete or t + self.plan_horizon_s <= times[-1] + 1e-9) and t <= times[-1] and abs(float(np.interp(t, times, pos)) - st.s_m) <= 2.0 \
                    and abs(float(np.interp(t, times, spd)) - st.speed_mps) <= 0.3:
                grid = t + np.arange(0.0, self.plan_horizon_s + 1e-9, self.plan_step_s)
                grid = grid[grid <= times[-1] + 1e-9] if complete else grid
                if grid.size >= 2:
                    return grid, np.interp(grid, times, pos), np.interp(grid, times, spd), np.interp(grid, times, frc)
        rest = [x for x in plan.stops if x.s_m > st.s_m + 1.0]
        times, pos, spd, frc = leader_plan(plan, st.s_m, st.speed_mps, t, 2.0 * self.plan_horizon_s, self.plan_step_s, rest)
        complete = times[-1] < t + 2.0 * self.plan_horizon_s - self.plan_step_s - 1e-9
        self._plans[tid] = (times, pos, spd, frc, complete)
        keep = times <= t + self.plan_horizon_s + 1e-9
        return times[keep], pos[keep], spd[keep], frc[keep]

    def stop_releases(self) -> set[str]:
        """Followers whose stop ends now (their convoy leaves the shared platform); cleared on reading."""
        out, self.releases = self.releases, set()
        return out

    def stop_holds(self) -> dict[str, float]:
        """Trains whose stop must not end before a time (a follower behind them in the platform has not
        served its own dwell): train -> time, s (:func:`~vcsumo.sim.convoy_plan.convoy_stop_holds`)."""
        return self.holds

    def make_step(self, snap: Snapshot) -> dict[str, float]:
        """Speed commands for the coupled followers present in the snapshot."""
        whole, snap = snap, (self.junction.visible(snap) if self.junction is not None else snap)
        self.insertion.update(whole.trains)
        self._send(snap)
        t = snap.time_s
        commands: dict[str, float] = {}
        record = t >= self._next_record - 1e-9
        if record:
            self._next_record = t + self.record_every_s
        self.channel.advance(t)  # what is due arrives whether or not its receiver runs
        trains = snap.trains
        waiting: list[tuple[str, str, int, float]] = []  # followers standing or stopping behind their predecessor in a platform
        for fid, f in self.followers.items():
            if fid not in trains:
                continue
            st = trains[fid]
            pst = trains.get(f.pred.id)
            received = self.channel.deliver(fid, t)
            fr = f.frames.get(f.pred.id)
            if not f.linked and pst is not None and fr is not None:
                # the link is up when a convoy starts (formed standing, or released formed): the follower holds its predecessor's state
                f.linked = True
                if f.pred.id not in received:
                    received = {**received, f.pred.id: Message(sender=f.pred.id, sent_time_s=t, length_m=f.pred.stock.length_m,
                                                               state=TrainStateMsg(t, pst.s_m + fr.offset_m, pst.speed_mps, pst.accel_mps2, 0.0),
                                                               received_time_s=t)}
                    self.channel.remember(fid, received[f.pred.id])
            coupled = (
                pst is not None and fr is not None and pst.s_m - f.pred.stock.length_m <= fr.shared_end_a_m and st.s_m <= fr.shared_end_b_m
                and (pst.s_m + fr.offset_m) - f.pred.stock.length_m > st.s_m  # the predecessor is ahead
                and (st.leader in (None, f.pred.id) or st.gap_m >= (pst.s_m + fr.offset_m) - f.pred.stock.length_m - st.s_m - 1.0)  # no train between (else SUMO drives it)
                # before its predecessor has reached a merge where their routes meet, only with it virtually ahead by the spacing
                # its stack keeps and the safe separation: on another track it is in no conflict with it but at the junction
                and (f.coupled or pst.s_m > fr.shared_start_a_m + 1e-6 or (pst.s_m + fr.offset_m) - f.pred.stock.length_m - st.s_m >= max(
                    self.coupled_spacing_m(fid, st.speed_mps), f.rule.required_gap(st.s_m, st.speed_mps, pst.s_m + fr.offset_m, pst.speed_mps, self.model.dead_time_s)))
            )
            # station stops are SUMO's (see module doc)
            while f.next_stop < len(f.stops_m) and st.s_m > f.stops_m[f.next_stop] + 1.0:
                f.formation.passed_stop(f.next_stop)
                f.next_stop += 1
                f.at_stop = False
                f.stood_since_s = math.nan
            stop_target = None  # where SUMO will stop this follower, when its stop is near
            if coupled and f.next_stop < len(f.stops_m):
                v = st.speed_mps
                s_pred = pst.s_m + fr.offset_m
                s_pred_rear = s_pred - f.pred.stock.length_m
                # SUMO stops the follower at its platform end, or behind a predecessor stopping or standing in the platform (margin and errors
                # behind its rear; not one running through: tests/test_unseen13_convoy_stop_run_through.py)
                s_stop, stand = f.stops_m[f.next_stop], f.pred_stands_m[f.next_stop]
                in_platform = s_stop - f.platforms_m[f.next_stop] - 1.0 <= s_pred <= s_stop + 1.0 and (stand is not None or pst.speed_mps < 0.1)
                target = min(s_stop, s_pred_rear - self.model.margin_m) if in_platform else s_stop
                to_stop = target - st.s_m
                stopping = f.braking.stopping_distance(st.s_m, v, 1.5 * self.step_s)
                if to_stop <= stopping + 150.0:
                    stop_target = target
                    if stand is not None and s_pred <= stand + 1.0 and pst.speed_mps > 0.1:
                        # the controller plans towards where a predecessor still braking into this platform will
                        # stand (its rear now would pull the target back step by step as it brakes in); the
                        # hand-over to SUMO below keeps to the rear where it is
                        stop_target = min(s_stop, stand - f.pred.stock.length_m - self.model.margin_m)
                # hand over to SUMO (and its supervision) once the absolute rule holds behind the predecessor
                # and the stop curve can still stop the train there: the run-health monitor then checks it so;
                # and within the authority the supervision will give it (built from the predecessor's position
                # a report period and the fixed times ago: handed over beyond it, it would overrun it at once)
                absolute_ok = s_pred_rear - st.s_m >= self.model.margin_m + f.braking.stopping_distance(st.s_m, v, self.model.dead_time_s) \
                    and snap.handover_authority_m.get(fid, math.inf) >= f.braking.stopping_distance(st.s_m, v, self.model.dead_time_s + 1.5 * self.step_s)
                if f.at_stop or (stop_target is not None and absolute_ok and to_stop >= stopping - 1.0):
                    if not f.at_stop:
                        f.stop_handovers += 1
                    f.at_stop = True
                    coupled = False
                # the convoy leaves a shared platform together, every member once its own dwell is served: the
                # predecessor is held at its stop until then (stop_holds), and the follower's stop ends as it moves off
                # (its dwell counts from its first stand at the stop: SUMO may close it up behind its predecessor after)
                dwell = f.dwells_s[f.next_stop]
                if f.at_stop and in_platform and dwell is not None:
                    if math.isnan(f.stood_since_s) and v < 0.01:
                        f.stood_since_s = t
                    elif t - f.stood_since_s >= max(MIN_CONVOY_DWELL_S, dwell) and pst.speed_mps > 0.1 and fid not in self.holds:
                        self.releases.add(fid)
                    if fid not in self.releases:
                        waiting.append((fid, f.pred.id, f.convoy.index(fid), f.stood_since_s + dwell))
                elif v >= 0.01:
                    f.stood_since_s = math.nan
            if not coupled:
                if f.coupled:
                    f.released_at_s = t
                f.coupled = False
                continue
            if not f.coupled:
                f.coupled, f.coupled_since_s = True, t
            sensed_gap = st.gap_m if st.leader == f.pred.id else None
            sensed_speed = pst.speed_mps if st.leader == f.pred.id else None
            obs = Observation(
                time_s=t, step_s=self.step_s, ego_id=fid,
                ego=TrainStateMsg(t, st.s_m, st.speed_mps, st.accel_mps2, f.last_cmd.force_n if f.last_cmd else 0.0 if st.speed_mps <= 0.0 else
                                  float(running_resistance(f.params, st.speed_mps, f.plan.profile.tunnel_factor_at(st.s_m)) + gradient_force(f.params, f.plan.profile.mean_gradient(st.s_m, f.params.length_m)))),
                params=f.params, profile=f.plan.profile, received=received, predecessor=f.pred.id, convoy=f.convoy,
                sensed_gap_m=sensed_gap, sensed_speed_mps=sensed_speed,
                # approaching its stop the follower keeps to service braking, so that SUMO (which serves it) can take over; the target is an obstacle too
                next_stop_m=stop_target,
            )
            t0 = time.perf_counter()
            cmd = f.stack.make_step(obs)  # controller -> supervisor -> separation guard, with fault handling
            f.interventions = f.stage.supervisor_interventions
            f.solve_ms.add(1000.0 * (time.perf_counter() - t0))
            f.last_cmd = cmd
            f.steps += 1
            f.infeasible += int(cmd.infeasible)
            f.modes[cmd.mode] = f.modes.get(cmd.mode, 0) + 1
            if cmd.emergency:
                f.emergency_steps += 1
                if not f.in_emergency:
                    f.emergency_episodes += 1
            f.in_emergency = cmd.emergency
            # the force -> the speed after one step (eq. 1b); the follower brakes at most with its emergency brake (SUMO's cap is off)
            p = f.params
            grad = f.plan.profile.mean_gradient(st.s_m, p.length_m)
            tf = f.plan.profile.tunnel_factor_at(st.s_m)
            f_min = -p.mass_kg * p.emergency_brake_decel_mps2
            v_floor = max(0.0, st.speed_mps + self.step_s * float(acceleration(p, st.speed_mps, f_min, grad, tf)))
            v_next = max(v_floor, st.speed_mps + self.step_s * float(acceleration(p, st.speed_mps, float(cmd.force_n), grad, tf)))
            guard = f.stack.guard
            f_in = guard.last_force_in_n if guard is not None and math.isfinite(guard.last_force_in_n) else float(cmd.force_n)
            v_nominal = max(v_floor, st.speed_mps + self.step_s * float(acceleration(p, st.speed_mps, f_in, grad, tf)))
            v_guard = guard.last_speed_mps if guard is not None else math.nan
            commands[fid] = v_next
            if record:
                gap_comm = None
                m = received.get(f.pred.id)
                if m is not None:
                    gap_comm = m.state.position_m - m.length_m - st.s_m
                gap = (pst.s_m + fr.offset_m) - f.pred.stock.length_m - st.s_m
                if st.speed_mps >= MOVING_MPS:
                    plan = self.trains[fid]
                    full = min(p.max_traction_n, p.max_power_w / st.speed_mps)  # the most traction the train has at this speed
                    f.formation.update(t, self.record_every_s, st.speed_mps, gap, self.coupled_spacing_m(fid, st.speed_mps, st.s_m),
                                       min(plan.profile.speed_limit_train(st.s_m, plan.stock.length_m), p.max_speed_ms), v_nominal, v_guard,
                                       at_full_traction=f_in >= 0.98 * full)
                self._records.append((
                    t, fid, f.pred.id, st.km, st.speed_mps, pst.speed_mps, gap,
                    sensed_gap, gap_comm, cmd.force_n, cmd.mode, cmd.emergency, cmd.infeasible,
                    cmd.info.get("cbf_true_barrier_m"), cmd.info.get("cbf_robust_barrier_m"), v_nominal, v_guard, v_next,
                ))
        self.holds = convoy_stop_holds(waiting, t, self.step_s)
        if self.junction is not None:
            commands = self.junction.limit(whole, commands, self.channel.latest, self.coupled_spacing_m)
        return commands

    def coupled_spacing_m(self, train_id: str, v_mps: float, position_m: float | None = None) -> float:
        """The spacing a follower's stack keeps behind its predecessor at a common speed v (with its
        front at ``position_m`` on its route: on the gradients there): its controller's coupled gap,
        at least its minimum safe gap (with a CBF: the safety distance d), m."""
        f = self.followers[train_id]
        return max(f.stack.coupled_gap_m(v_mps, position_m), f.d_min)

    # -----------------------------------------------------------------------------------
    def predecessor_of(self, train_id: str) -> str | None:
        f = self.followers.get(train_id)
        return f.pred.id if f is not None else None

    def safe_gap_m(self, train_id: str) -> float:
        f = self.followers.get(train_id)
        return f.d_min if f is not None else 50.0

    @property
    def records(self) -> list[dict]:
        """The follower records held in memory (all unless :meth:`stream_records` sent them to disk)."""
        return [dict(zip(VC_RECORD_COLUMNS, r)) for r in self._records.rows]

    def stream_records(self, out: Path) -> None:
        """Write the records to ``out``/vc_followers.csv in chunks during the run (bounded memory)."""
        self._records, self._streaming = CsvStream(Path(out) / "vc_followers.csv", VC_RECORD_COLUMNS, VC_RECORD_FLOATS), True

    def summary(self) -> dict:
        fs = list(self.followers.values())
        solve = RunningStats()
        for f in fs:
            solve = solve.merge(f.solve_ms)
        return {
            "controller": self.name + (f":{self.params_spec}" if self.params_spec else ""), "convoy_followers": len(fs),
            "coupled_steps": int(sum(f.steps for f in fs)), "controller_infeasible_steps": int(sum(f.infeasible for f in fs)),
            "vc_emergency_activations": int(sum(f.emergency_episodes for f in fs)), "vc_emergency_steps": int(sum(f.emergency_steps for f in fs)),
            "supervisor_interventions": int(sum(f.interventions for f in fs)),
            "guard_interventions": int(sum(f.guard_interventions for f in fs)),
            "controller_step_median_ms": solve.quantile(0.5) if solve.count else None,
            "controller_step_p99_ms": solve.quantile(0.99) if solve.count else None,
            "followers_formed": sum(1 for f in fs if f.formation.running_s > 0 and not f.formation.reason()),
            "followers_not_formed": sum(1 for f in fs if f.formation.reason()),
            "channel_sent": self.channel.sent, "channel_lost": self.channel.lost,
            "fault_events": len(self.fault_events()), "fault_emergency_steps": int(sum(f.stage.emergency_steps for f in fs)),
            **{f"fault_events_{k}": int(sum(f.stage.counts()[k] for f in fs)) for k in FAULT_KINDS},
        }

    def fault_events(self) -> list:
        """Every follower's fault events (:class:`~vcsumo.control.faults.FaultEvent`), by time."""
        return sorted((e for f in self.followers.values() for e in f.stage.events), key=lambda e: (e.time_s, e.train))

    def write_report(self, out: Path) -> None:
        """``vc_followers.csv`` (per follower step records), ``faults.csv`` (fault events) and ``vc_summary.json``."""
        if not self._streaming:
            self._records.frame().to_csv(out / "vc_followers.csv", index=False)
        else:
            self._records.close()
            if self._records.path.resolve() != (Path(out) / "vc_followers.csv").resolve():
                shutil.copyfile(self._records.path, Path(out) / "vc_followers.csv")
        faults_frame(self.fault_events()).to_csv(out / "faults.csv", index=False)
        per = []
        for fid, f in self.followers.items():
            per.append({"train": fid, "predecessor": f.pred.id, "coupled_steps": f.steps, "infeasible_steps": f.infeasible, "stop_handovers": f.stop_handovers,
                        "emergency_activations": f.emergency_episodes, "supervisor_interventions": f.interventions, "guard_interventions": f.guard_interventions,
                        "coupled_since_s": f.coupled_since_s, "released_at_s": f.released_at_s, "modes": f.modes,
                        "fault_events": len(f.stage.events), "fault_emergency_steps": f.stage.emergency_steps, **f.formation.row()})
        write_json(out / "vc_summary.json", {"summary": self.summary(), "followers": per})


def make_vc_driver(tt: TimetableFile, tt_path: Path, trains: list[PlannedTrain], controller: str, step_s: float, seed: int = 42,
                   channel: str | Path | None = None, cbf_config: str | None = None, guard: str | Path | None = None,
                   assumptions: AssumptionSet | None = None) -> VCDriver:
    """Build the vc driver for a timetable's convoys (errors name the timetable or the controller)."""
    parse_controller(controller)
    convoys = convoys_from_timetable(tt, tt_path, trains)
    return VCDriver(convoys, controller, step_s, seed, load_channel(channel), cbf_config, guard=load_guard(guard), assumptions=assumptions)
