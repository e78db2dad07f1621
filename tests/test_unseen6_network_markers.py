"""Sixth round of unseen inputs — a network of two lines of our own (a 60 km, 100 km/h valley line with
1.2 km blocks, and an 18 km, 80 km/h fell line with 1.5 km blocks joined to it at km 44).

Defect found: building the network warned "section 'main': signalling.signals_km: 4 of the signals
given are not built (6 km in the platform of BIR; 12 km in the platform of CED; …)" and "… 1 of the
signals given are not built (9 km in the platform of GOR)" although neither line file gives any
``signals_km``: the network cuts each line to the part it uses and hands its regular block markers
over as explicit ones (``network_file.line_part``), and the topology says every explicit marker it
drops — which is meant for a user's own ``signals_km`` only (regular markers in platforms or next to a
station signal are expected to go; a single line built alone says nothing).  The shipped
``italy_av_north`` warned the same for milano_bologna's regular marker at km 85.55.  Now the network
says only what a line file gives explicitly, naming the line ("fell: section 'main': …")."""

import warnings

import pytest

from vcsumo.network_file import load_network
from vcsumo.network_topology import build_network_topology

from .conftest import write
from .test_unseen6_junction_fouling import DMU

DALE = """name: dale
km_start: 0.0
km_end: 60.0
line_speed_kmh: 100
default_train: dmu90.yaml
stations:
  - {id: ASH, name: Ash, km: 0.3, platform_length_m: 200, dwell_s: 40}
  - {id: BIR, name: Birch, km: 6.0, platform_length_m: 200, dwell_s: 30}
  - {id: CED, name: Cedar, km: 12.0, platform_length_m: 200, dwell_s: 30}
  - {id: YEW, name: Yew, km: 59.7, platform_length_m: 200, dwell_s: 40}
signalling: {block_length_m: 1200}
"""
FELL = """name: fell
km_start: 0.0
km_end: 18.0
line_speed_kmh: 80
default_train: dmu90.yaml
stations:
  - {id: GOR, name: Gorse, km: 9.0, platform_length_m: 120, dwell_s: 30}
  - {id: FTP, name: Fell Top, km: 17.7, platform_length_m: 200, dwell_s: 40}
gradients:
  - {from_km: 2.0, to_km: 8.0, permille: 18.0}
SIGNALLING
"""
NET = """name: dalefell
lines:
  - {line: dale.yaml}
  - {line: fell.yaml}
joins:
  - {id: fell_junction, name: Fell Junction, end: {line: fell, at: start}, meets: {line: dale, km: 44.0}, towards: end, diverging_speed_kmh: 50}
"""


def _network(tmp_path, fell_signalling: str):
    write(tmp_path / "dmu90.yaml", DMU)
    write(tmp_path / "dale.yaml", DALE)
    write(tmp_path / "fell.yaml", FELL.replace("SIGNALLING", fell_signalling))
    return load_network(write(tmp_path / "network.yaml", NET))


def test_regular_block_markers_of_a_network_line_are_not_reported(tmp_path):
    net = _network(tmp_path, "signalling: {block_length_m: 1500}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # main: 2 warnings naming signals_km, which no line file gives
        topo = build_network_topology(net)
    assert topo.edges


def test_explicit_signals_of_a_network_line_are_named_with_the_line(tmp_path):
    net = _network(tmp_path, "signalling: {signals_km: [4.5, 9.0, 13.5]}")
    with pytest.warns(UserWarning, match=r"^fell: section 'main': signalling\.signals_km: 1 of the signals given are not built \(9 km in the platform of GOR\)"):
        build_network_topology(net)
