"""The junction study's set-up and runs: which trains, their routes, the merge/split geometry, the
release times, and one SUMO run of the pair (or of one train alone).

Names (module doc of :mod:`vcsumo.studies.junction`): the *branch* and the *main* service; the
*leader* passes the first junction first, the *follower* merges in behind it.  Positions are
route positions of train fronts, m; times s.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from vcsumo.errors import InputError, VcsumoError
from vcsumo.line import Branch, Line
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.running_time import speed_at, unhindered_run
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.separation import SeparationModel
from vcsumo.sim.junction_policy import JunctionPolicy
from vcsumo.sim.loop import MeasuringPoint, Scenario, simulate
from vcsumo.sim.network import BuiltNetwork
from vcsumo.sim.sumo_io import SignalRecording, SumoLogCounts, rail_signal_links, read_signal_switches, read_sumo_log, write_additional
from vcsumo.control.guard import load_guard
from vcsumo.sim.vc_driver import VCDriver, load_channel
from vcsumo.timetable import PlannedTrain

ROLES = ("branch", "main")
SIGNAL_VARIANTS = ("sumo", "braking-curve")


# -------------------------------------------------------------------------------------------
# Junctions of a line


def merge_direction(br: Branch) -> str:
    """Direction whose trains merge from this branch (the other direction diverges onto it)."""
    return "up" if br.leaves_towards == "start" else "down"


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


def resolve_junctions(line: Line, spec: list[str] | str | None, path: str | Path | None = None, field: str = "--junction") -> list[str]:
    """Branch ids to study ('all', a list, or None for the default). A line without branches is the line
    file's error; an unknown id is the request's: named by ``path`` (the study file) and ``field``."""
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
            raise InputError(path, field, f"unknown junction '{s}' (the branches of {line.path}: {', '.join(ids)}, or 'all')")
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
    assumptions: AssumptionSet | None = None
    """The separation model's set the pair runs are supervised and judged with (None: the shipped default)."""

    @property
    def model(self) -> SeparationModel:
        """The separation model under :attr:`assumptions`."""
        return SeparationModel(self.assumptions or load_assumptions())

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
                post_split_m: float = 10000.0, assumptions: AssumptionSet | None = None) -> Setup:
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
                 approach_m, post_m, assumptions=assumptions or load_assumptions())


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
    """Junction signal switches: time_s, signal, state (:func:`~vcsumo.sim.sumo_io.read_signal_switches`)."""
    log: SumoLogCounts
    """SUMO's warnings and errors of the run."""
    vc: dict = field(default_factory=dict)
    driver_counts: dict = field(default_factory=dict)
    """The junction policy's counters (:meth:`~vcsumo.sim.junction_policy.JunctionPolicy.counts`)."""
    trajectories: pd.DataFrame | None = None
    folder: Path | None = None


def signal_nodes(setup: Setup) -> list[str]:
    """The scenario's junction signal nodes (merge first)."""
    return [n for n in (setup.merge_node, setup.split_node) if n]


def signal_links(setup: Setup) -> dict[tuple[str, str, str], int]:
    """(signal node, incoming edge, outgoing edge) -> link index of the scenario's junction signals."""
    return rail_signal_links(setup.net.net_file, signal_nodes(setup))


def link_of(setup: Setup, role: str, node: str, links) -> tuple[int | None, str | None]:
    """(link index, incoming edge) of a train's route through a signal node."""
    es = setup.edges[role]
    k = next((i for i, e in enumerate(es) if setup.net.topology.edges[e].to_node == node), None)
    if k is None or k + 1 >= len(es):
        return None, None
    return links.get((node, es[k], es[k + 1])), es[k]


def signal_output(out: Path, node: str) -> Path:
    """Where a run records the switches of a junction signal."""
    return out / f"junction_signal_{node}.xml"


def trains_for(setup: Setup, first: str, offset_s: float, solo_times: dict[str, float]) -> tuple[list[PlannedTrain], dict[str, float]]:
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


def measuring_points(setup: Setup) -> list[MeasuringPoint]:
    """The loop's measuring points: one per label and role (``M:branch``, ``END:main``, ...), at the role's route position."""
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
        trains, deps = trains_for(setup, case.first, offset_s, solo_times or {})
    nodes = signal_nodes(setup)
    additional = write_additional(out / "network" / "junction.add.xml", [SignalRecording(n, signal_output(out, n)) for n in nodes])
    # the interlocking serves the merge in the planned order (the loop's approach locking, sim/interlocking.py)
    orders = {setup.merge_node: [t.id for t in trains]} if ordered and len(trains) == 2 and setup.merge_node else {}
    assumptions = setup.assumptions or load_assumptions()
    driver = policy = None
    if case.regime == "vc" and len(trains) == 2:
        policy = JunctionPolicy([trains], dt, SeparationModel(assumptions), link_handshake=link_warmup, speed_profile=speed_profile,
                                merge_authority=case.variant == "braking-curve")
        driver = VCDriver([trains], case.controller, dt, seed, load_channel(None), guard=load_guard(None), assumptions=assumptions, junction=policy)
    mps = measuring_points(setup)
    regime = case.regime if len(trains) == 2 else ("mb" if case.regime == "vc" else case.regime)
    scn = Scenario(setup.line, setup.net, trains, regime, step_length_s=dt, measuring_points=mps, record_period_s=1.0 if full else 3600.0,
                   full_outputs=full, trace_speeds=True, driver=driver, seed=seed, additional_files=[additional], assumptions=assumptions,
                   merge_orders=orders)
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
    rr = RunResult(offset_s, deps, passages, res.summary, res.trains, traces, viol, read_signal_switches([signal_output(out, n) for n in nodes]),
                   read_sumo_log(out / "sumo_errors.log"), trajectories=res.trajectories if full else None, folder=out)
    if driver is not None:
        rr.vc = driver.summary()
        rr.driver_counts = policy.counts()
        if full:
            driver.write_report(out)
    return rr


def solo_runs(setup: Setup, regime: str, dt: float, out: Path, seed: int) -> dict[str, RunResult]:
    """Each service running alone (same regime and step): the reference of lost times."""
    solo = {}
    for r in ROLES:
        rr = simulate_pair(setup, Case(setup.junction.id, setup.direction, r, regime), 0.0, None, out / f"solo_{r}", dt, seed, full=True, roles=(r,))
        (out / f"solo_{r}" / "fcd.xml").unlink(missing_ok=True)
        if rr.passages.get("END", {}).get(r) is None:
            raise VcsumoError(f"the {r} service did not reach the end of its route running alone ({setup.direction}, {regime}); see {out / f'solo_{r}'}")
        solo[r] = rr
    return solo


