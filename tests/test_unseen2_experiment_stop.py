"""Tier 2 — an experiment whose leader never stops within the run (found with a leader emergency
brake at a km the convoy did not reach in ``duration_s``): the stop measurement still reported a
brake onset (the last step), a "gap at rest" and a "gap at the leader's stop" for trains that were
running at 25 m/s — numbers for an event that did not happen."""

import math

import pandas as pd

from vcsumo.cli.main import main

from .conftest import write

EXPERIMENT = """
name: no_stop
step_s: 0.1
duration_s: DURATION
seeds: [1]
record_every: 5
track:
  straight: {length_m: 20000.0, speed_limit_mps: 40.0}
trains:
  - {id: L, stock: regional_emu160, position_m: 3000.0, speed_mps: 20.0}
  - {id: F, stock: regional_emu160, gap_m: coupled, speed_mps: 20.0, controller: cbc}
leader:
  driver: speed_tracker
  schedule: [[0.0, 20.0]]
  events:
    - {action: emergency_brake, at_m: 4000.0}
measurements:
  stop: {}
"""


def _stop(in_tmp, duration, out):
    exp = write(in_tmp / f"{out}.yaml", EXPERIMENT.replace("DURATION", str(duration)))
    assert main(["experiment", str(exp), "--out", out]) == 0
    m = pd.read_csv(in_tmp / out / "measurements.csv")
    m = m[m.window == "stop"]
    return {(r.train, r.quantity): r.value for r in m.itertuples()}


def test_no_stop_measured_when_the_leader_never_stops(in_tmp, capsys):
    # 1,000 m to the brake point at 20 m/s: 50 s; a 30 s run ends before it
    v = _stop(in_tmp, 30.0, "short")
    assert "the leader did not stop within the run" in capsys.readouterr().out
    for q in (("L", "leader_brake_onset_s"), ("L", "leader_stop_time_s"), ("F", "gap_at_brake_onset_m"), ("F", "gap_at_leader_stop_m"), ("F", "gap_at_rest_m")):
        assert math.isnan(v[q]), q
    # the same convoy given the time to stop: every quantity measured
    v = _stop(in_tmp, 400.0, "long")
    assert "did not stop" not in capsys.readouterr().out
    assert 45.0 < v[("L", "leader_brake_onset_s")] < 55.0 < v[("L", "leader_stop_time_s")]
    assert v[("F", "gap_at_rest_m")] > 0.0 and v[("F", "gap_at_brake_onset_m")] > v[("F", "gap_at_rest_m")] - 1e3
