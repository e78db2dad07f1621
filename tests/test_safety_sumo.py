"""Tier 2 — the safety campaign inside the SUMO loop (``vcsumo study safety --loop sumo``): real SUMO,
the VC driver, the leader's emergency stop at the top of its range, true trains in their vTypes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from vcsumo.cli.main import main
from vcsumo.dynamics import acceleration
from vcsumo.plant import emergency_brake_limit
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import brake_range
from vcsumo.studies import safety_sumo
from vcsumo.studies.safety import SafetyCampaign, draw_scenario, read_safety, run_safety_campaign, summarize_safety

pytestmark = pytest.mark.sumo


def test_vtype_variant_carries_the_true_train_and_keeps_the_model():
    st = load_rolling_stock("regional_emu160")
    true = st.params().with_(mass_kg=172000.0, service_brake_decel_mps2=0.76, emergency_brake_decel_mps2=1.1, davis_c_n_per_mps2=4.3)
    v = st.vtype_variant("s00007_t1", true)
    assert v.name == "regional_emu160_s00007_t1" and v.vtype_id(1.5) == "regional_emu160_s00007_t1@tf1.50"
    assert v.params() == st.params() and v.uncertainty == st.uncertainty  # everything on board plans with the nominal model
    xml = v.vtype_xml(1.5)
    assert 'mass="172000.0"' in xml and 'decel="0.7600"' in xml and f'resCoef_quadratic="{1.5 * 4.3 / 1000:.8f}"' in xml
    assert 'mass="165000.0"' in st.vtype_xml()
    with pytest.raises(ValueError):
        st.vtype_variant("Bad-Tag", true)


@pytest.fixture(scope="module")
def sumo_cfg():
    return SafetyCampaign(loop="sumo", lines=["hcmc_line1"], followers_max=1, outage_probability=0.0, heterogeneous_probability=0.0)


def test_a_scenario_runs_in_the_sumo_loop_with_the_leaders_emergency_stop(sumo_cfg, monkeypatch):
    seen = []
    step = safety_sumo.ConvoyEmergency.make_step

    def watch(self, snap):  # observe the leader's speed the loop reports, step by step
        cmds = step(self, snap)
        st = snap.trains.get(self.leader_id)
        if st is not None:
            seen.append((snap.time_s, st.s_m, st.speed_mps, self))
        return cmds

    monkeypatch.setattr(safety_sumo.ConvoyEmergency, "make_step", watch)
    sp = draw_scenario(sumo_cfg, 0)
    row = safety_sumo.run_sumo_scenario(sp, "cbf-cbc", sumo_cfg)
    assert row["error"] == "" and row["loop"] == "sumo" and row["leader_stock"] == "hcmc_l1"
    # the run-health monitor's rule held at every step, nothing collided, the CBF's true barrier stayed ≤ 0
    assert row["separation_violations"] == 0 and row["collisions"] == 0 and row["min_margin_m"] >= 0.0
    assert row["min_gap_m"] >= 70.0 and row["max_true_barrier_m"] <= 1e-6
    # after its brake time SUMO moved the leader at its true emergency rate (the top of its range, + resistance and grade)
    drv = seen[0][3]
    top = brake_range(load_rolling_stock("hcmc_l1"), load_assumptions(), "emergency")[1]
    assert drv.true[drv.leader_id].emergency_brake_decel_mps2 == pytest.approx(top)
    braking = [(t, s, v) for t, s, v, _ in seen if t > sp.brake_time_s + 0.3 and v > 1.0]
    assert len(braking) > 20
    dt = sumo_cfg.step_s
    for (t0, s0, v0), (t1, _, v1) in zip(braking, braking[1:]):
        p = drv.true[drv.leader_id]
        prof = drv.plans[drv.leader_id].profile
        want = float(acceleration(p, v0, -emergency_brake_limit(p, v0), prof.mean_gradient(s0, p.length_m), prof.tunnel_factor_at(s0)))
        assert (v1 - v0) / dt == pytest.approx(want, abs=0.02)
    assert seen[-1][2] == 0.0  # the leader stood still before the end


def test_campaign_in_the_sumo_loop_resumes_and_states_the_bound(tmp_path, sumo_cfg):
    cfg = sumo_cfg.model_copy(update={"controllers": ["cbc", "cbf-cbc"], "scenarios": 2})
    df = run_safety_campaign(cfg, tmp_path / "s", workers=1)
    assert len(df) == 4 and (df["loop"] == "sumo").all() and (df["error"] == "").all()
    assert (df["collisions"] == 0).all() and (df["separation_violations"] == 0).all()
    s = summarize_safety(df)
    assert (s["scenarios"] == 2).all() and (s["violation_rate_upper95"] == 1.0).all()  # 0 in 2: 3/N, at most 1
    walls = df.set_index("key")["wall_time_s"]
    again = run_safety_campaign(cfg, tmp_path / "s", workers=1)  # nothing runs again
    assert list(again.set_index("key").loc[walls.index, "wall_time_s"]) == list(walls)
    assert len(read_safety(tmp_path / "s")) == 4


def test_cli_runs_the_sumo_loop_into_the_same_table(tmp_path, capsys):
    out = tmp_path / "saf"
    assert main(["study", "safety", "--loop", "sumo", "--scenarios", "1", "--lines", "hcmc_line1", "--controllers", "cbc", "--followers-max", "1",
                 "--workers", "1", "--out", str(out)]) == 0
    assert main(["study", "safety", "--scenarios", "1", "--lines", "hcmc_line1", "--controllers", "cbc", "--followers-max", "1", "--workers", "1",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "sumo loop" in text and "offline loop" in text and "95 % upper bound" in text
    runs = pd.read_csv(out / "safety.csv")
    assert sorted(runs["loop"]) == ["offline", "sumo"] and bool(np.isfinite(runs["min_margin_m"]).all())
    assert main(["study", "safety", "--loop", "sumo", "--kinds", "merge", "--out", str(tmp_path / "bad")]) == 2


def test_a_flying_start_never_departs_above_its_edge_limit(line_factory, network_factory):
    """A follower placed in a lower limit than its leader (scenario s00079 of a 100-scenario SUMO
    campaign: milano_bologna down) must not depart above it: SUMO refuses a faster departure.  The
    scenario starts it at most at its permitted speed (tests/test_safety_start.py); a faster start
    is an error, never lowered silently (that made the SUMO loop run another scenario than the offline loop)."""
    from vcsumo.errors import VcsumoError
    from vcsumo.rolling_stock import load_rolling_stock
    from vcsumo.route_profile import RouteProfile
    from vcsumo.studies.safety_sumo import flying_start

    net = network_factory("regional_graded")
    track = net.topology.track_for("main", "up")
    full = RouteProfile.from_edges(net.topology, track.edges)
    s_low = 500.0  # inside the 80 km/h limit over the terminus
    assert full.speed_limit_at(s_low) < 30.0
    with pytest.raises(VcsumoError, match=r"train x would start at 159.8 km/h above the 80 km/h limit where it stands"):
        flying_start(net.topology, list(track.edges), full, load_rolling_stock("regional_emu160"), "x", s_low, 44.4, "up")
    t = flying_start(net.topology, list(track.edges), full, load_rolling_stock("regional_emu160"), "x", s_low, full.speed_limit_at(s_low), "up")
    assert t.depart_speed_mps == full.speed_limit_at(s_low)
    t = flying_start(net.topology, list(track.edges), full, load_rolling_stock("regional_emu160"), "y", 10000.0, 30.0, "up")
    assert t.depart_speed_mps == 30.0
