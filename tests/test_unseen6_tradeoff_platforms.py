"""Sixth round of unseen inputs — the trade-off study, all stops, on a slow line of our own: 45 m DMUs
calling at 200 m platforms.

Defect found: the trade-off table gave VC n=3 and n=4 all-stops 79.0 and 93.1 trains/h (×2.25 and
×2.65 over MB) without a word, although a convoy of 3 (3 × 45 m + 2 × 72 m = 279 m) or 4 (396 m) does
not fit a 200 m platform: the analytic VC headway stands the convoy in the platform as one train,
while its members stop one after another — the capacity study simulated n=3 at 49.5 trains/h, barely
above n=2 (48.6).  The figures stay (they are the analytic rule's), but the study now says, per
convoy size, that the convoy does not fit which platforms and that its figure is a bound the line
cannot run; a convoy that fits (n=2, 162 m) is not named."""

import pytest

from vcsumo.cli.main import main

from .conftest import write
from .test_unseen6_junction_fouling import DMU

pytestmark = pytest.mark.sumo

LINE = """name: dale_short
km_start: 0.0
km_end: 16.0
line_speed_kmh: 100
default_train: dmu90.yaml
stations:
  - {id: ASH, name: Ash, km: 0.3, platform_length_m: 200, dwell_s: 40}
  - {id: BIR, name: Birch, km: 6.0, platform_length_m: 200, dwell_s: 30}
  - {id: CED, name: Cedar, km: 11.0, platform_length_m: 300, dwell_s: 30}
  - {id: YEW, name: Yew, km: 15.7, platform_length_m: 200, dwell_s: 40}
signalling: {block_length_m: 1200}
headway: {measuring_points_km: [8.0], release_km: {up: 1.0, down: 15.0}}
"""


def test_convoys_longer_than_the_platforms_are_said(in_tmp, capsys, caplog):
    write(in_tmp / "dmu90.yaml", DMU)
    line = write(in_tmp / "line.yaml", LINE)
    code = main(["study", "tradeoff", "--line", str(line), "--pattern", "all-stops", "--convoy-sizes", "2,3,4", "--delays", "0.5",
                 "--uncertainties", "", "--position-errors", "", "--out", "t"])
    assert code == 0
    text = caplog.text + capsys.readouterr().err
    assert "a VC convoy of 3 (3 × 45 m + 2 × 72 m standstill gap = 279 m) does not fit the platform of BIR (200 m);" in text
    assert "a VC convoy of 4 (4 × 45 m + 3 × 72 m standstill gap = 396 m) does not fit the platform of BIR (200 m), CED (300 m);" in text
    assert "a VC convoy of 2 " not in text
