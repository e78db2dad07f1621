"""Tier 1 — line files: the shipped ones load; every kind of bad input is one clear error."""

from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vcsumo.errors import InputError, VcsumoError
from vcsumo.line import load_line, shipped_lines

from .conftest import write

GOOD = """
name: tiny
km_start: 0.0
km_end: 10.0
line_speed_kmh: 200
stations:
  - {id: A, name: Alpha, km: 0.2, platform_length_m: 200}
  - {id: B, name: Beta, km: 9.8, platform_length_m: 200}
speed_limits:
  - {from_km: 4.0, to_km: 5.0, speed_kmh: 120}
gradients:
  - {from_km: 2.0, to_km: 6.0, permille: 8.0}
tunnels:
  - {name: T1, from_km: 3.0, to_km: 4.5}
signalling: {block_length_m: 1000}
branches:
  - {id: br, name: Branch, junction_km: 7.0, leaves_towards: end, length_m: 3000, speed_kmh: 120, diverging_speed_kmh: 80}
"""


def test_shipped_lines_load():
    names = shipped_lines()
    assert {"firenze_bologna", "hcmc_line1", "milano_bologna", "felez_test"} <= set(names)
    for n in names:
        ln = load_line(n)
        assert ln.data.km_end > ln.data.km_start
        assert ln.data.default_train


def test_good_line_loads(tmp_path):
    ln = load_line(write(tmp_path / "tiny" / "line.yaml", GOOD))
    assert ln.name == "tiny" and len(ln.data.branches) == 1


def mutate(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize(
    "old,new,field,words",
    [
        ("km: 9.8,", "km: 12.0,", "stations[1].km", "beyond"),
        ("{from_km: 4.0, to_km: 5.0, speed_kmh: 120}", "{from_km: 4.0, to_km: 5.0, speed_kmh: 120}\n  - {from_km: 4.5, to_km: 6.0, speed_kmh: 100}", "speed_limits[1]", "overlaps"),
        ("platform_length_m: 200}\n  - {id: B", "platform_length_m: -5}\n  - {id: B", "stations[0].platform_length_m", "greater than or equal to 10"),
        ("length_m: 3000", "length_m: -3000", "branches[0].length_m", "greater than 0"),
        ("to_km: 6.0, permille: 8.0", "to_km: 16.0, permille: 8.0", "gradients[0]", "beyond"),
        ("line_speed_kmh: 200", "line_speed_kmh: 200\nspeedlimit: 3", "speedlimit", "unknown key"),
        ("signalling: {block_length_m: 1000}", "signalling: {}", "signalling", "block_length_m or signals_km"),
        ("junction_km: 7.0", "junction_km: 70.0", "branches[0].junction_km", "beyond"),
        ("junction_km: 7.0", "junction_km: 0.00001", "branches[0].junction_km", "within 10 m"),
        ("diverging_speed_kmh: 80", "diverging_speed_kmh: 180", "branches[0].diverging_speed_kmh", "exceeds"),
        ("km_end: 10.0", "km_end: -1.0", "km_end", "greater than km_start"),
        ("{id: B, name: Beta", "{id: A, name: Beta", "stations[1].id", "duplicate"),
        ("km_start: 0.0\n", "", "km_start", "missing"),
    ],
)
def test_bad_line_file_names_file_and_field(tmp_path, old, new, field, words):
    path = write(tmp_path / "bad" / "line.yaml", mutate(GOOD, old, new))
    with pytest.raises(InputError) as exc:
        load_line(path)
    msg = str(exc.value)
    assert str(path) in msg
    assert field in msg
    assert words in msg


def test_malformed_yaml_names_the_line(tmp_path):
    path = write(tmp_path / "x" / "line.yaml", GOOD.replace("signalling: {block_length_m: 1000}", "signalling: {block_length_m: 1000"))
    with pytest.raises(InputError) as exc:
        load_line(path)
    assert "malformed YAML" in str(exc.value) and "line " in str(exc.value)


def test_unknown_line_lists_the_shipped_ones():
    with pytest.raises(InputError) as exc:
        load_line("atlantis")
    assert "unknown line 'atlantis'" in str(exc.value) and "firenze_bologna" in str(exc.value)


def test_missing_line_file(tmp_path):
    with pytest.raises(InputError) as exc:
        load_line(tmp_path / "nope.yaml")
    assert "not found" in str(exc.value)


# -- fuzzing: any mutation of a valid file either loads or raises a VcsumoError, never anything else
_base = yaml.safe_load(GOOD)
_paths = [
    ("km_start",), ("km_end",), ("line_speed_kmh",), ("stations", 0, "km"), ("stations", 1, "platform_length_m"),
    ("speed_limits", 0, "from_km"), ("speed_limits", 0, "speed_kmh"), ("gradients", 0, "permille"), ("tunnels", 0, "to_km"),
    ("signalling", "block_length_m"), ("branches", 0, "junction_km"), ("branches", 0, "length_m"), ("stations", 0, "id"),
]
_values = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6), st.text(max_size=5), st.none(), st.lists(st.integers(), max_size=2))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(path=st.sampled_from(_paths), value=_values)
def test_fuzzed_line_files_never_crash(tmp_path_factory, path, value):
    import copy

    data = copy.deepcopy(_base)
    node = data
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    f = tmp_path_factory.mktemp("fuzz") / "line.yaml"
    f.write_text(yaml.safe_dump(data))
    try:
        ln = load_line(f)
    except VcsumoError as exc:
        assert str(f) in str(exc)
        return
    # if it loaded, the topology must build consistently
    from vcsumo.topology import build_topology

    topo = build_topology(ln)
    total = sum(e.length_m for e in topo.track_for("main", "up").edges and [topo.edges[x] for x in topo.track_for("main", "up").edges])
    assert total == pytest.approx((ln.data.km_end - ln.data.km_start) * 1000, abs=1.0)


@pytest.mark.parametrize(
    "old,new,field,words",
    [
        ("mass_kg: 500000.0", "mass_kg: -5", "mass_kg", "greater than 0"),
        ("length_m: 202.0", "length_m: 202.0\nwheels: 32", "wheels", "unknown key"),
        ("emergency_brake_decel_mps2: 1.2", "emergency_brake_decel_mps2: 0.3", "", "must not be below"),
        ("  mass_kg: {low: 461000.0, high: 540000.0}", "  mass_kg: {low: 520000.0, high: 540000.0}", "", "does not contain the nominal"),
    ],
)
def test_bad_rolling_stock_file(tmp_path, root, old, new, field, words):
    from vcsumo.rolling_stock import load_rolling_stock

    text = (root / "vcsumo" / "data" / "networks" / "rolling_stock" / "etr1000.yaml").read_text()
    assert old in text
    path = write(tmp_path / "mytrain.yaml", text.replace(old, new))
    with pytest.raises(InputError) as exc:
        load_rolling_stock(path)
    assert str(path) in str(exc.value) and field in str(exc.value) and words in str(exc.value)


def test_vtype_units_kilo_for_sumo():
    from vcsumo.rolling_stock import load_rolling_stock

    x = load_rolling_stock("etr1000").vtype_xml(1.5)
    assert 'maxPower="9800.0000"' in x and 'maxTraction="370.0000"' in x
    assert 'resCoef_constant="8.800000"' in x and 'resCoef_quadratic="0.01305000"' in x  # 8.7 N/(m/s)^2 x 1.5 in kN
    assert 'id="etr1000@tf1.50"' in x and 'carFollowModel="Rail"' in x and 'trainType="custom"' in x
