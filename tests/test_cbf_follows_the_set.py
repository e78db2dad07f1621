"""The CBF's leader brake is the assumption set's (``relative_braking``), as the run-health monitor's
rule and cbc's spacing: before, cbf.yaml fixed it at the emergency brake, so under a set whose leaders
brake at most at service the CBF kept a wider spacing than cbc tracked and rode its boundary
(regional_graded convoy, cbf-cbc: 4,566 emergency brake applications, 0 of 5 followers formed)."""

from __future__ import annotations

import json

import pytest

from vcsumo.cli.main import main
from vcsumo.control.cbf import CBFConfig, CBFSupervisor, level_route, model_leader_braking
from vcsumo.control.registry import StackContext, build_follower_stack
from vcsumo.errors import VcsumoError
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, SeparationModel

SERVICE_SET = load_assumptions().model_copy(update={"name": "service_rel", "relative_braking": "service"})


@pytest.mark.parametrize("kind", ["emergency", "service"])
def test_the_barrier_is_the_health_rule_of_the_set_whatever_its_relative_braking(kind):
    model = SeparationModel(load_assumptions().model_copy(update={"relative_braking": kind}))
    lead, fol = load_rolling_stock("terlizzi2024_leader"), load_rolling_stock("terlizzi2024_follower")
    sup = CBFSupervisor(lead, fol, CBFConfig(), model=model)
    prof = level_route()
    m = sup.model_for(prof)
    rule = RelativeBraking(model, fol, lead, prof)  # the run-health monitor's rule (vcsumo.sim.health)
    s_l, v_l, v_f = 20000.0, 40.0, 35.0
    for s_f in (17000.0, 18500.0, 19500.0):  # (a follower without actuator dynamics: the set's dead time alone)
        assert m.required_gap_m(s_l, v_l, s_f, v_f, 0.0) == pytest.approx(rule.required_gap(s_f, v_f, s_l, v_l, model.dead_time_s), abs=1e-6)


def test_a_leader_brake_stronger_than_the_sets_is_kept_weaker_refused():
    st = load_rolling_stock("regional_emu160")
    svc = SeparationModel(SERVICE_SET)
    assert model_leader_braking(svc, CBFConfig()) == "service"
    assert model_leader_braking(svc, CBFConfig(leader_braking="emergency")) == "emergency"  # more than the set: allowed
    prof = level_route()
    wide = CBFSupervisor(st, st, CBFConfig(leader_braking="emergency"), model=svc).required_gap_m(prof, 20000.0, 40.0, 15000.0, 40.0, 0.0)
    own = CBFSupervisor(st, st, CBFConfig(), model=svc).required_gap_m(prof, 20000.0, 40.0, 15000.0, 40.0, 0.0)
    assert wide > own + 50.0
    with pytest.raises(VcsumoError, match="leader_braking 'service' is weaker than the assumption set 'etcs_typical'"):
        build_follower_stack("cbf-cbc", StackContext(ego=st, predecessor=st, step_s=0.2, supervisor_params=CBFConfig(leader_braking="service"),
                                                     assumptions=load_assumptions()))
    # the paper's own barrier (distance: fixed) is not on the set: its service-box leader stays allowed
    build_follower_stack("cbf-cbc", StackContext(ego=st, predecessor=st, step_s=0.2, supervisor_params="cbf_terlizzi2024"))


def test_a_convoy_under_a_service_relative_braking_set_forms_and_stays_healthy(tmp_path):
    aset = tmp_path / "service_rel.yaml"
    aset.write_text("\n".join(f"{k}: {json.dumps(v)}" for k, v in SERVICE_SET.model_dump(mode="json").items()) + "\n")
    out = tmp_path / "run"
    code = main(["-q", "run", "--line", "regional_graded", "--timetable", "convoy", "--regime", "vc", "--controller", "cbf-cbc",
                 "--assumptions", str(aset), "--out", str(out)])
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    vc = json.loads((out / "vc_summary.json").read_text())["summary"]
    assert s["healthy"] and s["assumptions"] == "service_rel"
    # the CBF and cbc's spacing agree on the leader's brake: every follower forms (before: 0 of 5, 4,566 emergency brake applications)
    assert vc["convoy_followers"] == vc["followers_formed"] == 5 and vc["followers_not_formed"] == 0


def test_a_campaign_with_a_cbf_file_weaker_than_its_set_is_one_error_line_before_anything_runs(tmp_path, capsys):
    from pathlib import Path

    import vcsumo

    shipped = (Path(vcsumo.__file__).parent / "data" / "controllers" / "cbf.yaml").read_text()
    weak = tmp_path / "weak_cbf.yaml"
    weak.write_text(shipped.replace("distance: model\n", "distance: model\nleader_braking: service\n"))
    out = tmp_path / "campaign"
    code = main(["study", "safety", "--scenarios", "2", "--controllers", "cbf-cbc", "--cbf", str(weak), "--workers", "1", "--out", str(out)])
    assert code == 2 and not out.exists()
    err = capsys.readouterr().err
    assert f"{weak}: leader_braking: 'service' is weaker than the assumption set 'etcs_typical'" in err
    assert err.strip().splitlines() == [next(x for x in err.strip().splitlines() if x.startswith("error:"))]  # one line, no progress bar before it
