"""The line's fixed infrastructure as a tidy results table, ``infrastructure.csv``.

Plots read only results tables (:mod:`vcsumo.plots`); to put station names, signals and junctions
on a distance axis they need them in the results folder.  One row per object:

* ``kind`` — ``station`` (the line file's station, km of the platform centre), ``platform`` (where
  a train's front stops, per track), ``signal`` (a block or exit signal, per track and direction
  of travel), ``junction`` (where a branch leaves the main line);
* ``id``, ``name`` — from the line file (signals: the node id of the network);
* ``section`` — ``main`` or the branch id; ``km`` — chainage on that section, km;
* ``track``, ``direction`` — the track and direction of travel (``up``/``down``) a signal or a
  platform belongs to; empty for stations and junctions.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from vcsumo.network_file import Network
from vcsumo.topology import Topology

INFRASTRUCTURE_COLUMNS = ["kind", "id", "name", "section", "km", "track", "direction"]
INFRASTRUCTURE_FILE = "infrastructure.csv"


def infrastructure_table(topo: Topology) -> pd.DataFrame:
    """Stations, platforms, signals and junctions of a line's topology (columns :data:`INFRASTRUCTURE_COLUMNS`)."""
    rows: list[dict] = []
    if isinstance(topo.line, Network):  # sections '<line>.main', '<line>.<branch>'; the joins are junctions
        parts = [(f"{name}.", view.data) for name, view in topo.line.lines.items()]
        for j in topo.line.spec.joins:
            rows.append(dict(kind="junction", id=j.id, name=j.name or j.id, section=f"{j.meets.line}.main", km=j.meets.km, track="", direction=""))
    else:
        parts = [("", topo.line.data)]
    for px, line in parts:
        for st in line.stations:
            rows.append(dict(kind="station", id=st.id, name=st.name, section=f"{px}main", km=st.km, track="", direction=""))
        for br in line.branches:
            for st in br.stations:
                rows.append(dict(kind="station", id=st.id, name=st.name, section=f"{px}{br.id}", km=st.km, track="", direction=""))
            rows.append(dict(kind="junction", id=br.id, name=br.junction_name or br.name, section=f"{px}main", km=br.junction_km, track="", direction=""))
    for p in topo.platforms.values():
        rows.append(dict(kind="platform", id=p.id, name=p.station_name, section=p.section, km=p.km_stop, track=p.track,
                         direction=topo.tracks[p.track].direction if p.track in topo.tracks else ""))
    seen = set()
    for e in topo.edges.values():  # a signal stands at the end of the edges that lead into it
        node = topo.nodes[e.to_node]
        if node.signal and (node.id, e.direction) not in seen:
            seen.add((node.id, e.direction))
            rows.append(dict(kind="signal", id=node.id, name="", section=node.section, km=node.km, track=e.track, direction=e.direction))
    df = pd.DataFrame(rows, columns=INFRASTRUCTURE_COLUMNS)
    df["km"] = df["km"].astype(float).round(6)
    return df.sort_values(["kind", "section", "direction", "km"], kind="stable").reset_index(drop=True)


def write_infrastructure(topo: Topology, folder: Path) -> Path:
    """Write ``infrastructure.csv`` into a results folder; returns its path."""
    path = Path(folder) / INFRASTRUCTURE_FILE
    infrastructure_table(topo).to_csv(path, index=False)
    return path
