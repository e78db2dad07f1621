"""Eleventh round of unseen inputs — a headway measuring point behind the release point was dropped
without a word.

Found on a line of our own (release points km 1.0 up and km 27.0 down): ``vcsumo study headway
--points 0.2`` printed the down direction only (MB 69.5 s at km 0.2) and exited 0; the up direction,
where km 0.2 lies before the trains are released, had no row and no message. A point the trains
never pass after their release cannot be measured in that direction; it is now said, per direction.
"""

import pytest

from vcsumo.studies.headway import run_headway_case


def test_a_point_before_the_release_is_said_not_dropped(tmp_path, line_factory, network_factory):
    from vcsumo.rolling_stock import load_rolling_stock

    line = line_factory("felez_test")  # release km 1.2 up
    with pytest.warns(UserWarning) as caught:
        rows = run_headway_case(line, network_factory("felez_test"), load_rolling_stock("felez2019"), "up", "mb", tmp_path, [0.05, 1.0])
    assert rows == []
    said = [str(w.message) for w in caught]
    for km in ("0.05", "1"):  # before the release point's edge (not on the route) and on it, before the release
        assert f"up: measuring point km {km} lies before the release point (km 1.2) in this direction: not measured up" in said, said
