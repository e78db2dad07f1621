"""Tier 1 — hostile and broken inputs (issue 5 part 3).

Every kind of input file — line, timetable, train type, controller parameters, channel, guard,
study, delay configuration — is mutated from a valid shipped file (a key dropped, an unknown key,
a wrong type, NaN/inf, negative, zero, 1e12, strings for numbers, truncation, spliced bytes) and
loaded through the loader the CLI uses.  It either loads or raises a VcsumoError that names the
file (and the field, for a field problem); nothing else may escape.  Whole-file attacks (empty
file, a list instead of a mapping, ``!!python/...`` tags, duplicate keys, invalid UTF-8, binary,
alias bombs) and absurd values (1,000 km blocks, 0 m trains, negative dwell, 50 m/s² brakes,
10,000 km/h) are refused with one clear message.  Names taken from file contents cannot place
results outside the chosen results folder.

tests/test_line_files.py fuzzes single values of a small line file; this module covers the other
file kinds and the whole-file attacks.
"""

from __future__ import annotations

import copy
import math
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vcsumo.errors import InputError, VcsumoError

from .conftest import DATA, ROOT, write

# -------------------------------------------------------------------------------------------
# The loaders the CLI uses, per file kind (path -> loaded object; raises VcsumoError)


def _load_line(p: Path):
    from vcsumo.line import load_line

    return load_line(p)


def _load_stock(p: Path):
    from vcsumo.rolling_stock import load_rolling_stock

    st_ = load_rolling_stock(p)
    x = st_.vtype_xml(1.5)  # what SUMO gets: every number finite
    assert "nan" not in x and "inf" not in x
    prm = st_.params()
    assert all(math.isfinite(v) for v in (prm.mass_kg, prm.length_m, prm.max_speed_ms, prm.max_traction_n, prm.max_power_w))
    return st_


def _load_cbc(p: Path):
    from vcsumo.control.consensus import load_cbc_params

    return load_cbc_params(p)


def _load_mpc(p: Path):
    from vcsumo.control.mpc import load_mpc_settings

    return load_mpc_settings(p)


def _load_cbf(p: Path):
    from vcsumo.control.cbf import load_cbf_config

    return load_cbf_config(p)


def _load_cruise(p: Path):
    from vcsumo.control.cruise import load_cruise_config

    return load_cruise_config(p)


def _load_channel(p: Path):
    from vcsumo.sim.vc_driver import load_channel

    return load_channel(p)


def _load_guard(p: Path):
    from vcsumo.control.guard import load_guard

    return load_guard(p)


def _load_study(p: Path):
    from vcsumo.cli.study_files import load_study

    return load_study(p)


def _load_delays(p: Path):
    from vcsumo.delays import load_delay_config

    return load_delay_config(p)


DELAYS = """description: hostile-input base
origin: {probability: 0.3, distribution: exponential, mean_s: 120, cap_s: 900}
dwell: {probability: 0.1, distribution: uniform, min_s: 10, max_s: 60}
"""

# (kind, text of a valid file, loader)
FILES = {
    "line felez_test": ((DATA / "networks" / "felez_test" / "line.yaml").read_text(), _load_line),
    "line hcmc_line1": ((DATA / "networks" / "hcmc_line1" / "line.yaml").read_text(), _load_line),
    "train etr1000": ((DATA / "networks" / "rolling_stock" / "etr1000.yaml").read_text(), _load_stock),
    "train terlizzi2024_follower": ((DATA / "networks" / "rolling_stock" / "terlizzi2024_follower.yaml").read_text(), _load_stock),
    "controller cbc": ((DATA / "controllers" / "cbc.yaml").read_text(), _load_cbc),
    "controller cbc_liu": ((DATA / "controllers" / "cbc_liu.yaml").read_text(), _load_cbc),
    "controller mpc": ((DATA / "controllers" / "mpc.yaml").read_text(), _load_mpc),
    "controller cbf": ((DATA / "controllers" / "cbf.yaml").read_text(), _load_cbf),
    "controller cruise": ((DATA / "controllers" / "cruise_terlizzi2024.yaml").read_text(), _load_cruise),
    "channel": ((DATA / "controllers" / "channel.yaml").read_text(), _load_channel),
    "guard": ((DATA / "controllers" / "guard.yaml").read_text(), _load_guard),
    "study capacity": ((DATA / "studies" / "capacity_firenze_bologna.yaml").read_text(), _load_study),
    "study junction": ((DATA / "studies" / "junction_milano_bologna.yaml").read_text(), _load_study),
    "study batch": ((DATA / "studies" / "batch_firenze_bologna.yaml").read_text(), _load_study),
    "study headway": ((DATA / "studies" / "headway_firenze_bologna.yaml").read_text(), _load_study),
    "delays": (DELAYS, _load_delays),
}
TIMETABLES = {
    "timetable hcmc_line1/base": ("hcmc_line1", (DATA / "routes" / "hcmc_line1" / "base.yaml").read_text()),
    "timetable felez_test/convoy": ("felez_test", (DATA / "routes" / "felez_test" / "convoy.yaml").read_text()),
}


