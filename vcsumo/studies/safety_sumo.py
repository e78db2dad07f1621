"""The safety campaign inside the SUMO loop itself (``vcsumo study safety --loop sumo``).

A drawn scenario (:func:`~vcsumo.studies.safety_scenarios.draw_scenario`, kinds ``cruise`` and
``forming``: the same line, direction, rolling stock, speeds, brake time, channel and true
parameters as in the offline loop) runs in :func:`vcsumo.sim.loop.simulate` with the ``vc``
regime and the VC driver (:class:`~vcsumo.sim.vc_driver.VCDriver`: every follower's registry stack
— nominal controller → CBF supervisor → separation guard → fault stage — under the campaign's
assumption set, on what the seeded channel delivers):

* the convoy starts flying on the line's main track, at the offline loop's start
  (:func:`~vcsumo.studies.safety_scenarios.initial_gaps`: every train at most at its permitted speed
  where it stands, every follower outside its safe separation); a train SUMO does not insert there at
  that speed makes the run an error (SUMO's rail-signal insertion check is off: a convoy runs in one block);
* every train's SUMO vType carries its drawn true parameters (mass, resistance, traction, power,
  service and emergency deceleration — :meth:`vcsumo.rolling_stock.RollingStock.vtype_variant`),
  while everything on board plans with the nominal model and its box;
* the leader is driven by SUMO (moving block, braking-curve supervision) at most at its drawn speed
  (its vType's maxSpeed, as the offline loop's leader cruises at it) until its drawn brake time,
  then by :class:`ConvoyEmergency` with speed mode 26 (SUMO's deceleration cap off): each step it
  loses what its emergency brake at the top of its range, its true resistance and the gradient
  under it take off (eq. 1b with its true parameters), down to a stop;
* a follower's speed command cannot fall faster than its true train can brake (its emergency brake
  within ±10 % when its command is flagged ``emergency``, else its true service envelope): SUMO
  under speed mode 26 would follow any command, so the true braking is applied here.

Measured by the loop's own run-health monitor (:mod:`vcsumo.sim.health`: the relative-braking rule
on the true states for coupled followers, every step from the first, no exemption): smallest
margin, violations, time below, collisions with impact speed; plus the VC driver's emergency
activations and the CBF's true barrier.  The run's SUMO files go to a temporary folder and are
removed; the row is what remains.
"""

from __future__ import annotations

import math
import tempfile
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from vcsumo.control.channel import ChannelConfig, Window
from vcsumo.dynamics import TrainParams, acceleration, brake_force_limit
from vcsumo.errors import VcsumoError
from vcsumo.plant import emergency_brake_limit
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.separation import RelativeBraking, SeparationModel
from vcsumo.sim.loop import Scenario, Snapshot, simulate
from vcsumo.sim.vc_driver import VCDriver
from vcsumo.studies.safety_scenarios import (
    HEALTH_FAULT_COLUMNS, SafetyCampaign, ScenarioSpec, campaign_assumptions, follower_stacks_for, initial_gaps, line_route, spec_columns, stack_message_age_s, stock,
    true_params,
)
from vcsumo.timetable import PlannedTrain


@lru_cache(maxsize=8)
def _network(line_spec: str):
    """The line and its built SUMO network (cached per process; the build itself is cached on disk)."""
    from vcsumo.line import load_line
    from vcsumo.sim.network import build_network

    line = load_line(line_spec)
    return line, build_network(line)


FLYING_START_CHECKS = "collision leaderGap followerGap stop arrivalSpeed speedLimit"
"""SUMO's insertion checks for a flying start: all but ``junction`` — its rail-signal check inserts a
train only once the train ahead has left the block it starts in (a convoy follower starting in its
predecessor's block: 0.4 s late in scenario s00088), while a virtually coupled convoy runs inside one block."""

START_TOLERANCE = 0.01
"""How far SUMO's first report of a train may be from where and how fast the scenario starts it, m and
m/s (SUMO reports positions to 1 mm and speeds to 0.1 mm/s)."""


