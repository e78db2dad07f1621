"""The bad-input contract, swept over every kind of user file through the real command line.

House rule: a bad input file gives exactly one line ``error: <file>: <field>: <problem>`` naming the
file and the field, exit status 2, no traceback, and nothing half-written.  tests/test_hostile_inputs.py
fuzzes the loaders in this process; this module proves the rule where the user meets it — the
``vcsumo`` command — systematically rather than by example.

For each kind of file vcsumo reads (line, network, rolling stock, timetables of single trains, of
convoys and of through services on a network, controller, channel, assumption set, experiment,
study files of every ``study:``, batch delay configuration) a shipped valid file is copied and
mutated field by field (:func:`sweep`): every required field deleted, every value given the wrong
type, every number NaN, infinite, negative and (where a zero is impossible) zero, an unknown key in
every mapping; then physically impossible values one by one (:data:`SEMANTIC`: grade 200 ‰,
speed 0, dwell −5, mass 0, km outside the line, unknown stations/trains/controllers, duplicate ids,
times out of order, "25:61") and whole-file problems (empty, garbage, a folder, missing).

Each mutant runs the command that loads its file, in its own process and folder, with a time
limit.  Starting the CLI costs 1–2 s of imports, so the mutants are run by one driver process that
imports ``vcsumo.cli.main`` once and forks a child per mutant: the child changes to the mutant's
folder, points its stdout/stderr at files and calls ``vcsumo.cli.main.main(argv)`` — the console
script's own entry point — and its exit status is the process's.  A few mutants of different kinds
are also run through the installed ``vcsumo`` console script and through ``python -m vcsumo`` and
must give the same status and error line (:func:`test_console_script_agrees_with_the_driver`).

Interrupting a run (Ctrl-C, :func:`test_ctrl_c_mid_run_leaves_nothing`) leaves no folder either.
SIGTERM/SIGKILL of batch and capacity studies and their resuming with every finished run kept
exactly once are tests/test_campaign_faults.py and tests/test_batch.py; SUMO failing mid-run is
tests/test_faults.py and tests/test_cli.py.
"""

from __future__ import annotations

import copy
import json
import math
import re
import subprocess
import sys
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml

from .conftest import DATA

# -------------------------------------------------------------------------------------------
# Mutants


@dataclass
class Mutant:
    id: str
    files: dict[str, bytes | None]
    """Files of the mutant's folder (relative path -> bytes; None: a folder of that name)."""
    argv: list[str]
    target: str
    """The file the error must name (relative path in the mutant's folder)."""
    field: str | None
    """Text the error line must hold after the file (the field or YAML path); None: no field (whole file)."""
    max_lines: int = 1
    """Error lines allowed: one per problem (a value that is a mapping or a list of several changes may have more)."""


@dataclass
class Kind:
    name: str
    target: str
    text: str
    argv: list[str]
    support: dict[str, str] = field(default_factory=dict)
    positive: tuple[str, ...] = ()
    """Numeric fields (dotted, list items as ``[]``) for which zero is impossible as well as negatives."""
    signed: tuple[str, ...] = ()
    """Numeric fields that may be negative (km, grades, elevations)."""
    skip: tuple[str, ...] = ()
    """Paths (prefixes) not swept: free text, free-form mappings (sources), open lists of names."""
    one_item: bool = True
    """Sweep only the first item of each list (every item has the same fields)."""


def _read(rel: str) -> str:
    return (DATA / rel).read_text()


def _dotted(path: tuple) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else ("." if out else "") + str(p)
    return out


def _pattern(path: tuple) -> str:
    """``('stations', 0, 'km')`` -> ``stations[].km`` (the form of :attr:`Kind.positive`, :attr:`Kind.signed`, :data:`REQUIRED`)."""
    out = ""
    for p in path:
        out += "[]" if isinstance(p, int) else ("." if out else "") + str(p)
    return out


def _leaves(node, prefix=()):
    if isinstance(node, dict):
        for k, v in node.items():
            yield prefix + (k,), v
            yield from _leaves(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield prefix + (i,), v
            yield from _leaves(v, prefix + (i,))


def _set(data, path: tuple, value) -> None:
    node = data
    for p in path[:-1]:
        node = node[p]
    if value is _DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value


def _get(data, path: tuple):
    for p in path:
        data = data[p]
    return data


_DELETE = object()


def _dump(data) -> bytes:
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True).encode()


def _mutant(kind: Kind, label: str, raw: bytes | None, fld: str | None, *, target_missing: bool = False) -> Mutant:
    files: dict[str, bytes | None] = {k: v.encode() for k, v in kind.support.items()}
    if not target_missing:
        files[kind.target] = raw
    return Mutant(f"{kind.name}:{label}", files, list(kind.argv), kind.target, fld)


