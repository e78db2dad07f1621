"""The end of the track under a large position error: the supervision stops a train its position
error short of the end, and that train has arrived.

Found by unseen7 (2026-11-28): felez_test, one train from Origin to the open end under MB with an
assumption set of position_error_m = 150 m.  The supervision's curve to the end of the track ends at
end − e, but whether that target was within reach was measured to the end itself: at 148 m from the
end, 9 m/s (the target already 2 m behind the front) the permitted speed was ∞, and the train ran on
at 9 m/s and stood 51 m short of the end — 99 m past its supervised stopping point, which no counter
saw.  With e = 10 m (etcs_typical) the 50 m of the reach's slack had hidden it.  And SUMO's end stop
(the window in which the train arrives) was 100 m long whatever the position error: a train stopped
150 m short would never have arrived.
"""

from __future__ import annotations

import json

import pandas as pd

from tests.conftest import write
from vcsumo.cli.main import main

TIMETABLE = """name: to_the_end
line: felez_test
services:
  - {id: E, train: felez2019, origin: ORIG, destination: end, departure: 0}
"""

ASSUMPTIONS = """name: err{e}
braking_uncertainty: 0.10
reaction_time_s: 0.5
brake_build_up_s: 3.0
t2t_delay_bound_s: 0.5
position_report_period_s: 2.0
position_error_m: {e}
safety_margin_m: 50.0
overlap_m: 50.0
"""

END_S_M = 4975.0
"""The end of the track on the route from Origin (km 5.0), m of the route."""


def test_a_train_stands_its_position_error_short_of_the_end_of_track_and_has_arrived(in_tmp):
    write(in_tmp / "tt.yaml", TIMETABLE)
    for e in (10, 150):
        write(in_tmp / f"err{e}.yaml", ASSUMPTIONS.format(e=e))
        assert main(["run", "--line", "felez_test", "--timetable", "tt.yaml", "--regime", "mb", "--assumptions", f"err{e}.yaml",
                     "--end-time", "900", "--out", f"r{e}"]) == 0
        summary = json.loads((in_tmp / f"r{e}" / "summary.json").read_text())
        assert summary["trains_arrived"] == 1 and summary["healthy"] is True
        traj = pd.read_csv(in_tmp / f"r{e}" / "trajectories.csv")
        front = traj["s_m"].max()
        # stands short of its supervised stopping point (end − e), and not far short of it
        assert END_S_M - e - 60.0 <= front <= END_S_M - e + 0.5, (e, front)
