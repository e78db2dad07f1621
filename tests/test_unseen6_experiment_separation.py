"""Sixth round of unseen inputs — the offline experiment of five heterogeneous trains on a 20 permille
descent (see test_unseen6_experiment_coupled_cbf), checked against the run-health monitor's rule.

Defect found: an experiment did not measure the gaps against the safe separation at all — its health
knew collisions, the CBF's true barrier and overspeed only — so a follower with vcsumo's separation
guard could run below the relative-braking safe separation and the run was reported healthy (exit 0);
the check could not fire.  Measured after the fact on the five-train run: the ``mpc`` follower, placed
``gap_m: coupled`` at the NMPC's own spacing, started 51.8 m inside the rule (2.2 s below it, until
its guard had braked it out).  Now every follower's smallest margin to the monitor's rule on the true
states, its episodes and time below it are measured (``min_margin_m``, ``separation_violations``,
``below_separation_time_s``); a follower with the separation guard below it makes the run NOT
HEALTHY, named; one without the guard (``guard: false``: a paper's own architecture, e.g. Felez's
4 m standstill gap) is measured and printed, not judged.  A guarded follower placed ``coupled`` starts
1 m outside the rule (mpc: margin +0.5 m over the whole run, was −51.8 m)."""

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write
from .test_unseen6_junction_fouling import DMU

EXPERIMENT = """
name: separation
step_s: 0.2
duration_s: 12.0
seeds: [1]
record_every: 5
track:
  straight: {length_m: 20000.0, speed_limit_mps: 25.0, grades: [{from_m: 3000.0, permille: -20.0}]}
trains:
  - {id: L, stock: dmu90.yaml, position_m: 6000.0, speed_mps: 20.0}
  - {id: F, stock: regional_emu160, GAP, speed_mps: 20.0, controller: CTRL, guard: GUARD}
leader:
  driver: speed_tracker
  schedule: [[0.0, 20.0]]
channel: {period_s: 0.5, delay_s: 0.1, exp_rate_per_s: 5.0, loss_probability: 0.01}
"""


def _run(in_tmp, capsys, gap: str, controller: str, guard: str):
    write(in_tmp / "dmu90.yaml", DMU)
    exp = write(in_tmp / "sep.yaml", EXPERIMENT.replace("GAP", gap).replace("CTRL", controller).replace("GUARD", guard))
    code = main(["experiment", str(exp), "--out", "e", "--no-plots"])
    m = pd.read_csv(in_tmp / "e" / "measurements.csv")
    value = {q: m[(m.train == "F") & (m.quantity == q)].value.iloc[0] for q in ("min_margin_m", "separation_violations", "below_separation_time_s")}
    return code, capsys.readouterr().out, value


def test_a_guarded_follower_below_the_safe_separation_is_not_healthy(in_tmp, capsys):
    code, out, v = _run(in_tmp, capsys, "gap_m: 60.0", "cbc", "true")  # 60 m behind at 20 m/s: far inside the rule
    assert v["separation_violations"] == 1 and v["min_margin_m"] < -100.0 and v["below_separation_time_s"] > 0.0
    assert code == 1 and "NOT HEALTHY (below the safe separation: F 1 episode, margin -" in out


def test_an_unguarded_follower_is_measured_not_judged(in_tmp, capsys):
    code, out, v = _run(in_tmp, capsys, "gap_m: 60.0", "cbc", "false")
    assert v["separation_violations"] >= 1
    assert code == 0 and "NOT HEALTHY" not in out
    assert "below the safe separation without the separation guard (guard: false, not judged): F " in out


def test_a_guarded_follower_placed_coupled_starts_outside_the_rule(in_tmp, capsys):
    code, out, v = _run(in_tmp, capsys, "gap_m: coupled", "mpc", "true")  # main: -51.8 m at t = 0 behind the DMU
    assert v["separation_violations"] == 0 and v["min_margin_m"] >= 0.0
    assert code == 0 and "NOT HEALTHY" not in out
