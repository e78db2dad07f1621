"""Track topology: the line turned into directed tracks, nodes, edges, signals and platforms.

The graph itself (:class:`Topology`, nodes, edges, tracks, platforms) is :mod:`vcsumo.track_graph`;
this module builds it from a line (:func:`build_topology`) and re-exports it.

This is the single source of geometry for both the SUMO network (:mod:`vcsumo.sim.network`) and
vcsumo's own route profiles (:mod:`vcsumo.route_profile`), so kilometres, speeds, gradients and
tunnels are identical in the plant and in the model.

Layout
------
* Double track: one track per direction (``main_up`` runs towards increasing km, ``main_down``
  towards decreasing km), each a chain of nodes and edges.  Single track: one chain of nodes with
  a pair of opposite edges (``bidi``) between each pair.
* A branch has tracks ``<id>_up`` and ``<id>_down``: the track used by trains travelling in the
  main line's ``up`` (``down``) direction.  Junctions are grade-separated (the up and down tracks
  have their own junction nodes), as Bivio Emilia is (inside the Pianoro tunnel).
* Nodes are placed at every change of speed, gradient, curve or tunnel, at platform ends, at
  junctions and at block signals.  Signal nodes become SUMO ``rail_signal`` junctions: block
  markers every ``block_length_m`` (or at ``signals_km``), the exit of every platform and every
  junction.
* Curve resistance is folded into the SUMO elevation as an equivalent gradient per direction of
  travel (600/R ‰·g/10, see :func:`vcsumo.dynamics.curve_equivalent_gradient`), because SUMO's Rail
  model knows gradients but not curves; on single track the two directions share nodes, so there
  curves are left out of the SUMO plant (a warning says so).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

from vcsumo.dynamics import curve_equivalent_gradient
from vcsumo.errors import InputError
from vcsumo.line import Branch, Line, Station
from vcsumo.track_graph import EPS_KM, Platform, TopoEdge, TopoNode, Topology, Track, converge_onto_single_track, reachable
from vcsumo.units import kmh_to_ms

TRACK_SPACING_M = 8.0
BRANCH_ANGLE_RAD = math.radians(8.0)

# -------------------------------------------------------------------------------------------
# Building


@dataclass
class _Section:
    """One chainage range (main line or branch) with its profile lists."""

    id: str
    c0: float
    c1: float
    line_speed_ms: float
    speed_limits: list
    gradients: list
    curves: list
    tunnels: list
    stations: list[Station]
    block_length_m: float | None
    signals_km: list[float] | None
    single: bool
    min_block_m: float
    origin_km: float | None = None  # regular markers counted from here (None: c0)

    def speed_at(self, c: float) -> float:
        for r in self.speed_limits:
            if r.from_km - EPS_KM <= c <= r.to_km + EPS_KM:
                return kmh_to_ms(r.speed_kmh)
        return self.line_speed_ms

    def gradient_at(self, c: float) -> float:
        for r in self.gradients:
            if r.from_km - EPS_KM <= c <= r.to_km + EPS_KM:
                return r.permille / 1000.0
        return 0.0

    def radius_at(self, c: float) -> float:
        for r in self.curves:
            if r.from_km - EPS_KM <= c <= r.to_km + EPS_KM:
                return r.radius_m
        return math.inf

    def tunnel_at(self, c: float):
        for t in self.tunnels:
            if t.from_km - EPS_KM <= c <= t.to_km + EPS_KM:
                return t
        return None


def _round_km(c: float) -> float:
    return round(c, 6)


def _signal_positions(sec: _Section, mandatory: set[float]) -> set[float]:
    """Block markers (regular or explicit) minus those too close to mandatory signals or in platforms."""
    if sec.signals_km:
        markers = [c for c in sec.signals_km if sec.c0 < c < sec.c1]
    elif sec.block_length_m:
        step = sec.block_length_m / 1000.0
        o = sec.c0 if sec.origin_km is None else sec.origin_km
        n = int(math.floor((sec.c1 - o) / step + 1e-9))
        markers = [o + i * step for i in range(1, n + 1) if sec.c0 < o + i * step < sec.c1 - 1e-9]
    else:
        markers = []
    keep = set()
    dropped = []
    min_km = sec.min_block_m / 1000.0
    for c in markers:
        st = next((x for x in sec.stations if x.km - x.platform_length_m / 2000.0 - 1e-9 <= c <= x.km + x.platform_length_m / 2000.0 + 1e-9), None)
        if st is not None:
            dropped.append(f"{c:g} km in the platform of {st.id}")
            continue
        if any(abs(c - m) < min_km for m in mandatory):
            dropped.append(f"{c:g} km within {sec.min_block_m:g} m of a station or junction signal")
            continue
        keep.add(_round_km(c))
    if sec.signals_km and dropped:  # (regular markers falling there are expected to go; the user's own are said)
        warnings.warn(f"section '{sec.id}': signalling.signals_km: {len(dropped)} of the signals given are not built ({'; '.join(dropped)})", stacklevel=2)
    return keep


def _breakpoints(sec: _Section, extra: set[float], keep: frozenset[float] = frozenset()) -> list[float]:
    """Sorted edge breakpoints of a section; points closer than 1 m merge, but points in ``keep``
    (junctions, which must be nodes) win over the point they merge with."""
    pts = {sec.c0, sec.c1}
    for lst in (sec.speed_limits, sec.gradients, sec.curves, sec.tunnels):
        for r in lst:
            pts.add(r.from_km)
            pts.add(r.to_km)
    for st in sec.stations:
        pts.add(st.km - st.platform_length_m / 2000.0)
        pts.add(st.km + st.platform_length_m / 2000.0)
    pts |= extra
    pts = sorted({_round_km(p) for p in pts if sec.c0 - EPS_KM <= p <= sec.c1 + EPS_KM})
    # merge points closer than 1 m (keep the first)
    out: list[float] = []
    for p in pts:
        if out and p - out[-1] < 0.001:
            if p in keep and out[-1] not in keep and len(out) > 1:
                out[-1] = p
            continue
        out.append(p)
    if out[-1] != _round_km(sec.c1):
        out[-1] = _round_km(sec.c1)
    return out


def _elevations(sec: _Section, pts: list[float], z0: float) -> list[float]:
    z = [z0]
    for a, b in zip(pts, pts[1:]):
        z.append(z[-1] + sec.gradient_at(0.5 * (a + b)) * (b - a) * 1000.0)
    return z


def _curve_integral(sec: _Section, pts: list[float]) -> list[float]:
    acc = [0.0]
    for a, b in zip(pts, pts[1:]):
        acc.append(acc[-1] + curve_equivalent_gradient(sec.radius_at(0.5 * (a + b))) * (b - a) * 1000.0)
    return acc


def build_topology(line: Line, block_length_m: float | None = None, junctions_km: frozenset[float] = frozenset()) -> Topology:
    """Turn a line into its track topology.  ``block_length_m`` overrides the line's block length;
    ``junctions_km`` are main-line points where another line of a network joins (a node and a
    signal on every main track, as at a branch's junction)."""
    d = line.data
    sig = d.signalling
    blk = block_length_m if block_length_m is not None else sig.block_length_m
    sig_km = None if block_length_m is not None else sig.signals_km
    topo = Topology(line=line, block_length_m=blk)
    single_main = d.tracks == "single"

    main = _Section(
        id="main", c0=d.km_start, c1=d.km_end, line_speed_ms=kmh_to_ms(d.line_speed_kmh), speed_limits=list(d.speed_limits),
        gradients=list(d.gradients), curves=list(d.curves), tunnels=list(d.tunnels), stations=list(d.stations),
        block_length_m=blk, signals_km=sig_km, single=single_main, min_block_m=sig.min_block_length_m,
        origin_km=sig.block_origin_km if block_length_m is None else None,
    )
    junction_kms = {_round_km(b.junction_km) for b in d.branches} | {_round_km(k) for k in junctions_km}
    mandatory_up = {_round_km(st.km + st.platform_length_m / 2000.0) for st in d.stations} | junction_kms
    mandatory_down = {_round_km(st.km - st.platform_length_m / 2000.0) for st in d.stations} | junction_kms
    markers = _signal_positions(main, mandatory_up | mandatory_down)
    pts = _breakpoints(main, markers | junction_kms, frozenset(junction_kms | mandatory_up | mandatory_down))
    zgeo = _elevations(main, pts, d.start_elevation_m)
    cint = _curve_integral(main, pts)
    if single_main and d.curves:
        warnings.warn(f"{line.path}: curves on single track are not in the SUMO plant (only in vcsumo's model)", stacklevel=2)

    def xy_main(c: float, direction: str) -> tuple[float, float]:
        x = (c - d.km_start) * 1000.0
        y = 0.0 if (single_main or direction == "up") else TRACK_SPACING_M
        return x, y

    # --- main line tracks
    junction_nodes: dict[tuple[float, str], str] = {}
    if single_main:
        node_ids = []
        for i, c in enumerate(pts):
            nid = f"main_n{i}"
            x, y = xy_main(c, "up")
            is_sig = _round_km(c) in (markers | mandatory_up | mandatory_down) and 0 < i < len(pts) - 1
            topo.nodes[nid] = TopoNode(nid, x, y, zgeo[i], is_sig, "main", c)
            node_ids.append(nid)
            if _round_km(c) in junction_kms:
                junction_nodes[(_round_km(c), "up")] = nid
                junction_nodes[(_round_km(c), "down")] = nid
        _add_track(topo, main, "up", pts, node_ids, increasing=True, bidi=True)
        _add_track(topo, main, "down", pts[::-1], node_ids[::-1], increasing=False, bidi=True)
    else:
        for direction, increasing in (("up", True), ("down", False)):
            mand = mandatory_up if increasing else mandatory_down
            node_ids = []
            for i, c in enumerate(pts):
                nid = f"main_{direction}_n{i}"
                x, y = xy_main(c, direction)
                zeq = zgeo[i] + (cint[i] if increasing else -cint[i])
                is_sig = _round_km(c) in (markers | mand) and 0 < i < len(pts) - 1
                topo.nodes[nid] = TopoNode(nid, x, y, zeq, is_sig, "main", c)
                node_ids.append(nid)
                if _round_km(c) in junction_kms:
                    junction_nodes[(_round_km(c), direction)] = nid
            order = range(len(pts)) if increasing else range(len(pts) - 1, -1, -1)
            _add_track(topo, main, direction, [pts[i] for i in order], [node_ids[i] for i in order], increasing=increasing, bidi=False)

    # --- branches
    for br in d.branches:
        _add_branch(topo, line, br, junction_nodes, blk if br.block_length_m is None else br.block_length_m, sig.min_block_length_m)

    if single_main:  # a double-track branch of a single-track line: its tracks converge one signal before the junction
        converge_onto_single_track(topo, {junction_nodes[(_round_km(b.junction_km), "up")] for b in d.branches
                                          if (b.tracks or d.tracks) == "double"})

    # --- successors (no reversing onto the bidi twin)
    out_of: dict[str, list[str]] = {}
    for e in topo.edges.values():
        out_of.setdefault(e.from_node, []).append(e.id)
    for e in topo.edges.values():
        topo.successors[e.id] = [n for n in out_of.get(e.to_node, []) if n != e.bidi and not _reverses(line, e, topo.edges[n])]
    # turnout speeds: every main<->branch transition
    for e in topo.edges.values():
        for n in topo.successors[e.id]:
            ne = topo.edges[n]
            if ne.section != e.section:
                br = line.branch(ne.section if ne.section != "main" else e.section)
                topo.turnout_speed_ms[(e.id, n)] = kmh_to_ms(br.diverging_speed_kmh)

    # --- open ends and kilometrage
    topo.km_origin["main"] = d.km_start
    ends = [("start", "main", "up"), ("end", "main", "down")]
    ends += [(f"branch:{br.id}", br.id, "up" if br.leaves_towards == "start" else "down") for br in d.branches]
    for name, sec, inward in ends:
        first, last = topo.tracks.get(f"{sec}_{inward}"), topo.tracks.get(f"{sec}_{'down' if inward == 'up' else 'up'}")
        if first and first.edges and last and last.edges:  # (a section shorter than 1 m has no edges)
            topo.endpoints[name] = ([first.edges[0]], [last.edges[-1]])

    # --- platforms
    for sec_id, stations in [("main", d.stations)] + [(b.id, b.stations) for b in d.branches]:
        for st in stations:
            for direction in ("up", "down"):
                tr = topo.tracks.get(f"{sec_id}_{direction}")
                if tr is None:
                    continue
                half = st.platform_length_m / 2000.0
                if tr.increasing:
                    stop_km = st.km + half
                else:
                    stop_km = st.km - half
                eid = None
                for cand in tr.edges:
                    e = topo.edges[cand]
                    if abs(e.km_to - stop_km) < 1e-5:
                        eid = cand
                        break
                if eid is None:  # pragma: no cover - breakpoints guarantee a node at each platform end
                    raise InputError(line.path, f"stations.{st.id}", "platform end is not on a node")
                e = topo.edges[eid]
                pid = f"{st.id}_{direction}"
                topo.platforms[pid] = Platform(
                    id=pid, station_id=st.id, station_name=st.name, section=sec_id, track=tr.id, edge=eid,
                    start_pos_m=max(0.0, e.length_m - st.platform_length_m), end_pos_m=e.length_m,
                    dwell_s=st.dwell_s, km_stop=stop_km, length_m=st.platform_length_m,
                )
    return topo


def _reverses(line: Line, e: TopoEdge, ne: TopoEdge) -> bool:
    """A move between a single-track main line and a double-track branch that would reverse at the
    junction (they share its node): onto the branch from the main line's side it does not leave
    towards, or off it onto the main line's track running back towards that side; or, where a double track converges onto one, from one of its tracks onto the other."""
    if e.section == ne.section:
        return e.direction != ne.direction
    if "main" not in (e.section, ne.section):
        return False
    br = line.branch(ne.section if e.section == "main" else e.section)
    if line.data.tracks != "single" or (br.tracks or line.data.tracks) != "double":
        return False
    main = e if e.section == "main" else ne
    towards_end = main.km_to > main.km_from
    return towards_end != (br.leaves_towards == "end") if main is e else towards_end == (br.leaves_towards == "end")


def _add_track(topo: Topology, sec: _Section, direction: str, pts: list[float], node_ids: list[str], increasing: bool, bidi: bool) -> None:
    tid = f"{sec.id}_{direction}"
    tr = Track(id=tid, section=sec.id, direction=direction, increasing=increasing)
    for i, (a, b) in enumerate(zip(pts, pts[1:])):
        mid = 0.5 * (a + b)
        eid = f"{tid}_{i}"
        tun = sec.tunnel_at(mid)
        twin = None
        if bidi:
            other = "down" if direction == "up" else "up"
            twin = f"{sec.id}_{other}_{len(pts) - 2 - i}"
        g = sec.gradient_at(mid)
        topo.edges[eid] = TopoEdge(
            id=eid, track=tid, section=sec.id, direction=direction, from_node=node_ids[i], to_node=node_ids[i + 1],
            km_from=a, km_to=b, length_m=round(abs(b - a) * 1000.0, 3), speed_ms=sec.speed_at(mid),
            gradient=g if b > a else -g, curve_radius_m=sec.radius_at(mid), tunnel=tun.name if tun else None,
            tunnel_factor=tun.aero_factor if tun else 1.0, bidi=twin,
        )
        tr.edges.append(eid)
    topo.tracks[tid] = tr


def _add_branch(topo: Topology, line: Line, br: Branch, junction_nodes: dict, blk: float | None, min_block_m: float) -> None:
    d = line.data
    blen = br.length_m / 1000.0
    single = (br.tracks or d.tracks) == "single"
    sec = _Section(
        id=br.id, c0=0.0, c1=blen, line_speed_ms=kmh_to_ms(br.speed_kmh), speed_limits=list(br.speed_limits),
        gradients=list(br.gradients), curves=list(br.curves), tunnels=list(br.tunnels), stations=list(br.stations),
        block_length_m=blk, signals_km=None, single=single, min_block_m=min_block_m,
    )
    # on a branch, 'away from the junction' = increasing branch km
    # up-track travels away from the junction iff the branch leaves towards the end
    up_away = br.leaves_towards == "end"
    mand_away = {_round_km(st.km + st.platform_length_m / 2000.0) for st in br.stations}
    mand_towards = {_round_km(st.km - st.platform_length_m / 2000.0) for st in br.stations}
    markers = _signal_positions(sec, mand_away | mand_towards)
    pts = _breakpoints(sec, markers, frozenset(mand_away | mand_towards))
    zrel = _elevations(sec, pts, 0.0)
    cint = _curve_integral(sec, pts)
    jkm = _round_km(br.junction_km)
    xj = (br.junction_km - d.km_start) * 1000.0
    xsign = -1.0 if br.leaves_towards == "start" else 1.0

    def xy(b_km: float, direction: str) -> tuple[float, float]:
        dist = b_km * 1000.0
        off = 0.0 if (single or direction == "up") else TRACK_SPACING_M
        return xj + xsign * dist * math.cos(BRANCH_ANGLE_RAD), -off - 3 * TRACK_SPACING_M * min(1.0, dist / 200.0) - dist * math.sin(BRANCH_ANGLE_RAD)

    def make_nodes(direction: str, away: bool) -> list[str]:
        jn = junction_nodes[(jkm, direction)]
        zj = topo.nodes[jn].z
        ids = [jn]
        mand = mand_away if away else mand_towards
        for i, c in enumerate(pts[1:], start=1):
            nid = f"{br.id}_{direction}_n{i}" if not single else f"{br.id}_n{i}"
            if nid in topo.nodes:
                ids.append(nid)
                continue
            x, y = xy(c, direction)
            sign = 1.0 if away else -1.0
            z = zj + zrel[i] + (0.0 if single else sign * cint[i])
            is_sig = _round_km(c) in (markers | mand) and i < len(pts) - 1
            topo.nodes[nid] = TopoNode(nid, x, y, z, is_sig, br.id, c)
            ids.append(nid)
        return ids

    if single:
        ids = make_nodes("up", True)
        fwd_dir = "up" if up_away else "down"
        back_dir = "down" if up_away else "up"
        _add_track(topo, sec, fwd_dir, pts, ids, increasing=True, bidi=True)
        _add_track(topo, sec, back_dir, pts[::-1], ids[::-1], increasing=False, bidi=True)
        # single-track branch on a double-track main line: away-track starts at the junction node of its direction
        if d.tracks == "double":
            jn_fwd = junction_nodes[(jkm, fwd_dir)]
            jn_back = junction_nodes[(jkm, back_dir)]
            first = topo.tracks[f"{br.id}_{fwd_dir}"].edges[0]
            last = topo.tracks[f"{br.id}_{back_dir}"].edges[-1]
            topo.edges[first] = _replace_node(topo.edges[first], from_node=jn_fwd)
            topo.edges[last] = _replace_node(topo.edges[last], to_node=jn_back)
        return
    for direction in ("up", "down"):
        away = up_away if direction == "up" else not up_away
        ids = make_nodes(direction, away)
        if away:
            _add_track(topo, sec, direction, pts, ids, increasing=True, bidi=False)
        else:
            _add_track(topo, sec, direction, pts[::-1], ids[::-1], increasing=False, bidi=False)


def _replace_node(e: TopoEdge, **kw) -> TopoEdge:
    from dataclasses import replace

    return replace(e, **kw)


__all__ = [
    "BRANCH_ANGLE_RAD", "EPS_KM", "TRACK_SPACING_M", "Platform", "TopoEdge", "TopoNode", "Topology", "Track", "build_topology", "reachable",
]
