"""The safety campaign checks the stack the capacity study runs: the objects built, not the names.

`vcsumo study safety` is there to falsify the very controller stack whose spacing produces the
capacity figures (README, "The safety campaign"; the shared note *safe-separation*: "on the exact
controller stack that produces the capacity figures, not on a simplified copy").  The capacity
study's followers are built by the VC driver (`vcsumo/studies/capacity.py` `run_case`: the default
channel, every stage every step); the campaign's offline loop builds its own
(`follower_stacks_for`).  Until 2026-12-01 the campaign wrapped every nominal controller in a 0.4 s
ATO cycle (`SampledController`, `control_period_s: 0.4`) that no capacity run has, and its SUMO loop
silently ignored that option.  Compared here field by field on the same line and train; the one
difference left is the odometry bound of the offline loop's own measured positions (its guard and
CBF must keep the rule on true positions, the SUMO loop's positions are exact).
"""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from vcsumo.control.stack import SampledController
from vcsumo.line import load_line
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel
from vcsumo.sim.network import build_network
from vcsumo.sim.vc_driver import VCDriver, load_channel
from vcsumo.studies.capacity_route import Case, route_setup, unit_trains
from vcsumo.studies.safety_scenarios import SafetyCampaign, follower_stacks_for, line_route

LINE = "hcmc_line1"
DT = 0.2  # the VC regime's step (the capacity study's vc_step_s and the campaign's step_s)


@pytest.fixture(scope="module")
def capacity_stacks():
    """The followers' stacks of one capacity-study probe (run_case's VC driver), by controller."""
    line = load_line(LINE)
    net = build_network(line)
    assumptions = load_assumptions()
    stock = line_route(LINE, "up").stock
    setup = route_setup(line, net, stock, "up", DT, SeparationModel(assumptions))
    out = {}
    for controller in ("cbc", "cbf-cbc"):
        units = unit_trains(net.topology, setup, stock, Case("up", "vc", controller, 2, "non-stop"), 1, 0.0, [300.0])
        driver = VCDriver(units, controller, DT, 42, load_channel(None), assumptions=assumptions)
        out[controller] = next(iter(driver.followers.values())).stack
    return out


def _facts(stack) -> dict:
    """What a stack does, stage by stage (the nominal controller as the stage runs it)."""
    sup, guard, nominal = stack.supervisor, stack.guard, stack.nominal
    ref = getattr(nominal, "default_gap", None)
    return {
        "name": stack.name,
        "stage_runs": type(stack.stage.controller).__name__,
        "nominal": type(nominal).__name__,
        "nominal_params": nominal.params.model_dump() if hasattr(nominal.params, "model_dump") else None,
        "d_min_m": stack.d_min_m,
        "guard_d_min_m": guard.d_min_m,
        "guard_config": guard.cfg.model_dump(),
        "guard_set": guard.model.assumptions.model_dump(),
        "supervisor": None if sup is None else sup.cfg.model_dump(exclude={"position_error_m"}),
        "reference_delay_s": None if ref is None else (ref.delay_s, ref.message_age_s, ref.buffer_m),
        "coupled_gap_m": [round(stack.coupled_gap_m(v, None), 6) for v in (5.0, 15.0, 25.0)],
    }


@pytest.mark.parametrize("controller", ["cbc", "cbf-cbc"])
def test_the_offline_campaign_builds_the_capacity_studys_stack(capacity_stacks, controller):
    cfg = SafetyCampaign(lines=[LINE], controllers=[controller])
    campaign = follower_stacks_for(controller, line_route(LINE, "up"), ["T0", "T1"], cfg)[0]
    capacity = capacity_stacks[controller]
    assert not isinstance(campaign.stage.controller, SampledController)  # the nominal controller every step, as in every capacity run
    assert _facts(campaign) == _facts(capacity)
    # the one difference: the offline loop's odometry (measured positions within ±e_s), which its guard keeps the rule against
    assert campaign.guard.position_error_m == cfg.position_error_max_m and capacity.guard.position_error_m == 0.0


def test_an_ato_cycle_is_an_offline_option_and_refused_by_the_sumo_loop(tmp_path):
    cfg = SafetyCampaign(lines=[LINE], controllers=["cbc"], control_period_s=0.4)
    st = follower_stacks_for("cbc", line_route(LINE, "up"), ["T0", "T1"], cfg)[0]
    assert isinstance(st.stage.controller, SampledController) and math.isclose(st.stage.controller.period_s, 0.4)
    # the SUMO loop's VC driver runs the nominal controller every step: the option would be ignored there (it was)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "vcsumo.cli.main", "study", "safety", "--loop", "sumo", "--scenarios", "1", "--control-period-s", "0.4",
                           "--out", str(out)], capture_output=True, text=True)
    assert proc.returncode == 2 and not out.exists()
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: --control-period-s:") and "every step" in lines[0], lines
