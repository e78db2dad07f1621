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

The VC follower (:class:`JunctionVCDriver`, a subclass of the lead's ``VCDriver``)
-----------------------------------------------------------------------------------
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
"""

from __future__ import annotations

import math
import re
import shutil
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from vcsumo.errors import InputError, VcsumoError
from vcsumo.line import Branch, Line
from vcsumo.sim.network import BuiltNetwork
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.running_time import speed_at, unhindered_run
from vcsumo.sim.loop import MeasuringPoint, Scenario, Snapshot, simulate
from vcsumo.timetable import PlannedTrain
from vcsumo.dynamics import acceleration, discrete_approach_speed
from vcsumo.sim.vc_driver import VCDriver, guaranteed_decel, guard_speed

ROLES = ("branch", "main")
SIGNAL_VARIANTS = ("sumo", "braking-curve")
DEFAULT_OFFSETS_S = (0.0, 10.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0)
FORMED_RATE_MPS = 1.0
FORMED_HOLD_S = 30.0
HINDRANCE_ABS_MPS = 0.3
HINDRANCE_REL = 0.005

JUNCTION_COLUMNS = [
    "line", "junction", "junction_name", "direction", "junction_kind", "junction_throughput_trains_per_h",
    "merge_junction", "merge_km", "split_junction", "split_km",
    "leader_service", "follower_service", "regime", "controller", "junction_signal", "train",
    "leader_speed_at_junction_mps", "follower_speed_at_junction_mps",
    "formation_start_m_before_merge", "vc_control_start_m_before_merge", "formed_m_after_merge", "formation_time_s",
    "formation_distance_m", "formed_gap_m", "formed_speed_mps", "formed_lost_time_s",
    "merge_min_offset_s", "merge_headway_s", "merge_throughput_trains_per_h",
    "split_min_offset_s", "split_headway_s", "split_throughput_trains_per_h", "split_is_bottleneck",
    "first_through_junction", "order_kept", "merging_service_delay_s", "merging_service_delay_end_s", "first_service_delay_end_s",
    "min_gap_merge_m", "min_gap_split_m", "gap_violations_merge", "gap_violations_split", "gap_violations", "collisions",
    "sumo_emergency_brakes", "sumo_emergency_warnings", "red_signal_stops",
    "merge_red_max_required_decel_mps2", "merge_red_inside_braking_s", "split_red_max_required_decel_mps2", "split_red_inside_braking_s",
    "max_overspeed_mps", "vc_guard_interventions", "vc_emergency_activations", "vc_supervisor_interventions", "junction_signal_caps",
    "junction_signal_overruns", "speed_profile_caps", "simulations", "wall_time_s",
]


# -------------------------------------------------------------------------------------------
# Junctions of a line


def merge_direction(br: Branch) -> str:
    """Direction whose trains merge from this branch (the other direction diverges onto it)."""
    return "up" if br.leaves_towards == "start" else "down"


def _other(direction: str) -> str:
    return "down" if direction == "up" else "up"


def partner_junction(line: Line, br: Branch, direction: str) -> Branch | None:
    """The junction the pair meets on the other side of ``br`` in ``direction``.

    Merge direction of ``br``: the nearest junction downstream where a branch diverges from
    ``direction`` (the split).  Split direction: the nearest junction upstream where a branch merges
    into ``direction`` (where the pair merged).  None when there is none.
    """
    sign = 1.0 if direction == "up" else -1.0
    merging = merge_direction(br) == direction
    cands = []
    for b in line.data.branches:
        if b.id == br.id or abs(b.junction_km - br.junction_km) < 1e-6:
            continue
        ahead = sign * (b.junction_km - br.junction_km) > 0
        if merging and ahead and merge_direction(b) != direction:
            cands.append((sign * (b.junction_km - br.junction_km), b))
        if not merging and not ahead and merge_direction(b) == direction:
            cands.append((sign * (br.junction_km - b.junction_km), b))
    return min(cands, key=lambda x: x[0])[1] if cands else None


def default_junctions(line: Line) -> list[str]:
    """The first branch (file order) that has a partner junction, else the first branch."""
    brs = line.data.branches
    if not brs:
        return []
    for b in brs:
        if partner_junction(line, b, merge_direction(b)) is not None:
            return [b.id]
    return [brs[0].id]


def resolve_junctions(line: Line, spec: list[str] | str | None) -> list[str]:
    """Branch ids to study ('all', a list, or None for the default); errors name the file and field."""
    if not line.data.branches:
        raise InputError(line.path, "branches", "the line has no branches: the junction study needs at least one junction (a branch's junction_km)")
    ids = [b.id for b in line.data.branches]
    if spec is None or spec == [] or spec == "":
        return default_junctions(line)
    items = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec) if s.strip()]
    if items == ["all"]:
        return ids
    for s in items:
        sid = s.removeprefix("branch:")
        if sid not in ids:
            raise InputError(line.path, "branches", f"unknown junction '{s}' (--junction takes a branch id: {', '.join(ids)}, or 'all')")
    return [s.removeprefix("branch:") for s in items]


# -------------------------------------------------------------------------------------------
# Geometry of one (junction, direction)


@dataclass
class Setup:
    """Routes, release states and junction positions of the two services in one direction."""

    line: Line
    net: BuiltNetwork
    stock: RollingStock
    junction: Branch
    direction: str
    merge: Branch | None
    split: Branch | None
    edges: dict[str, list[str]]
    profiles: dict[str, RouteProfile]
    start_s: dict[str, float]
    start_v: dict[str, float]
    s_merge: dict[str, float]
    """Route position of the merge junction node per role (absent without a merge)."""
    s_split: dict[str, float]
    merge_node: str | None
    split_node: str | None
    points: dict[str, dict[str, float]]
    """label -> role -> route position of the measuring point."""
    approach_m: float
    post_m: float
    window_m: float = 5000.0

    @property
    def key(self) -> str:
        return "merge" if self.merge is not None else "split"

    def s_key(self, role: str) -> float:
        return self.s_merge[role] if self.merge is not None else self.s_split[role]

    @property
    def key_node(self) -> str:
        return self.merge_node if self.merge is not None else self.split_node  # type: ignore[return-value]


def _node_index(topo, edges: list[str], node: str, side: str) -> int:
    for i, e in enumerate(edges):
        if (topo.edges[e].from_node if side == "from" else topo.edges[e].to_node) == node:
            return i
    raise VcsumoError(f"junction node {node} is not on the main track")  # pragma: no cover - topology guarantees it


def build_setup(line: Line, net: BuiltNetwork, stock: RollingStock, junction: str, direction: str, approach_m: float = 12000.0, post_m: float = 20000.0,
                post_split_m: float = 10000.0) -> Setup:
    topo = net.topology
    br = line.branch(junction)
    if direction == merge_direction(br):
        merge, split = br, partner_junction(line, br, direction)
    else:
        split, merge = br, partner_junction(line, br, direction)
    main = topo.track_for("main", direction)
    full = RouteProfile.from_edges(topo, main.edges)
    L = stock.length_m
    p = stock.params()
    merge_node = topo.edges[topo.track_for(merge.id, direction).edges[-1]].to_node if merge else None
    split_node = topo.edges[topo.track_for(split.id, direction).edges[0]].from_node if split else None
    i_m = _node_index(topo, main.edges, merge_node, "from") if merge else None
    j_s = _node_index(topo, main.edges, split_node, "to") if split else None
    s_m_full = float(full.starts_m[i_m]) if merge else None
    s_s_full = float(full.starts_m[j_s] + full.lengths_m[j_s]) if split else None
    s_first = s_m_full if merge else s_s_full
    s_last = s_s_full if split else s_m_full
    # main service: release approach_m before the first junction, route to the end of the window
    start_min = min(L + 1.0, full.length_m)
    s_rel = max(start_min, s_first - approach_m)
    if s_rel <= start_min + 1.0:
        s_rel, v_rel = start_min, 0.0
    else:
        run0 = unhindered_run(p, full, dt=0.5, s0=start_min, end_s=s_rel + 1.0, stop_at_end=False)
        v_rel = speed_at(run0, s_rel)
        if math.isnan(v_rel):  # pragma: no cover
            raise VcsumoError(f"train {stock.name} cannot reach the release point on main_{direction}")
    s_end = min(full.length_m, s_last + (post_split_m if split else post_m))
    i_rel = full.index_at(s_rel)
    i_end = full.index_at(max(s_end - 1.0, s_rel))
    if merge is not None and i_m > i_end:  # pragma: no cover
        i_end = i_m
    main_edges = main.edges[i_rel : i_end + 1]
    off_main = float(full.starts_m[i_rel])
    edges: dict[str, list[str]] = {"main": main_edges}
    start_s = {"main": s_rel - off_main}
    start_v = {"main": v_rel}
    # branch service
    if merge is not None:
        b_edges = list(topo.track_for(merge.id, direction).edges)
        trunk_to = (j_s + 1) if split else (i_end + 1)
        x_edges = b_edges + main.edges[i_m:trunk_to]
        v_entry = min(topo.edges[b_edges[0]].speed_ms, p.max_speed_ms)
        x_start = min(L + 1.0, topo.edges[b_edges[0]].length_m)
        start_v["branch"] = v_entry
        start_s["branch"] = x_start
    else:
        x_edges = main.edges[i_rel : j_s + 1]
        start_v["branch"] = v_rel
        start_s["branch"] = start_s["main"]
    if split is not None:
        x_edges = x_edges + list(topo.track_for(split.id, direction).edges)
    edges["branch"] = x_edges
    for role in ROLES:
        es = edges[role]
        for a, b in zip(es, es[1:]):
            if b not in topo.successors.get(a, []):  # pragma: no cover - construction guarantees it
                raise VcsumoError(f"route of the {role} service is broken at {a} -> {b}")
    profiles = {r: RouteProfile.from_edges(topo, edges[r]) for r in ROLES}
    s_merge, s_split = {}, {}
    for r in ROLES:
        pr, es = profiles[r], edges[r]
        if merge is not None:
            k = _node_index(topo, es, merge_node, "from")
            s_merge[r] = float(pr.starts_m[k])
        if split is not None:
            k = _node_index(topo, es, split_node, "to")
            s_split[r] = float(pr.starts_m[k] + pr.lengths_m[k])
    # measuring points
    points: dict[str, dict[str, float]] = {}
    if merge is not None:
        points["M"] = dict(s_merge)
        span = (s_split["main"] - s_merge["main"]) / 2.0 if split is not None else max(0.0, profiles["main"].length_m - s_merge["main"] - 1000.0)
        d_pm = min(10000.0, span)
        points["PM"] = {r: s_merge[r] + d_pm for r in ROLES}
    if split is not None:
        points["S"] = dict(s_split)
    points["END"] = {r: profiles[r].length_m - 100.0 for r in ROLES}
    return Setup(line, net, stock, br, direction, merge, split, edges, profiles, start_s, start_v, s_merge, s_split, merge_node, split_node, points,
                 approach_m, post_m)


# -------------------------------------------------------------------------------------------
# Simulation runs


@dataclass(frozen=True)
class Case:
    junction: str
    direction: str
    first: str
    regime: str
    controller: str | None = None
    variant: str | None = None

    @property
    def label(self) -> str:
        if self.regime != "vc":
            return self.regime
        return f"vc {self.controller}" + ("" if self.variant == "sumo" else f" {self.variant}")

    @property
    def slug(self) -> str:
        s = f"{self.junction}_{self.direction}_{self.first}-first_{self.regime}"
        if self.regime == "vc":
            s += f"_{self.controller}_{self.variant}"
        return re.sub(r"[^A-Za-z0-9_.+-]", "-", s)


@dataclass
class RunResult:
    offset_s: float
    departures: dict[str, float]
    """Scheduled release per role, s."""
    passages: dict[str, dict[str, float]]
    """label -> role -> passage time, s."""
    summary: dict
    trains: pd.DataFrame
    traces: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    """role -> (time s, route position m, speed m/s) at every step."""
    violations: pd.DataFrame
    signals: pd.DataFrame
    log_counts: dict[str, int]
    vc: dict = field(default_factory=dict)
    driver_counts: dict = field(default_factory=dict)
    trajectories: pd.DataFrame | None = None
    folder: Path | None = None


def _junction_net(net: BuiltNetwork, nodes: list[str], folder: Path, order: tuple[str, str, str] | None = None) -> BuiltNetwork:
    """The network with an additional file that also records the junction signals' switches and,
    with ``order`` = (signal, first train, second train), makes the signal serve them in that order
    (SUMO rail-signal predecessor constraint)."""
    folder.mkdir(parents=True, exist_ok=True)
    txt = net.stations_file.read_text().rstrip()
    if not txt.endswith("</additional>"):  # pragma: no cover - written by network.py
        return net
    ev = "".join(f'    <timedEvent type="SaveTLSSwitchStates" source="{n}" dest="../junction_signal_{n}.xml"/>\n' for n in nodes)
    if order is not None:
        sig, first, second = order
        ev += (f'    <railSignalConstraints id="{sig}">\n'
               f'        <predecessor tripId="{second}" tl="{sig}" foes="{first}" limit="1"/>\n'
               f'    </railSignalConstraints>\n')
    path = folder / "stations_junction.add.xml"
    path.write_text(txt[: -len("</additional>")] + ev + "</additional>\n")
    return replace(net, stations_file=path)


def _signal_links(net: BuiltNetwork, nodes: list[str]) -> dict[tuple[str, str, str], int]:
    """(signal node, incoming edge, outgoing edge) -> link index of the rail signal."""
    out: dict[tuple[str, str, str], int] = {}
    want = set(nodes)
    for _, el in ET.iterparse(net.net_file, events=("end",)):
        if el.tag == "connection" and el.get("tl") in want:
            out[(el.get("tl"), el.get("from"), el.get("to"))] = int(el.get("linkIndex"))
        if el.tag != "edge":
            el.clear()
    return out


def _link_of(setup: Setup, role: str, node: str, links) -> tuple[int | None, str | None]:
    """(link index, incoming edge) of a train's route through a signal node."""
    es = setup.edges[role]
    k = next((i for i, e in enumerate(es) if setup.net.topology.edges[e].to_node == node), None)
    if k is None or k + 1 >= len(es):
        return None, None
    return links.get((node, es[k], es[k + 1])), es[k]


def _read_signals(folder: Path, nodes: list[str]) -> pd.DataFrame:
    rows = []
    for n in nodes:
        f = folder / f"junction_signal_{n}.xml"
        if not f.is_file():
            continue
        try:
            for el in ET.parse(f).getroot().iter("tlsState"):
                rows.append((float(el.get("time")), n, el.get("state")))
        except ET.ParseError:  # pragma: no cover
            continue
    return pd.DataFrame(rows, columns=["time_s", "signal", "state"])


_EMERG_RE = re.compile(r"performs emergency braking")
_STOP_RE = re.compile(r"performs emergency stop")
_AGG_RE = re.compile(r"(\d+) total messages of type: (.*)")


def _log_counts(folder: Path) -> dict[str, int]:
    """SUMO's warnings of emergency braking (deceleration above the train's emergency rate) and of
    emergency stops (a red signal passed at speed: the train is stopped at the signal within a step)."""
    f = folder / "sumo_errors.log"
    counts = {"emergency_warnings": 0, "red_signal_stops": 0}
    if not f.is_file():
        return counts
    for ln in f.read_text(errors="replace").splitlines():
        m = _AGG_RE.search(ln)
        if m:  # --aggregate-warnings: the total of a type replaces the lines beyond the limit (the reason becomes '%')
            n = int(m.group(1))
            if _EMERG_RE.search(m.group(2)):
                counts["emergency_warnings"] = max(counts["emergency_warnings"], n)
            elif _STOP_RE.search(m.group(2)):
                counts["red_signal_stops"] = max(counts["red_signal_stops"], n)
            continue
        if _EMERG_RE.search(ln):
            counts["emergency_warnings"] += 1
        elif _STOP_RE.search(ln):
            counts["red_signal_stops"] += 1
    return counts


class JunctionVCDriver(VCDriver):
    """The lead's :class:`~vcsumo.sim.vc_driver.VCDriver` with a train-to-train link handshake and, optionally,
    a braking curve for the merge junction's signal (see the module doc).

    ``merge_stops``: follower id -> (route position of the junction signal in the follower's frame,
    route position of the junction in its predecessor's frame).
    """

    def __init__(self, convoys, controller: str, step_s: float, seed: int, channel, guard, merge_stops: dict[str, tuple[float, float]] | None = None,
                 link_warmup: bool = True, speed_profile: bool = True):
        super().__init__(convoys, controller, step_s, seed, channel, guard=guard)
        self.linked: set[str] = set()
        self.link_warmup = link_warmup
        self.speed_profile = speed_profile
        self.speed_profile_caps = 0
        self._targets = {fid: f.plan.profile.restriction_targets() for fid, f in self.followers.items()}
        self.merge_stops = merge_stops or {}
        self.signal_caps = 0
        self.signal_overruns = 0
        self.first_command: dict[str, tuple[float, float]] = {}
        orig = self.channel.deliver

        def deliver(receiver: str, t: float):
            got = orig(receiver, t)
            f = self.followers.get(receiver)
            if f is not None and f.pred.id in got:
                self.linked.add(receiver)
            return got

        self.channel.deliver = deliver  # type: ignore[method-assign]

    def make_step(self, snap: Snapshot) -> dict[str, float]:
        if self.link_warmup:
            hide = [fid for fid in self.followers if fid in snap.trains and fid not in self.linked]
            if hide:  # SUMO drives it until the first message of its predecessor has arrived
                snap = Snapshot(snap.time_s, snap.step_s, {k: v for k, v in snap.trains.items() if k not in hide})
        cmds = super().make_step(snap)
        for fid, v_cmd in list(cmds.items()):
            st = snap.trains[fid]
            self.first_command.setdefault(fid, (snap.time_s, st.s_m))
            f = self.followers[fid]
            p = f.plan.stock.params()
            prof = f.plan.profile
            v = st.speed_mps
            # the train cannot brake harder than its emergency brake (as in VCDriver)
            grad = prof.mean_gradient(st.s_m, p.length_m)
            tf = prof.tunnel_factor_at(st.s_m)
            v_floor = max(0.0, v + self.step_s * float(acceleration(p, v, -p.mass_kg * p.emergency_brake_decel_mps2, grad, tf)))
            v_new = v_cmd
            if self.speed_profile:  # lower limits ahead (turnouts, restrictions): SUMO's own braking curve
                b = f.plan.stock.service_brake_decel_mps2
                reach = v * v / (2 * b) + 2 * v * self.step_s + 10.0
                for ps, pv in self._targets[fid]:
                    if ps <= st.s_m:
                        continue
                    if ps - st.s_m > reach:
                        break
                    v_new = min(v_new, discrete_approach_speed(ps - st.s_m, pv, b, self.step_s))
                if v_new < v_cmd - 1e-9:
                    self.speed_profile_caps += 1
            ms = self.merge_stops.get(fid)
            if ms is not None:
                s_stop_f, s_junction_pred = ms
                pst = snap.trains.get(f.pred.id)
                if pst is not None and pst.s_m < s_junction_pred and st.s_m < s_stop_f:
                    # the junction signal may be red for the follower until its predecessor's front passes
                    dec = p.emergency_brake_decel_mps2 if self.guard.follower_decel == "emergency" else p.service_brake_decel_mps2
                    g_low, _ = prof.gradient_range(st.s_m - p.length_m, s_stop_f + 10.0)
                    b_f = guaranteed_decel(p, v, dec, g_low)
                    v_cap = guard_speed(st.s_m, b_f, self.step_s, s_stop_f - 2.0, 0.0, 0.0, 1.0, 0.0)
                    if v_cap < v_new - 1e-9:
                        self.signal_caps += 1
                        if v_cap < v_floor - 1e-6:
                            self.signal_overruns += 1
                        v_new = v_cap
            if v_new < v_cmd - 1e-9:
                cmds[fid] = max(v_new, v_floor)
        return cmds


def _trains_for(setup: Setup, first: str, offset_s: float, solo_times: dict[str, float]) -> tuple[list[PlannedTrain], dict[str, float]]:
    """Leader first; release times so that, alone, the follower reaches the merge ``offset_s`` after
    the leader (without a merge: the follower is released ``offset_s`` after the leader at the same point)."""
    follower = "main" if first == "branch" else "branch"
    if setup.merge is None:  # both start at the same point of the main line: Δ is the release interval
        dep = {first: 0.0, follower: offset_s}
    else:
        dep = {first: 0.0, follower: solo_times[first] + offset_s - solo_times[follower]}
    base = min(dep.values())
    dep = {r: d - base for r, d in dep.items()}
    trains = []
    for role in (first, follower):
        trains.append(PlannedTrain(
            id=role, service=f"{role}_service", stock=setup.stock, edges=setup.edges[role], profile=setup.profiles[role], depart_s=round(dep[role], 3),
            depart_pos_m=setup.start_s[role], depart_speed_mps=setup.start_v[role], direction=setup.direction, end_pos_m=None,
            start_s_m=setup.start_s[role], stop_at_end=False,
        ))
    return trains, {t.id: t.depart_s for t in trains}


def _measuring_points(setup: Setup) -> list[MeasuringPoint]:
    out = []
    for lab, per in setup.points.items():
        for role, s in per.items():
            sec, km = setup.profiles[role].km_at(s)
            out.append(MeasuringPoint(f"{lab}:{role}", sec, km))
    return out


def simulate_pair(setup: Setup, case: Case, offset_s: float, solo_times: dict[str, float] | None, out: Path, dt: float, seed: int = 42,
                  full: bool = False, roles: tuple[str, ...] = ROLES, link_warmup: bool = True, ordered: bool = True,
                  speed_profile: bool = True) -> RunResult:
    """One SUMO run of the pair (or of one train alone: ``roles`` of one element, offset ignored)."""
    if len(roles) == 1:
        r = roles[0]
        trains = [PlannedTrain(id=r, service=f"{r}_service", stock=setup.stock, edges=setup.edges[r], profile=setup.profiles[r], depart_s=0.0,
                               depart_pos_m=setup.start_s[r], depart_speed_mps=setup.start_v[r], direction=setup.direction, end_pos_m=None,
                               start_s_m=setup.start_s[r], stop_at_end=False)]
        deps = {r: 0.0}
    else:
        trains, deps = _trains_for(setup, case.first, offset_s, solo_times or {})
    nodes = [n for n in (setup.merge_node, setup.split_node) if n]
    order = (setup.merge_node, trains[0].id, trains[1].id) if (ordered and len(trains) == 2 and setup.merge_node) else None
    net = _junction_net(setup.net, nodes, out / "_additional", order)
    driver = None
    if case.regime == "vc" and len(trains) == 2:
        from vcsumo.sim.vc_driver import load_channel, load_guard

        leader, follower = trains
        stops = None
        if case.variant == "braking-curve" and setup.merge is not None:
            stops = {follower.id: (setup.s_merge[follower.id], setup.s_merge[leader.id])}
        driver = JunctionVCDriver([[leader, follower]], case.controller, dt, seed, load_channel(None), load_guard(None), stops, link_warmup, speed_profile)
    mps = _measuring_points(setup)
    regime = case.regime if len(trains) == 2 else ("mb" if case.regime == "vc" else case.regime)
    scn = Scenario(setup.line, net, trains, regime, step_length_s=dt, measuring_points=mps, record_period_s=1.0 if full else 3600.0,
                   full_outputs=full, trace_speeds=True, driver=driver, seed=seed)
    res = simulate(scn, out)
    passages: dict[str, dict[str, float]] = {}
    for _, row in res.passages.iterrows():
        lab, role = str(row.measuring_point).split(":")
        if role == row.train:
            passages.setdefault(lab, {})[role] = float(row.time_s)
    traces = {}
    dep_actual = dict(zip(res.trains.train, res.trains.departure_s))
    for tid, (ss, vv) in res.speed_traces.items():
        t0 = dep_actual.get(tid, deps[tid])
        traces[tid] = (t0 + dt * np.arange(len(ss)), np.asarray(ss), np.asarray(vv))
    viol = pd.read_csv(out / "violations.csv") if (out / "violations.csv").is_file() else pd.DataFrame()
    rr = RunResult(offset_s, deps, passages, res.summary, res.trains, traces, viol, _read_signals(out, nodes), _log_counts(out),
                   trajectories=res.trajectories if full else None, folder=out)
    if driver is not None:
        rr.vc = driver.summary()
        rr.driver_counts = {"signal_caps": driver.signal_caps, "signal_overruns": driver.signal_overruns, "first_command": dict(driver.first_command),
                            "speed_profile_caps": driver.speed_profile_caps}
        if full:
            driver.write_report(out)
    return rr


# -------------------------------------------------------------------------------------------
# Analysis of one run


def lost_time(run: RunResult, solo: dict[str, RunResult], label: str, role: str) -> float:
    t = run.passages.get(label, {}).get(role)
    t0 = solo[role].passages.get(label, {}).get(role)
    if t is None or t0 is None:
        return math.inf
    return (t - run.departures[role]) - (t0 - solo[role].departures[role])


def _time_at(trace: tuple[np.ndarray, np.ndarray, np.ndarray], s: float) -> float:
    t, ss, _ = trace
    if len(ss) == 0 or s < ss[0] or s > ss[-1]:
        return math.nan
    i = int(np.searchsorted(ss, s, side="left"))
    if i == 0:
        return float(t[0])
    s0, s1 = ss[i - 1], ss[i]
    return float(t[i - 1] + (t[i] - t[i - 1]) * (s - s0) / (s1 - s0)) if s1 > s0 else float(t[i])


def virtual_gap(setup: Setup, run: RunResult, leader: str, follower: str, at: str = "key") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time, follower distance to the junction, virtual gap) on the follower's steps."""
    tl, sl, _ = run.traces.get(leader, (np.array([]),) * 3)
    tf, sf, _ = run.traces.get(follower, (np.array([]),) * 3)
    if len(tl) < 2 or len(tf) == 0:
        return np.array([]), np.array([]), np.array([])
    sk = setup.s_merge if (at == "merge" or (at == "key" and setup.merge is not None)) else setup.s_split
    sel = (tf >= tl[0]) & (tf <= tl[-1])
    xl = np.interp(tf[sel], tl, sl) - sk[leader]
    xf = sf[sel] - sk[follower]
    return tf[sel], xf, xl - setup.stock.length_m - xf


