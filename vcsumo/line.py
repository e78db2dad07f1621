"""Line files: the description of a railway line from which the SUMO network is built.

A line file (``networks/<line>/line.yaml``) describes one line in the units engineers use:
kilometres (the line's own chainage), km/h, ‰ and metres.  It is loaded into the frozen models
below, checked for consistency (:func:`check_line`) and converted to SI once, by the network
builder (:mod:`vcsumo.topology`).  The format is documented field by field in the README.

Conventions
-----------
* ``km`` is the line's chainage.  The ``up`` direction runs towards increasing km, ``down``
  towards decreasing km.
* Gradients are in ‰, positive when rising towards increasing km (branch: rising away from the
  junction).  Ranges not listed are level.
* Speed limits are given as a line speed plus restricted ranges; ranges must not overlap.
* A branch leaves the main line at ``junction_km``; its own chainage is 0 at the junction and grows
  away from it.  ``leaves_towards: start`` means the branch runs alongside the main line towards
  its start (trains from the branch merge into the ``up`` direction, ``down`` trains diverge onto
  it); ``end`` the opposite.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from vcsumo.config import MAX_PROBLEMS_SHOWN, InputProblems, StrictModel, is_dir, is_file, load_model
from vcsumo.errors import InputError

TrackLayout = Literal["double", "single"]
MAX_LINE_KM = 2000.0
"""Longest line (or branch) vcsumo builds, km."""
Km = Annotated[float, Field(ge=-100000.0, le=100000.0, allow_inf_nan=False)]
SPEED_DOC = "5–600 km/h (below 5 km/h is shunting, not a line speed, and makes runs endless; 600 km/h is above any wheel-rail record)"


class Station(StrictModel):
    """A station (or stop) with a platform on every track of the section."""

    id: str = Field(description="Short identifier used by timetables, e.g. 'FIRI'", pattern=r"^[A-Za-z][A-Za-z0-9_\-]*$")
    name: str = Field(description="Full station name")
    km: Km = Field(description="Chainage of the platform centre, km")
    platform_length_m: float = Field(ge=10, le=5000, description="Usable platform length, m (10–5,000: no platform is shorter than a car or longer than 5 km)")
    dwell_s: float = Field(default=60.0, ge=0, le=86400, description="Default dwell time of a stopping train, s (0–86,400: a dwell is not negative and not longer than a day)")


class SpeedRange(StrictModel):
    """A speed limit over a km range (both directions)."""

    from_km: Km = Field(description="Start of the range, km")
    to_km: Km = Field(description="End of the range, km")
    speed_kmh: float = Field(ge=5, le=600, description="Maximum permitted speed, km/h; " + SPEED_DOC)


class GradientRange(StrictModel):
    """A constant gradient over a km range."""

    from_km: Km = Field(description="Start of the range, km")
    to_km: Km = Field(description="End of the range, km")
    permille: float = Field(ge=-80, le=80, description="Gradient, ‰, positive rising towards increasing km")


class CurveRange(StrictModel):
    """A curve of constant radius over a km range."""

    from_km: Km = Field(description="Start of the curve, km")
    to_km: Km = Field(description="End of the curve, km")
    radius_m: float = Field(gt=50, le=1e6, description="Curve radius, m (50 m–1,000 km: tighter is a tram, wider is straight track)")


class Tunnel(StrictModel):
    """A tunnel: aerodynamic drag is multiplied by ``aero_factor`` inside (Felez eq. 1b, T_f)."""

    name: str = Field(description="Tunnel name")
    from_km: Km = Field(description="Portal at the lower chainage, km")
    to_km: Km = Field(description="Portal at the higher chainage, km")
    aero_factor: float = Field(default=1.5, ge=1.0, le=4.0, description="Tunnel factor T_f on the quadratic (aerodynamic) resistance term, -")


class Signalling(StrictModel):
    """Fixed-block signalling: regular block markers or explicit signal positions."""

    block_length_m: float | None = Field(default=None, ge=100, le=50000, description="Regular block length, m (markers from the section start); 100 m–50 km: shorter is not a block section, longer exceeds any real block")
    signals_km: list[Km] | None = Field(default=None, description="Explicit block-marker positions, km (both directions)")
    block_origin_km: Km | None = Field(default=None, description="Where the regular markers are counted from, km (default: the section start; a line cut from a longer one keeps the longer line's markers)")
    min_block_length_m: float = Field(default=100.0, ge=0, le=10000, description="Regular markers closer than this to a station or junction signal are dropped, m")

    @model_validator(mode="after")
    def _one_way(self) -> "Signalling":
        if self.block_length_m is None and not self.signals_km:
            raise ValueError("give either block_length_m or signals_km")
        if self.block_length_m is not None and self.signals_km:
            raise ValueError("give block_length_m or signals_km, not both")
        if self.block_origin_km is not None and self.block_length_m is None:
            raise ValueError("block_origin_km counts regular markers: give block_length_m with it")
        return self


class HeadwaySettings(StrictModel):
    """Where the headway study releases trains and where it measures."""

    measuring_points_km: list[Km] = Field(min_length=1, description="Measuring points on the main line, km")
    release_km: dict[Literal["up", "down"], Km] = Field(
        default_factory=dict,
        description="Per direction, where trains are released with a flying start at their unhindered speed, km (default: the line end)",
    )


class Branch(StrictModel):
    """A branch (interconnection, diverging line) leaving the main line at a junction."""

    id: str = Field(pattern=r"^[a-z][a-z0-9_]*$", description="Identifier, used as origin/destination 'branch:<id>'")
    name: str = Field(description="Name of the branch")
    junction_name: str = Field(default="", description="Name of the junction (Bivio ...)")
    end_name: str = Field(default="", description="Name of the place at the far end of the branch")
    junction_km: Km = Field(description="Main-line chainage of the junction, km")
    leaves_towards: Literal["start", "end"] = Field(description="The branch runs alongside the main line towards its start or its end")
    length_m: float = Field(gt=0, le=MAX_LINE_KM * 1000, description="Length of the branch from the junction to its far end, m (at most MAX_LINE_KM)")
    speed_kmh: float = Field(ge=5, le=600, description="Line speed on the branch, km/h; " + SPEED_DOC)
    diverging_speed_kmh: float = Field(ge=5, le=600, description="Speed through the turnout at the junction, km/h; " + SPEED_DOC)
    tracks: TrackLayout | None = Field(default=None, description="double or single; default: as the main line")
    speed_limits: list[SpeedRange] = Field(default_factory=list, description="Restrictions in branch km (0 at the junction)")
    gradients: list[GradientRange] = Field(default_factory=list, description="Gradients in branch km, ‰ rising away from the junction")
    curves: list[CurveRange] = Field(default_factory=list, description="Curves in branch km")
    tunnels: list[Tunnel] = Field(default_factory=list, description="Tunnels in branch km")
    stations: list[Station] = Field(default_factory=list, description="Stations in branch km")
    block_length_m: float | None = Field(default=None, ge=100, le=50000, description="Block length on the branch, m, 100 m–50 km (default: as the main line)")


class LineFile(StrictModel):
    """A line file (``networks/<line>/line.yaml``)."""

    name: str = Field(pattern=r"^[A-Za-z0-9_\-]+$", description="Identifier of the line")
    title: str = Field(default="", description="Human-readable title")
    notes: str = Field(default="", description="Free text: assumptions, caveats")
    sources: dict[str, str] = Field(default_factory=dict, description="Source key -> citation or URL")
    km_start: Km = Field(description="Chainage of the start of the main line, km")
    km_end: Km = Field(description="Chainage of the end of the main line, km")
    tracks: TrackLayout = Field(default="double", description="double (one track per direction) or single (both directions)")
    start_elevation_m: float = Field(default=0.0, ge=-1000, le=9000, allow_inf_nan=False, description="Elevation at km_start, m")
    line_speed_kmh: float = Field(ge=5, le=600, description="Line speed where no restriction applies, km/h; " + SPEED_DOC)
    directions: dict[Literal["up", "down"], str] = Field(default_factory=dict, description="Labels of the directions")
    default_train: str | None = Field(default=None, description="Rolling stock used when a study names none")
    stations: list[Station] = Field(default_factory=list)
    speed_limits: list[SpeedRange] = Field(default_factory=list, description="Speed restrictions below line_speed_kmh (or above it)")
    gradients: list[GradientRange] = Field(default_factory=list)
    curves: list[CurveRange] = Field(default_factory=list)
    tunnels: list[Tunnel] = Field(default_factory=list)
    signalling: Signalling
    headway: HeadwaySettings | None = None
    branches: list[Branch] = Field(default_factory=list)


# --------------------------------------------------------------------------------------------
# Consistency checks (file-level, with the field named)


def _check_ranges(items: list, name: str, lo: float, hi: float, allow_overlap: bool = False) -> list[tuple[str, str]]:
    problems: list[tuple[str, str]] = []
    for i, r in enumerate(items):
        field = f"{name}[{i}]"
        if r.to_km <= r.from_km:
            problems.append((field, f"to_km ({r.to_km}) must be greater than from_km ({r.from_km})"))
        if r.from_km < lo - 1e-9 or r.to_km > hi + 1e-9:
            problems.append((field, f"range {r.from_km}–{r.to_km} km lies beyond the section ({lo}–{hi} km)"))
    if not allow_overlap:
        order = sorted(range(len(items)), key=lambda i: items[i].from_km)
        for a, b in zip(order, order[1:]):
            if items[b].from_km < items[a].to_km - 1e-9:
                problems.append((f"{name}[{b}]", f"range {items[b].from_km}–{items[b].to_km} km overlaps {name}[{a}] ({items[a].from_km}–{items[a].to_km} km)"))
    return problems


def _check_stations(stations: list[Station], name: str, lo: float, hi: float) -> list[tuple[str, str]]:
    problems = []
    for i, st in enumerate(stations):
        half = st.platform_length_m / 2000.0
        if st.km - half < lo - 1e-9 or st.km + half > hi + 1e-9:
            problems.append((f"{name}[{i}].km", f"platform {st.km - half:.3f}–{st.km + half:.3f} km of '{st.id}' lies beyond the section ({lo}–{hi} km)"))
        elif 1e-9 < min(st.km - half - lo, hi - st.km - half) < 0.01 - 1e-9:
            problems.append((f"{name}[{i}].km", f"platform {st.km - half:.3f}–{st.km + half:.3f} km of '{st.id}' ends within 10 m of the section end ({lo}–{hi} km); end it there or leave 10 m"))
    order = sorted(range(len(stations)), key=lambda i: stations[i].km)
    for a, b in zip(order, order[1:]):
        sa, sb = stations[a], stations[b]
        if sb.km - sb.platform_length_m / 2000 < sa.km + sa.platform_length_m / 2000 + 0.01 - 1e-9:
            problems.append((f"{name}[{b}]", f"platform of '{sb.id}' overlaps the platform of '{sa.id}' or lies within 10 m of it"))
    return problems


def check_line(line: LineFile) -> list[tuple[str, str]]:
    """Return every (field, problem) of a parsed line file; empty when consistent."""
    p: list[tuple[str, str]] = []
    lo, hi = line.km_start, line.km_end
    if hi <= lo:
        p.append(("km_end", f"km_end ({hi}) must be greater than km_start ({lo})"))
        return p
    if hi - lo > MAX_LINE_KM:
        p.append(("km_end", f"line length {hi - lo:g} km exceeds {MAX_LINE_KM:g} km"))
        return p
    p += _check_ranges(line.speed_limits, "speed_limits", lo, hi)
    p += _check_ranges(line.gradients, "gradients", lo, hi)
    p += _check_ranges(line.curves, "curves", lo, hi)
    p += _check_ranges(line.tunnels, "tunnels", lo, hi)
    p += _check_stations(line.stations, "stations", lo, hi)
    ids: dict[str, str] = {}
    for i, st in enumerate(line.stations):
        if st.id in ids:
            p.append((f"stations[{i}].id", f"duplicate station id '{st.id}'"))
        ids[st.id] = f"stations[{i}]"
    if line.signalling.signals_km:
        for i, k in enumerate(line.signalling.signals_km):
            if not lo <= k <= hi:
                p.append((f"signalling.signals_km[{i}]", f"signal at {k} km lies beyond the line ({lo}–{hi} km)"))
    if line.headway:
        for i, k in enumerate(line.headway.measuring_points_km):
            if not lo < k < hi:
                p.append((f"headway.measuring_points_km[{i}]", f"measuring point {k} km lies beyond the line ({lo}–{hi} km)"))
        for d, k in line.headway.release_km.items():
            if not lo <= k <= hi:
                p.append((f"headway.release_km.{d}", f"release point {k} km lies beyond the line ({lo}–{hi} km)"))
    branch_ids = set()
    for b_i, br in enumerate(line.branches):
        f = f"branches[{b_i}]"
        if br.id in branch_ids:
            p.append((f"{f}.id", f"duplicate branch id '{br.id}'"))
        branch_ids.add(br.id)
        if not lo < br.junction_km < hi and not (
            (br.leaves_towards == "end" and abs(br.junction_km - hi) < 1e-9) or (br.leaves_towards == "start" and abs(br.junction_km - lo) < 1e-9)
        ):
            p.append((f"{f}.junction_km", f"junction at {br.junction_km} km lies beyond the line ({lo}–{hi} km)"))
        elif 0 < min(br.junction_km - lo, hi - br.junction_km) < 0.01:
            p.append((f"{f}.junction_km", f"junction at {br.junction_km} km lies within 10 m of a line end ({lo}–{hi} km); put it at the end or further in"))
        if br.diverging_speed_kmh > br.speed_kmh + 1e-9:
            p.append((f"{f}.diverging_speed_kmh", f"turnout speed {br.diverging_speed_kmh} km/h exceeds the branch line speed {br.speed_kmh} km/h"))
        blen = br.length_m / 1000.0
        p += _check_ranges(br.speed_limits, f"{f}.speed_limits", 0.0, blen)
        p += _check_ranges(br.gradients, f"{f}.gradients", 0.0, blen)
        p += _check_ranges(br.curves, f"{f}.curves", 0.0, blen)
        p += _check_ranges(br.tunnels, f"{f}.tunnels", 0.0, blen)
        p += _check_stations(br.stations, f"{f}.stations", 0.0, blen)
        for i, st in enumerate(br.stations):
            if st.id in ids:
                p.append((f"{f}.stations[{i}].id", f"duplicate station id '{st.id}' (also {ids[st.id]})"))
            ids[st.id] = f"{f}.stations[{i}]"
    order = sorted(range(len(line.branches)), key=lambda i: line.branches[i].junction_km)
    for a, b in zip(order, order[1:]):
        if abs(line.branches[a].junction_km - line.branches[b].junction_km) < 0.2 and line.branches[a].leaves_towards == line.branches[b].leaves_towards:
            p.append((f"branches[{b}].junction_km", f"junction closer than 200 m to the junction of branch '{line.branches[a].id}' on the same side"))
    for i, st in enumerate(line.stations):
        for b_i, br in enumerate(line.branches):
            if abs(st.km - br.junction_km) * 1000 < st.platform_length_m / 2 + 10:
                p.append((f"branches[{b_i}].junction_km", f"junction at {br.junction_km} km lies inside the platform of station '{st.id}'"))
    return p


# --------------------------------------------------------------------------------------------
# Locating and loading line files


_PACKAGE_ONLY = [0]
"""How many :func:`package_data` blocks are open (then ``$VCSUMO_HOME`` is not read)."""


def project_root() -> Path:
    """The folder holding ``networks/``, ``routes/``, ``controllers/`` and ``studies/``.

    The data shipped inside the package (``vcsumo/data``, installed with it as package data), or
    ``$VCSUMO_HOME`` if set (a folder of the same shape, e.g. your own lines and timetables) —
    except inside :func:`package_data`.
    """
    import os

    env = os.environ.get("VCSUMO_HOME")
    if env and not _PACKAGE_ONLY[0]:
        return Path(env).resolve()
    return Path(__file__).resolve().parent / "data"


@contextmanager
def package_data():
    """Within this block every name resolves in the package's own data, whatever ``$VCSUMO_HOME`` says:
    the papers' reproductions run the shipped experiment files with the trains and controller
    parameters they name (with a home of one's own lines they were not found)."""
    _PACKAGE_ONLY[0] += 1
    try:
        yield
    finally:
        _PACKAGE_ONLY[0] -= 1


def shipped_lines() -> list[str]:
    """Names of the lines shipped in ``networks/``."""
    base = project_root() / "networks"
    return sorted(p.parent.name for p in base.glob("*/line.yaml"))


def resolve_line_path(spec: str | Path) -> Path:
    """Turn ``--line`` (a shipped line name or a path to a line file) into a file path."""
    path = Path(spec)
    if path.suffix in (".yaml", ".yml") or is_file(path):
        if not is_file(path):
            raise InputError(path, None, "line file not found")
        if path.name == "network.yaml":
            raise InputError(path, None, "this is a network of lines: this needs one line (a line of the network, or a line.yaml)")
        return path.resolve()
    if is_dir(path) and is_file(path / "line.yaml"):
        return (path / "line.yaml").resolve()
    candidate = project_root() / "networks" / str(spec) / "line.yaml"
    if is_file(candidate):
        return candidate
    network = project_root() / "networks" / str(spec) / "network.yaml"
    if is_file(network) or (is_dir(path) and is_file(path / "network.yaml")):
        raise InputError(network if is_file(network) else path / "network.yaml", None,
                         f"'{spec}' is a network of lines: this needs one line (a line of the network, or a line.yaml)")
    raise InputError(None, "--line", f"unknown line '{spec}' (shipped lines: {', '.join(shipped_lines()) or 'none'}; or give a path to a line.yaml)")


class Line:
    """A loaded, checked line file plus where it came from."""

    def __init__(self, data: LineFile, path: Path):
        self.data = data
        self.path = path

    @property
    def name(self) -> str:
        return self.data.name

    def source_files(self) -> list[Path]:
        """Every file the line is read from (a network: its file and its line files)."""
        return [self.path]

    def input_files(self) -> dict[str, Path]:
        """The files a results folder records as inputs: ``line`` (a network: also ``line_<name>`` per line)."""
        return {"line": self.path}

    def source_digest(self) -> str:
        """SHA-256 of the line file (a network: of the digests of all its files), hex."""
        import hashlib

        digests = [hashlib.sha256(p.read_bytes()).hexdigest() for p in self.source_files()]
        return digests[0] if len(digests) == 1 else hashlib.sha256("|".join(digests).encode()).hexdigest()

    def station(self, station_id: str) -> tuple[str, Station]:
        """Return (section, station) for a station id; section is 'main' or a branch id."""
        for st in self.data.stations:
            if st.id == station_id:
                return "main", st
        for br in self.data.branches:
            for st in br.stations:
                if st.id == station_id:
                    return br.id, st
        raise KeyError(station_id)

    def all_station_ids(self) -> list[str]:
        ids = [s.id for s in self.data.stations]
        for br in self.data.branches:
            ids += [s.id for s in br.stations]
        return ids

    def branch(self, branch_id: str) -> Branch:
        for br in self.data.branches:
            if br.id == branch_id:
                return br
        raise KeyError(branch_id)

    def direction_label(self, direction: str) -> str:
        return self.data.directions.get(direction, direction)  # type: ignore[arg-type]


def load_line(spec: str | Path) -> Line:
    """Load and check a line by shipped name or path; errors name the file and the field."""
    path = resolve_line_path(spec)
    data = load_model(LineFile, path)
    problems = check_line(data)
    if problems:
        errors = [InputError(path, field, msg) for field, msg in problems[:MAX_PROBLEMS_SHOWN]]
        raise errors[0] if len(errors) == 1 else InputProblems(errors)
    train = Path(data.default_train or "")
    if train.suffix in (".yaml", ".yml") and not train.is_absolute() and is_file(path.parent / train):
        # a train file named by a relative path is the one next to the line file (as a timetable's trains), wherever vcsumo runs from
        data = data.model_copy(update={"default_train": str(path.parent / train)})
    return Line(data, path)