def sweep(kind: Kind) -> list[Mutant]:
    """Field by field: delete, wrong type, NaN, inf, negative, zero; an unknown key in every mapping."""
    base = yaml.safe_load(kind.text)
    out: list[Mutant] = []
    for path, value in _leaves(base):
        pat = _pattern(path)
        if any(pat == s or pat.startswith(s + ".") or pat.startswith(s + "[") for s in kind.skip):
            continue
        if kind.one_item and any(isinstance(p, int) and p > 0 for p in path):
            continue
        name = _dotted(path)

        def add(label: str, v, fld: str = name) -> None:
            data = copy.deepcopy(base)
            _set(data, path, v)
            out.append(_mutant(kind, f"{name}={label}", _dump(data), fld))

        if isinstance(path[-1], str) and _required(kind, path):
            add("deleted", _DELETE)
        if isinstance(value, bool):
            add("'sometimes'", "sometimes")
        elif isinstance(value, (int, float)):
            add("'abc'", "abc")
            add("nan", math.nan)
            add("inf", math.inf)
            if pat not in kind.signed:
                add("-5", -5)
                if pat in kind.positive:
                    add("0", 0)
        elif isinstance(value, str):
            add("{a: 1}", {"a": 1})
            out[-1].max_lines = 2  # where a mapping is allowed too (a train's overrides): its problems, one line each
        elif isinstance(value, list):
            add("'x'", "x") if value and not isinstance(value[0], str) else None
        elif isinstance(value, dict):
            data = copy.deepcopy(base)
            _get(data, path)["zz_extra"] = 1
            out.append(_mutant(kind, f"{name}.zz_extra", _dump(data), f"{name}.zz_extra"))
    data = copy.deepcopy(base)
    data["zz_extra"] = 1
    out.append(_mutant(kind, "zz_extra", _dump(data), "zz_extra"))
    return out


def _required(kind: Kind, path: tuple) -> bool:
    return _pattern(path) in REQUIRED.get(kind.name, ()) or (len(path) == 1 and path[0] in REQUIRED.get(kind.name, ()))


def whole_file(kind: Kind) -> list[Mutant]:
    return [
        _mutant(kind, "empty", b"", None),
        _mutant(kind, "garbage", b"\x00\x01 not yaml {{{ ]]] \xff\n", None),
        _mutant(kind, "not a mapping", b"- just\n- a list\n", None),
        _mutant(kind, "unclosed bracket", kind.text.encode() + b"\nzz: {a: [1, 2\n", None),
        _mutant(kind, "a folder", None, None),
        _mutant(kind, "missing", b"", None, target_missing=True),
    ]


def semantic(kind: Kind, changes: list[tuple[str, object, str]]) -> list[Mutant]:
    """(dotted path, value, field the error must name); the path ``a.b[2].c`` is created as needed."""
    base = yaml.safe_load(kind.text)
    out = []
    for dotted, value, fld in changes:
        data = copy.deepcopy(base)
        path = tuple(int(p) if p.isdigit() else p for p in dotted.replace("[", ".").replace("]", "").split("."))
        if callable(value):
            value(data)
        else:
            _set(data, path, value)
        out.append(_mutant(kind, f"{dotted}={value.__name__ if callable(value) else value!r}"[:90], _dump(data), fld))
        out[-1].max_lines = 3  # a duplicated record can break two rules (id and place)
    return out


# ---- the kinds of file and the command that loads each

RUN = ["run", "--regime", "fbs", "--out", "r"]
TT_WITH_STOCK = "name: t\nline: felez_test\nservices:\n  - {id: T, train: stock.yaml, origin: ORIG, destination: STOP, departure: 0}\n"
TT_FELEZ = _read("routes/felez_test/test.yaml")
NET_TT = """name: through
line: italy_av_north
services:
  - {id: FR1, train: etr1000, origin: MIRO, destination: FISMN, departure: "06:00", stops: [{station: BOAV, dwell_s: 120}]}
  - {id: FR2, train: etr1000, origin: FISMN, destination: MIRO, departure: "06:10", stops: [{station: BOAV, dwell_s: 120}]}
"""