class ConvoyEmergency:
    """A loop driver around the VC driver: the leader's emergency stop and every train's true braking.

    ``make_step`` returns the VC driver's speed commands, each raised to what the follower's true
    train reaches when braking as hard as it can (its emergency brake if the command is flagged
    ``emergency``, else its service brake); from ``brake_time_s`` on it also commands the convoy
    leader down at its true emergency rate (the loop then drives it with speed mode 26)."""

    def __init__(self, vc: VCDriver, leader_id: str, brake_time_s: float, true: dict[str, TrainParams], plans: dict[str, PlannedTrain], step_s: float):
        self.vc, self.leader_id, self.brake_time_s, self.true, self.plans, self.dt = vc, leader_id, brake_time_s, true, plans, step_s
        self.leader_braked_at_s = math.nan
        self.start_error: str | None = None
        """After the first step: "" when SUMO started every train where and as fast as the scenario
        starts it (its depart position and speed), else what differed (SUMO inserts a train later, or
        elsewhere, when its own insertion rules refuse the start: a different scenario)."""

    def predecessor_of(self, train_id: str) -> str | None:
        return self.vc.predecessor_of(train_id)

    def stop_releases(self) -> set[str]:
        """The VC driver's convoy followers released at a shared stop (the loop resumes them)."""
        return self.vc.stop_releases()

    def decel_mps2(self, train_id: str, s_m: float, v_mps: float, emergency: bool) -> float:
        """The true train's strongest deceleration at (s, v), m/s² (eq. 1b with its true parameters)."""
        p, prof = self.true[train_id], self.plans[train_id].profile
        force = emergency_brake_limit(p, v_mps) if emergency else float(brake_force_limit(p, max(v_mps, 0.0)))
        return -float(acceleration(p, v_mps, -force, prof.mean_gradient(s_m, p.length_m), prof.tunnel_factor_at(s_m)))

    def check_start(self, snap: Snapshot) -> str:
        """What differs between SUMO's first report of the trains and the scenario's start ("" if nothing)."""
        wrong = []
        for tid, plan in self.plans.items():
            st = snap.trains.get(tid)
            if st is None:
                wrong.append(f"{tid} was not inserted")
            elif abs(st.s_m - plan.depart_pos_m) > START_TOLERANCE or abs(st.speed_mps - plan.depart_speed_mps) > START_TOLERANCE:
                wrong.append(f"{tid} at {st.s_m:.2f} m and {st.speed_mps:.2f} m/s, not {plan.depart_pos_m:.2f} m and {plan.depart_speed_mps:.2f} m/s")
        return f"SUMO did not start the scenario's convoy as drawn at t = {snap.time_s:g} s: {'; '.join(wrong)}" if wrong else ""

    def make_step(self, snap: Snapshot) -> dict[str, float]:
        if self.start_error is None:
            self.start_error = self.check_start(snap)
        cmds = self.vc.make_step(snap)
        for fid, v_cmd in cmds.items():
            st = snap.trains[fid]
            last = self.vc.followers[fid].last_cmd
            floor = st.speed_mps - self.dt * self.decel_mps2(fid, st.s_m, st.speed_mps, last is not None and last.emergency)
            cmds[fid] = max(v_cmd, floor, 0.0)
        st = snap.trains.get(self.leader_id)
        if st is not None and snap.time_s >= self.brake_time_s - 1e-9:
            if math.isnan(self.leader_braked_at_s):
                self.leader_braked_at_s = snap.time_s
            cmds[self.leader_id] = max(0.0, st.speed_mps - self.dt * self.decel_mps2(self.leader_id, st.s_m, st.speed_mps, True))
        return cmds


def flying_start(topo, full_edges: list[str], full: RouteProfile, train, tid: str, s_m: float, v_mps: float, direction: str) -> PlannedTrain:
    """A planned train on the main track with its front at ``s_m`` of the full route, at ``v_mps``,
    departing at t = 0.  The speed is the scenario's (:func:`~vcsumo.studies.safety_scenarios.initial_gaps`:
    at most what the train is permitted where it stands), so the SUMO loop starts the offline loop's
    scenario; a speed above the limit of the edge it starts on (SUMO would refuse the departure) is an
    error, never lowered here."""
    limit = full.speed_limit_at(s_m)
    if v_mps > limit + 1e-9:
        raise VcsumoError(f"train {tid} would start at {3.6 * v_mps:.1f} km/h above the {3.6 * limit:.0f} km/h limit where it stands "
                          f"(route position {s_m:.0f} m): the scenario must start every train at most at its permitted speed")
    i0 = full.index_at(s_m)
    edges = full_edges[i0:]
    pos = s_m - float(full.starts_m[i0])
    return PlannedTrain(id=tid, service=tid, stock=train, edges=edges, profile=RouteProfile.from_edges(topo, edges), depart_s=0.0, depart_pos_m=pos,
                        depart_speed_mps=v_mps, direction=direction, end_pos_m=None, start_s_m=pos, stop_at_end=False,
                        insertion_checks=FLYING_START_CHECKS)


