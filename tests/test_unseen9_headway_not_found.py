"""A measuring point without a sustainable headway is a failed row of the headway study, never a number.

Found by unseen9 (2026-11-28) reading the headway study beside the capacity study: when the bisection
found no release interval at which the later train was unhindered (as the capacity study's
all-stops cases on a line of our own before the junction-position fix), the row took the passages of
the last probe — the largest interval tried — as its ``headway_sim_s``, with ``healthy`` True and no
error, and the command exited 0.  Now ``headway_sim_s`` is empty, ``error`` says what hindered the
train at the largest interval, and the row is counted as failed.  The case is made real here by a
lost-time tolerance no run can meet (-1 s).
"""

from __future__ import annotations

import math

from vcsumo.studies.headway import measuring_points, run_headway_case


def test_a_point_without_a_headway_is_an_error_not_the_largest_interval(tmp_path, line_factory, network_factory):
    from vcsumo.rolling_stock import load_rolling_stock

    line = line_factory("felez_test")
    rows = run_headway_case(line, network_factory("felez_test"), load_rolling_stock("felez2019"), "up", "mb", tmp_path,
                            measuring_points(line, [1.5]), tolerance_s=-1.0)
    assert len(rows) == 1
    row = rows[0]
    assert math.isnan(row["release_interval_s"]) and math.isnan(row["headway_sim_s"]), row
    assert row["error"].startswith("no sustainable headway found: a later train was hindered at every release interval tried, up to ")
    assert "lost" in row["error"]
