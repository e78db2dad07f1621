"""Network files: line files joined at named nodes into one network of lines.

A network file (``networks/<name>/network.yaml``) lists line files (shipped names, or paths
relative to the network file), each optionally used over part of its main line only
(``from_km``/``to_km``, in the line's own chainage) and with a chosen set of its branches, and
*joins* them: at each join, a line's end (``start``, ``end`` or ``branch:<id>``) meets another
line's main line at a km.  At that line's own end the two lines simply continue into each other;
inside it, the joining line leaves through a junction, exactly as a branch does (``towards`` says
along which way it runs, ``diverging_speed_kmh`` is the turnout speed).  The joins must connect
every line and form no loop.

A loaded network is a :class:`Network`: a :class:`~vcsumo.line.Line` (name, path, stations, the
line files it reads) whose topology :mod:`vcsumo.network_topology` builds by building every line
with the ordinary builder and stitching them at the joins.  What stays per line: its chainage
(sections are ``<line>.main`` and ``<line>.<branch>``, km in the line's own chainage), its
``up``/``down`` directions and its signals.  Station ids must be unique across the network.
Studies made for one line (headway, capacity, junction, safety) read a line's file (``.data``);
given a network they stop with one error naming the network file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field

from vcsumo.config import MAX_PROBLEMS_SHOWN, InputProblems, StrictModel, is_dir, is_file, load_model, read_yaml
from vcsumo.errors import InputError
from vcsumo.line import Km, Line, LineFile, Signalling, Station, check_line, load_line, project_root

JUNCTION_KM_TOLERANCE = 0.0005
"""A join's km within this of a line end is at that end (a continuation), km (0.5 m)."""


class NetworkLine(StrictModel):
    """A line of the network, used whole or over part of its main line."""

    line: str = Field(description="Shipped line name, or path to a line file (relative to the network file)")
    from_km: Km | None = Field(default=None, description="Use the main line from this chainage on, km (default: its km_start)")
    to_km: Km | None = Field(default=None, description="Use the main line up to this chainage, km (default: its km_end)")
    branches: list[str] | None = Field(default=None, description="Ids of the branches kept (default: every branch whose junction lies in the part used)")


class LineEnd(StrictModel):
    """An end of a line of the network."""

    line: str = Field(description="Name of a line of the network (its line file's ``name``)")
    at: str = Field(pattern=r"^(start|end|branch:[a-z][a-z0-9_]*)$", description="'start' or 'end' of its main line (of the part used), or 'branch:<id>' (the far end of a branch)")


class LinePoint(StrictModel):
    """A point on the main line of a line of the network."""

    line: str = Field(description="Name of a line of the network")
    km: Km = Field(description="Chainage on that line's main line, km: its start or end (the lines continue into each other) or a point inside (a junction)")


class Join(StrictModel):
    """A named node where a line's end meets another line."""

    id: str = Field(pattern=r"^[A-Za-z][A-Za-z0-9_\-]*$", description="Node name (timetables may route 'via' it)")
    name: str = Field(default="", description="Full name, e.g. 'Bivio Venezia'")
    end: LineEnd
    meets: LinePoint
    towards: Literal["start", "end"] | None = Field(
        default=None, description="At a junction inside the met line: the joining line runs alongside it towards its start or its end (as a branch's leaves_towards)")
    diverging_speed_kmh: float | None = Field(default=None, ge=5, le=600, description="At a junction: speed through the turnout, km/h (5–600)")


class NetworkFile(StrictModel):
    """A network file (``networks/<name>/network.yaml``)."""

    name: str = Field(pattern=r"^[A-Za-z0-9_\-]+$", description="Identifier of the network (timetables name it as their line)")
    title: str = Field(default="", description="Human-readable title")
    notes: str = Field(default="", description="Free text: assumptions, caveats")
    sources: dict[str, str] = Field(default_factory=dict, description="Source key -> citation or URL")
    default_train: str | None = Field(default=None, description="Rolling stock used when a study names none (default: the first line's)")
    lines: list[NetworkLine] = Field(min_length=1, description="The lines joined")
    joins: list[Join] = Field(default_factory=list, description="Where the lines meet")


# --------------------------------------------------------------------------------------------
# One line, used over part of its main line


