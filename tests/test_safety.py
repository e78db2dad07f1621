"""The Monte Carlo safety campaign (vcsumo study safety): scenarios, runs, resume, failures, CLI."""

import math

import pandas as pd
import pytest

from vcsumo.cli.main import main
from vcsumo.control.base import Command
from vcsumo.errors import InputError
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.studies.safety import (
    SAFETY_COLUMNS, SafetyCampaign, SampledController, check_campaign, draw_scenario, line_route, read_safety, run_faults, run_safety_campaign,
    run_scenario, scenario_task, summarize_safety, violation_upper_bound,
)


def test_scenarios_are_seeded_and_within_the_configured_ranges():
    cfg = SafetyCampaign(scenarios=10)
    a = [draw_scenario(cfg, k) for k in range(40)]
    b = [draw_scenario(cfg.model_copy(update={"scenarios": 5000, "controllers": ["cbc"]}), k) for k in range(40)]
    assert a == b  # scenario k does not depend on the campaign size or the controllers
    assert draw_scenario(cfg.model_copy(update={"seed": 7}), 3) != a[3]
    for sp in a:
        assert 0.0 <= sp.loss_probability <= cfg.loss_max
        assert 0.0 <= sp.delay_s <= cfg.delay_max_s
        assert 0.0 <= sp.position_error_m <= cfg.position_error_max_m
        assert 1 <= sp.followers <= cfg.followers_max and len(sp.corners) == sp.followers + 1
        assert sp.outage is None or 1.0 <= sp.outage[1] - sp.outage[0] <= cfg.outage_max_s
        route = line_route(sp.line, sp.direction)
        assert len(sp.stocks) == sp.followers + 1 and set(sp.stocks) <= set(cfg.rolling_stock) | {route.stock.name}
        v_top = min(load_rolling_stock(n).max_speed_ms for n in sp.stocks)
        assert 0.0 < sp.leader_speed_mps <= min(v_top, route.profile.max_speed()) + 1e-9
        if sp.kind in ("merge", "split"):
            assert route.junctions and any(abs(j.s_m - sp.junction_s_m) < 1e-6 for j in route.junctions)
    assert {sp.kind for sp in a} == {"cruise", "forming", "merge", "split"}
    assert all(sp.kind in ("cruise", "forming") for sp in a if sp.line == "hcmc_line1")  # no junction on the metro line
    assert any(len(set(sp.stocks)) > 1 for sp in a)  # heterogeneous convoys are drawn
    assert all(len(set(sp.stocks)) == 1 for sp in (draw_scenario(cfg.model_copy(update={"heterogeneous_probability": 0.0}), k) for k in range(10)))
    sumo = [draw_scenario(cfg.model_copy(update={"loop": "sumo"}), k) for k in range(20)]
    assert {sp.kind for sp in sumo} <= {"cruise", "forming"}


class _Counting:
    def __init__(self):
        self.calls = 0

    def make_step(self, obs):
        self.calls += 1
        return Command(force_n=float(self.calls))


def test_sampled_controller_holds_between_periods():
    from types import SimpleNamespace

    inner = _Counting()
    ctl = SampledController(inner, 0.4)
    forces = [ctl.make_step(SimpleNamespace(time_s=k * 0.2)).force_n for k in range(6)]
    assert inner.calls == 3 and forces == [1.0, 1.0, 2.0, 2.0, 3.0, 3.0]


@pytest.fixture(scope="module")
def cruise_scenario():
    cfg = SafetyCampaign(lines=["firenze_bologna"], kinds=["cruise"], followers_max=1, outage_probability=0.0, heterogeneous_probability=0.0)
    return cfg, draw_scenario(cfg, 0)