KINDS = {
    "line": Kind("line", "line.yaml", _read("networks/regional_graded/line.yaml"), ["build-network", "--line", "line.yaml"],
                 positive=("line_speed_kmh", "stations[].platform_length_m", "speed_limits[].speed_kmh", "signalling.block_length_m",
                           "branches[].length_m", "branches[].speed_kmh", "branches[].diverging_speed_kmh", "branches[].stations[].platform_length_m"),
                 signed=("km_start", "km_end", "start_elevation_m", "stations[].km", "speed_limits[].from_km", "speed_limits[].to_km",
                         "gradients[].from_km", "gradients[].to_km", "gradients[].permille", "headway.measuring_points_km[]",
                         "headway.release_km.up", "headway.release_km.down", "branches[].junction_km",
                         "branches[].gradients[].permille"),
                 skip=("notes", "title", "sources", "directions")),
    "line hcmc": Kind("line hcmc", "line.yaml", _read("networks/hcmc_line1/line.yaml"), ["build-network", "--line", "line.yaml"],
                      positive=("line_speed_kmh", "stations[].platform_length_m", "speed_limits[].speed_kmh", "signalling.block_length_m"),
                      signed=("km_start", "km_end", "start_elevation_m", "stations[].km", "speed_limits[].from_km", "speed_limits[].to_km",
                              "gradients[].from_km", "gradients[].to_km", "gradients[].permille", "tunnels[].from_km", "tunnels[].to_km",
                              "headway.measuring_points_km[]", "headway.release_km.up", "headway.release_km.down"),
                      skip=("notes", "title", "sources", "directions")),
    "network": Kind("network", "network.yaml", _read("networks/italy_av_north/network.yaml"), ["build-network", "--line", "network.yaml"],
                    support={"venezia_link.yaml": _read("networks/italy_av_north/venezia_link.yaml")},
                    signed=("lines[].from_km", "joins[].meets.km"), positive=("joins[].diverging_speed_kmh",),
                    skip=("notes", "title", "sources")),
    "stock": Kind("stock", "stock.yaml", _read("networks/rolling_stock/terlizzi2024_follower.yaml"),
                  RUN + ["--line", "felez_test", "--timetable", "tt.yaml"], support={"tt.yaml": TT_WITH_STOCK},
                  positive=("length_m", "mass_kg", "rotating_mass_factor", "max_speed_kmh", "max_traction_n", "max_power_w",
                            "service_brake_decel_mps2", "emergency_brake_decel_mps2", "uncertainty.mass_kg.low", "uncertainty.mass_kg.high",
                            "uncertainty.max_accel_mps2.low", "uncertainty.max_accel_mps2.high", "uncertainty.service_brake_decel_mps2.low",
                            "uncertainty.service_brake_decel_mps2.high", "uncertainty.max_power_w.low", "uncertainty.max_power_w.high"),
                  skip=("notes", "title", "sources")),
    "stock felez2019": Kind("stock felez2019", "stock.yaml", _read("networks/rolling_stock/felez2019.yaml"),
                            RUN + ["--line", "felez_test", "--timetable", "tt.yaml"], support={"tt.yaml": TT_WITH_STOCK},
                            positive=("length_m", "mass_kg", "rotating_mass_factor", "max_speed_kmh", "max_traction_n", "max_power_w",
                                      "service_brake_decel_mps2", "emergency_brake_decel_mps2", "max_brake_power_w", "max_jerk_mps3"),
                            skip=("notes", "title", "sources")),
    "timetable": Kind("timetable", "tt.yaml", _read("routes/regional_graded/all_stations.yaml"), RUN + ["--line", "regional_graded", "--timetable", "tt.yaml"],
                      positive=("services[].repeat.count", "services[].repeat.every_s"), skip=("description",)),
    "convoy": Kind("convoy", "tt.yaml", _read("routes/felez_test/convoy.yaml"),
                   ["run", "--regime", "vc", "--out", "r", "--line", "felez_test", "--timetable", "tt.yaml"],
                   positive=("services[].repeat.count", "services[].repeat.every_s"), skip=("description",)),
    "network timetable": Kind("network timetable", "tt.yaml", NET_TT, RUN + ["--line", "italy_av_north", "--timetable", "tt.yaml"]),
    "controller": Kind("controller", "ctrl.yaml", _read("controllers/cbc.yaml"),
                       ["run", "--regime", "vc", "--out", "r", "--line", "felez_test", "--timetable", "tt.yaml", "--controller", "cbc:ctrl.yaml"],
                       support={"tt.yaml": _read("routes/felez_test/convoy.yaml")},
                       positive=("k_pos_per_s2", "max_message_age_s")),
    "controller mpc": Kind("controller mpc", "ctrl.yaml", _read("controllers/mpc.yaml"),
                           ["run", "--regime", "vc", "--out", "r", "--line", "felez_test", "--timetable", "tt.yaml", "--controller", "mpc:ctrl.yaml"],
                           support={"tt.yaml": _read("routes/felez_test/convoy.yaml")},
                           positive=("step_s", "horizon_steps", "a_leader_mps2", "a_follower_mps2", "sqp_max_iterations", "dp.ds_min_m", "dp.ds_max_m",
                                     "dp.ds_time_s", "dp.dv_mps", "dp.n_controls"), skip=("notes",)),
    "channel": Kind("channel", "channel.yaml", _read("controllers/channel.yaml"),
                    ["run", "--regime", "vc", "--out", "r", "--line", "felez_test", "--timetable", "tt.yaml", "--channel", "channel.yaml"],
                    support={"tt.yaml": _read("routes/felez_test/convoy.yaml")}, positive=("period_s",)),
    "assumptions": Kind("assumptions", "a.yaml", _read("assumptions/etcs_typical.yaml"),
                        RUN + ["--line", "felez_test", "--timetable", "tt.yaml", "--assumptions", "a.yaml"],
                        support={"tt.yaml": TT_FELEZ},
                        skip=("notes", "title", "sources")),
    "experiment": Kind("experiment", "exp.yaml", _read("studies/experiments/felez2019_mb.yaml"), ["experiment", "exp.yaml", "--no-plots", "--out", "r"],
                       positive=("step_s", "duration_s", "record_every", "track.straight.length_m", "track.straight.speed_limit_mps",
                                 "trains[].horizon_steps", "leader.felez.horizon_steps", "leader.felez.stop_at_m"),
                       skip=("notes", "title", "sources", "why", "track.why", "variants")),
    "study capacity": Kind("study capacity", "s.yaml", _read("studies/capacity_hcmc_line1.yaml"), ["study", "run", "s.yaml", "--out", "r"],
                           positive=("convoy_sizes[]",), skip=("title",)),
    "study headway": Kind("study headway", "s.yaml", _read("studies/headway_firenze_bologna.yaml"), ["study", "run", "s.yaml", "--out", "r"],
                          skip=("title", "notes")),
    "study junction": Kind("study junction", "s.yaml", _read("studies/junction_milano_bologna.yaml"), ["study", "run", "s.yaml", "--out", "r"],
                           skip=("title", "notes")),
    "study safety": Kind("study safety", "s.yaml", _read("studies/safety.yaml"), ["study", "run", "s.yaml", "--out", "r"],
                         positive=("scenarios", "step_s", "control_period_s", "channel_period_s", "max_duration_s"), skip=("title", "notes")),
    "study tradeoff": Kind("study tradeoff", "s.yaml", _read("studies/tradeoff_firenze_bologna.yaml"), ["study", "run", "s.yaml", "--out", "r"],
                           positive=("convoy_sizes[]",), skip=("title", "notes")),
    "study batch": Kind("study batch", "s.yaml", "study: batch\nline: felez_test\ntimetables: tt.yaml\nregimes: [fbs, mb]\nseeds: 2\n",
                        ["study", "run", "s.yaml", "--out", "r"], support={"tt.yaml": TT_FELEZ}, positive=("seeds",)),
    "delays": Kind("delays", "d.yaml", "origin: {probability: 0.3, distribution: exponential, mean_s: 120, cap_s: 900}\n"
                   "dwell: {probability: 0.1, distribution: uniform, min_s: 10, max_s: 60}\n",
                   ["batch", "--line", "felez_test", "--timetables", "tt.yaml", "--regimes", "fbs", "--seeds", "1", "--delay-config", "d.yaml", "--out", "r"],
                   support={"tt.yaml": TT_FELEZ}, positive=("origin.mean_s", "origin.cap_s", "dwell.max_s")),
}

