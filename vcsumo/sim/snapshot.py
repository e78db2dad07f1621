"""What the simulation loop hands a driver each step: every running train's state
(:class:`TrainState`, built on demand by :class:`StepTrains`) in a :class:`Snapshot`, and the
:class:`Driver` protocol a vcsumo driver implements (it never sees libsumo)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol


class TrainState(NamedTuple):
    """What the loop knows about a train after a step (SI units; passed to drivers)."""

    id: str
    time_s: float
    s_m: float
    """Front position along the train's own route, m."""
    section: str
    km: float
    speed_mps: float
    accel_mps2: float
    edge: str
    leader: str | None
    gap_m: float
    """Front-to-rear distance to the train ahead on the route, m (inf if none within look-ahead)."""


class StepTrains(dict):
    """The running trains of one step, id -> :class:`TrainState`, each state built when first asked
    for (a driver reads its convoys' trains, not every train of a network).  A dict underneath (a
    membership test or a walk over the ids costs what a dict's does); read it as a mapping."""

    __slots__ = ("_t",)

    def __init__(self, t: float, rows: dict[str, tuple]):
        super().__init__(rows)  # id -> (profile, s, speed, accel, edge, leader, gap) until built
        self._t = t

    def __getitem__(self, vid: str) -> TrainState:
        row = dict.__getitem__(self, vid)
        if type(row) is TrainState:
            return row
        prof, s, v, a, edge, lead, gap = row
        section, km = prof.km_at(s)
        ts = TrainState(vid, self._t, s, section, km, v, a, edge, lead, gap)
        dict.__setitem__(self, vid, ts)
        return ts

    def get(self, vid: str, default=None):
        return self[vid] if vid in self else default

    def values(self):
        return [self[k] for k in self]

    def items(self):
        return [(k, self[k]) for k in self]


@dataclass(frozen=True)
class Snapshot:
    time_s: float
    step_s: float
    trains: Mapping[str, TrainState]
    """Every running train of the step (read it as a mapping: the loop builds each state when asked for)."""
    junction_authority_m: dict[str, float] = field(default_factory=dict)
    """Distance from a convoy follower's front to the end of movement authority a merging junction
    ahead sets (approach locking, :meth:`vcsumo.sim.interlocking.MergeLocking.authority_distance`
    behind its predecessor), m; absent: none."""
    handover_authority_m: dict[str, float] = field(default_factory=dict)
    """Distance from a convoy follower's front to the end of movement authority the braking-curve
    supervision would give it were SUMO to drive it (the regime's rule behind the train ahead, with
    the assumption set's report period and fixed times), m: it may be handed over only within it;
    absent: no limit."""


class Driver(Protocol):
    """A vcsumo driver (VC controllers + safety filter).  It never sees libsumo."""

    def make_step(self, snapshot: Snapshot) -> dict[str, float]:
        """Speed commands (m/s) for the trains it drives this step; other trains stay with SUMO."""
        ...

    def predecessor_of(self, train_id: str) -> str | None:
        """The train a follower is coupled behind (None: not a convoy follower)."""
        ...

    def stop_releases(self) -> set[str]:
        """Trains whose stop (dwell) ends now, e.g. a follower leaving with its convoy."""
        ...
