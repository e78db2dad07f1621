"""SUMO's input and output files, written and read through an XML library (never spliced as strings).

* :func:`write_additional` — an additional file that records rail signal switches (``timedEvent
  SaveTLSSwitchStates``) and makes rail signals serve trains in a given order
  (``railSignalConstraints`` / ``predecessor``); it is loaded next to the network's stations file;
* :func:`write_sumocfg` — the run's ``.sumocfg`` (for ``sumo-gui``), paths relative to the run folder;
* :func:`read_signal_switches` — the ``SaveTLSSwitchStates`` output: (time, signal, state) rows;
* :func:`rail_signal_links` — the link index of every (signal, incoming edge, outgoing edge) in a net file;
* :func:`read_sumo_log` — SUMO's warning and error log (``--error-log``) as :class:`SumoLogCounts`.

SUMO's log and ``--aggregate-warnings N`` (the loop runs SUMO with N = 3): the first N messages of a
type are written as they happen, later ones are only counted, and when the simulation closes SUMO
writes one line ``Warning: <total> total messages of type: <format>`` per type that went over N,
where ``<format>`` is the message with every value replaced by ``%`` and ``<total>`` counts every
message of the type, the N written ones included.  :func:`read_sumo_log` therefore counts a type
that has a total line by its total, and the lines written for it are not counted again.  Values
replaced by ``%`` are lost: a total line of emergency stops does not say which were at a red
signal, hence :attr:`SumoLogCounts.emergency_stops_at_red_signal` is a lower bound.

SUMO 1.28 writes an emergency braking as ``Warning: Vehicle 'F' performs emergency braking on lane
'main_up_7_0' with decel=0.74, wished=0.50, severity=1.31, time=383.50.`` — ``decel`` the speed the
train lost in the step over the step length (grade and resistance included), ``wished`` the vType's
``decel``, ``severity`` = (decel − wished) / (emergencyDecel − wished) (above 1: beyond the vType's
``emergencyDecel``), ``time`` the simulated time at the start of the step (the loop observes the
train's new speed one step length later).  The written ones are kept
one by one (:class:`SumoEmergencyBraking`, :attr:`SumoLogCounts.emergency_braking_events`) so that
the run-health monitor can judge each against what the train's brake did
(:meth:`vcsumo.sim.health.HealthMonitor.judge_sumo_emergency_brakings`).
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass, field
from pathlib import Path

import pandas as pd

from vcsumo.errors import SumoError

# -------------------------------------------------------------------------------------------
# Additional files


@dataclass(frozen=True)
class SignalRecording:
    """Record every switch of rail signal ``signal`` (its tls id) into ``output`` (SaveTLSSwitchStates)."""

    signal: str
    output: Path


@dataclass(frozen=True)
class PredecessorConstraint:
    """Rail signal ``signal`` lets ``train`` pass only after ``foes`` (ids of trips) have passed it."""

    signal: str
    train: str
    foes: tuple[str, ...]
    limit: int = 1
    """How many of the foes' most recent passages are remembered (SUMO's ``limit``)."""


def write_additional(path: Path, recordings: list[SignalRecording] | tuple = (), constraints: list[PredecessorConstraint] | tuple = ()) -> Path:
    """Write an additional file with signal recordings and rail-signal predecessor constraints.

    Output paths are written relative to the file's folder (SUMO resolves them from there), so the
    run folder can be moved as a whole.
    """
    root = ET.Element("additional")
    for r in recordings:
        dest = os.path.relpath(Path(r.output).resolve(), Path(path).resolve().parent)
        ET.SubElement(root, "timedEvent", type="SaveTLSSwitchStates", source=r.signal, dest=Path(dest).as_posix())
    by_signal: dict[str, list[PredecessorConstraint]] = {}
    for c in constraints:
        if not c.foes:
            raise ValueError(f"predecessor constraint at signal {c.signal} for {c.train} names no foe")
        by_signal.setdefault(c.signal, []).append(c)
    for sig, cs in by_signal.items():
        el = ET.SubElement(root, "railSignalConstraints", id=sig)
        for c in cs:
            ET.SubElement(el, "predecessor", tripId=c.train, tl=c.signal, foes=" ".join(c.foes), limit=str(c.limit))
    ET.indent(root)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text('<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n")
    return path


REPLAY_PREFIX = "replay-"
"""Output prefix of a replay (``sumo -c scenario.sumocfg`` in the results folder): the recorded
fcd.xml, tripinfo.xml, stops.xml and logs are never overwritten."""


def write_sumocfg(path: Path, args: list[str], out: Path) -> None:
    """A .sumocfg equivalent to the run's SUMO options ``args``, with paths relative to the results
    folder ``out`` (for sumo-gui); a replay writes ``replay-*`` files (:data:`REPLAY_PREFIX`)
    beside the recorded ones."""
    root = ET.Element("configuration")
    it = iter(args)
    for opt in it:
        val = next(it)
        key = opt.lstrip("-")
        key = {"n": "net-file", "r": "route-files", "a": "additional-files"}.get(key, key)
        parts = []
        for v in val.split(","):
            if key in ("net-file", "route-files", "additional-files") or key.endswith("-output") or key.endswith("-log"):
                try:
                    v = str(Path(v).resolve().relative_to(out.resolve()))
                except ValueError:
                    pass
            parts.append(v)
        ET.SubElement(root, key, value=",".join(parts))
    ET.SubElement(root, "output-prefix", value=REPLAY_PREFIX)
    ET.indent(root)
    path.write_text('<?xml version="1.0" encoding="UTF-8"?>\n<!-- vcsumo scenario: open with  sumo-gui -c scenario.sumocfg  (SUMO alone: the braking-curve supervision, tunnel vType switching and VC drivers are not replayed; '
                    f'the replay writes {REPLAY_PREFIX}* files, the recorded outputs stay as they are) -->\n' + ET.tostring(root, encoding="unicode") + "\n")


# -------------------------------------------------------------------------------------------
# Network and signal outputs


def rail_signal_links(net_file: Path, signals: list[str]) -> dict[tuple[str, str, str], int]:
    """(signal, incoming edge, outgoing edge) -> link index of the rail signal, from a net file."""
    out: dict[tuple[str, str, str], int] = {}
    want = set(signals)
    for _, el in ET.iterparse(net_file, events=("end",)):
        if el.tag == "connection" and el.get("tl") in want:
            out[(el.get("tl"), el.get("from"), el.get("to"))] = int(el.get("linkIndex"))
        if el.tag != "edge":
            el.clear()
    return out


def read_signal_switches(files: list[Path]) -> pd.DataFrame:
    """Switches recorded by SaveTLSSwitchStates: columns ``time_s``, ``signal``, ``state`` (one
    character per link: ``r``/``s`` red, ``G``/``g`` green), files in the given order; a file SUMO
    did not write (no switch) gives no rows."""
    rows = []
    for f in files:
        if not f.is_file():
            continue
        try:
            root = ET.parse(f).getroot()
        except ET.ParseError as exc:
            raise SumoError(f"{f}: SUMO's signal output is not valid XML ({exc})") from None
        rows += [(float(el.get("time")), el.get("id"), el.get("state")) for el in root.iter("tlsState")]
    return pd.DataFrame(rows, columns=["time_s", "signal", "state"])


# -------------------------------------------------------------------------------------------
# The warning and error log


@dataclass(frozen=True)
class SumoEmergencyBraking:
    """One 'performs emergency braking' warning as SUMO wrote it (SI units)."""

    vehicle: str
    lane: str
    time_s: float
    """Simulated time SUMO stamped it with, s."""
    decel_mps2: float
    """The train's deceleration over the step (its speed change / step length), m/s²."""
    wished_mps2: float
    """The vType's ``decel``, m/s²."""
    severity: float
    """(decel − wished) / (emergencyDecel − wished): above 1 beyond the vType's emergencyDecel."""