REQUIRED = {
    "line": ("name", "km_start", "km_end", "line_speed_kmh", "stations[].id", "stations[].name", "stations[].km", "stations[].platform_length_m",
             "speed_limits[].from_km", "speed_limits[].to_km", "speed_limits[].speed_kmh", "gradients[].from_km", "gradients[].to_km",
             "gradients[].permille", "branches[].id", "branches[].junction_km", "branches[].leaves_towards", "branches[].length_m",
             "branches[].speed_kmh", "branches[].diverging_speed_kmh"),
    "line hcmc": ("name", "km_start", "km_end", "line_speed_kmh", "stations[].id", "stations[].name", "stations[].km", "stations[].platform_length_m",
                  "speed_limits[].from_km", "speed_limits[].to_km", "speed_limits[].speed_kmh", "gradients[].from_km", "gradients[].to_km",
                  "gradients[].permille", "tunnels[].name", "tunnels[].from_km", "tunnels[].to_km"),
    "stock felez2019": ("name", "length_m", "mass_kg", "max_speed_kmh", "max_traction_n", "max_power_w", "davis_a_n", "davis_b_n_per_mps",
                        "davis_c_n_per_mps2", "service_brake_decel_mps2", "emergency_brake_decel_mps2"),
    "network": ("name", "lines", "lines[].line", "joins[].id", "joins[].end", "joins[].meets", "joins[].end.line", "joins[].end.at",
                "joins[].meets.line", "joins[].meets.km"),
    "stock": ("name", "length_m", "mass_kg", "max_speed_kmh", "max_traction_n", "max_power_w", "davis_a_n", "davis_b_n_per_mps",
              "davis_c_n_per_mps2", "service_brake_decel_mps2", "emergency_brake_decel_mps2", "uncertainty.mass_kg.low", "uncertainty.mass_kg.high"),
    "timetable": ("name", "services", "services[].id", "services[].train", "services[].origin", "services[].destination", "services[].departure",
                  "services[].stops[].station"),
    "convoy": ("name", "services", "services[].id", "services[].train", "services[].origin", "services[].destination", "services[].departure",
               "convoys[].id", "convoys[].services"),
    "network timetable": ("name", "services", "services[].id", "services[].train", "services[].origin", "services[].destination",
                          "services[].departure", "services[].stops[].station"),
    "experiment": ("name", "trains", "trains[].id", "trains[].stock", "track"),
    "study capacity": ("study", "line"),
    "study headway": ("study", "line"),
    "study junction": ("study", "line"),
    "study safety": ("study",),
    "study tradeoff": ("study", "line"),
    "study batch": ("study", "line"),
}