def run_sumo_scenario(spec: ScenarioSpec, controller: str, cfg: SafetyCampaign) -> dict:
    """Run one scenario with one controller in the SUMO loop; return its row of ``safety.csv``."""
    t_wall = time.perf_counter()
    route = line_route(spec.line, spec.direction)
    line, net = _network(spec.line)
    topo = net.topology
    a = campaign_assumptions(cfg.assumptions)
    model = SeparationModel(a)
    stocks = [stock(s) for s in spec.stocks]
    n = spec.followers + 1
    rng = np.random.default_rng(spec.seed)
    params = [true_params(stocks[k], rng, c, emergency_top=(k == 0), assumptions=a) for k, c in enumerate(spec.corners)]
    ids = [f"{spec.id}_t{k}" for k in range(n)]
    rules = [RelativeBraking(model, stocks[k], stocks[k - 1], route.profile) for k in range(1, n)]
    positions, speeds, gaps0 = initial_gaps(spec, follower_stacks_for(controller, route, ids, cfg, stocks), stocks, rules, model, route.profile, cfg.step_s)
    # the leader cruises at most at its drawn speed until it brakes (the offline loop's leader too): SUMO drives it, its vType capped there
    variants = [stocks[k].vtype_variant(ids[k], params[k], max_speed_ms=speeds[0] if k == 0 else None) for k in range(n)]
    trains = [flying_start(topo, route.edges, route.profile, variants[k], ids[k], positions[k], speeds[k], spec.direction) for k in range(n)]
    outages = [Window(start_s=spec.outage[0], end_s=spec.outage[1])] if spec.outage else []
    channel = ChannelConfig(model="exponential", period_s=cfg.channel_period_s, delay_s=spec.delay_s, mean_extra_s=spec.mean_extra_delay_s,
                            loss_probability=spec.loss_probability, outages=outages)
    vc = VCDriver([trains], controller, cfg.step_s, seed=spec.seed, channel=channel, cbf_config=cfg.cbf_config, assumptions=a,
                  message_age_s=stack_message_age_s(cfg))
    driver = ConvoyEmergency(vc, ids[0], spec.brake_time_s, dict(zip(ids, params)), {t.id: t for t in trains}, cfg.step_s)
    # long enough for the leader to stop and the slowest follower to stop behind it
    v_top = max(speeds)
    a_low = min(model.follower_decel(s, 0.0, kind="emergency") for s in stocks)
    end = min(cfg.max_duration_s, spec.brake_time_s + v_top / a_low + 60.0)
    scn = Scenario(line, net, trains, "vc", step_length_s=cfg.step_s, record_period_s=3600.0, assumptions=a, seed=spec.seed % 2**31, end_time_s=end,
                   driver=driver, full_outputs=False)
    with tempfile.TemporaryDirectory(prefix="vcsumo-safety-") as tmp:
        res = simulate(scn, Path(tmp) / "run")
    fol = res.trains.set_index("train").loc[ids[1:]]
    sups = [vc.followers[i].stack.supervisor for i in ids[1:]]
    supervised = sups[0] is not None
    # the true barrier at the first step the follower sensed its predecessor (SUMO reports it from the first step both run); from the
    # supervisor's counters: the VC driver keeps no barrier history (until 2026-11-28 read from it, so always NaN in this loop)
    firsts = [s.stats.first_true_barrier_m for s in sups if s is not None]
    b0 = max((b for b in firsts if math.isfinite(b)), default=math.nan)
    bmax = max(s.stats.max_true_barrier_m for s in sups) if supervised else math.nan
    bmax = bmax if math.isfinite(bmax) else math.nan
    margins = fol["min_margin_m"].dropna()
    summ = vc.summary()
    return {
        **spec_columns(spec, route.profile), "loop": "sumo", "controller": controller, "supervised": supervised, "initial_gap_m": min(gaps0),
        "min_gap_m": float(fol["min_gap_m"].min()), "min_margin_m": float(margins.min()) if len(margins) else math.nan,
        "separation_violations": int(fol["separation_violations"].sum()), "below_separation_time_s": float(fol["below_separation_time_s"].sum()),
        "collisions": int(res.summary["collisions"]), "max_impact_kmh": float(res.summary["max_impact_kmh"]),
        **{c: int(res.summary[c]) for c in HEALTH_FAULT_COLUMNS},
        "emergency_activations": summ["vc_emergency_activations"], "emergency_time_s": summ["vc_emergency_steps"] * cfg.step_s,
        "initial_true_barrier_m": b0 if math.isfinite(b0) else math.nan, "max_true_barrier_m": bmax if supervised else math.nan,
        "time_lost_s": math.nan, "simulated_s": float(res.summary["simulated_until_s"]), "wall_time_s": time.perf_counter() - t_wall,
        "error": driver.start_error or ("" if not math.isnan(driver.leader_braked_at_s) else "the leader never braked (the run ended first)"),
    }