def _window_count(viol: pd.DataFrame, run: RunResult, setup: Setup, s_j: dict[str, float], w: float) -> int:
    if viol is None or viol.empty:
        return 0
    n = 0
    for _, v in viol.iterrows():
        tr = run.traces.get(v.train)
        if tr is None:
            continue
        s = float(np.interp(v.time_s, tr[0], tr[1]))
        if abs(s - s_j[v.train]) <= w:
            n += 1
    return n


def signal_exposure(setup: Setup, run: RunResult, follower: str, node: str | None, s_node: dict[str, float], links: dict[tuple[str, str], int]) -> tuple[float, float]:
    """(max deceleration needed to stop at the junction signal while it is red for the follower,
    time red inside its service braking distance) — nan, 0 without data."""
    if node is None or run.signals.empty or follower not in run.traces:
        return math.nan, 0.0
    li, _ = _link_of(setup, follower, node, links)
    sig = run.signals[run.signals.signal == node].sort_values("time_s")
    if li is None or sig.empty:
        return math.nan, 0.0
    times = sig.time_s.to_numpy()
    red = np.array([(s[li] if li < len(s) else "G") in "rs" for s in sig.state])
    t, s, v = run.traces[follower]
    idx = np.searchsorted(times, t, side="right") - 1
    is_red = np.where(idx >= 0, red[np.clip(idx, 0, len(red) - 1)], False)
    d = s_node[follower] - s
    mask = is_red & (d > 0.0)
    if not mask.any():
        return 0.0, 0.0
    b = setup.stock.service_brake_decel_mps2
    req = v[mask] ** 2 / (2.0 * np.maximum(d[mask], 0.5))
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    inside = float(((v[mask] ** 2 / (2 * b)) >= d[mask]).sum() * dt)
    return float(req.max()), inside