def _dup(key: str):
    def f(data):
        data[key].append(copy.deepcopy(data[key][0]))
    f.__name__ = f"duplicate {key}[0]"
    return f


def _dup_branch(data):
    data["branches"].append(dict(copy.deepcopy(data["branches"][0]), junction_km=30.0, stations=[]))


SEMANTIC = {
    "line": [
        ("gradients[0].permille", 200.0, "gradients[0].permille"),
        ("line_speed_kmh", 0, "line_speed_kmh"),
        ("stations[1].dwell_s", -5, "stations[1].dwell_s"),
        ("stations[1].km", 400.0, "stations[1].km"),
        ("stations[1].km", -3.0, "stations[1].km"),
        ("km_end", -10.0, "km_end"),
        ("km_end", 0.0, "km_end"),
        ("speed_limits[1].to_km", 14.0, "speed_limits[1]"),
        ("speed_limits[2].to_km", 90.0, "speed_limits[2]"),
        ("gradients[1].from_km", 2.0, "gradients[1]"),
        ("stations", _dup("stations"), "stations[7].id"),
        ("branches", _dup_branch, "branches[1].id"),
        ("stations[1].id", "bad id!", "stations[1].id"),
        ("stations[1].platform_length_m", 1e9, "stations[1].platform_length_m"),
        ("headway.measuring_points_km", [100.0], "headway.measuring_points_km[0]"),
        ("branches[0].junction_km", 80.0, "branches[0].junction_km"),
        ("branches[0].leaves_towards", "sideways", "branches[0].leaves_towards"),
        ("branches[0].stations[0].km", 50.0, "branches[0].stations[0].km"),
        ("signalling.block_length_m", 10.0, "signalling.block_length_m"),
        ("default_train", "maglev", "default_train"),
        ("tracks", "triple", "tracks"),
    ],
    "network": [
        ("lines[0].line", "atlantis", "lines[0].line"),
        ("lines[2].line", "nowhere.yaml", "lines[2].line"),
        ("lines[0].from_km", 900.0, "lines[0].from_km"),
        ("joins[0].meets.km", 900.0, "joins[0].meets.km"),
        ("joins[0].meets.line", "atlantis", "joins[0].meets.line"),
        ("joins[0].end.at", "middle", "joins[0].end.at"),
        ("joins", _dup("joins"), "joins[2].id"),
        ("lines[0].branches", ["atlantis"], "lines[0].branches[0]"),
        ("default_train", "maglev", "default_train"),
        ("joins[1].diverging_speed_kmh", 0, "joins[1].diverging_speed_kmh"),
    ],
    "stock": [
        ("mass_kg", 0, "mass_kg"),
        ("length_m", 0, "length_m"),
        ("length_m", 20000.0, "length_m"),
        ("max_speed_kmh", 0, "max_speed_kmh"),
        ("service_brake_decel_mps2", 30.0, "service_brake_decel_mps2"),
        ("emergency_brake_decel_mps2", 0.3, "emergency_brake_decel_mps2"),
        ("uncertainty.mass_kg.low", 600000.0, "uncertainty.mass_kg"),
        ("traction_lag_s", -1.0, "traction_lag_s"),
        ("max_speed_kmh", 5000.0, "max_speed_kmh"),
        ("rotating_mass_factor", 0.5, "rotating_mass_factor"),
        ("max_jerk_mps3", 0, "max_jerk_mps3"),
    ],
    "timetable": [
        ("services[0].stops[0].dwell_s", -5, "services[0].stops[0].dwell_s"),
        ("services[0].stops[0].station", "ATLANTIS", "services[0].stops[0].station"),
        ("services[0].origin", "ATLANTIS", "services[0].origin"),
        ("services[0].destination", "ALD", "services[0].destination"),
        ("services[0].train", "maglev", "services[0].train"),
        ("services[0].departure", "25:61", "services[0].departure"),
        ("services[0].departure", "06:61", "services[0].departure"),
        ("services[0].arrival", "05:00", "services[0].arrival"),
        ("services[0].stops[0].arrival", "07:00", "services[0].stops[0].arrival"),
        ("services[0].stops[0].departure", "05:59", "services[0].stops[0].departure"),
        ("services[0].repeat.count", 0, "services[0].repeat.count"),
        ("services[0].repeat", {"count": 2, "every_s": 900, "until": "07:00"}, "services[0].repeat"),
        ("services[0].repeat.until", "05:00", "services[0].repeat.until"),
        ("services", _dup("services"), "services[4].id"),
        ("services[0].id", "../evil", "services[0].id"),
        ("line", "felez_test", "line"),
        ("services[2].destination", "branch:atlantis", "services[2].destination"),
        ("services[0].departure", "-00:05", "services[0].departure"),
        ("services[0].departure", "6 o'clock", "services[0].departure"),
        ("services[0].train", "nowhere.yaml", "services[0].train"),
        ("services[0].via", ["ATLANTIS"], "services[0].via[0]"),
        ("services[0].repeat.every_s", 1e9, "services[0].repeat.every_s"),
    ],
    "convoy": [
        ("convoys[0].services", ["UL", "GHOST"], "convoys[0].services[1]"),
        ("convoys[0].services", ["UL"], "convoys[0].services"),
        ("convoys[0].services", ["UL", "UL"], "convoys[0].services"),
        ("convoys[0].services", ["UL", "DF"], "convoys[0].services"),
        ("convoys[1].services", ["UL", "UF"], "convoys[1].services"),
        ("convoys[1].id", "CU", "convoys[1].id"),
        ("services[1].repeat.count", 2, "convoys[0]"),
    ],
    "network timetable": [
        ("services[0].stops[0].station", "ATLANTIS", "services[0].stops[0].station"),
        ("services[0].origin", "BOLOGNA", "services[0].origin"),
        ("services[0].destination", "MIRO", "services[0].destination"),
        ("services[0].departure", "25:61", "services[0].departure"),
        ("services[0].stops[0].dwell_s", -5, "services[0].stops[0].dwell_s"),
        ("services[0].arrival", "05:00", "services[0].arrival"),
        ("services", _dup("services"), "services[2].id"),
        ("line", "firenze_bologna", "line"),
    ],
    "controller": [
        ("law", "warp", "law"),
        ("topology", "XYZ", "topology"),
        ("gap.headway_s", -1.5, "gap.headway_s"),
        ("delay_compensation", "sometimes", "delay_compensation"),
    ],
    "channel": [
        ("model", "telepathy", "model"),
        ("loss_probability", 1.5, "loss_probability"),
    ],
    "assumptions": [
        ("braking_uncertainty", 1.5, "braking_uncertainty"),
        ("absolute_braking", "prayer", "absolute_braking"),
        ("relative_braking", "prayer", "relative_braking"),
    ],
    "experiment": [
        ("trains[1].controller", "warp", "trains[1].controller"),
        ("trains[1].stock", "maglev", "trains[1].stock"),
        ("trains[1].params", "no_such_params", "trains[1].params"),
        ("trains[0].position_m", 9000.0, "trains[0].position_m"),
        ("trains[1].overrides.predictor", "XX", "trains[1].overrides.predictor"),
        ("trains", _dup("trains"), "trains[2].id"),
        ("leader.driver", "warp", "leader.driver"),
        ("leader.felez.stop_at_m", 100.0, "leader.felez.stop_at_m"),
        ("step_s", 0, "step_s"),
        ("seeds", [-1], "seeds[0]"),
        ("track.straight.length_m", 50.0, "track.straight"),
        ("variants[0].set", {"trains.9.gap_m": 1.0}, "variants[0].set"),
    ],
    "study capacity": [
        ("controllers", ["warp"], "controllers[0]"),
        ("line", "atlantis", "line"),
        ("train", "maglev", "train"),
        ("convoy_sizes", [1, 0], "convoy_sizes[1]"),
        ("directions", ["sideways"], "directions[0]"),
        ("study", "warp", "study"),
        ("block_length_m", 0, "block_length_m"),
        ("step_length_s", 0, "step_length_s"),
        ("vc_step_length_s", -0.2, "vc_step_length_s"),
        ("fixed_time_s", -1, "fixed_time_s"),
        ("workers", 0, "workers"),
        ("assumptions", "nowhere.yaml", "assumptions"),
        ("train", "nowhere.yaml", "train"),
        ("out", "../elsewhere", "out"),
        ("seed", "x", "seed"),
    ],
    "study headway": [
        ("line", "atlantis", "line"),
        ("regime", "vc", "regime"),
        ("points_km", [900.0], "points_km[0]"),
    ],
    "study junction": [
        ("junction", "atlantis", "junction"),
        ("controllers", ["warp"], "controllers[0]"),
    ],
    "study safety": [
        ("controllers", ["warp"], "controllers[0]"),
        ("lines", ["atlantis"], "lines[0]"),
        ("kinds", ["warp"], "kinds[0]"),
        ("rolling_stock", ["maglev"], "rolling_stock[0]"),
        ("loss_max", 1.5, "loss_max"),
        ("loop", "warp", "loop"),
    ],
    "study tradeoff": [
        ("convoy_sizes", [1], "convoy_sizes[0]"),
        ("uncertainties", [1.5], "uncertainties[0]"),
        ("train", "maglev", "train"),
    ],
    "study batch": [
        ("regimes", ["warp"], "regimes[0]"),
        ("timetables", "nowhere.yaml", "timetables"),
        ("line", "atlantis", "line"),
        ("delay_config", "nowhere.yaml", "delay_config"),
        ("first_seed", -1, "first_seed"),
        ("window_s", 0, "window_s"),
        ("step_length_s", 5, "step_length_s"),
        ("controllers", ["cbc"], "controllers"),
        ("timetables", "*.nothing", "timetables"),
    ],
    "delays": [
        ("origin.probability", 1.5, "origin.probability"),
        ("origin.distribution", "warp", "origin.distribution"),
        ("dwell.min_s", 100, "dwell"),
    ],
}