@dataclass
class SumoLogCounts:
    """SUMO's warnings and errors of one run, by kind (see the module doc for aggregated totals)."""

    emergency_braking: int = 0
    """'performs emergency braking': a train decelerated above its vType's emergencyDecel."""
    emergency_stops: int = 0
    """'performs emergency stop': SUMO stopped a train at the end of a lane within one step (in
    vcsumo runs: a red signal passed at speed by a train under speed mode 26), any reason."""
    emergency_stops_at_red_signal: int = 0
    """Of those, the ones whose written line names a red signal (a lower bound when aggregated)."""
    teleports: int = 0
    """'Teleporting …': a train moved by SUMO (vcsumo runs with teleporting off)."""
    collisions: int = 0
    """'…; collision with vehicle …' (any kind: rear, junction, frontal, side)."""
    stop_warnings: int = 0
    """Stop-related warnings: a scheduled stop skipped, aborted, ignored or not reachable."""
    other_warnings: int = 0
    """Every other warning."""
    errors: int = 0
    """Lines starting with 'Error:'."""
    emergency_braking_events: list[SumoEmergencyBraking] = field(default_factory=list)
    """The emergency brakings SUMO wrote one by one (with ``--aggregate-warnings N`` the first N;
    :attr:`emergency_braking` counts them all)."""

    def as_dict(self) -> dict[str, int]:
        """The counts by kind (the events are not counts: :attr:`emergency_braking_events`)."""
        d = asdict(self)
        d.pop("emergency_braking_events")
        return d