def _lost_along(run: RunResult, solo: RunResult, role: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time, route position, lost time) of a train along its route against its solo run."""
    t, ss, _ = run.traces[role]
    t0, s0, _ = solo.traces[role]
    keep = np.concatenate([[True], np.diff(s0) > 1e-6])
    t_solo = np.interp(ss, s0[keep], t0[keep], left=np.nan, right=np.nan)
    return t, ss, (t - run.departures[role]) - (t_solo - solo.departures[role])


def formation(setup: Setup, run: RunResult, solo: dict[str, RunResult], leader: str, follower: str) -> dict:
    """Formation start/end around the merge junction in one run (module doc)."""
    out = {"formation_start_m_before_merge": math.nan, "formed_m_after_merge": math.nan, "formation_time_s": math.nan,
           "formation_distance_m": math.nan, "formed_gap_m": math.nan, "formed_speed_mps": math.nan, "formed_lost_time_s": math.nan}
    if setup.merge is None or follower not in run.traces or leader not in run.traces:
        return out
    tf, sf, vf = run.traces[follower]
    _, ss0, vs0 = solo[follower].traces[follower]
    vref = np.interp(sf, ss0, vs0)
    excess = (vref - vf) - np.maximum(HINDRANCE_ABS_MPS, HINDRANCE_REL * vref)
    bad = np.nonzero(excess > 0)[0]
    if not len(bad):
        return out
    i_start = int(bad[0])
    out["formation_start_m_before_merge"] = round(float(setup.s_merge[follower] - sf[i_start]), 1)
    # formed: from where on the lost time stays within max(1 s, 5 %) of its value at the end of the trunk
    t, s, lost = _lost_along(run, solo[follower], follower)
    s_final = (setup.s_split[follower] - setup.window_m) if setup.split is not None else setup.points["END"][follower]
    s_final = max(s_final, setup.s_merge[follower] + 1000.0)
    ok = np.isfinite(lost) & (s <= s_final)
    if not ok.any():
        return out
    l_final = float(np.interp(s_final, s[ok], lost[ok]))
    tol = max(1.0, 0.05 * abs(l_final))
    idx = np.nonzero(ok)[0]
    after = idx[idx >= i_start]
    if not len(after):
        return out
    dev = np.abs(lost[after] - l_final) > tol
    if not dev.any():
        i_form = int(after[0])
    else:
        last = int(np.nonzero(dev)[0][-1])
        if last + 1 >= len(after):
            return out
        i_form = int(after[last + 1])
    tg, xg, g = virtual_gap(setup, run, leader, follower, "merge")
    out["formed_m_after_merge"] = round(float(s[i_form] - setup.s_merge[follower]), 1)
    out["formed_gap_m"] = round(float(np.interp(t[i_form], tg, g)), 1) if len(tg) else math.nan
    out["formed_speed_mps"] = round(float(vf[i_form]), 2)
    out["formed_lost_time_s"] = round(l_final, 2)
    out["formation_time_s"] = round(float(t[i_form] - tf[i_start]), 1)
    out["formation_distance_m"] = round(float(s[i_form] - sf[i_start]), 1)
    return out


def _max_overspeed(setup: Setup, run: RunResult, role: str) -> float:
    """Largest excess of a train's speed over the limit under the whole train (turnouts included), m/s."""
    if role not in run.traces:
        return 0.0
    _, ss, vv = run.traces[role]
    prof, L = setup.profiles[role], setup.stock.length_m
    step = max(1, len(ss) // 4000)
    return max(0.0, max((float(v) - prof.speed_limit_train(float(x), L) for x, v in zip(ss[::step], vv[::step])), default=0.0))


def actual_order(setup: Setup, run: RunResult, leader: str) -> tuple[str, str]:
    """(first, second) train through the first junction of the scenario; the planned order if unknown."""
    follower = "main" if leader == "branch" else "branch"
    p = run.passages.get("M" if setup.merge is not None else "S", {})
    if leader in p and follower in p and p[follower] < p[leader]:
        return follower, leader
    return leader, follower


def run_metrics(setup: Setup, case: Case, run: RunResult, solo: dict[str, RunResult], links, window_m: float) -> dict:
    """Metrics of one pair run (used for the sweep table and the case row).

    ``follower_*``/``leader_*`` lost times refer to the planned order (the hindrance test);
    gaps, signal exposure and the merging service's delay to the actual order through the junction.
    """
    leader = case.first
    follower = "main" if leader == "branch" else "branch"
    m: dict = {"offset_s": run.offset_s}
    for lab in setup.points:
        m[f"follower_lost_{lab}_s"] = lost_time(run, solo, lab, follower)
        m[f"leader_lost_{lab}_s"] = lost_time(run, solo, lab, leader)
    for lab in ("M", "S"):
        p = run.passages.get(lab, {})
        m[f"headway_{lab}_s"] = (p[follower] - p[leader]) if leader in p and follower in p else math.nan
    key = "M" if setup.merge is not None else "S"
    m["order_kept"] = bool(m.get(f"headway_{key}_s", math.nan) > 0)
    first, second = actual_order(setup, run, leader)
    m["first_through_junction"] = first
    lab_d = "PM" if setup.merge is not None else "END"
    m["merging_service_delay_s"] = lost_time(run, solo, lab_d, second)
    m["merging_service_delay_end_s"] = lost_time(run, solo, "END", second)
    m["first_service_delay_end_s"] = lost_time(run, solo, "END", first)
    s = run.summary
    m.update({"gap_violations": s["gap_violations"], "collisions": s["collisions"], "sumo_emergency_brakes": s["emergency_brakes"],
              "sumo_emergency_warnings": run.log_counts["emergency_warnings"], "red_signal_stops": run.log_counts["red_signal_stops"],
              "teleports": s["teleports"], "min_gap_m": s["min_gap_m"]})
    # windows
    for kind, node, sj in (("merge", setup.merge_node, setup.s_merge), ("split", setup.split_node, setup.s_split)):
        if node is None:
            m[f"min_gap_{kind}_m"] = math.nan
            m[f"gap_violations_{kind}"] = 0
            m[f"{kind}_red_max_required_decel_mps2"] = math.nan
            m[f"{kind}_red_inside_braking_s"] = math.nan
            continue
        t, xf, g = virtual_gap(setup, run, first, second, kind)
        sel = np.abs(xf) <= window_m
        if kind == "merge" and len(t):
            tl, sl, _ = run.traces[first]
            sel &= np.interp(t, tl, sl) >= sj[first]  # both in line: the first train has entered the junction
        if kind == "split" and len(t):
            tl, sl, _ = run.traces[first]
            x_rear_l = np.interp(t, tl, sl) - sj[first] - setup.stock.length_m
            sel &= x_rear_l <= 0.0  # the leader still occupies the shared track
        m[f"min_gap_{kind}_m"] = round(float(g[sel].min()), 2) if len(t) and sel.any() else math.nan
        m[f"gap_violations_{kind}"] = _window_count(run.violations, run, setup, sj, window_m)
        req, inside = signal_exposure(setup, run, second, node, sj, links)
        m[f"{kind}_red_max_required_decel_mps2"] = round(req, 3) if not math.isnan(req) else math.nan
        m[f"{kind}_red_inside_braking_s"] = round(inside, 1)
    m["max_overspeed_mps"] = round(max((_max_overspeed(setup, run, r) for r in ROLES), default=0.0), 2)
    m["vc_guard_interventions"] = run.vc.get("guard_interventions", 0) if run.vc else 0
    m["vc_emergency_activations"] = run.vc.get("vc_emergency_activations", 0) if run.vc else 0
    m["vc_supervisor_interventions"] = run.vc.get("supervisor_interventions", 0) if run.vc else 0
    m["junction_signal_caps"] = run.driver_counts.get("signal_caps", 0)
    m["junction_signal_overruns"] = run.driver_counts.get("signal_overruns", 0)
    m["speed_profile_caps"] = run.driver_counts.get("speed_profile_caps", 0)
    return m


def unhindered(m: dict, label: str, tolerance_s: float, setup: Setup) -> bool:
    """The pair passes the merge ('merge') or the split ('split') without hindrance (module doc)."""
    if m["collisions"] or m["teleports"]:
        return False
    if label == "merge":
        if m["gap_violations_merge"]:
            return False
        return m["follower_lost_PM_s"] <= tolerance_s and m["leader_lost_PM_s"] <= tolerance_s and m["order_kept"]
    if m["gap_violations_split"]:
        return False
    base_f = m.get("follower_lost_PM_s", 0.0) if setup.merge is not None else 0.0
    base_l = m.get("leader_lost_PM_s", 0.0) if setup.merge is not None else 0.0
    if math.isinf(base_f) or math.isinf(base_l):
        return False
    return m["follower_lost_END_s"] - base_f <= tolerance_s and m["leader_lost_END_s"] - base_l <= tolerance_s and (
        setup.merge is not None or m["order_kept"])


# -------------------------------------------------------------------------------------------
# A case: sweep, bisection, analysis runs


def _relative_braking_offset(setup: Setup, dt: float) -> float:
    """Release interval a follower needs behind a leader at the common release point to keep the
    relative braking distance of the VC guard there (gradients over the braking distance ahead) + 60 m, s."""
    from vcsumo.sim.vc_driver import guaranteed_decel, strongest_decel

    stock, v = setup.stock, setup.start_v["main"]
    p = stock.params()
    if v <= 0.5:
        return 0.0
    s0 = setup.start_s["main"]
    g_low, g_high = setup.profiles["main"].gradient_range(s0 - p.length_m, s0 + v * v / (2 * stock.service_brake_decel_mps2) + 10.0)
    b_f = guaranteed_decel(p, v, stock.emergency_brake_decel_mps2, g_low)
    a_l = strongest_decel(p, v, stock.emergency_brake_decel_mps2, g_high, 1.5)
    gap = max(0.0, 1.5 * v * dt + v * v / (2 * b_f) - v * v / (2 * a_l)) + 60.0
    return (gap + stock.length_m) / v


@dataclass
class CaseOutcome:
    row: dict
    sweep: list[dict]
    runs: dict[str, RunResult]
    """'simultaneous', 'merge_min', 'split_min' analysis runs."""


def run_case(setup: Setup, case: Case, solo: dict[str, RunResult], out: Path, dt: float, offsets: list[float], tolerance_s: float, resolution_s: float,
             window_m: float, seed: int, links, link_warmup: bool = True) -> CaseOutcome:
    t_wall = time.perf_counter()
    leader = case.first
    follower = "main" if leader == "branch" else "branch"
    solo_times = {r: solo[r].passages[setup.key[0].upper()][r] - solo[r].departures[r] for r in ROLES}
    d0 = 0.0
    if setup.merge is None:  # both start at the same point: the follower must fit behind the leader
        d0 = math.ceil(_relative_braking_offset(setup, dt))
    cache: dict[float, tuple[dict, RunResult]] = {}
    count = [0]

    def probe(off: float) -> dict:
        key = round(off, 2)
        if key not in cache:
            count[0] += 1
            sub = out / "probes" / f"o{key:08.2f}"
            rr = simulate_pair(setup, case, key, solo_times, sub, dt, seed, full=False, link_warmup=link_warmup)
            m = run_metrics(setup, case, rr, solo, links, window_m)
            cache[key] = (m, rr)
        return cache[key][0]

    grid = sorted({round(d0 + o, 2) for o in offsets})
    for o in grid:
        probe(o)
    labels = ["merge"] if setup.merge is not None else []
    if setup.split is not None:
        labels.append("split")
    mins: dict[str, float] = {}
    for lab in labels:
        # extend the grid until the largest offset is unhindered
        hi_o = max(cache)
        tries = 0
        while not unhindered(cache[hi_o][0], lab, tolerance_s, setup) and tries < 4:
            hi_o = round(hi_o * 1.5 + 30.0, 2)
            probe(hi_o)
            tries += 1
        if not unhindered(cache[hi_o][0], lab, tolerance_s, setup):
            mins[lab] = math.nan
            continue
        keys = sorted(k for k in cache if k >= d0 - 1e-9)
        # smallest offset from which every probed offset above is unhindered
        hi = keys[-1]
        for k in reversed(keys):
            if unhindered(cache[k][0], lab, tolerance_s, setup):
                hi = k
            else:
                break
        lower = [k for k in keys if k < hi]
        if not lower:
            mins[lab] = hi
            continue
        lo = lower[-1]
        while hi - lo > resolution_s:
            mid = round(0.5 * (lo + hi), 2)
            if unhindered(probe(mid), lab, tolerance_s, setup):
                hi = mid
            else:
                lo = mid
        mins[lab] = hi
    # analysis runs with full outputs: simultaneous arrival and the minimum offsets
    runs: dict[str, RunResult] = {}
    analysis = {"simultaneous": grid[0]}
    for lab, v in mins.items():
        if not math.isnan(v):
            analysis[f"{lab}_min"] = v
    done: dict[float, RunResult] = {}
    for name, off in analysis.items():
        if off not in done:
            count[0] += 1
            done[off] = simulate_pair(setup, case, off, solo_times, out / f"{name}_o{off:07.2f}", dt, seed, full=True, link_warmup=link_warmup)
            (done[off].folder / "fcd.xml").unlink(missing_ok=True)  # its content is in trajectories.csv; keeps the folder small
        runs[name] = done[off]
    shutil.rmtree(out / "probes", ignore_errors=True)
    sim = runs["simultaneous"]
    m0 = run_metrics(setup, case, sim, solo, links, window_m)
    row = {
        "line": setup.line.name, "junction": setup.junction.id, "junction_name": setup.junction.junction_name or setup.junction.name,
        "direction": setup.direction, "merge_junction": setup.merge.id if setup.merge else "", "merge_km": setup.merge.junction_km if setup.merge else math.nan,
        "split_junction": setup.split.id if setup.split else "", "split_km": setup.split.junction_km if setup.split else math.nan,
        "leader_service": leader, "follower_service": follower, "regime": case.regime, "controller": case.controller or "",
        "junction_signal": case.variant or "", "train": setup.stock.name,
        "leader_speed_at_junction_mps": round(_speed_at_trace(solo[leader], leader, setup.s_key(leader)), 2),
        "follower_speed_at_junction_mps": round(_speed_at_trace(solo[follower], follower, setup.s_key(follower)), 2),
    }
    row["junction_kind"] = "merge" if (setup.merge is not None and setup.merge.id == setup.junction.id) else "split"
    first, second = actual_order(setup, sim, leader)
    row.update(formation(setup, sim, solo, first, second))
    fc = sim.driver_counts.get("first_command", {}).get(follower) if sim.driver_counts else None
    row["vc_control_start_m_before_merge"] = round(setup.s_merge[follower] - fc[1], 1) if (fc and setup.merge is not None) else math.nan
    for lab, col in (("merge", "merge"), ("split", "split")):
        v = mins.get(lab, math.nan)
        row[f"{col}_min_offset_s"] = round(v, 2) if not math.isnan(v) else math.nan
        h = math.nan
        if f"{lab}_min" in runs:
            p = runs[f"{lab}_min"].passages.get("M" if lab == "merge" else "S", {})
            if leader in p and follower in p:
                h = p[follower] - p[leader]
        row[f"{col}_headway_s"] = round(h, 2) if not math.isnan(h) else math.nan
        row[f"{col}_throughput_trains_per_h"] = round(3600.0 / h, 1) if h and not math.isnan(h) and h > 0 else math.nan
    row["junction_throughput_trains_per_h"] = row[f"{row['junction_kind']}_throughput_trains_per_h"]
    if setup.split is None:
        row["split_is_bottleneck"] = None
    elif setup.merge is None:
        row["split_is_bottleneck"] = True
    else:
        a, b = row["split_min_offset_s"], row["merge_min_offset_s"]
        row["split_is_bottleneck"] = bool(a > b + resolution_s) if not (math.isnan(a) or math.isnan(b)) else None
    row["first_through_junction"] = first
    row["merging_service_delay_s"] = _r(m0["merging_service_delay_s"])
    row["merging_service_delay_end_s"] = _r(m0["merging_service_delay_end_s"])
    row["first_service_delay_end_s"] = _r(m0["first_service_delay_end_s"])
    row["order_kept"] = m0["order_kept"]
    for k in ("min_gap_merge_m", "min_gap_split_m", "gap_violations_merge", "gap_violations_split", "gap_violations", "collisions", "sumo_emergency_brakes",
              "sumo_emergency_warnings", "red_signal_stops", "merge_red_max_required_decel_mps2", "merge_red_inside_braking_s",
              "split_red_max_required_decel_mps2", "split_red_inside_braking_s", "vc_guard_interventions", "vc_emergency_activations",
              "vc_supervisor_interventions", "junction_signal_caps", "junction_signal_overruns", "speed_profile_caps", "max_overspeed_mps"):
        row[k] = m0.get(k)
    row["simulations"] = count[0]
    row["wall_time_s"] = round(time.perf_counter() - t_wall, 1)
    sweep = []
    for off in sorted(cache):
        m, _ = cache[off]
        r = {"line": setup.line.name, "junction": setup.junction.id, "direction": setup.direction, "leader_service": leader, "regime": case.regime,
             "controller": case.controller or "", "junction_signal": case.variant or ""}
        r.update({k: (_r(v) if isinstance(v, float) else v) for k, v in m.items()})
        r["unhindered_merge"] = unhindered(m, "merge", tolerance_s, setup) if setup.merge is not None else None
        r["unhindered_split"] = unhindered(m, "split", tolerance_s, setup) if setup.split is not None else None
        sweep.append(r)
    return CaseOutcome(row, sweep, runs)


def _r(x, nd: int = 2):
    if x is None:
        return math.nan
    if isinstance(x, float) and (math.isinf(x) or math.isnan(x)):
        return x
    return round(float(x), nd)


def _speed_at_trace(run: RunResult, role: str, s: float) -> float:
    tr = run.traces.get(role)
    if tr is None or len(tr[1]) == 0:
        return math.nan
    return float(np.interp(s, tr[1], tr[2]))


def _solo_runs(setup: Setup, regime: str, dt: float, out: Path, seed: int) -> dict[str, RunResult]:
    solo = {}
    for r in ROLES:
        rr = simulate_pair(setup, Case(setup.junction.id, setup.direction, r, regime), 0.0, None, out / f"solo_{r}", dt, seed, full=True, roles=(r,))
        (out / f"solo_{r}" / "fcd.xml").unlink(missing_ok=True)
        if rr.passages.get("END", {}).get(r) is None:
            raise VcsumoError(f"the {r} service did not reach the end of its route running alone ({setup.direction}, {regime}); see {out / f'solo_{r}'}")
        solo[r] = rr
    return solo


# -------------------------------------------------------------------------------------------
# Tables for the plots


def trajectory_rows(setup: Setup, case: Case, run_name: str, run: RunResult) -> pd.DataFrame:
    """1 s samples of a run: per train distances to the junctions, speed, virtual and sensed gap."""
    tr = run.trajectories
    if tr is None or tr.empty:
        return pd.DataFrame()
    leader = case.first
    follower = "main" if leader == "branch" else "branch"
    df = tr[["time_s", "train", "s_m", "speed_mps", "gap_m", "leader"]].copy()
    df["role"] = np.where(df.train == leader, "leader", "follower") if run_name != "solo" else "alone"
    df["service"] = df.train
    df["distance_to_merge_m"] = df.apply(lambda r: r.s_m - setup.s_merge[r.train], axis=1) if setup.merge is not None else math.nan
    df["distance_to_split_m"] = df.apply(lambda r: r.s_m - setup.s_split[r.train], axis=1) if setup.split is not None else math.nan
    df["virtual_gap_m"] = math.nan
    if run_name != "solo" and leader in run.traces and follower in run.traces:
        t, _, g = virtual_gap(setup, run, leader, follower)
        if len(t) and setup.split is not None:
            # after the split the two trains are on different tracks: no gap
            tl, sl, _ = run.traces[leader]
            tf, sf, _ = run.traces[follower]
            parted = ((np.interp(t, tl, sl) - setup.stock.length_m) > setup.s_split[leader]) | (np.interp(t, tf, sf) > setup.s_split[follower])
            g = np.where(parted, np.nan, g)
        fsel = df.train == follower
        if len(t):
            df.loc[fsel, "virtual_gap_m"] = np.interp(df.loc[fsel, "time_s"], t, g, left=np.nan, right=np.nan)
    df = df.rename(columns={"gap_m": "sensed_gap_m", "leader": "sensed_leader", "s_m": "route_position_m"})
    df.insert(0, "run", run_name)
    df.insert(0, "offset_s", run.offset_s if run_name != "solo" else math.nan)
    for k, v in (("split_junction", setup.split.id if setup.split else ""), ("merge_junction", setup.merge.id if setup.merge else ""),
                 ("junction_signal", case.variant or ""), ("controller", case.controller or ""), ("regime", case.regime), ("leader_service", case.first),
                 ("direction", setup.direction), ("junction", setup.junction.id), ("line", setup.line.name)):
        df.insert(0, k, v)
    return df.round(3)


def signal_rows(setup: Setup, case: Case, run_name: str, run: RunResult, links) -> pd.DataFrame:
    if run.signals.empty:
        return pd.DataFrame()
    leader = case.first
    rows = []
    for _, s in run.signals.iterrows():
        for role in ROLES:
            li, e_in = _link_of(setup, role, s.signal, links)
            if li is None or li >= len(s.state):
                continue
            rows.append({"line": setup.line.name, "junction": setup.junction.id, "direction": setup.direction, "leader_service": leader,
                         "regime": case.regime, "controller": case.controller or "", "junction_signal": case.variant or "", "run": run_name,
                         "offset_s": run.offset_s, "time_s": s.time_s, "signal": s.signal,
                         "junction_kind": "merge" if s.signal == setup.merge_node else "split", "service": role,
                         "role": "leader" if role == leader else "follower", "incoming_edge": e_in, "aspect": "red" if s.state[li] in "rs" else "green"})
    return pd.DataFrame(rows)


# -------------------------------------------------------------------------------------------
# The study


def cases_for(junctions: list[str], line: Line, directions: tuple[str, ...], firsts: tuple[str, ...], controllers: list[str], variants: tuple[str, ...]) -> list[Case]:
    out = []
    for j in junctions:
        for d in directions:
            for f in firsts:
                out.append(Case(j, d, f, "fbs"))
                out.append(Case(j, d, f, "mb"))
                for c in controllers:
                    for v in variants:
                        out.append(Case(j, d, f, "vc", c, v))
    return out


def run_junction_study(
    line: Line, net: BuiltNetwork, stock: RollingStock, out: Path, controllers: list[str] | None = None, junctions: list[str] | str | None = None,
    directions: tuple[str, ...] = ("up", "down"), firsts: tuple[str, ...] = ("main", "branch"), variants: tuple[str, ...] = ("braking-curve",),
    offsets_s: tuple[float, ...] = DEFAULT_OFFSETS_S, tolerance_s: float = 2.0, resolution_s: float = 1.0, window_m: float = 5000.0,
    approach_m: float = 12000.0, post_m: float = 20000.0, step_s: float = 0.5, vc_step_s: float = 0.2, seed: int = 42,
    link_warmup: bool = True, progress: Callable[[int, int, str], None] | None = None,
) -> pd.DataFrame:
    """Every junction × direction × leader service × regime (× VC controller × variant).

    Writes ``junction.csv``, ``junction_sweep.csv``, ``junction_trajectories.csv``,
    ``junction_signals.csv``, ``junction_<regime>.png`` and ``junction_sweep.png`` into ``out``.
    """
    from vcsumo.sim.vc_driver import parse_controller

    controllers = ["cbc", "cbf-cbc"] if controllers is None else list(controllers)
    for c in controllers:
        parse_controller(c)
    for d in directions:
        if d not in ("up", "down"):
            raise InputError(None, "--directions", f"unknown direction '{d}' (choose up, down)")
    for f in firsts:
        if f not in ROLES:
            raise InputError(None, "--first", f"unknown service '{f}' (choose main, branch)")
    for v in variants:
        if v not in SIGNAL_VARIANTS:
            raise InputError(None, "--junction-signal", f"unknown variant '{v}' (choose {', '.join(SIGNAL_VARIANTS)})")
    if not offsets_s or any(o < 0 for o in offsets_s):
        raise InputError(None, "--offsets", "offsets must be a non-empty list of times ≥ 0 s")
    if tolerance_s <= 0 or resolution_s <= 0 or window_m <= 0 or approach_m <= 0 or post_m <= 0:
        raise InputError(None, "--tolerance-s/--resolution-s/--window-m/--approach-m/--post-m", "must be positive")
    jids = resolve_junctions(line, junctions)
    if line.data.tracks == "single":
        raise InputError(line.path, "tracks", "the junction study needs a double-track line (merging and splitting trains run in one direction)")
    out.mkdir(parents=True, exist_ok=True)
    cases = cases_for(jids, line, directions, firsts, controllers, variants)
    setups: dict[tuple[str, str], Setup] = {}
    solos: dict[tuple[str, str, str, float], dict[str, RunResult]] = {}
    nodes_all: list[str] = []
    rows, sweep, traj, sigs = [], [], [], []
    links_cache: dict[tuple[str, str], dict] = {}
    for k, case in enumerate(cases):
        if progress:
            progress(k, len(cases), f"{case.junction} {case.direction} {case.first}-first {case.label}")
        skey = (case.junction, case.direction)
        if skey not in setups:
            setups[skey] = build_setup(line, net, stock, case.junction, case.direction, approach_m, post_m)
            setups[skey].window_m = window_m
            nodes = [n for n in (setups[skey].merge_node, setups[skey].split_node) if n]
            nodes_all += nodes
            links_cache[skey] = _signal_links(net, nodes)
        setup = setups[skey]
        links = links_cache[skey]
        dt = vc_step_s if case.regime == "vc" else step_s
        solo_regime = "mb" if case.regime == "vc" else case.regime
        okey = (case.junction, case.direction, solo_regime, dt)
        base = out / "runs" / f"{case.junction}_{case.direction}"
        if okey not in solos:
            solos[okey] = _solo_runs(setup, solo_regime, dt, base / f"solo_{solo_regime}_dt{dt:g}", seed)
            for r, rr in solos[okey].items():
                c_solo = Case(case.junction, case.direction, r, solo_regime)
                t = trajectory_rows(setup, c_solo, "solo", rr)
                if not t.empty:
                    t["step_s"] = dt
                    traj.append(t)
        solo = solos[okey]
        res = run_case(setup, case, solo, base / case.slug, dt, list(offsets_s), tolerance_s, resolution_s, window_m, seed, links, link_warmup)
        rows.append(res.row)
        sweep += res.sweep
        for name, rr in res.runs.items():
            t = trajectory_rows(setup, case, name, rr)
            if not t.empty:
                t["step_s"] = dt
                traj.append(t)
            s = signal_rows(setup, case, name, rr, links)
            if not s.empty:
                sigs.append(s)
    if progress:
        progress(len(cases), len(cases), "plots")
    df = pd.DataFrame(rows, columns=JUNCTION_COLUMNS)
    df.to_csv(out / "junction.csv", index=False)
    pd.DataFrame(sweep).to_csv(out / "junction_sweep.csv", index=False)
    tdf = pd.concat(traj, ignore_index=True) if traj else pd.DataFrame()
    tdf.to_csv(out / "junction_trajectories.csv", index=False)
    (pd.concat(sigs, ignore_index=True) if sigs else pd.DataFrame()).to_csv(out / "junction_signals.csv", index=False)
    from vcsumo.plots.junction import plot_junction_regimes, plot_junction_sweep

    plot_junction_regimes(out / "junction_trajectories.csv", out)
    plot_junction_sweep(out / "junction_sweep.csv", out / "junction_sweep.png")
    return df
