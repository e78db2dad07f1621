"""Junction behaviour of virtually coupled followers: the VC driver's ``junction`` option.

A convoy that forms at a junction needs three things the plain VC driver does not do.  Each is one
switch of :class:`JunctionPolicy`:

* ``link_handshake`` — a follower joins its convoy only once the first train-to-train message of
  its predecessor has arrived; until then SUMO drives it (under the loop's braking-curve
  supervision).  A follower that joins its predecessor's track at a merge (its route does not start
  on the predecessor's) also waits until that message puts the predecessor virtually ahead of it by
  at least the spacing its stack keeps (``spacing(follower, v)``: the controller's coupled gap, at
  least its minimum safe gap — with a CBF its safety distance d): approaching on another track it
  is in no conflict with its predecessor but at the junction, where the end of authority protects
  it, so it is not braked to open a virtual gap it does not need yet (coupled at once, a follower
  virtually 10 m behind a faster predecessor is braked to a standstill by the guard, and a cbf-cbc
  one held until the gap reaches d).  Without the handshake the driver couples a follower as soon
  as its predecessor is in the simulation, holding the predecessor's state of that first step as if
  a message had come.
* ``speed_profile`` — the follower's command is capped by its braking curve to every lower speed
  limit ahead (turnouts and speed restrictions).  The controllers only see the limit under the
  train, so a follower diverging at a split would otherwise enter the turnout at line speed.
* ``merge_authority`` — the end of movement authority at a merging junction: while the loop's
  approach locking (:class:`vcsumo.sim.interlocking.MergeLocking`) gives another train priority
  there, the follower's authority ends at the junction (less the margin and the position errors),
  and behind its own convoy predecessor until that train's front has passed it — the time SUMO's
  junction signal is red for the follower.  The loop hands the distance to each follower in the
  :class:`~vcsumo.sim.loop.Snapshot` (``junction_authority_m``); the policy caps the command by the
  braking curve to it.  Steps at which the follower could not stop before it even with its
  guaranteed emergency brake are counted (``signal_overruns``).

The braking curves are those of the separation model and the loop's supervision of the trains SUMO
drives (:class:`vcsumo.signalling.separation.RouteBraking`: the follower's guaranteed service
brake on the route's gradients): to an end of authority after the set's
dead time + 1.5 steps, to a lower limit after 1.5 steps (an operational target, as in
:mod:`vcsumo.sim.supervision`).  A cap never asks for more than the emergency brake: the command is
bounded below by the speed the train reaches after one step of emergency braking (eq. 1b, as in the
VC driver).

How the driver uses it (``VCDriver(..., junction=policy)``; one call before and one after its step)::

    shown = policy.visible(snap)                                  # the link handshake
    commands = ...the driver's step on shown...
    commands = policy.limit(snap, commands, channel.latest, spacing)   # links seen, braking curves

``channel.latest(receiver)`` (:meth:`vcsumo.control.channel.Channel.latest`) returns what the
channel has delivered to a follower so far; ``limit`` runs after the driver's deliveries of the
step, so a follower whose first message arrives at step k is driven from step k + 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

from vcsumo.control.base import Message
from vcsumo.dynamics import TrainParams, acceleration
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.sim.loop import Snapshot
from vcsumo.timetable import PlannedTrain


@dataclass
class _Member:
    plan: PlannedTrain
    predecessor: str
    params: TrainParams
    targets: list[tuple[float, float]]
    braking: RouteBraking
    """Guaranteed service braking (the braking curves, as the supervision's)."""
    emergency: RouteBraking
    """Guaranteed emergency braking (can it still stop before its end of authority?)."""
    joins_at_merge: bool
    """Its route does not start on its predecessor's: it joins it at a merge."""
    cannot_stop: bool = False


@dataclass
class JunctionPolicy:
    """The VC driver's junction option for convoys that merge and split at junctions (module doc)."""

    convoys: list[list[PlannedTrain]]
    """The driver's convoys, leader first (every other member follows the one before it)."""
    step_s: float
    """The driver's step, s."""
    model: SeparationModel
    """The separation model (its assumption set) of the run."""
    link_handshake: bool = True
    speed_profile: bool = True
    merge_authority: bool = True
    linked: set[str] = field(default_factory=set)
    """Followers whose predecessor's first message has arrived."""
    speed_profile_caps: int = 0
    """Steps at which the braking curve to a lower limit ahead lowered a command."""
    signal_caps: int = 0
    """Steps at which the braking curve to the end of authority at a merge lowered a command."""
    signal_overruns: int = 0
    """Steps at which a follower could not stop before its end of authority at a merge even with its
    guaranteed emergency brake."""
    signal_overrun_episodes: int = 0
    """Times that began."""
    first_command: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Follower id -> (time s, route position m) of the first step the driver commanded it."""

    def __post_init__(self) -> None:
        self._members: dict[str, _Member] = {}
        for members in self.convoys:
            for k in range(1, len(members)):
                ego = members[k]
                self._members[ego.id] = _Member(ego, members[k - 1].id, ego.stock.params(), ego.profile.restriction_targets(),
                                                RouteBraking(self.model, ego.stock, ego.profile),
                                                RouteBraking(self.model, ego.stock, ego.profile, "emergency"), ego.edges[0] not in members[k - 1].edges)

    def visible(self, snap: Snapshot) -> Snapshot:
        """The snapshot the driver may act on: without the followers not linked yet (link handshake)."""
        if not self.link_handshake:
            return snap
        hide = [fid for fid in self._members if fid in snap.trains and fid not in self.linked]
        if not hide:
            return snap
        return Snapshot(snap.time_s, snap.step_s, {k: v for k, v in snap.trains.items() if k not in hide}, snap.junction_authority_m,
                        snap.handover_authority_m)

    def limit(self, snap: Snapshot, commands: dict[str, float], delivered: Callable[[str], Mapping[str, Message]],
              spacing: Callable[[str, float], float] | None = None) -> dict[str, float]:
        """Record the links the channel has made (``delivered(follower)``: sender -> latest message;
        ``spacing(follower, v)``: the spacing its stack keeps at speed v, m) and cap the driver's speed
        commands (m/s) by the braking curves; returns the commands.  ``snap`` is the whole snapshot
        (not the :meth:`visible` one: a follower not linked yet is judged on its own state)."""
        for fid, m in self._members.items():
            if fid in self.linked:
                continue
            msg = delivered(fid).get(m.predecessor)
            if msg is None:
                continue
            st = snap.trains.get(fid)
            if m.joins_at_merge and spacing is not None:
                if st is None or msg.state.position_m - msg.length_m - st.s_m < spacing(fid, st.speed_mps):
                    continue
            self.linked.add(fid)
        out = dict(commands)
        dt = self.step_s
        dead = self.model.dead_time_s + 1.5 * dt
        for fid, v_cmd in commands.items():
            m = self._members.get(fid)
            st = snap.trains.get(fid)
            if m is None or st is None:
                continue
            self.first_command.setdefault(fid, (snap.time_s, st.s_m))
            p, prof, s, v = m.params, m.plan.profile, st.s_m, st.speed_mps
            v_new = v_cmd
            if self.speed_profile:
                reach = 1.3 * m.braking.stopping_distance(s, v, 2.0 * dt) + 50.0
                for ps, pv in m.targets:
                    if ps <= s:
                        continue
                    if ps - s > reach:
                        break
                    v_new = min(v_new, m.braking.permitted_speed(s, ps, pv, 1.5 * dt, v))
                if v_new < v_cmd - 1e-9:
                    self.speed_profile_caps += 1
            d_ma = snap.junction_authority_m.get(fid, math.inf) if self.merge_authority else math.inf
            cannot = False
            if math.isfinite(d_ma):
                v_cap = m.braking.permitted_speed(s, s + d_ma, 0.0, dead, v) if d_ma > 0.0 else 0.0
                cannot = d_ma < m.emergency.stopping_distance(s, v, self.model.dead_time_s)
                if v_cap < v_new - 1e-9:
                    self.signal_caps += 1
                    v_new = v_cap
            if cannot:
                self.signal_overruns += 1
                self.signal_overrun_episodes += int(not m.cannot_stop)
            m.cannot_stop = cannot
            if v_new < v_cmd - 1e-9:
                grad = prof.mean_gradient(s, p.length_m)
                v_floor = max(0.0, v + dt * float(acceleration(p, v, -p.mass_kg * p.emergency_brake_decel_mps2, grad, prof.tunnel_factor_at(s))))
                out[fid] = max(v_new, v_floor)
        return out

    def counts(self) -> dict:
        """The policy's counters (``first_command``: follower -> (time s, route position m))."""
        return {"signal_caps": self.signal_caps, "signal_overruns": self.signal_overruns, "signal_overrun_episodes": self.signal_overrun_episodes,
                "first_command": dict(self.first_command), "speed_profile_caps": self.speed_profile_caps}
