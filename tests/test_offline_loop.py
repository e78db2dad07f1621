"""The one offline loop (vcsumo.sim.offline.run_convoy) and the safety campaign on it: the campaign's
followers are the registry's stacks (guard included), its leader brakes at the top of its box."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from vcsumo.cli.main import main
from vcsumo.control.base import Command
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.faults import FaultStage
from vcsumo.control.guard import SeparationGuard
from vcsumo.control.stack import SampledController
from vcsumo.plant import PlantState
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.sim.offline import EmergencyBrake, ForceProfile, Odometry, OfflineTrain, SpeedProfile, flat_profile, run_convoy, steady_force
from vcsumo.studies.safety import SafetyCampaign, draw_scenario, follower_stacks_for, line_route, run_scenario, true_params

STOCK = load_rolling_stock("etr1000")
P = STOCK.params()
PROFILE = flat_profile(30000.0, speed_limit_mps=90.0)


class Recorder:
    """A real (trivial) controller that holds a force and keeps what it was shown."""

    def __init__(self, force=0.0, emergency=False):
        self.force, self.emergency, self.seen = force, emergency, []

    def make_step(self, obs):
        self.seen.append(obs)
        return Command(self.force, mode="rec", emergency=self.emergency)


def _train(tid, s, v, driver, **kw):
    return OfflineTrain(tid, P, PlantState(s, v, steady_force(P, v, PROFILE, s)), driver, **kw)


def test_messages_odometry_and_prior_knowledge():
    rng = np.random.default_rng(3)
    rec = Recorder(force=steady_force(P, 40.0, PROFILE, 0.0))
    plans = []

    def plan(t, s, v):
        plans.append((t, s))
        return np.array([t, t + 1.0]), np.array([s, s + v]), np.array([v, v]), np.zeros(2)

    trains = [_train("L", 5000.0, 40.0, SpeedProfile((0.0, 1e4), (40.0, 40.0)), plan=plan), _train("F", 4000.0, 40.0, rec, sends=False)]
    ch = Channel(ChannelConfig(model="constant", period_s=1.0, delay_s=2.5, loss_probability=0.0))
    run = run_convoy(trains, PROFILE, 0.5, 10.0, channel=ch, odometry=Odometry([1.0, -1.0], 0.4, rng), known_at_start=True)
    first = rec.seen[0]
    # the follower knew its predecessor at t = 0 (the channel delivers the first message only at 2.5 s)
    assert first.received["L"].sent_time_s == 0.0 and first.received["L"].plan_times_s is None
    assert rec.seen[5].received["L"].sent_time_s == 0.0 and rec.seen[5].received["L"].plan_times_s is not None  # delivered at 2.5 s
    # measured positions: bias ± noise within the bound, in the ego state, the messages and the sensed gap
    f = run.frame[run.frame.train == "F"].reset_index(drop=True)
    for k, obs in enumerate(rec.seen):
        assert abs(obs.ego.position_m - (f.position_m[k] - 1.0)) <= 0.2 + 1e-9
    assert all(abs(tp - round(tp)) < 1e-9 for tp, _ in plans) and len(plans) == 11  # the leader's plan hook at every packet
    assert ch.sent == 11  # only the leader sends (the follower has sends=False)


def test_emergency_commands_use_the_emergency_brake_unless_the_papers_plant_is_asked_for():
    def decel(emergency_brake):
        trains = [_train("L", 5000.0, 50.0, ForceProfile((0.0, 1.0), (-1e12, -1e12))),
                  _train("F", 4000.0, 50.0, Recorder(force=-1e12, emergency=True))]
        df = run_convoy(trains, PROFILE, 0.2, 10.0, emergency_brake=emergency_brake).frame
        last = df[df.time_s == df.time_s.max()].set_index("train")
        return -last.accel_mps2["L"], -last.accel_mps2["F"]

    lead, fol = decel(True)
    assert lead < 0.75 < P.emergency_brake_decel_mps2 / P.rotating_mass_factor < fol  # service (not flagged) vs emergency
    _, fol_paper = decel(False)
    assert fol_paper == pytest.approx(lead)


def test_emergency_brake_event_and_a_non_finite_command():
    trains = [_train("L", 5000.0, 50.0, EmergencyBrake(SpeedProfile((0.0, 1e4), (50.0, 50.0)), 2.0)),
              _train("F", 3000.0, 50.0, Recorder(force=math.nan))]
    df = run_convoy(trains, PROFILE, 0.2, 12.0).frame
    end = df[df.time_s == df.time_s.max()].set_index("train")
    assert (end.accel_mps2 < -P.emergency_brake_decel_mps2 / P.rotating_mass_factor).all()  # both on the full emergency brake


def test_the_campaign_runs_the_registry_stack_with_the_guard():
    cfg = SafetyCampaign(lines=["hcmc_line1"], followers_max=2)
    route = line_route("hcmc_line1", "up")
    for name in ("mpc", "cbc", "cbf-mpc", "cbf-cbc"):
        stacks = follower_stacks_for(name, route, ["T0", "T1", "T2"], cfg)
        for st in stacks:
            assert isinstance(st.stage, FaultStage) and isinstance(st.guard, SeparationGuard) and st.stage.guard is st.guard
            assert st.stage.controller is st.nominal and not isinstance(st.stage.controller, SampledController)  # every step, as the capacity study's stacks
            assert (st.supervisor is not None) == name.startswith("cbf-") and st.guard.d_min_m == st.d_min_m
        if name == "mpc":  # one NMPC per follower, its route data shared
            assert stacks[0].nominal is not stacks[1].nominal and stacks[0].nominal._route is stacks[1].nominal._route


def test_the_campaign_leader_brakes_at_the_top_of_its_box():
    rng = np.random.default_rng(0)
    top = true_params(STOCK, rng, corner=False, emergency_top=True)
    assert top.emergency_brake_decel_mps2 == pytest.approx(1.2 * 1.1)
    drawn = [true_params(STOCK, rng, corner=True).emergency_brake_decel_mps2 for _ in range(20)]
    assert set(np.round(drawn, 6)) == {round(1.2 * 0.9, 6), round(1.2 * 1.1, 6)}  # corners of the box stay corners


@pytest.fixture(scope="module")
def cruise_scenario():
    cfg = SafetyCampaign(lines=["firenze_bologna"], kinds=["cruise"], followers_max=1, outage_probability=0.0, heterogeneous_probability=0.0)
    return cfg, draw_scenario(cfg, 0)


def test_under_the_leaders_emergency_brake_both_stacks_keep_their_distance(cruise_scenario):
    cfg, sp = cruise_scenario
    sup = run_scenario(sp, "cbf-cbc", cfg)
    raw = run_scenario(sp, "cbc", cfg)
    # the separation model's margin (50 m) + 2 odometry errors (2 × 10 m) stays between the trains
    assert sup["separation_violations"] == 0 and sup["collisions"] == 0 and sup["min_gap_m"] >= 70.0 and sup["min_margin_m"] >= 0.0
    assert sup["emergency_activations"] >= 1
    # consensus control behind a leader braking at 1.32 m/s² is held by the separation guard (the separation
    # model's relative braking on what the channel delivered): no collision, the margin kept (as close as
    # under the CBF: 80.6 and 80.5 m, now that cbc's spacing budgets the channel's message age)
    assert raw["collisions"] == 0 and raw["separation_violations"] == 0 and raw["min_gap_m"] >= 70.0 and raw["min_margin_m"] >= 0.0


def test_cli_campaign_writes_table_report_and_plot(tmp_path, capsys):
    out = tmp_path / "saf"
    assert main(["study", "safety", "--scenarios", "2", "--lines", "hcmc_line1", "--controllers", "cbc,cbf-cbc", "--workers", "1", "--out", str(out)]) == 0
    assert "cbf-cbc" in capsys.readouterr().out
    runs = pd.read_csv(out / "report" / "safety_runs.csv")
    assert len(runs) == 4 and (runs["error"].isna() | (runs["error"].astype(str) == "")).all() and (out / "report" / "safety_gaps.png").stat().st_size > 10_000