def all_mutants() -> list[Mutant]:
    out: list[Mutant] = []
    for name, kind in KINDS.items():
        out += sweep(kind) + semantic(kind, SEMANTIC.get(name, [])) + whole_file(kind)
    seen: set = set()
    unique = []
    for m in out:  # the same file twice (a semantic mutant the sweep made already): once
        key = (tuple(m.argv), tuple(sorted((k, v) for k, v in m.files.items() if v is not None)), tuple(k for k, v in m.files.items() if v is None))
        if key not in seen:
            seen.add(key)
            unique.append(m)
    out, count = unique, {}
    for m in out:  # the same label twice (a list and its item): numbered
        count[m.id] = count.get(m.id, 0) + 1
        if count[m.id] > 1:
            m.id += f"#{count[m.id]}"
    return out


MUTANTS = all_mutants()

# -------------------------------------------------------------------------------------------
# The driver: one process imports the CLI, forks one child per mutant


DRIVER = textwrap.dedent(r"""
    import json, os, signal, sys, time
    jobs = json.load(open(sys.argv[1]))
    PARALLEL = 2
    import vcsumo.cli.main as cli
    # every module the commands import on first use (matplotlib, CasADi, libsumo), loaded once before forking
    import importlib, pkgutil, vcsumo
    for mod in pkgutil.walk_packages(vcsumo.__path__, "vcsumo."):
        if not mod.name.endswith("__main__"):
            importlib.import_module(mod.name)
    from vcsumo.line import load_line
    from vcsumo.network_file import load_line_or_network
    from vcsumo.sim.network import build_network
    for name in ("felez_test", "regional_graded", "italy_av_north"):  # the shipped networks the mutants run on
        build_network(load_line_or_network(name), None)
    def start(job):
        pid = os.fork()
        if pid == 0:
            try:
                os.chdir(job["dir"])
                fo = os.open("stdout.txt", os.O_WRONLY | os.O_CREAT, 0o644)
                fe = os.open("stderr.txt", os.O_WRONLY | os.O_CREAT, 0o644)
                os.dup2(fo, 1); os.dup2(fe, 2)
                rc = cli.main(job["argv"])
            except SystemExit as e:
                rc = e.code if isinstance(e.code, int) else 1
            except BaseException:
                import traceback; traceback.print_exc(); rc = 99
            sys.stdout.flush(); sys.stderr.flush()
            os._exit(rc)
        return pid

    results, running, todo = {}, {}, list(jobs)
    while todo or running:
        while todo and len(running) < PARALLEL:
            job = todo.pop(0)
            running[start(job)] = (job, time.monotonic())
        for pid, (job, t0) in list(running.items()):
            done, st = os.waitpid(pid, os.WNOHANG)
            if done:
                status = os.waitstatus_to_exitcode(st)
            elif time.monotonic() - t0 > job["timeout_s"]:
                os.kill(pid, signal.SIGKILL); os.waitpid(pid, 0); status = "timeout"
            else:
                continue
            del running[pid]
            results[job["id"]] = {"rc": status, "seconds": time.monotonic() - t0}
        time.sleep(0.002)
    json.dump(results, open(sys.argv[2], "w"))
""")

