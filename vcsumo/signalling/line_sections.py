"""The line sections of UIC 406 (:mod:`vcsumo.signalling.uic406`): the main line's track of one
direction between two consecutive section boundaries — the main line's ends, the stopping position
of every station on that track, every junction (and, in a network of lines, where the lines join)."""

from __future__ import annotations

from dataclasses import dataclass

from vcsumo.line import Line
from vcsumo.network_file import Network
from vcsumo.topology import Topology


@dataclass(frozen=True)
class Section:
    """A line section: the main track of one direction between two boundaries."""

    direction: str
    from_km: float
    to_km: float
    from_name: str
    to_name: str
    main: str = "main"
    """Topology section of the main line (a network of lines: ``<line>.main``)."""

    @property
    def label(self) -> str:
        return f"{self.from_name}-{self.to_name}" if self.main == "main" else f"{self.main[:-5]}:{self.from_name}-{self.to_name}"

    @property
    def length_m(self) -> float:
        return abs(self.to_km - self.from_km) * 1000.0


def line_sections(line: Line, topo: Topology) -> list[Section]:
    """Every main-line section of both directions, in running order (see the module docstring);
    a network of lines: of every line's main line, bounded also where the lines join."""
    if isinstance(line, Network):
        mains = []
        for name, view in line.lines.items():
            joins = {round(j.meets.km, 6): f"J:{j.id}" for j in line.spec.joins if j.meets.line == name}
            joins |= {round(view.data.km_start if j.end.at == "start" else view.data.km_end, 6): f"J:{j.id}"
                      for j in line.spec.joins if j.end.line == name and j.end.at in ("start", "end")}
            mains.append((f"{name}.main", view.data, joins))
    else:
        mains = [("main", line.data, {})]
    out: list[Section] = []
    for main, d, joins in mains:
        for direction in ("up", "down"):
            try:
                track = topo.track_for(main, direction)
            except KeyError:  # pragma: no cover - every built line has both
                continue
            bounds: dict[float, str] = {round(d.km_start, 6): "start", round(d.km_end, 6): "end"} | joins
            for p in topo.platforms.values():
                if p.track == track.id:
                    bounds[round(p.km_stop, 6)] = p.station_id
            for br in d.branches:
                bounds.setdefault(round(br.junction_km, 6), f"J:{br.id}")
            kms = sorted(bounds, reverse=not track.increasing)
            for a, b in zip(kms, kms[1:]):
                out.append(Section(direction, a, b, bounds[a], bounds[b], main))
    return out
