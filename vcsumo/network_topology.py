"""The track topology of a network of lines: every line built alone, then stitched at the joins.

Each line (the part the network uses) is built by :func:`vcsumo.topology.build_topology`, with a
node and a signal on its main tracks wherever another line joins inside it.  Its ids get the
line's name as prefix (``milano_bologna.main_up_12``; sections ``milano_bologna.main``, tracks
``milano_bologna.main_up``), its geometry is turned and moved so that the lines meet where they
join (lengths, gradients and speeds are the line's own: only the plane position changes, and the
elevation by a constant), and at every join the joining line's end edges are re-attached to the
met line's nodes:

* at the met line's end, the two lines continue into each other (the trains leaving one enter
  the other) and the node becomes a signal;
* inside it, the joining line leaves through a grade-separated junction like a branch: trains on
  the met line's track running ``towards`` diverge onto it, trains from it merge into the other
  track; both connections get the turnout speed.

Platforms keep their ids (``<station>_<direction>``: station ids are unique in a network), open
ends are named ``<line>:start``, ``<line>:end`` and ``<line>:branch:<id>``, and every join's
nodes are listed under its name (:attr:`~vcsumo.topology.Topology.named_nodes`) for ``via``.
"""

from __future__ import annotations

import math
import warnings
from collections import deque
from dataclasses import replace

from vcsumo.network_file import Join, Network
from vcsumo.topology import BRANCH_ANGLE_RAD, Topology, Track, build_topology
from vcsumo.track_graph import converge_onto_single_track
from vcsumo.units import kmh_to_ms

Z_MISMATCH_WARN_M = 0.5
"""Warn when the two tracks of a join cannot both meet at the same elevation (curves on one line), m."""


def _prefixed(part: Topology, name: str) -> Topology:
    """A copy of a line's topology with every id, track and section prefixed by ``<name>.``."""
    px = f"{name}."
    out = Topology(line=part.line, block_length_m=part.block_length_m)
    out.nodes = {px + k: replace(n, id=px + k, section=px + n.section) for k, n in part.nodes.items()}
    out.edges = {px + k: replace(e, id=px + k, track=px + e.track, section=px + e.section, from_node=px + e.from_node, to_node=px + e.to_node,
                                 bidi=None if e.bidi is None else px + e.bidi) for k, e in part.edges.items()}
    out.tracks = {px + k: Track(px + t.id, px + t.section, t.direction, t.increasing, [px + e for e in t.edges]) for k, t in part.tracks.items()}
    out.successors = {px + k: [px + x for x in v] for k, v in part.successors.items()}
    out.turnout_speed_ms = {(px + a, px + b): v for (a, b), v in part.turnout_speed_ms.items()}
    out.platforms = {k: replace(p, section=px + p.section, track=px + p.track, edge=px + p.edge) for k, p in part.platforms.items()}
    out.endpoints = {f"{name}:{k}": ([px + x for x in a], [px + x for x in b]) for k, (a, b) in part.endpoints.items()}
    out.km_origin = {px + k: v for k, v in part.km_origin.items()}
    return out


def _unit(dx: float, dy: float) -> tuple[float, float]:
    n = math.hypot(dx, dy) or 1.0
    return dx / n, dy / n


def _rotate(v: tuple[float, float], a: float) -> tuple[float, float]:
    c, s = math.cos(a), math.sin(a)
    return c * v[0] - s * v[1], s * v[0] + c * v[1]


class _Port:
    """Where a join attaches on one line: the node the other line's edges are re-attached to (or
    whose edges are re-attached), its position and the direction leaving this line there."""

    def __init__(self, node: str, xy: tuple[float, float], z: float, out_dir: tuple[float, float]):
        self.node, self.xy, self.z, self.out_dir = node, xy, z, out_dir


