"""Network builder: line file (or network of lines) → plain XML → netconvert → SUMO network (cached).

Writes ``line.nod.xml`` (nodes with z, ``rail_signal`` at every signal), ``line.edg.xml`` (one edge
per piece of track, explicit ``length`` and kilometrage ``distance``), ``line.con.xml`` (every
connection, with the diverging speed through turnouts) and ``stations.add.xml`` (a ``trainStop``
per platform and track), then runs netconvert from the ``eclipse-sumo`` wheel.

Builds are cached in the user cache folder (``platformdirs.user_cache_dir("vcsumo")/networks/<line>/<fingerprint>/``,
``$VCSUMO_CACHE`` if set), never inside the package or the source tree; the fingerprint covers the
line file's bytes (a network: its file's and every line file's), the block-length override, the builder version, the bytes of the
modules that build it and the SUMO version, so a changed line file (or builder) is rebuilt and an unchanged one is not.  A build goes into a temporary folder
first and is renamed into place, so concurrent runs never see half a network.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

from vcsumo import network_topology, topology, track_graph
from vcsumo.errors import SumoError
from vcsumo.line import Line
from vcsumo.network_file import Network
from vcsumo.network_topology import build_network_topology
from vcsumo.sim.sumo_paths import sumo_binary, sumo_version
from vcsumo.topology import Topology, build_topology

BUILDER_VERSION = "5"
_BUILDER_SOURCES = tuple(Path(m.__file__) for m in (track_graph, topology, network_topology)) + (Path(__file__),)
"""The modules whose code decides the network (their bytes are part of the fingerprint)."""


@dataclass(frozen=True)
class BuiltNetwork:
    """Paths of a built network plus the topology it came from."""

    topology: Topology
    net_file: Path
    stations_file: Path
    folder: Path
    fingerprint: str


def fingerprint(line: Line, block_length_m: float | None) -> str:
    """Hash of every input file of the line (a network: its file and its lines') and the settings."""
    h = hashlib.sha256()
    for path in line.source_files():
        h.update(path.read_bytes())
    for path in _BUILDER_SOURCES:  # the code that builds it: worktrees of other versions share the cache folder
        h.update(path.read_bytes())
    h.update(f"|block={block_length_m}|builder={BUILDER_VERSION}|sumo={sumo_version()}".encode())
    return h.hexdigest()[:16]


def cache_dir() -> Path:
    """Where built networks are cached: ``$VCSUMO_CACHE`` or the user cache folder (platformdirs)."""
    env = os.environ.get("VCSUMO_CACHE")
    if env:
        return Path(env).expanduser().resolve()
    from platformdirs import user_cache_dir

    return Path(user_cache_dir("vcsumo", appauthor=False))


def _build_root(line: Line) -> Path:
    root = cache_dir() / "networks" / line.name
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SumoError(f"{root}: cannot create the network cache folder ({exc.strerror}); set VCSUMO_CACHE to a writable folder") from None
    return root


def build_network(line: Line, block_length_m: float | None = None, force: bool = False) -> BuiltNetwork:
    """Build (or reuse) the SUMO network of a line."""
    topo = build_network_topology(line, block_length_m) if isinstance(line, Network) else build_topology(line, block_length_m)
    fp = fingerprint(line, block_length_m)
    root = _build_root(line)
    folder = root / fp
    net_file = folder / "line.net.xml"
    stations_file = folder / "stations.add.xml"
    if folder.is_dir() and net_file.is_file() and stations_file.is_file() and not force:
        return BuiltNetwork(topo, net_file, stations_file, folder, fp)
    tmp = Path(tempfile.mkdtemp(prefix=f".{fp}-", dir=root))
    try:
        write_plain_xml(topo, tmp)
        cmd = [
            sumo_binary("netconvert"),
            "-n", str(tmp / "line.nod.xml"), "-e", str(tmp / "line.edg.xml"), "-x", str(tmp / "line.con.xml"),
            "-o", str(tmp / "line.net.xml"), "--no-turnarounds", "true", "--offset.disable-normalization", "true",
            "--geometry.min-dist", "0", "--junctions.corner-detail", "0", "--no-warnings", "true", "--precision", "4",
        ]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0 or not (tmp / "line.net.xml").is_file():
            errors = [ln for ln in (proc.stderr + proc.stdout).splitlines() if "rror" in ln] or (proc.stderr or proc.stdout).splitlines()[-5:]
            raise SumoError(f"{line.path}: netconvert failed building the network: " + " | ".join(errors))
        (tmp / "build.json").write_text(json.dumps({"line": str(line.path), "block_length_m": block_length_m, "fingerprint": fp, "sumo": sumo_version()}, indent=1))
        if folder.exists():
            shutil.rmtree(folder, ignore_errors=True)
        try:
            os.replace(tmp, folder)
        except OSError:
            # another process finished the same build first
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return BuiltNetwork(topo, net_file, stations_file, folder, fp)


def write_plain_xml(topo: Topology, folder: Path) -> None:
    """Write the plain-XML inputs of netconvert and the stations additional file."""
    folder.mkdir(parents=True, exist_ok=True)
    signals = topo.signal_nodes()
    nod = ["<nodes>"]
    for n in topo.nodes.values():
        kind = "rail_signal" if n.id in signals else "priority"
        nod.append(f'  <node id="{n.id}" x="{n.x:.3f}" y="{n.y:.3f}" z="{n.z:.4f}" type="{kind}"/>')
    nod.append("</nodes>")
    (folder / "line.nod.xml").write_text("\n".join(nod) + "\n")

    edg = ["<edges>"]
    for e in topo.edges.values():
        spread = ' spreadType="center"' if e.bidi else ""
        # SUMO kilometrage: metres from the line start, negative when it decreases along the edge
        dist_attr = ""
        if e.section in topo.km_origin:
            dist = (e.km_from - topo.km_origin[e.section]) * 1000.0
            signed = dist if e.km_to > e.km_from else -dist
            if abs(signed) > 0:
                dist_attr = f' distance="{signed:.3f}"'
        head = (
            f'  <edge id="{e.id}" from="{e.from_node}" to="{e.to_node}" numLanes="1" speed="{e.speed_ms:.4f}" '
            f'length="{e.length_m:.3f}" allow="rail rail_fast rail_electric" priority="1"{dist_attr}{spread}'
        )
        if e.tunnel:
            edg.append(head + ">")
            edg.append(f'    <param key="tunnel" value={quoteattr(e.tunnel)}/>')
            edg.append(f'    <param key="tunnel_factor" value="{e.tunnel_factor}"/>')
            edg.append("  </edge>")
        else:
            edg.append(head + "/>")
    edg.append("</edges>")
    (folder / "line.edg.xml").write_text("\n".join(edg) + "\n")

    con = ["<connections>"]
    for eid, nxt in topo.successors.items():
        for n in nxt:
            sp = topo.turnout_speed_ms.get((eid, n))
            sp_attr = f' speed="{sp:.4f}"' if sp is not None else ""
            con.append(f'  <connection from="{eid}" to="{n}" fromLane="0" toLane="0"{sp_attr}/>')
    con.append("</connections>")
    (folder / "line.con.xml").write_text("\n".join(con) + "\n")

    add = ["<additional>"]
    for p in topo.platforms.values():
        add.append(
            f'  <trainStop id="{p.id}" lane="{p.edge}_0" startPos="{p.start_pos_m:.3f}" endPos="{p.end_pos_m:.3f}" '
            f'name={quoteattr(p.station_name)} friendlyPos="true"/>'
        )
    add.append("</additional>")
    (folder / "stations.add.xml").write_text("\n".join(add) + "\n")