@pytest.fixture(scope="module")
def load_timetable_on(line_factory, network_factory):
    """Timetable loader of ``vcsumo run``: load, check against the line, plan every train, form convoys."""
    from vcsumo.timetable import load_timetable, plan_trains
    from vcsumo.sim.vc_driver import convoys_from_timetable

    def load(line_name: str, p: Path):
        line = line_factory(line_name)
        tt, path = load_timetable(p, line)
        trains = plan_trains(tt, path, line, network_factory(line_name).topology)
        if tt.convoys:
            convoys_from_timetable(tt, path, trains)
        return trains

    return load


def test_every_base_file_loads(tmp_path, load_timetable_on):
    """The fuzzing starts from valid files: each loads as it is."""
    for i, (kind, (text, loader)) in enumerate(FILES.items()):
        loader(write(tmp_path / str(i) / "f.yaml", text))
    for i, (kind, (line, text)) in enumerate(TIMETABLES.items()):
        assert load_timetable_on(line, write(tmp_path / f"t{i}" / "f.yaml", text))


# -------------------------------------------------------------------------------------------
# Mutations


HOSTILE = st.one_of(
    st.sampled_from([0, -1, -1e12, 1e12, 1e300, -0.0, float("nan"), float("inf"), float("-inf"), "", "1e3", "12", "abc", None, True, False,
                     [], {}, [1, 2], {"a": 1}, "../../evil", "x" * 500, "2024-01-01", "00:00", "-00:05", "99:99"]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**20), max_value=10**20),
    st.text(max_size=12),
)