def _end_port(topo: Topology, key: str) -> tuple[_Port, str, str]:
    """(port, edge entering the line at the end, edge leaving it) of an open end."""
    into, out = topo.endpoints[key][0][0], topo.endpoints[key][1][0]
    e = topo.edges[into]
    a, b = topo.nodes[e.from_node], topo.nodes[e.to_node]
    return _Port(e.from_node, (a.x, a.y), a.z, _unit(a.x - b.x, a.y - b.y)), into, out


def _junction_edges(topo: Topology, section: str, km: float) -> dict[str, tuple[str, str]]:
    """direction -> (edge of the main track arriving at km, edge leaving it)."""
    out = {}
    for direction in ("up", "down"):
        tr = topo.track_for(section, direction)
        arrive = next(e for e in tr.edges if abs(topo.edges[e].km_to - km) < 1e-5)
        leave = next(e for e in tr.edges if abs(topo.edges[e].km_from - km) < 1e-5)
        out[direction] = (arrive, leave)
    return out


def build_network_topology(net: Network, block_length_m: float | None = None) -> Topology:
    """Build every line of the network and stitch them at the joins (see the module doc)."""
    names = list(net.lines)
    inner: dict[str, set[float]] = {n: set() for n in names}
    for jn in net.spec.joins:
        if net.join_end_of_met_line(jn) is None:
            inner[jn.meets.line].add(jn.meets.km)
    parts = {}
    for n in names:
        view = net.line_view(n, block_length_m)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            part = _prefixed(build_topology(view, None, frozenset(inner[n])), n)
        for w in caught:  # the view keeps regular markers regular (line_part): a signals_km warning is the line file's own, said with its line
            named = "signalling.signals_km" in str(w.message)
            warnings.warn(f"{n}: {w.message}" if named else w.message, w.category, stacklevel=2)
        part.km_origin = {k: net.full_lines[n].data.km_start if k == f"{n}.main" else v for k, v in part.km_origin.items()}
        parts[n] = part

    # ports of every join, in each line's own frame
    ports = []
    for jn in net.spec.joins:
        a, b = parts[jn.end.line], parts[jn.meets.line]
        pa, into_a, out_a = _end_port(a, f"{jn.end.line}:{jn.end.at}")
        met_end = net.join_end_of_met_line(jn)
        if met_end is not None:
            end_b, into_b, out_b = _end_port(b, f"{jn.meets.line}:{met_end}")
            # trains leaving b enter a, and the other way round; b's nodes stay
            attach = {"into": b.edges[out_b].to_node, "out": b.edges[into_b].from_node}
            nb = b.nodes[attach["into"]]
            pb = _Port(attach["into"], (nb.x, nb.y), nb.z, end_b.out_dir)
            links = [(out_b, into_a, None), (out_a, into_b, None)]
            if a.edges[into_a].bidi == out_a and attach["into"] != attach["out"]:
                # a single track running into a double track: a's end edge pair stays one track used both
                # ways (SUMO keeps opposing trains apart only on such a pair); b's two tracks converge on
                # a's end node instead
                node_a = a.edges[into_a].from_node
                attach = {"into": node_a, "out": node_a, "b_into": into_b, "b_out": out_b}
        else:
            je = _junction_edges(b, f"{jn.meets.line}.main", jn.meets.km)
            diverge, merge = ("up", "down") if jn.towards == "end" else ("down", "up")
            node = b.edges[je[diverge][0]].to_node
            leave = b.edges[je[diverge][1]]
            base = _unit(b.nodes[leave.to_node].x - b.nodes[leave.from_node].x, b.nodes[leave.to_node].y - b.nodes[leave.from_node].y)
            out_dir = _rotate(base, -BRANCH_ANGLE_RAD if jn.towards == "end" else BRANCH_ANGLE_RAD)
            pb = _Port(node, (b.nodes[node].x, b.nodes[node].y), b.nodes[node].z, out_dir)
            attach = {"into": node, "out": b.edges[je[merge][1]].from_node}
            v = kmh_to_ms(jn.diverging_speed_kmh or 0.0)
            links = [(je[diverge][0], into_a, v), (out_a, je[merge][1], v)]
        ports.append((jn, pa, pb, into_a, out_a, attach, links))

    # place the lines: a tree of joins from the first line
    place = {names[0]: (0.0, (0.0, 0.0), 0.0)}  # name -> (rotation, translation, elevation shift)
    todo = deque([names[0]])
    while todo:
        cur = todo.popleft()
        for jn, pa, pb, *_ in ports:
            la, lb = jn.end.line, jn.meets.line
            if cur not in (la, lb) or (la in place and lb in place):
                continue
            fixed, moving = (la, lb) if la in place else (lb, la)
            pf, pm = (pa, pb) if fixed == la else (pb, pa)
            rot, (tx, ty), dz = place[fixed]
            d_fixed = _rotate(pf.out_dir, rot)
            r = math.atan2(-d_fixed[1], -d_fixed[0]) - math.atan2(pm.out_dir[1], pm.out_dir[0])
            xf = _rotate(pf.xy, rot)
            xm = _rotate(pm.xy, r)
            place[moving] = (r, (xf[0] + tx - xm[0], xf[1] + ty - xm[1]), pf.z + dz - pm.z)
            todo.append(moving)

    topo = Topology(line=net, block_length_m=block_length_m)
    for n in names:
        part = parts[n]
        rot, (tx, ty), dz = place[n]
        for k, node in part.nodes.items():
            x, y = _rotate((node.x, node.y), rot)
            topo.nodes[k] = replace(node, x=x + tx, y=y + ty, z=node.z + dz)
        topo.edges.update(part.edges)
        topo.tracks.update(part.tracks)
        topo.successors.update(part.successors)
        topo.turnout_speed_ms.update(part.turnout_speed_ms)
        topo.platforms.update(part.platforms)
        topo.endpoints.update(part.endpoints)
        topo.km_origin.update(part.km_origin)

    # stitch
    for jn, pa, pb, into_a, out_a, attach, links in ports:
        _stitch(topo, jn, into_a, out_a, attach, links)
        topo.endpoints.pop(f"{jn.end.line}:{jn.end.at}", None)
        met_end = net.join_end_of_met_line(jn)
        if met_end is not None:
            topo.endpoints.pop(f"{jn.meets.line}:{met_end}", None)
    inner_nodes = {attach["into"] for jn, _, _, _, _, attach, _ in ports if net.join_end_of_met_line(jn) is None}
    converge_onto_single_track(topo, inner_nodes)  # a double-track line joined inside a single-track one
    used = {e.from_node for e in topo.edges.values()} | {e.to_node for e in topo.edges.values()}
    topo.nodes = {k: v for k, v in topo.nodes.items() if k in used}
    return topo