def _clip(items: list, lo: float, hi: float) -> list:
    out = []
    for r in items:
        a, b = max(r.from_km, lo), min(r.to_km, hi)
        if b - a > 1e-9:
            out.append(r.model_copy(update={"from_km": a, "to_km": b}))
    return out


def _elevation_at(d: LineFile, km: float) -> float:
    z = d.start_elevation_m
    for g in d.gradients:
        a, b = max(g.from_km, d.km_start), min(g.to_km, km)
        if b > a:
            z += g.permille * (b - a)  # ‰ × km = m
    return z


def line_part(d: LineFile, lo: float, hi: float, branches: list[str] | None, block_length_m: float | None = None) -> LineFile:
    """The line file cut to its main line from ``lo`` to ``hi`` km (stations, ranges and branches
    inside), with the block markers where the whole line has them (its ``signals_km``, or its regular markers
    counted from its start: ``block_origin_km``).

    Not validated here: :func:`check_network` checks the cut (platforms cut through, ranges).
    """
    sig = d.signalling
    blk = block_length_m if block_length_m is not None else sig.block_length_m
    if block_length_m is None and sig.signals_km:
        signalling = Signalling.model_construct(block_length_m=None, signals_km=[k for k in sig.signals_km if lo < k < hi], block_origin_km=None,
                                                min_block_length_m=sig.min_block_length_m)
    else:  # the whole line's regular markers (counted from its start), not the cut's
        origin = sig.block_origin_km if block_length_m is None and sig.block_origin_km is not None else d.km_start
        signalling = Signalling.model_construct(block_length_m=blk, signals_km=None, block_origin_km=origin, min_block_length_m=sig.min_block_length_m)
    keep = [b for b in d.branches if (branches is None or b.id in branches) and lo - 1e-9 <= b.junction_km <= hi + 1e-9]
    keep = [b if b.block_length_m is not None or blk is None else b.model_copy(update={"block_length_m": blk}) for b in keep]
    return d.model_copy(update={
        "km_start": lo, "km_end": hi, "start_elevation_m": _elevation_at(d, lo),
        "stations": [s for s in d.stations if lo <= s.km <= hi],
        "speed_limits": _clip(d.speed_limits, lo, hi), "gradients": _clip(d.gradients, lo, hi),
        "curves": _clip(d.curves, lo, hi), "tunnels": _clip(d.tunnels, lo, hi),
        "signalling": signalling,
        "headway": None, "branches": keep,
    })


# --------------------------------------------------------------------------------------------
# The loaded network


class Network(Line):
    """A loaded, checked network of lines: a :class:`~vcsumo.line.Line` for the loop, the
    timetables and the network builder (see the module doc)."""

    def __init__(self, spec: NetworkFile, path: Path, lines: dict[str, Line]):
        self.spec = spec
        self.path = path
        self.full_lines = lines
        """Line name -> the line as loaded (whole), in file order."""
        self.entries = {name: e for name, e in zip(lines, spec.lines)}
        self.lines = {name: self.line_view(name) for name in lines}
        """Line name -> the part used (a Line whose file is cut to it)."""

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def title(self) -> str:
        return self.spec.title

    @property
    def data(self) -> LineFile:  # type: ignore[override]
        """A network has no single line file: what needs one stops here, naming the network."""
        raise InputError(self.path, None, f"'{self.name}' is a network of lines ({', '.join(self.full_lines)}): this needs one line; give one of its lines")

    @property
    def default_train(self) -> str | None:
        return self.spec.default_train or next((ln.data.default_train for ln in self.full_lines.values() if ln.data.default_train), None)

    def source_files(self) -> list[Path]:
        return [self.path] + [ln.path for ln in self.full_lines.values()]

    def input_files(self) -> dict[str, Path]:
        return {"line": self.path} | {f"line_{name}": ln.path for name, ln in self.full_lines.items()}

    def range_km(self, name: str) -> tuple[float, float]:
        e, d = self.entries[name], self.full_lines[name].data
        return (d.km_start if e.from_km is None else e.from_km), (d.km_end if e.to_km is None else e.to_km)

    def line_view(self, name: str, block_length_m: float | None = None) -> Line:
        """The part of line ``name`` the network uses, as a line (block length override applied)."""
        full = self.full_lines[name]
        lo, hi = self.range_km(name)
        return Line(line_part(full.data, lo, hi, self.entries[name].branches, block_length_m), full.path)

    def station(self, station_id: str) -> tuple[str, Station]:
        """(section '<line>.main' or '<line>.<branch>', station) of a station id."""
        for name, ln in self.lines.items():
            try:
                sec, st = ln.station(station_id)
            except KeyError:
                continue
            return f"{name}.{sec}", st
        raise KeyError(station_id)

    def all_station_ids(self) -> list[str]:
        return [s for ln in self.lines.values() for s in ln.all_station_ids()]

    def branch(self, branch_id: str):
        raise KeyError(branch_id)

    def direction_label(self, direction: str) -> str:
        return direction

    def join_end_of_met_line(self, j: Join) -> str | None:
        """'start' or 'end' when the join meets the other line at that end (a continuation), else None."""
        lo, hi = self.range_km(j.meets.line)
        if abs(j.meets.km - lo) <= JUNCTION_KM_TOLERANCE:
            return "start"
        if abs(j.meets.km - hi) <= JUNCTION_KM_TOLERANCE:
            return "end"
        return None