def test_cbf_supervision_keeps_the_safe_separation_under_the_leaders_emergency_brake(cruise_scenario):
    cfg, sp = cruise_scenario
    sup = run_scenario(sp, "cbf-cbc", cfg)
    raw = run_scenario(sp, "cbc", cfg)
    # the leader brakes to a stop at the top of its emergency range; the supervised follower keeps the
    # run-health monitor's rule (relative braking on the true states) at every step, and the CBF's true barrier ≤ 0
    assert sup["error"] == "" and sup["loop"] == "offline" and sup["leader_stock"] == "etr1000"
    assert sup["separation_violations"] == 0 and sup["collisions"] == 0 and sup["below_separation_time_s"] == 0.0
    assert sup["min_margin_m"] >= 0.0 and sup["min_gap_m"] >= 70.0  # margin + 2 position errors of etcs_typical
    assert sup["initial_true_barrier_m"] <= 0.0 and sup["max_true_barrier_m"] <= 1e-6
    assert sup["emergency_activations"] >= 1
    # the consensus controller has no barrier; its separation guard keeps the rule too.  (Until cbc's
    # spacing budgeted the channel's message age and the build-up from full traction, the CBF rode its
    # boundary — 55 one-step emergency brakings, 27 s — and so left 0.5 m more room than cbc alone; now
    # 36 and 13.6 s, and the two minimum margins are within 0.1 m, 6.55 and 6.65 m.)
    assert math.isnan(raw["max_true_barrier_m"]) and raw["separation_violations"] == 0 and raw["min_margin_m"] >= 0.0


def test_violation_bound_is_the_rule_of_three_or_clopper_pearson():
    assert violation_upper_bound(0, 1000) == pytest.approx(0.003)
    assert violation_upper_bound(0, 100) == pytest.approx(0.03)
    # k = n − 1: P(X ≤ n − 1) = 1 − p^n = 0.05  →  p = 0.95^(1/n)
    assert violation_upper_bound(9, 10) == pytest.approx(0.95 ** 0.1, abs=1e-9)
    assert violation_upper_bound(1, 10) == pytest.approx(0.3942, abs=1e-4)
    assert violation_upper_bound(10, 10) == 1.0 and math.isnan(violation_upper_bound(0, 0))
    b = [violation_upper_bound(k, 200) for k in range(6)]
    assert all(x < y for x, y in zip(b[1:], b[2:])) and b[1] > 1 / 200


def test_summary_states_the_campaign_size_and_the_bound():
    rows = [{"loop": "offline", "controller": "cbc", "supervised": False, "separation_violations": v, "collisions": c, "error": "",
             "initial_true_barrier_m": math.nan, "max_true_barrier_m": math.nan, "min_gap_m": 80.0, "min_margin_m": -1.0 if v else 2.0,
             "max_impact_kmh": 0.0, "emergency_activations": 1, "emergency_time_s": 1.0, "time_lost_s": 0.0, "wall_time_s": 0.1}
            for v, c in [(0, 0)] * 18 + [(2, 0), (1, 1)]]
    rows.append({**rows[0], "error": "boom"})
    s = summarize_safety(pd.DataFrame(rows)).iloc[0]
    assert s["scenarios"] == 20 and s["failed_runs"] == 1 and s["scenarios_with_violation"] == 2 and s["separation_violations"] == 3
    assert s["violation_rate"] == 0.1 and s["violation_rate_upper95"] == pytest.approx(violation_upper_bound(2, 20))


def _run(scenario: str, controller: str = "cbf-cbc", **kw) -> dict:
    """A finished row of safety.csv: a clean supervised run unless ``kw`` says otherwise."""
    row = {c: 0 for c in SAFETY_COLUMNS} | {
        "key": f"h:offline:{scenario}:{controller}", "loop": "offline", "scenario": scenario, "controller": controller, "supervised": controller.startswith("cbf-"),
        "line": "hcmc_line1", "direction": "up", "kind": "cruise", "followers": 1, "leader_stock": "hcmc_l1", "follower_stocks": "hcmc_l1",
        "initial_gap_m": 300.0, "min_gap_m": 120.0, "min_margin_m": 5.0, "initial_true_barrier_m": -40.0, "max_true_barrier_m": -2.0, "error": ""}
    if not row["supervised"]:
        row |= {"initial_true_barrier_m": math.nan, "max_true_barrier_m": math.nan}
    return row | kw


