"""The separation guard in the safety campaign's offline loop: hard seeded scenarios that broke the
run-health monitor's rule on main@5abdbef keep it now (issue 10).

Each case is one scenario of the default campaign (``vcsumo study safety``, seed 2026, drawn by
index: the same scenario whatever the campaign size) run with the unsupervised stacks the capacity
studies run (controller → separation guard → fault stage).  On main@5abdbef the guard tested the
rule one step ahead with the set's dead time + 1.5 steps from the speed it commanded, ignoring the
brake build-up from the force the follower applied: in the 200-scenario campaign mpc broke the rule
in 174 scenarios, cbc in 63; the four below are among the deepest (figures of that run).  The guard
now tests the force one step ahead, with the build-up from it
(:class:`vcsumo.control.guard.BrakeBuildUp`) and the odometry bound the stack is told.
"""

from __future__ import annotations

import pytest

from vcsumo.studies.safety import run_scenario
from vcsumo.studies.safety_scenarios import SafetyCampaign, draw_scenario

CAMPAIGN = SafetyCampaign()

HARD = [
    # (scenario, controller): what main@5abdbef measured
    pytest.param(76, "mpc", id="s00076-mpc"),   # hcmc_line1, forming, regional EMU behind an ETR1000: 5 violations, margin −24.9 m
    pytest.param(157, "cbc", id="s00157-cbc"),  # milano_bologna, merge, ETR1000s: 1 violation, margin −46.6 m
    pytest.param(29, "cbc", id="s00029-cbc"),   # milano_bologna, split, three ETR1000s: 1 violation, margin −43.7 m
    pytest.param(19, "cbc", id="s00019-cbc"),   # hcmc_line1, cruise, regional EMU + ETR1000 behind an HCMC train: 1 violation, margin −8.8 m
]


@pytest.mark.parametrize(("index", "controller"), HARD)
def test_hard_scenarios_keep_the_monitors_rule(index, controller):
    spec = draw_scenario(CAMPAIGN, index)
    row = run_scenario(spec, controller, CAMPAIGN)
    assert row["error"] == ""
    assert row["separation_violations"] == 0 and row["collisions"] == 0 and row["min_margin_m"] >= -0.01
    # the leader did brake, and the guard did brake the followers (nothing else flags an emergency here)
    assert row["simulated_s"] > spec.brake_time_s and row["emergency_activations"] > 0