def _stitch(topo: Topology, jn: Join, into_a: str, out_a: str, attach: dict[str, str], links: list[tuple[str, str, float | None]]) -> None:
    if "b_into" in attach:  # the met line's end edges move onto the joining single track's end node
        moves = [(attach["b_into"], "from_node"), (attach["b_out"], "to_node")]
    else:
        moves = [(into_a, "from_node"), (out_a, "to_node")]
    new = attach["into"], attach["out"]
    for (edge, end), node in zip(moves, new):
        old = getattr(topo.edges[edge], end)
        if abs(topo.nodes[old].z - topo.nodes[node].z) > Z_MISMATCH_WARN_M:
            warnings.warn(f"join {jn.id}: the tracks meet {abs(topo.nodes[old].z - topo.nodes[node].z):.1f} m apart in elevation "
                          "(curves folded into the elevation differ); the first edge's gradient absorbs it", stacklevel=3)
        topo.edges[edge] = replace(topo.edges[edge], **{end: node})
    for node in (attach["into"], attach["out"]):
        topo.nodes[node] = replace(topo.nodes[node], signal=True)
    for a, b, speed in links:
        if b not in topo.successors.setdefault(a, []):
            topo.successors[a].append(b)
        if speed:
            topo.turnout_speed_ms[(a, b)] = speed
    topo.named_nodes[jn.id] = sorted({attach["into"], attach["out"]})