# one finished run per case of the rule, and what is wrong with it (None: clean)
VERDICT_RUNS = {
    "clean": (_run("s00000"), None),
    "clean, unsupervised": (_run("s00001", "cbc"), None),
    "started outside the safe set, b never above b(0)": (_run("s00002", initial_true_barrier_m=3.0, max_true_barrier_m=3.0), None),
    "violation only": (_run("s00003", separation_violations=1, min_margin_m=-0.4, below_separation_time_s=1.2), "a separation violation"),
    "collision only": (_run("s00004", collisions=1, max_impact_kmh=4.0), "a collision"),
    "barrier breach only": (_run("s00005", max_true_barrier_m=0.5), "a barrier breach"),
    "breach above b(0) > 0": (_run("s00006", initial_true_barrier_m=3.0, max_true_barrier_m=3.5), "a barrier breach"),
}


def _cli_on(rows: list[dict], monkeypatch, tmp_path, capsys) -> tuple[int, pd.DataFrame, str, str]:
    """``vcsumo study safety`` on a campaign whose runs are ``rows``: its exit status, the summary it
    writes, its stdout and its stderr but the progress bar (nothing is simulated)."""
    from vcsumo.studies import safety

    written = {}
    df = pd.DataFrame(rows, columns=SAFETY_COLUMNS)
    monkeypatch.setattr(safety, "run_safety_campaign", lambda cfg, out, **kw: df.copy())
    monkeypatch.setattr(safety, "write_safety_report", lambda out, cfg, d, summary, t: written.setdefault("summary", summary))
    capsys.readouterr()
    code = main(["study", "safety", "--scenarios", str(len(rows)), "--workers", "1", "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    return code, written["summary"], cap.out, "\n".join(ln for ln in cap.err.splitlines() if "safety (offline)" not in ln)  # without the progress bar


@pytest.mark.parametrize("case", list(VERDICT_RUNS))
def test_the_exit_status_and_the_summary_judge_a_run_by_one_rule(case, monkeypatch, tmp_path, capsys):
    """A run alone: the CLI exits 1 exactly when the summary counts it (a violation, a collision or a
    barrier breach), with one line naming what was wrong; else 0 and the bar is met."""
    row, wrong = VERDICT_RUNS[case]
    code, summary, out, err = _cli_on([row], monkeypatch, tmp_path, capsys)
    s = summary.iloc[0]
    counted = int(s["scenarios_with_violation"]) + int(s["barrier_breaches"])
    assert code == (1 if wrong else 0) and counted == (1 if wrong else 0), (code, s.to_dict())
    assert ("bar met" in out) == (wrong is None) and ("bar NOT met" in out) == (wrong is not None)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if wrong:
        assert lines == [f"error: 1 of 1 runs of the safety campaign is not clean (1 not healthy: 1 with {wrong}); "
                         f"results kept in {tmp_path / 'o' / 'safety.csv'}"]
    else:
        assert lines == []


def test_summary_counts_and_exit_verdict_agree_on_a_mixed_campaign(monkeypatch, tmp_path, capsys):
    rows = [row for row, _ in VERDICT_RUNS.values()] + [_run("s00007", "cbc", error="boom")]
    code, summary, out, err = _cli_on(rows, monkeypatch, tmp_path, capsys)
    finished = pd.DataFrame(rows[:-1])
    faults = run_faults(finished)
    assert [list(faults.columns[r]) for _, r in faults.iterrows()] == [[], [], [], ["separation_violation"], ["collision"], ["barrier_breach"],
                                                                        ["barrier_breach"]]
    assert summary["scenarios_with_violation"].sum() == 2 and summary["collisions"].sum() == 1 and summary["barrier_breaches"].sum() == 2
    assert summary["failed_runs"].sum() == 1 and summary["scenarios"].sum() == 7
    assert code == 1 and "bar NOT met" in out
    assert err.strip() == (f"error: 5 of 8 runs of the safety campaign are not clean (1 failed, 4 not healthy: 1 with a separation violation, "
                           f"1 with a collision, 2 with a barrier breach); results kept in {tmp_path / 'o' / 'safety.csv'}")


def test_campaign_resumes_and_keeps_finished_rows(tmp_path):
    cfg = SafetyCampaign(lines=["hcmc_line1"], controllers=["cbc", "cbf-cbc"], scenarios=2, followers_max=1)
    df1 = run_safety_campaign(cfg, tmp_path / "c", workers=1)
    assert len(df1) == 4 and (df1["error"] == "").all() and list(pd.read_csv(tmp_path / "c" / "safety.csv").columns) == SAFETY_COLUMNS
    seen = []
    df2 = run_safety_campaign(cfg.model_copy(update={"scenarios": 3}), tmp_path / "c", workers=1, progress=lambda d, t: seen.append((d, t)))
    assert len(df2) == 6 and seen[0] == (2, 3) and seen[-1] == (3, 3)  # only scenario 2 ran
    kept = df2.set_index("key").loc[df1["key"], "wall_time_s"]
    assert list(kept) == list(df1["wall_time_s"])
    # a line cut off by an interruption is dropped and that run is done again
    path = tmp_path / "c" / "safety.csv"
    path.write_bytes(path.read_bytes()[:-20])
    df3 = run_safety_campaign(cfg.model_copy(update={"scenarios": 3}), tmp_path / "c", workers=1)
    assert len(df3) == 6 and len(read_safety(tmp_path / "c")) == 6
    s = summarize_safety(df3)
    assert set(s["controller"]) == {"cbc", "cbf-cbc"} and (s["scenarios"] == 3).all()
    assert int(s.loc[s["controller"] == "cbf-cbc", "scenarios_with_violation"].iloc[0]) == 0 and (s["loop"] == "offline").all()


def test_failing_scenario_becomes_rows_with_its_error():
    cfg = SafetyCampaign(lines=["no_such_line"], controllers=["cbc", "mpc"])
    rows = scenario_task((cfg, 0, ("cbc", "mpc")))
    assert [r["controller"] for r in rows] == ["cbc", "mpc"] and all("no_such_line" in r["error"] for r in rows)


def test_bad_campaign_inputs_are_one_clear_error(tmp_path):
    with pytest.raises(InputError, match="unknown controller 'pid'"):
        check_campaign(SafetyCampaign(controllers=["pid"]))
    with pytest.raises(Exception, match="no_such_line"):
        check_campaign(SafetyCampaign(lines=["no_such_line"]))
    assert main(["study", "safety", "--scenarios", "2", "--controllers", "cbc,warp", "--out", str(tmp_path / "x")]) == 2
    assert main(["study", "safety", "--scenarios", "0", "--out", str(tmp_path / "y")]) == 2
    assert main(["study", "safety", "--kinds", "teleport", "--out", str(tmp_path / "z")]) == 2
    assert not any(tmp_path.iterdir())




def test_cli_writes_table_report_and_plot(tmp_path, capsys):
    out = tmp_path / "saf"
    code = main(["study", "safety", "--scenarios", "2", "--lines", "hcmc_line1", "--controllers", "cbc,cbf-cbc", "--workers", "2", "--out", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "cbf-cbc" in text and ("bar met" in text or "bar NOT met" in text) and "95 % upper bound" in text
    runs = pd.read_csv(out / "report" / "safety_runs.csv")
    assert len(runs) == 4 and (out / "report" / "safety_gaps.png").stat().st_size > 10_000
    assert (out / "report" / "meta.json").is_file() and (out / "report" / "safety_summary.csv").is_file()


def test_study_file_runs_the_campaign_and_is_validated(tmp_path):
    study = tmp_path / "s.yaml"
    study.write_text("study: safety\nlines: [hcmc_line1]\ncontrollers: [cbf-cbc]\nscenarios: 1\nfollowers_max: 1\nworkers: 1\n")
    assert main(["study", "run", str(study), "--out", str(tmp_path / "o")]) == 0
    meta = (tmp_path / "o" / "report" / "meta.json").read_text()
    assert "s.yaml" in meta and '"scenarios": 1' in meta and "eclipse-sumo" in meta
    bad = tmp_path / "b.yaml"
    bad.write_text("study: safety\nlines: [hcmc_line1]\nscenarois: 10\n")
    with pytest.raises(InputError, match="scenarois"):
        from vcsumo.cli.study_files import load_study

        load_study(bad)
