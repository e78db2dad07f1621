"""Explicit block signals (``signalling.signals_km``) that cannot be built — inside a platform, or
closer than ``min_block_length_m`` to a station or junction signal — are said, naming each one
(found by the fourth round of unseen inputs: they were dropped silently); block markers from
``block_length_m`` that fall there go without a word, as before."""

import warnings

import pytest

from vcsumo.line import load_line
from vcsumo.topology import build_topology

from .conftest import write

LINE = """
name: marks
km_start: 0.0
km_end: 10.0
line_speed_kmh: 160
stations:
  - {id: AAA, name: Alpha, km: 0.5, platform_length_m: 300}
  - {id: MID, name: Middle, km: 5.0, platform_length_m: 400}
  - {id: ZZZ, name: Zulu, km: 9.5, platform_length_m: 300}
signalling:
  signals_km: [2.0, 4.0, 5.1, 7.0]
"""


def test_explicit_signals_not_built_are_named(tmp_path):
    line = load_line(write(tmp_path / "line.yaml", LINE))
    with pytest.warns(UserWarning, match=r"signals_km: 1 of the signals given are not built \(5\.1 km in the platform of MID\)"):
        topo = build_topology(line)
    assert topo.signal_nodes()  # the others are built


def test_regular_block_markers_in_platforms_go_without_a_word(tmp_path):
    line = load_line(write(tmp_path / "line.yaml", LINE.replace("signals_km: [2.0, 4.0, 5.1, 7.0]", "block_length_m: 1000")))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (a warning fails the test)
        topo = build_topology(line)
    # the markers outside the platforms are built (1, 2, 3, 4, 6, 7, 8 km; 5 km falls in MID's platform)
    kms = {round(topo.nodes[topo.edges[e].to_node].km, 3) for e in topo.tracks["main_up"].edges if topo.edges[e].to_node in topo.signal_nodes()}
    assert {2.0, 3.0, 4.0, 6.0, 7.0} <= kms and 5.0 not in kms
