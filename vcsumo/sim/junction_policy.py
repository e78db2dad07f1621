"""Junction behaviour of virtually coupled followers: options applied around the VC driver's step.

A convoy that forms at a junction needs three things the plain VC driver does not do.  Each is one
option of :class:`JunctionPolicy`:

* ``link_handshake`` — a follower joins its convoy only once the first train-to-train message of
  its predecessor has arrived; until then SUMO drives it.  Without it the driver couples a follower
  as soon as its predecessor is in the simulation, and with no message yet its guard assumes the
  predecessor stands at the follower's own front and commands an emergency brake (a leader inserted
  on the other approach of a merge triggers it).
* ``speed_profile`` — the follower's command is capped by the braking curve at its service
  deceleration (as SUMO's own driver brakes) to every lower speed limit ahead: turnouts and speed
  restrictions.  The controllers only see the limit under the train, so a follower diverging at a
  split would otherwise enter the turnout at line speed.
* ``merge_signals`` — the braking curve to the merge signal: while its predecessor's front has not
  passed the merge junction (the time SUMO's moving-block junction signal may be red for the
  follower; SUMO turns it green when the predecessor's front passes), the follower must be able to
  stop at the junction signal with the deceleration the VC guard relies on (``signal_decel``).
  Steps at which even the emergency brake could not keep that curve are counted
  (``signal_overruns``).

A cap never asks for more than the emergency brake: the command is bounded below by the speed the
train reaches after one step of emergency braking (eq. 1b, as in the VC driver).

How the driver uses it (one call before and one after its own step)::

    snap = policy.visible(snap)                                   # the link handshake
    commands = ...the driver's step on snap...
    commands = policy.limit(snap, commands, channel.latest)       # links seen, speed caps

``channel.latest(receiver)`` (:meth:`vcsumo.control.channel.Channel.latest`) returns what the
channel has delivered to a follower so far; ``limit`` must run after the driver's deliveries of the
step, so a follower whose first message arrives at step k is driven from step k + 1.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

from vcsumo.dynamics import acceleration, discrete_approach_speed
from vcsumo.sim.loop import Snapshot
from vcsumo.control.guard import guaranteed_decel, guard_speed
from vcsumo.timetable import PlannedTrain

SIGNAL_MARGIN_M = 2.0
"""The braking curve to a merge signal ends this far before the signal, m."""


@dataclass(frozen=True)
class MergeSignal:
    """A merge junction's signal as one follower meets it."""

    stop_s_m: float
    """Route position of the junction signal in the follower's frame, m."""
    predecessor_passed_s_m: float
    """Route position of the junction in its predecessor's frame: once the predecessor's front is
    beyond it the signal can be green for the follower, m."""


@dataclass
class _Member:
    plan: PlannedTrain
    predecessor: str
    params: object
    targets: list[tuple[float, float]]


@dataclass
class JunctionPolicy:
    """Options of the VC driver for convoys that merge and split at junctions (module doc)."""

    convoys: list[list[PlannedTrain]]
    """The driver's convoys, leader first (every other member follows the one before it)."""
    step_s: float
    """The driver's step, s."""
    link_handshake: bool = True
    speed_profile: bool = True
    merge_signals: dict[str, MergeSignal] = field(default_factory=dict)
    """Follower id -> the merge signal it must be able to stop at (none: no braking curve to a signal)."""
    signal_decel: str = "emergency"
    """Deceleration of the braking curve to a merge signal: the follower's ``emergency`` or
    ``service`` brake."""
    linked: set[str] = field(default_factory=set)
    """Followers whose predecessor's first message has arrived."""
    speed_profile_caps: int = 0
    """Steps at which the braking curve to a lower limit ahead lowered a command."""
    signal_caps: int = 0
    """Steps at which the braking curve to the merge signal lowered a command."""
    signal_overruns: int = 0
    """Steps at which even the emergency brake could not keep the braking curve to the merge signal."""
    first_command: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Follower id -> (time s, route position m) of the first step the driver commanded it."""

    def __post_init__(self) -> None:
        if self.signal_decel not in ("emergency", "service"):
            raise ValueError(f"signal_decel must be 'emergency' or 'service', not {self.signal_decel!r}")
        self._members: dict[str, _Member] = {}
        for members in self.convoys:
            for k in range(1, len(members)):
                ego = members[k]
                self._members[ego.id] = _Member(ego, members[k - 1].id, ego.stock.params(), ego.profile.restriction_targets())

    def visible(self, snap: Snapshot) -> Snapshot:
        """The snapshot the driver may act on: without the followers not linked yet (link handshake)."""
        if not self.link_handshake:
            return snap
        hide = [fid for fid in self._members if fid in snap.trains and fid not in self.linked]
        if not hide:
            return snap
        return Snapshot(snap.time_s, snap.step_s, {k: v for k, v in snap.trains.items() if k not in hide})

    def limit(self, snap: Snapshot, commands: dict[str, float], delivered: Callable[[str], Mapping[str, object]]) -> dict[str, float]:
        """Record the links the channel has made (``delivered(follower)``: sender -> latest message)
        and cap the driver's speed commands (m/s) by the braking curves; returns the commands."""
        for fid, m in self._members.items():
            if fid not in self.linked and m.predecessor in delivered(fid):
                self.linked.add(fid)
        out = dict(commands)
        for fid, v_cmd in commands.items():
            m = self._members.get(fid)
            st = snap.trains.get(fid)
            if m is None or st is None:
                continue
            self.first_command.setdefault(fid, (snap.time_s, st.s_m))
            p, prof, v = m.params, m.plan.profile, st.speed_mps
            grad = prof.mean_gradient(st.s_m, p.length_m)
            tf = prof.tunnel_factor_at(st.s_m)
            v_floor = max(0.0, v + self.step_s * float(acceleration(p, v, -p.mass_kg * p.emergency_brake_decel_mps2, grad, tf)))
            v_new = v_cmd
            if self.speed_profile:
                b = m.plan.stock.service_brake_decel_mps2
                reach = v * v / (2 * b) + 2 * v * self.step_s + 10.0
                for ps, pv in m.targets:
                    if ps <= st.s_m:
                        continue
                    if ps - st.s_m > reach:
                        break
                    v_new = min(v_new, discrete_approach_speed(ps - st.s_m, pv, b, self.step_s))
                if v_new < v_cmd - 1e-9:
                    self.speed_profile_caps += 1
            ms = self.merge_signals.get(fid)
            pst = snap.trains.get(m.predecessor)
            if ms is not None and pst is not None and pst.s_m < ms.predecessor_passed_s_m and st.s_m < ms.stop_s_m:
                dec = p.emergency_brake_decel_mps2 if self.signal_decel == "emergency" else p.service_brake_decel_mps2
                g_low, _ = prof.gradient_range(st.s_m - p.length_m, ms.stop_s_m + 10.0)
                v_cap = guard_speed(st.s_m, guaranteed_decel(p, v, dec, g_low), self.step_s, ms.stop_s_m - SIGNAL_MARGIN_M, 0.0, 0.0, 1.0, 0.0)
                if v_cap < v_new - 1e-9:
                    self.signal_caps += 1
                    if v_cap < v_floor - 1e-6:
                        self.signal_overruns += 1
                    v_new = v_cap
            if v_new < v_cmd - 1e-9:
                out[fid] = max(v_new, v_floor)
        return out

    def counts(self) -> dict:
        """The policy's counters (``first_command``: follower -> (time s, route position m))."""
        return {"signal_caps": self.signal_caps, "signal_overruns": self.signal_overruns, "first_command": dict(self.first_command),
                "speed_profile_caps": self.speed_profile_caps}