# --------------------------------------------------------------------------------------------
# Checks


def _check_parts(spec: NetworkFile, lines: dict[str, Line]) -> list[tuple[str, str]]:
    p: list[tuple[str, str]] = []
    seen_station: dict[str, str] = {}
    for i, (name, e) in enumerate(zip(lines, spec.lines)):
        d = lines[name].data
        lo = d.km_start if e.from_km is None else e.from_km
        hi = d.km_end if e.to_km is None else e.to_km
        if not d.km_start - 1e-9 <= lo < d.km_end:
            p.append((f"lines[{i}].from_km", f"{lo} km lies outside line {name} ({d.km_start}–{d.km_end} km)"))
            continue
        if not d.km_start < hi <= d.km_end + 1e-9:
            p.append((f"lines[{i}].to_km", f"{hi} km lies outside line {name} ({d.km_start}–{d.km_end} km)"))
            continue
        if hi <= lo:
            p.append((f"lines[{i}].to_km", f"to_km ({hi}) must be greater than from_km ({lo})"))
            continue
        for st in d.stations:
            half = st.platform_length_m / 2000.0
            for k, fld in ((lo, "from_km"), (hi, "to_km")):
                if st.km - half < k < st.km + half:
                    p.append((f"lines[{i}].{fld}", f"{k} km cuts through the platform of station '{st.id}' ({st.km - half:.3f}–{st.km + half:.3f} km)"))
        ids = {b.id for b in d.branches}
        for k, bid in enumerate(e.branches or []):
            if bid not in ids:
                p.append((f"lines[{i}].branches[{k}]", f"line {name} has no branch '{bid}' (branches: {', '.join(sorted(ids)) or 'none'})"))
            elif not lo - 1e-9 <= next(b for b in d.branches if b.id == bid).junction_km <= hi + 1e-9:
                p.append((f"lines[{i}].branches[{k}]", f"the junction of branch '{bid}' lies outside the part used ({lo}–{hi} km)"))
        if p:
            continue
        part = line_part(d, lo, hi, e.branches)
        for fld, msg in check_line(part):
            p.append((f"lines[{i}]", f"line {name} used from {lo} to {hi} km: {fld}: {msg}"))
        ln = Line(part, lines[name].path)
        for sid in ln.all_station_ids():
            if sid in seen_station:
                p.append((f"lines[{i}].line", f"station id '{sid}' of line {name} is also a station of line {seen_station[sid]}: "
                          "station ids must be unique in a network (use part of one line: from_km/to_km)"))
            seen_station.setdefault(sid, name)
    return p