_PREFIXES = ("Warning: ", "Error: ")
_TOTAL_RE = re.compile(r"^(\d+) total messages of type: (.*)$")
_REPEAT_MARK = "Repeating initial error messages:"
_KINDS = (  # first match wins; each pattern also matches the message's format ('%' for values)
    ("collisions", re.compile(r"; (?:%|[\w ]*collision) with (?:vehicle|person) ")),
    ("emergency_braking", re.compile(r"performs emergency braking")),
    ("emergency_stops", re.compile(r"performs emergency stop")),
    ("teleports", re.compile(r"^Teleporting ")),
    ("stop_warnings", re.compile(r"(?<!emergency )\bstops?\b", re.IGNORECASE)),
)
_TELEPORT_END_RE = re.compile(r"ends teleporting")
_QUOTED_RE = re.compile(r"'[^']*'")
_RED_SIGNAL_RE = re.compile(r"because of a red traffic light")
_NUMBER = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|-?nan|-?inf)"
_EMERGENCY_BRAKING_RE = re.compile(
    r"^Vehicle '(.*)' performs emergency braking on lane '(.*)' with decel=" + _NUMBER + r", wished=" + _NUMBER
    + r", severity=" + _NUMBER + r", time=(-?[\d:]+(?:\.\d*)?)\.?$")


def sumo_time_s(text: str) -> float:
    """A time as SUMO writes it: seconds (``383.50``) or, with ``--human-readable-time``,
    ``[d:]h:mm:ss[.ss]``, in s."""
    parts = text.split(":")
    if len(parts) == 1:
        return float(text)
    scale = (1.0, 60.0, 3600.0, 86400.0)
    if len(parts) > len(scale):
        raise ValueError(f"not a SUMO time: {text!r}")
    sign = -1.0 if parts[0].startswith("-") else 1.0
    return sign * sum(abs(float(p)) * f for p, f in zip(reversed(parts), scale))


def parse_emergency_braking(body: str) -> SumoEmergencyBraking | None:
    """The warning's text after ``Warning: `` as a :class:`SumoEmergencyBraking` (None: not one,
    or its values are aggregated away as ``%``)."""
    m = _EMERGENCY_BRAKING_RE.match(body.strip())
    if m is None:
        return None
    try:
        return SumoEmergencyBraking(m.group(1), m.group(2), sumo_time_s(m.group(6)), float(m.group(3)), float(m.group(4)), float(m.group(5)))
    except ValueError:
        return None


def _kind(prefix: str, body: str) -> str | None:
    if prefix.startswith("Error"):
        return "errors"
    text = _QUOTED_RE.sub("'%'", body)  # ids and lane names never decide the kind
    if _TELEPORT_END_RE.search(text):
        return None  # the end of a teleport already counted
    for name, rx in _KINDS:
        if rx.search(text):
            return name
    return "other_warnings"


def _format_regex(fmt: str) -> re.Pattern:
    return re.compile(".*?".join(re.escape(p) for p in fmt.split("%")) + r"\Z", re.DOTALL)


def read_sumo_log(path: Path) -> SumoLogCounts:
    """Count SUMO's warnings and errors in a log written with ``--error-log`` (or ``--log``); lines
    without a ``Warning:``/``Error:`` prefix are SUMO's progress messages and are skipped.  A missing
    file gives zero counts."""
    counts = SumoLogCounts()
    if not path.is_file():
        return counts
    lines: list[tuple[str, str]] = []
    totals: list[tuple[str, str, int]] = []
    seen: set[str] = set()
    repeating = False
    for ln in path.read_text(errors="replace").splitlines():
        if ln.strip() == _REPEAT_MARK:  # --verbose: SUMO repeats its first errors at the end
            repeating = True
            continue
        prefix = next((p for p in _PREFIXES if ln.startswith(p)), None)
        if prefix is None or (repeating and ln in seen):
            continue
        seen.add(ln)
        body = ln[len(prefix):].strip()
        m = _TOTAL_RE.match(body)
        if m:
            totals.append((prefix, m.group(2), int(m.group(1))))
        else:
            lines.append((prefix, body))
    aggregated = [(p, _format_regex(fmt)) for p, fmt, _ in totals]
    for prefix, body in lines:
        kind = _kind(prefix, body)
        if kind == "emergency_stops" and _RED_SIGNAL_RE.search(body):
            counts.emergency_stops_at_red_signal += 1
        if kind == "emergency_braking":
            ev = parse_emergency_braking(body)
            if ev is not None:
                counts.emergency_braking_events.append(ev)
        if kind is None or any(p == prefix and rx.match(body) for p, rx in aggregated):
            continue  # counted by its type's total
        setattr(counts, kind, getattr(counts, kind) + 1)
    for prefix, fmt, n in totals:
        kind = _kind(prefix, fmt)
        if kind is not None:
            setattr(counts, kind, getattr(counts, kind) + n)
    return counts