TIMEOUT_S = 30.0


def _materialise(m: Mutant, d: Path) -> None:
    d.mkdir(parents=True)
    for rel, raw in m.files.items():
        p = d / rel
        if raw is None:
            p.mkdir()
        else:
            p.write_bytes(raw)


def _listing(d: Path) -> set[str]:
    return {str(p.relative_to(d)) for p in d.rglob("*")}


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    """Run every mutant once; id -> (exit status, stdout, stderr, files created in its folder)."""
    root = tmp_path_factory.mktemp("contract")
    jobs, before = [], {}
    for i, m in enumerate(MUTANTS):
        d = root / f"m{i:04d}"
        _materialise(m, d)
        before[m.id] = _listing(d)
        jobs.append({"id": m.id, "dir": str(d), "argv": m.argv, "timeout_s": TIMEOUT_S})
    (root / "jobs.json").write_text(json.dumps(jobs))
    proc = subprocess.run([sys.executable, "-c", DRIVER, str(root / "jobs.json"), str(root / "results.json")], capture_output=True, text=True,
                          timeout=TIMEOUT_S * len(jobs) + 600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rcs = json.loads((root / "results.json").read_text())
    out = {}
    for i, m in enumerate(MUTANTS):
        d = root / f"m{i:04d}"
        created = _listing(d) - before[m.id] - {"stdout.txt", "stderr.txt"}
        out[m.id] = (rcs[m.id]["rc"], (d / "stdout.txt").read_text(errors="replace"), (d / "stderr.txt").read_text(errors="replace"), created)
    return out


def assert_contract(m: Mutant, rc, stdout: str, stderr: str, created: set[str]) -> None:
    assert rc == 2, f"exit status {rc}\nstdout: {stdout[-800:]}\nstderr: {stderr[-1500:]}"
    assert "Traceback" not in stdout + stderr, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert lines, "nothing on stderr"
    last = lines[-1]
    assert all(ln.startswith("error: ") for ln in lines), stderr  # one line per problem, nothing else
    assert len(lines) <= m.max_lines, f"{len(lines)} lines for at most {m.max_lines} problems: {stderr}"
    assert Path(m.target).name in last, f"the error does not name {m.target}: {last}"
    if m.field is not None:  # the field, or the record holding it (a range, an interval, a service's times)
        parent = re.sub(r"(\.[^.\[\]]+|\[\d+\])$", "", m.field)
        assert m.field in last or (parent and f": {parent}:" in last), f"the error does not name the field {m.field}: {last}"
    assert not created, f"left behind: {sorted(created)}"


@pytest.mark.parametrize("m", MUTANTS, ids=[m.id for m in MUTANTS])
def test_bad_input_is_one_line_exit_2_nothing_written(outcomes, m):
    assert_contract(m, *outcomes[m.id])


# -------------------------------------------------------------------------------------------
# The console script and ``python -m vcsumo`` give what the driver's children gave


AGREE = ["line:gradients[0].permille=200.0", "stock:mass_kg=-5", "timetable:services[0].departure='25:61'", "experiment:a folder",
         "study safety:controllers=['warp']", "delays:missing"]


@pytest.mark.parametrize("how", ["console script", "python -m vcsumo"])
def test_console_script_agrees_with_the_driver(outcomes, tmp_path, how):
    exe = [str(Path(sys.executable).parent / "vcsumo")] if how == "console script" else [sys.executable, "-m", "vcsumo"]
    picked = AGREE[::2] if how == "console script" else AGREE[1::2]
    for mid in picked:
        m = next(x for x in MUTANTS if x.id == mid)
        d = tmp_path / f"m{MUTANTS.index(m):04d}"
        _materialise(m, d)
        before = _listing(d)
        proc = subprocess.run(exe + m.argv, cwd=d, capture_output=True, text=True, timeout=120)
        assert_contract(m, proc.returncode, proc.stdout, proc.stderr, _listing(d) - before)
        rc, _, err, _ = outcomes[mid]
        assert proc.returncode == rc
        assert _last(proc.stderr, d) == _last(err, None), (proc.stderr, err)


def _last(stderr: str, d: Path | None) -> str:
    """The last error line with the mutant's folder left out (``/tmp/.../m0012/line.yaml`` -> ``line.yaml``)."""
    last = [ln for ln in stderr.splitlines() if ln.strip()][-1]
    return re.sub(r"(?<=[ ':])/\S*/m?\d+/", "", last)


# -------------------------------------------------------------------------------------------
# Ctrl-C in the middle of a run: exit 130, no results folder, no partial folder


LONG_TT = "name: long\nline: felez_test\nservices:\n  - {id: T, train: felez2019, origin: ORIG, destination: STOP, departure: 0, repeat: {count: 300, every_s: 60}}\n"
"""300 trains a minute apart at 0.05 s steps (~20 s of CPU), interrupted while SUMO runs."""


@pytest.mark.parametrize("argv", [["run", "--line", "felez_test", "--timetable", "long.yaml", "--regime", "mb", "--step-length", "0.05", "--out", "r"],
                                  ["experiment", "felez2019_mb", "--no-plots", "--seeds", ",".join(str(k) for k in range(1, 31)), "--out", "r"]],
                         ids=["run", "experiment"])
def test_ctrl_c_mid_run_leaves_nothing(tmp_path, argv):
    import signal
    import time

    (tmp_path / "long.yaml").write_text(LONG_TT)
    # SIGINT as a terminal gives it: a shell running the tests in the background (`.ci/run &`) makes
    # its children ignore SIGINT, and Python then installs no KeyboardInterrupt handler
    proc = subprocess.Popen([str(Path(sys.executable).parent / "vcsumo"), *argv], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob("r.partial-*")):  # the command is writing its results
            assert proc.poll() is None and time.monotonic() < deadline, "the command ended before it wrote anything"
            time.sleep(0.02)
        time.sleep(0.5)
        assert proc.poll() is None, "the command ended before it was interrupted"
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in out + err and [ln for ln in err.splitlines() if ln.strip()][-1].strip() == "interrupted"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["long.yaml"], "left behind"