def _check_joins(net: Network) -> list[tuple[str, str]]:
    p: list[tuple[str, str]] = []
    names = list(net.full_lines)
    parent = {n: n for n in names}

    def root(n: str) -> str:
        while parent[n] != n:
            n = parent[n]
        return n

    used_ends: dict[tuple[str, str], int] = {}
    inner: dict[int, tuple[str, float, str | None]] = {}  # join index -> (met line, km, towards) of the junctions inside lines
    ids: dict[str, int] = {}
    stations = set(net.all_station_ids())
    for j, jn in enumerate(net.spec.joins):
        f = f"joins[{j}]"
        if jn.id in ids:
            p.append((f"{f}.id", f"duplicate node name '{jn.id}' (also joins[{ids[jn.id]}])"))
        elif jn.id in stations:
            p.append((f"{f}.id", f"node name '{jn.id}' is also a station id (names must be unambiguous in 'via')"))
        ids.setdefault(jn.id, j)
        bad = False
        for side, fld in ((jn.end.line, "end.line"), (jn.meets.line, "meets.line")):
            if side not in net.full_lines:
                p.append((f"{f}.{fld}", f"'{side}' is not a line of the network (lines: {', '.join(names)})"))
                bad = True
        if bad:
            continue
        if jn.end.line == jn.meets.line:
            p.append((f"{f}.meets.line", f"line {jn.end.line} cannot join itself"))
            continue
        view = net.lines[jn.end.line]
        if jn.end.at.startswith("branch:") and jn.end.at[7:] not in {b.id for b in view.data.branches}:
            p.append((f"{f}.end.at", f"line {jn.end.line} has no branch '{jn.end.at[7:]}' in the part used (branches: "
                      f"{', '.join(b.id for b in view.data.branches) or 'none'})"))
            continue
        lo, hi = net.range_km(jn.meets.line)
        km = jn.meets.km
        met_end = net.join_end_of_met_line(jn)
        ends = [(jn.end.line, jn.end.at)] + ([(jn.meets.line, met_end)] if met_end else [])
        if met_end is None:
            if not lo < km < hi:
                p.append((f"{f}.meets.km", f"{km} km lies outside line {jn.meets.line} (part used: {lo}–{hi} km)"))
                continue
            if min(km - lo, hi - km) < 0.01:
                p.append((f"{f}.meets.km", f"{km} km lies within 10 m of an end of line {jn.meets.line} ({lo}–{hi} km): put it at the end or further in"))
                continue
            if jn.towards is None:
                p.append((f"{f}.towards", f"a junction inside line {jn.meets.line} needs towards: start or end (the way the joining line runs alongside it)"))
            if jn.diverging_speed_kmh is None:
                p.append((f"{f}.diverging_speed_kmh", "a junction inside a line needs the turnout speed, km/h"))
            else:  # as a branch's (line files refuse a turnout faster than the branch)
                own = view.data.line_speed_kmh if not jn.end.at.startswith("branch:") else \
                    next(b.speed_kmh for b in view.data.branches if b.id == jn.end.at[7:])
                if jn.diverging_speed_kmh > own + 1e-9:
                    p.append((f"{f}.diverging_speed_kmh", f"turnout speed {jn.diverging_speed_kmh:g} km/h exceeds the line speed of "
                              f"{jn.end.line}{'' if not jn.end.at.startswith('branch:') else ' ' + jn.end.at} ({own:g} km/h)"))
            md = net.lines[jn.meets.line].data
            for st in md.stations:
                if abs(st.km - km) * 1000 < st.platform_length_m / 2 + 10:
                    p.append((f"{f}.meets.km", f"junction at {km} km lies inside the platform of station '{st.id}'"))
            for br in md.branches:
                if abs(br.junction_km - km) < 0.2 and br.leaves_towards == jn.towards:
                    p.append((f"{f}.meets.km", f"junction closer than 200 m to the junction of branch '{br.id}' on the same side"))
            for k, (other, other_km, other_towards) in inner.items():
                if other == jn.meets.line and abs(other_km - km) < 0.2 and other_towards == jn.towards:
                    p.append((f"{f}.meets.km", f"junction closer than 200 m to the junction of joins[{k}] ({net.spec.joins[k].id}) on the same side"))
            inner[j] = (jn.meets.line, km, jn.towards)
        elif jn.towards is not None or jn.diverging_speed_kmh is not None:
            p.append((f"{f}.towards" if jn.towards is not None else f"{f}.diverging_speed_kmh",
                      f"{km} km is the {met_end} of line {jn.meets.line}: the lines continue into each other (no junction, no turnout)"))
        rejoined = False
        for end in ends:
            if end in used_ends:
                p.append((f, f"the {end[1]} of line {end[0]} is already joined (joins[{used_ends[end]}])"))
                rejoined = True
            used_ends.setdefault(end, j)
        a, b = root(jn.end.line), root(jn.meets.line)
        if a == b and not rejoined:  # (an end joined again closes a loop too: said once)
            p.append((f, f"joins form a loop: {jn.end.line} and {jn.meets.line} are already joined"))
        parent[a] = b
    if not p:
        for i, n in enumerate(names):
            if root(n) != root(names[0]):
                p.append((f"lines[{i}].line", f"line {n} is not joined to line {names[0]} (add a join)"))
    return p