def _paths(node, prefix=()):
    """Every key/index path into a loaded YAML tree (not the root)."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield prefix + (i,)
            yield from _paths(v, prefix + (i,))


def _parent(data, path):
    node = data
    for p in path[:-1]:
        node = node[p]
    return node


@st.composite
def mutated(draw, text: str) -> tuple[bytes, str, tuple | None]:
    """(file bytes, operation, mutated path or None) from a valid YAML ``text``."""
    base = yaml.safe_load(text)
    paths = sorted(_paths(base), key=repr)
    op = draw(st.sampled_from(["replace", "replace", "replace", "drop", "unknown", "truncate", "splice"]))
    if op == "truncate":
        raw = text.encode()
        return raw[: draw(st.integers(0, len(raw)))], op, None
    if op == "splice":
        raw = text.encode()
        at = draw(st.integers(0, len(raw)))
        return raw[:at] + draw(st.binary(min_size=1, max_size=8)) + raw[at:], op, None
    data = copy.deepcopy(base)
    path = draw(st.sampled_from(paths))
    parent = _parent(data, path)
    if op == "replace":
        parent[path[-1]] = draw(HOSTILE)
    elif op == "drop":
        del parent[path[-1]]
    else:  # an unknown key in a mapping (the root or any nested one)
        target = draw(st.sampled_from([()] + [q for q in paths if isinstance(_get(base, q), dict)]))
        _get(data, target)["zz_bogus_key"] = "x"
        path = target + ("zz_bogus_key",)
    return yaml.safe_dump(data, allow_unicode=True).encode(), op, path


def _get(data, path):
    for p in path:
        data = data[p]
    return data


def _check(load, f: Path, op: str, path: tuple | None) -> None:
    """Either it loads, or one VcsumoError naming the file (and the field) — nothing else."""
    try:
        load(f)
    except VcsumoError as exc:
        msg = str(exc)
        assert str(f) in msg, msg
        assert "\n" not in msg, msg
        if op == "unknown":  # free-form mappings (sources) take any key; elsewhere the key is named
            assert "zz_bogus_key" in msg, msg
        elif op in ("replace", "drop") and isinstance(exc, InputError):
            # a value problem names a field: the message holds a field path or the key's name
            key = str(path[-1]) if not isinstance(path[-1], int) else ""
            assert exc.field or (key and key in msg), msg


FUZZ = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.mark.parametrize("kind", sorted(FILES))
@FUZZ
@given(data=st.data())
def test_fuzzed_files_load_or_name_the_file(tmp_path_factory, data, kind):
    text, loader = FILES[kind]
    raw, op, path = data.draw(mutated(text), label="mutation")
    f = tmp_path_factory.mktemp("fz") / "input.yaml"
    f.write_bytes(raw)
    _check(loader, f, op, path)


@pytest.mark.parametrize("kind", sorted(TIMETABLES))
@FUZZ
@given(data=st.data())
def test_fuzzed_timetables_load_or_name_the_file(tmp_path_factory, load_timetable_on, data, kind):
    line, text = TIMETABLES[kind]
    raw, op, path = data.draw(mutated(text), label="mutation")
    f = tmp_path_factory.mktemp("fz") / "timetable.yaml"
    f.write_bytes(raw)
    _check(lambda p: load_timetable_on(line, p), f, op, path)


# -------------------------------------------------------------------------------------------
# Whole-file attacks, every kind


def _first_line_with_key(text: str) -> str:
    return next(ln for ln in text.splitlines() if ln and not ln.startswith(("#", " ", "-")) and ":" in ln)


WHOLE_FILE = {
    "empty": lambda t: b"",
    "only a comment": lambda t: b"# nothing here\n",
    "document marker only": lambda t: b"---\n",
    "a list": lambda t: b"- 1\n- 2\n",
    "a string": lambda t: b"just some words\n",
    "a number": lambda t: b"42\n",
    "python tag (os.system)": lambda t: b'!!python/object/apply:os.system ["echo pwned > pwned.txt"]\n',
    "python tag in a value": lambda t: (t + '\nzz: !!python/object/apply:os.system ["echo pwned > pwned.txt"]\n').encode(),
    "python name tag": lambda t: (t + "\nzz: !!python/name:os.system\n").encode(),
    "custom tag": lambda t: (t + "\nzz: !custom 1\n").encode(),
    "duplicate key": lambda t: (t + "\n" + _first_line_with_key(t) + "\n").encode(),
    "invalid UTF-8": lambda t: t.encode() + b"\nzz: \xff\xfe\n",
    "latin-1 text": lambda t: (t + "\n# café\n").encode("latin-1", "replace").replace(b"caf?", b"caf\xe9"),
    "binary (PNG header)": lambda t: b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR",
    "NUL byte": lambda t: t.encode() + b"\n\x00\n",
    "tabs": lambda t: b"a:\n\tb: 1\n",
    "unterminated flow": lambda t: b"a: {b: 1\n",
    "undefined alias": lambda t: b"a: *nowhere\n",
    "alias bomb": lambda t: ("a: &a [" + ",".join(["x"] * 10) + "]\n" + "".join(
        f"{n}: &{n} [" + ",".join([f"*{p}"] * 10) + "]\n" for p, n in zip("abcdef", "bcdefg"))).encode(),
    "deep nesting": lambda t: b"a: " + b"[" * 3000 + b"]" * 3000 + b"\n",
}


@pytest.mark.parametrize("attack", sorted(WHOLE_FILE))
def test_whole_file_attacks_are_one_clear_error(tmp_path, monkeypatch, attack, load_timetable_on):
    monkeypatch.chdir(tmp_path)
    kinds = [(k, text, loader) for k, (text, loader) in FILES.items()]
    kinds += [(k, text, lambda p, line=line: load_timetable_on(line, p)) for k, (line, text) in TIMETABLES.items()]
    for i, (kind, text, loader) in enumerate(kinds):
        f = tmp_path / str(i) / "input.yaml"
        f.parent.mkdir()
        f.write_bytes(WHOLE_FILE[attack](text))
        with pytest.raises(VcsumoError) as exc:
            loader(f)
        msg = str(exc.value)
        assert str(f) in msg and "\n" not in msg, (kind, msg)
        if "python" in attack or "custom" in attack:
            assert "is not allowed" in msg, (kind, msg)
        if attack == "duplicate key":
            assert "duplicate key" in msg and "line " in msg, (kind, msg)
        if attack in ("empty", "only a comment", "document marker only"):
            assert "empty" in msg, (kind, msg)
    assert not (tmp_path / "pwned.txt").exists()


def test_yaml_merge_keys_still_work(tmp_path):
    """Anchors and '<<' merges are plain YAML: an explicit key may override a merged one."""
    from vcsumo.config import read_yaml

    f = write(tmp_path / "m.yaml", "base: &b {a: 1, b: 2}\nx: {<<: *b, a: 5}\n")
    assert read_yaml(f) == {"base": {"a": 1, "b": 2}, "x": {"a": 5, "b": 2}}


def test_every_yaml_read_is_safe():
    """No unsafe YAML loading anywhere in the package: one reader, a SafeLoader subclass."""
    import vcsumo.config as config

    loader = config._StrictSafeLoader
    assert issubclass(loader, yaml.constructor.SafeConstructor)  # SafeLoader or libyaml's CSafeLoader
    assert not issubclass(loader, (yaml.constructor.FullConstructor, yaml.constructor.UnsafeConstructor))
    offenders = []
    for f in sorted((ROOT / "vcsumo").rglob("*.py")):
        for n, line in enumerate(f.read_text().splitlines(), 1):
            code = line.split("#")[0]
            if any(bad in code for bad in ("yaml.unsafe_load", "yaml.full_load", "yaml.Loader", "FullLoader", "UnsafeLoader", "yaml.load_all")):
                offenders.append(f"{f.relative_to(ROOT)}:{n}")
            if "yaml.load(" in code and "Loader=_StrictSafeLoader" not in code:
                offenders.append(f"{f.relative_to(ROOT)}:{n}")
    assert not offenders


def test_python_tag_does_not_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    f = write(tmp_path / "line.yaml", '!!python/object/apply:os.system ["touch pwned"]\n')
    with pytest.raises(InputError) as exc:
        _load_line(f)
    assert "!!python/object/apply:os.system" in str(exc.value) and "line 1" in str(exc.value)
    assert not (tmp_path / "pwned").exists()


# -------------------------------------------------------------------------------------------
# Absurd values: rejected with one message naming the file and the field


def _set(data, dotted: str, value):
    keys = [int(k) if k.isdigit() else k for k in dotted.replace("[", ".").replace("]", "").split(".")]
    node = data
    for k in keys[:-1]:
        node = node[k]
    node[keys[-1]] = value


ABSURD = [
    # (kind, dotted path, value, field named, words)
    ("line felez_test", "signalling.block_length_m", 1e6, "signalling.block_length_m", "less than or equal to 50000"),
    ("line felez_test", "line_speed_kmh", 0, "line_speed_kmh", "greater than or equal to 5"),
    ("line felez_test", "line_speed_kmh", 10000, "line_speed_kmh", "less than or equal to 600"),
    ("line felez_test", "stations[1].km", 50.0, "stations[1].km", "beyond the section"),
    ("line felez_test", "stations[0].dwell_s", -30, "stations[0].dwell_s", "greater than or equal to 0"),
    ("line felez_test", "km_end", 1e12, "km_end", "less than or equal to 100000"),
    ("line felez_test", "km_end", float("nan"), "km_end", "finite number"),
    ("line hcmc_line1", "signalling.block_length_m", 0, "signalling.block_length_m", "greater than or equal to 100"),
    ("train etr1000", "length_m", 0, "length_m", "greater than or equal to 10"),
    ("train etr1000", "length_m", 1e12, "length_m", "less than or equal to 1500"),
    ("train etr1000", "mass_kg", 0, "mass_kg", "greater than 0"),
    ("train etr1000", "mass_kg", -500000, "mass_kg", "greater than 0"),
    ("train etr1000", "mass_kg", 1e12, "mass_kg", "less than or equal to 5"),
    ("train etr1000", "service_brake_decel_mps2", 0, "service_brake_decel_mps2", "greater than 0"),
    ("train etr1000", "service_brake_decel_mps2", 50, "service_brake_decel_mps2", "less than or equal to 3"),
    ("train etr1000", "emergency_brake_decel_mps2", 50, "emergency_brake_decel_mps2", "less than or equal to 5"),
    ("train etr1000", "max_speed_kmh", 0, "max_speed_kmh", "greater than or equal to 10"),
    ("train etr1000", "max_speed_kmh", 10000, "max_speed_kmh", "less than or equal to 600"),
    ("train etr1000", "max_power_w", float("inf"), "max_power_w", "finite number"),
    ("train etr1000", "max_speed_kmh", "fast", "max_speed_kmh", "valid number"),
    ("train etr1000", "max_traction_n", 5e6, "max_traction_n", "max_traction_n / mass_kg = 10 m/s² exceeds 3 m/s²"),
    ("train etr1000", "emergency_brake_decel_mps2", 0.3, "emergency_brake_decel_mps2", "must not be below service_brake_decel_mps2 (0.65 m/s²)"),
    ("train terlizzi2024_follower", "mass_kg", 1e6, "uncertainty.mass_kg", "does not contain the nominal value 1e+06"),
    ("train terlizzi2024_follower", "uncertainty.mass_kg.low", 0, "uncertainty.mass_kg.low", "must be positive and finite"),
    ("train terlizzi2024_follower", "uncertainty.davis_a_n.low", -5, "uncertainty.davis_a_n.low", "finite and not negative"),
    ("controller cbc", "k_pos_per_s2", -0.04, "k_pos_per_s2", "greater than 0"),
    ("controller cbc", "k_vel_per_s", -0.8, "k_vel_per_s", "greater than or equal to 0"),
    ("controller cbc", "gap.d_min_m", -50, "gap.d_min_m", "greater than or equal to 0"),
    ("controller cbc_liu", "liu.k1_per_s2", -0.06, "liu.k1_per_s2", "greater than 0"),
    ("controller mpc", "a_leader_mps2", -1.25, "a_leader_mps2", "greater than 0"),
    ("controller mpc", "a_follower_mps2", 50, "a_follower_mps2", "less than or equal to 5"),
    ("controller mpc", "horizon_steps", 1e6, "horizon_steps", "less than or equal to 400"),
    ("controller mpc", "k_d", -100, "k_d", "greater than or equal to 0"),
    ("controller cbf", "safety_distance_m", -1000, "safety_distance_m", "greater than 0"),
    ("controller cbf", "epsilon", 1.5, "epsilon", "less than 1"),
    ("controller cruise", "horizon_s", -12, "horizon_s", "greater than 0"),
    ("controller cruise", "theta1_s_per_m2", -2, "theta1_s_per_m2", "greater than or equal to 0"),
    ("channel", "loss_probability", 1.5, "loss_probability", "less than or equal to 1"),
    ("channel", "loss_probability", -0.1, "loss_probability", "greater than or equal to 0"),
    ("channel", "period_s", 0, "period_s", "greater than or equal to 0.01"),
    ("channel", "delay_s", -0.1, "delay_s", "greater than or equal to 0"),
    ("guard", "sensor", "sometimes", "sensor", "valid boolean"),
    ("study batch", "regimes", ["fbs", "warp"], "regimes[1]", "'fbs', 'mb' or 'vc'"),
    ("study headway", "regime", "warp", "regime", "'fbs', 'mb' or 'both'"),
    ("study capacity", "controllers", ["cbc", "warp"], "controllers[1]", "unknown controller 'warp'"),
    ("study capacity", "controllers", ["cbc:no_such_params"], "controllers[0]", "'no_such_params' not found"),
    ("study capacity", "convoy_sizes", [1, 0], "convoy_sizes[1]", "greater than or equal to 1"),
    ("study capacity", "block_length_m", 1e6, "block_length_m", "less than or equal to 50000"),
    ("study capacity", "line", "atlantis", "line", "unknown line 'atlantis'"),
    ("study capacity", "train", "maglev", "train", "unknown train 'maglev'"),
    ("study headway", "trains", ["etr1000", "maglev"], "trains[1]", "unknown train 'maglev'"),
    ("study junction", "controllers", ["cbf-warp"], "controllers[0]", "unknown controller 'cbf-warp'"),
    ("study junction", "junction", "0", "junction", "unknown junction '0'"),
    ("study junction", "controllers", ["cbc\nfake second line"], "controllers[0]", "unknown controller 'cbc\\nfake second line'"),
    ("study junction", "line", "x" * 5000, "line", "unknown line 'xxx"),
    ("study junction", "controllers", ["cbc:" + "p" * 5000], "controllers[0]", "controller parameter set 'ppp"),
    ("study batch", "seeds", 10**9, "seeds", "less than or equal to 1000"),
    ("study batch", "delay_config", "nowhere.yaml", "delay_config", "not found"),
    ("delays", "origin.probability", 1.5, "origin.probability", "less than or equal to 1"),
    ("delays", "dwell.min_s", -10, "dwell.min_s", "greater than or equal to 0"),
]


@pytest.mark.parametrize("kind,dotted,value,field,words", ABSURD, ids=[f"{a[0]}:{a[1]}={a[2]!r}"[:60] for a in ABSURD])
def test_absurd_values_are_rejected_naming_file_and_field(tmp_path, kind, dotted, value, field, words):
    text, loader = FILES[kind]
    data = yaml.safe_load(text)
    _set(data, dotted, value)
    f = write(tmp_path / "input.yaml", yaml.safe_dump(data))
    with pytest.raises(InputError) as exc:
        loader(f)
    msg = str(exc.value)
    assert msg.startswith(f"{f}: {field}") and words in msg, msg
    assert exc.value.path == str(f) and (exc.value.field or "") == field


TT_ABSURD = [
    # (timetable, dotted path, value, field named, words)
    ("timetable hcmc_line1/base", "services[0].stops[0].dwell_s", -30, "services[0].stops[0].dwell_s", "greater than or equal to 0"),
    ("timetable hcmc_line1/base", "services[0].stops[1].station", "ATLANTIS", "services[0].stops[1].station", "unknown station 'ATLANTIS'"),
    ("timetable hcmc_line1/base", "services[0].stops[2].arrival", "25:99", "services[0].stops[2].arrival", "not a valid time"),
    ("timetable hcmc_line1/base", "services[0].destination", "ATLANTIS", "services[0].destination", "unknown station 'ATLANTIS'"),
    ("timetable hcmc_line1/base", "services[0].train", "maglev", "services[0].train", "unknown train 'maglev'"),
    ("timetable hcmc_line1/base", "services[0].departure", -5, "services[0].departure", "between 0 s and"),
    ("timetable hcmc_line1/base", "services[0].departure", 1e12, "services[0].departure", "between 0 s and"),
    ("timetable hcmc_line1/base", "services[0].repeat.every_s", 0, "services[0].repeat.every_s", "greater than or equal to 1"),
    ("timetable hcmc_line1/base", "services[0].repeat.count", 10**6, "services[0].repeat.count", "less than or equal to 1000"),
    ("timetable hcmc_line1/base", "line", "atlantis", "line", "not 'hcmc_line1'"),
    ("timetable felez_test/convoy", "convoys[0].services", ["UL", "GHOST"], "convoys[0].services[1]", "'GHOST', which does not exist"),
    ("timetable felez_test/convoy", "services[0].id", "../../evil", "services[0].id", "should match pattern"),
    ("timetable felez_test/convoy", "name", "../../evil", "name", "should match pattern"),
    ("timetable felez_test/convoy", "name", "/tmp/evil", "name", "should match pattern"),
    ("timetable felez_test/convoy", "services[1].origin", "ORIG\nerror: fake", "services[1].origin", "unknown station 'ORIG\\nerror: fake'"),
    ("timetable felez_test/convoy", "services[1].train", "t" * 5000 + ".yaml", "services[1].train", "train file 'tttt"),
    ("timetable felez_test/convoy", "services[1].train", "no_such_train.yaml", "services[1].train", "train file 'no_such_train.yaml' not found"),
]


@pytest.mark.parametrize("kind,dotted,value,field,words", TT_ABSURD, ids=[f"{a[1]}={a[2]!r}"[:60] for a in TT_ABSURD])
def test_absurd_timetables_are_rejected_naming_file_and_field(tmp_path, load_timetable_on, kind, dotted, value, field, words):
    line, text = TIMETABLES[kind]
    data = yaml.safe_load(text)
    _set(data, dotted, value)
    f = write(tmp_path / "tt.yaml", yaml.safe_dump(data))
    with pytest.raises(InputError) as exc:
        load_timetable_on(line, f)
    msg = str(exc.value)
    assert msg.startswith(f"{f}: {field}") and words in msg, msg


# -------------------------------------------------------------------------------------------
# Output containment: names from file contents stay inside the results folder


@settings(max_examples=300, deadline=None)
@given(name=st.text(max_size=300) | st.sampled_from(["..", ".", "../../x", "/etc/passwd", "a/../../b", "..\\..\\x", "~/x", "cbc:../../../../tmp/x.yaml"]))
def test_safe_component_is_one_harmless_path_component(name):
    from vcsumo.results import safe_component

    c = safe_component(name)
    assert c and c not in (".", "..") and "/" not in c and "\\" not in c and "\x00" not in c
    assert len(c.encode("utf-8")) <= 120
    root = Path("/srv/results/out")
    assert (root / c).parent == root and Path(c).name == c
    assert safe_component(name) == c  # deterministic: resumable batch runs find their folders again


def test_default_out_stays_under_results(in_tmp):
    from vcsumo.results import default_out

    for name in ("x-/../../../tmp/evil-fbs", "../..", "a\\..\\..\\b", "\x00"):
        out = default_out("run", name)
        assert out.parent == Path("results"), out
        assert in_tmp / "results" in (in_tmp / out).resolve().parents


def test_controller_specs_cannot_steer_case_folders_out(tmp_path, line_factory):
    """Capacity cases and batch runs are named after the controller spec, which may be a path."""
    from vcsumo.studies.batch import plan_runs
    from vcsumo.delays import NO_DELAYS
    from vcsumo.studies.capacity import Case, _case_dir

    out = tmp_path / "out"
    evil = "cbc:../../../../../../tmp/evil.yaml"
    d = _case_dir(out, Case("up", "vc", evil, 2, "non-stop"))
    assert d.parent == out / "runs" and (out / "runs") in d.resolve().parents
    specs = plan_runs(line_factory("felez_test"), [DATA / "routes" / "felez_test" / "convoy.yaml"], ["vc"], [1], [evil], NO_DELAYS, out)
    assert specs and all(Path(s.run_dir).parent == (out / "runs").resolve() for s in specs)


@pytest.mark.parametrize("out,ok", [("../../..", False), ("/tmp/elsewhere", False), ("sub/../../x", False), ("~/x", False),
                                    ("res/capacity_1", True), ("res", True)])
def test_study_file_out_cannot_leave_the_current_folder(tmp_path, out, ok):
    from vcsumo.cli.study_files import load_study

    f = write(tmp_path / "s.yaml", f"study: capacity\nline: felez_test\ncontrollers: [cbc]\nout: '{out}'\n")
    if ok:
        assert load_study(f).out == out
    else:
        with pytest.raises(InputError) as exc:
            load_study(f)
        assert str(exc.value).startswith(f"{f}: out: ") and "relative folder without '..'" in str(exc.value)


# -------------------------------------------------------------------------------------------
# The real CLI: exit 2, one line naming the file, no traceback, nothing left behind


def _cli_cases(d: Path) -> list[tuple[list[str], Path, str]]:
    line = (DATA / "networks" / "felez_test" / "line.yaml").read_text()
    bad_line = write(d / "badline" / "line.yaml", line.replace("block_length_m: 500", "block_length_m: 1000000"))
    tag_line = write(d / "tagline" / "line.yaml", '!!python/object/apply:os.system ["touch pwned"]\n')
    bin_line = d / "binline" / "line.yaml"
    bin_line.parent.mkdir()
    bin_line.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    tt = (DATA / "routes" / "felez_test" / "test.yaml").read_text()
    bad_tt = write(d / "tt_bad.yaml", tt.replace("every_s: 60", "every_s: -60"))
    dup_tt = write(d / "tt_dup.yaml", tt + "name: again\n")
    evil_tt = write(d / "tt_evil.yaml", tt.replace("name: test", "name: ../../../evil"))
    bad_study = write(d / "study_bad.yaml", "study: capacity\nline: felez_test\ncontrollers: [cbc, warp]\nout: r\n")
    out_study = write(d / "study_out.yaml", "study: capacity\nline: felez_test\ncontrollers: [cbc]\nout: ../r\n")
    regime_study = write(d / "study_regime.yaml", "study: batch\nline: felez_test\ntimetables: x.yaml\nregimes: [warp]\nout: r\n")
    run = ["run", "--line", "felez_test", "--regime", "fbs", "--out", "r", "--timetable"]
    return [
        (["build-network", "--line", str(bad_line)], bad_line, "signalling.block_length_m"),
        (["run", "--line", str(tag_line), "--timetable", "test", "--regime", "fbs", "--out", "r"], tag_line, "is not allowed"),
        (["run", "--line", str(bin_line), "--timetable", "test", "--regime", "fbs", "--out", "r"], bin_line, "not UTF-8"),
        (run + [str(bad_tt)], bad_tt, "services[0].repeat.every_s"),
        (run + [str(dup_tt)], dup_tt, "duplicate key 'name'"),
        (["run", "--line", "felez_test", "--regime", "fbs", "--timetable", str(evil_tt)], evil_tt, "name: String should match pattern"),
        (["study", "run", str(bad_study)], bad_study, "controllers[1]: unknown controller 'warp'"),
        (["study", "run", str(out_study)], out_study, "out: '../r' must be a relative folder"),
        (["study", "run", str(regime_study)], regime_study, "regimes[0]"),
    ]


def test_cli_broken_files_exit_2_with_one_line(in_tmp, capsys):
    from vcsumo.cli.main import main

    for args, path, words in _cli_cases(in_tmp):
        assert main(args) == 2, args
        cap = capsys.readouterr()
        err = cap.err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"error: {path}") and words in err[0], (args, cap.err)
        assert "Traceback" not in cap.err + cap.out
    assert not (in_tmp / "r").exists() and not list(in_tmp.glob("r.partial*")) and not (in_tmp.parent / "r").exists()
    assert not (in_tmp / "results").exists() and not (in_tmp / "pwned").exists()


def test_cli_subprocess_no_traceback(in_tmp):
    """The installed console script, as a user runs it: stderr is the one error line."""
    cases = _cli_cases(in_tmp)
    exe = Path(sys.executable).parent / "vcsumo"
    for args, path, words in (cases[1], cases[4], cases[6]):
        proc = subprocess.run([str(exe), *args], cwd=in_tmp, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"error: {path}") and words in lines[0], proc.stderr
        assert "Traceback" not in proc.stderr + proc.stdout
    assert not (in_tmp / "r").exists() and not (in_tmp / "results").exists() and not (in_tmp / "pwned").exists()


def test_cli_unwritable_out_is_one_line(in_tmp, capsys):
    """A results folder that cannot be created is the user's to fix: exit 2, one line naming it."""
    from vcsumo.cli.main import main

    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", "/proc/vcsumo-nope/r"]) == 2
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: /proc/vcsumo-nope") and "Traceback" not in cap.err