# --------------------------------------------------------------------------------------------
# Locating and loading


def shipped_networks() -> list[str]:
    """Names of the networks shipped in ``networks/``."""
    return sorted(p.parent.name for p in (project_root() / "networks").glob("*/network.yaml"))


def network_path(spec: str | Path) -> Path | None:
    """The network file ``spec`` names (a shipped network, a folder holding a network.yaml, a
    network.yaml or a YAML file with a top-level ``lines`` list), or None when it names a line."""
    path = Path(spec)
    if is_file(path):
        if path.name == "network.yaml":
            return path.resolve()
        if path.suffix in (".yaml", ".yml"):
            try:
                doc = read_yaml(path)
            except InputError:
                return None  # the line loader reports it
            return path.resolve() if isinstance(doc, dict) and isinstance(doc.get("lines"), list) else None
        return None
    if is_dir(path) and is_file(path / "network.yaml"):
        return (path / "network.yaml").resolve()
    if path.suffix not in (".yaml", ".yml") and is_file(project_root() / "networks" / str(spec) / "network.yaml"):
        return project_root() / "networks" / str(spec) / "network.yaml"
    return None


def _load_member(spec: str, base: Path, net_path: Path, field: str) -> Line:
    path = Path(spec)
    if path.suffix in (".yaml", ".yml") or "/" in spec:
        path = path if path.is_absolute() else base / path
        if not is_file(path):
            raise InputError(net_path, field, f"line file {path} not found")
        if network_path(path) is not None:
            raise InputError(net_path, field, f"{path} is a network file: a network joins line files (list the lines of that network instead)")
        return load_line(path)
    try:
        return load_line(spec)
    except InputError as exc:
        if exc.path is None:
            raise InputError(net_path, field, exc.message) from None
        raise


def load_network(spec: str | Path) -> Network:
    """Load and check a network by shipped name or path; errors name the file and the field."""
    path = network_path(spec)
    if path is None:
        raise InputError(None, "--line", f"'{spec}' is not a network (shipped networks: {', '.join(shipped_networks()) or 'none'})")
    nf = load_model(NetworkFile, path)
    lines: dict[str, Line] = {}
    for i, e in enumerate(nf.lines):
        ln = _load_member(e.line, path.parent, path, f"lines[{i}].line")
        if ln.name in lines:
            raise InputError(path, f"lines[{i}].line", f"line {ln.name} is listed twice")
        lines[ln.name] = ln
    problems = _check_parts(nf, lines)
    if not problems:
        problems = _check_joins(Network(nf, path, lines))
    if problems:  # one line each, as a line file's (until 2026-12-01 the first and "(and N more problems)", never shown)
        errors = [InputError(path, field, msg) for field, msg in problems[:MAX_PROBLEMS_SHOWN]]
        raise errors[0] if len(errors) == 1 else InputProblems(errors)
    return Network(nf, path, lines)


def load_line_or_network(spec: str | Path) -> Line:
    """``--line``: a line (shipped name or line file) or a network of lines (shipped name or network file)."""
    from vcsumo.rolling_stock import rolling_stock_path

    line = load_network(spec) if network_path(spec) is not None else load_line(spec)
    own = line.spec.default_train if isinstance(line, Network) else line.data.default_train
    if own:  # a train the file names must exist, even for a command that does not run it (build-network)
        try:
            rolling_stock_path(own)
        except InputError as exc:
            raise InputError(line.path, "default_train", exc.message) from None
    return line
