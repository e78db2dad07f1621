"""Trade-off study: analytic capacity of FBS, MB and VC against the T2T delay bound, the braking
uncertainty and the position error, every regime under the same changed assumption set."""

import json

import pandas as pd
import pytest

from vcsumo.cli.main import main
from vcsumo.line import load_line
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel
from vcsumo.sim.network import build_network
from vcsumo.studies.tradeoff import (
    BREAKEVEN_COLUMNS, RULE_INPUTS, TRADEOFF_COLUMNS, TradeoffConfig, TradeoffLine, breakeven_delays, capacities, changed, study_units,
    tradeoff_table,
)

from .conftest import write

pytestmark = pytest.mark.sumo  # netconvert builds the networks

SWEEPS = {"t2t_delay_bound_s": [0.1, 0.25, 0.5, 1.0, 2.0, 3.0], "braking_uncertainty": [0.0, 0.05, 0.1, 0.15, 0.2],
          "position_error_m": [0.0, 5.0, 10.0, 20.0, 50.0]}


@pytest.fixture(scope="module")
def graded(line_factory, network_factory):
    """regional_graded, up, all stops: grades from −10 to +10 ‰ under the stations and a restriction on a descent."""
    return TradeoffLine(line_factory("regional_graded"), network_factory("regional_graded"), load_rolling_stock("regional_emu160"), "up", "all-stops")


@pytest.fixture(scope="module")
def graded_table(graded):
    return tradeoff_table(graded, load_assumptions(), SWEEPS, [2, 3, 4])


def _series(table, param, regime, n):
    r = table[(table.parameter == param) & (table.regime == regime) & (table.convoy_size == n)].sort_values("value")
    return r.value.to_numpy(), r.capacity_trains_per_h.to_numpy()


def test_table_is_tidy_and_passes_through_the_base(graded_table):
    t = graded_table
    assert list(t.columns) == TRADEOFF_COLUMNS
    assert (t.error == "").all() and t.capacity_trains_per_h.notna().all()
    base = load_assumptions()
    for param in SWEEPS:
        g = t[t.parameter == param]
        assert (g.base_value == getattr(base, param)).all()
        at_base = g[g.value == getattr(base, param)].set_index(["regime", "convoy_size"]).capacity_trains_per_h
        other = t[(t.parameter == "t2t_delay_bound_s") & (t.value == base.t2t_delay_bound_s)].set_index(["regime", "convoy_size"]).capacity_trains_per_h
        assert at_base.to_dict() == other.to_dict()  # every sweep's base point is the same computation
    for _, r in t.iterrows():
        assert r.capacity_trains_per_h == pytest.approx(3600.0 * r.convoy_size / r.headway_s, rel=1e-3)
    g = t.set_index(["parameter", "value", "regime", "convoy_size"])
    for (p, v, reg, n), r in g.iterrows():
        assert r.gain_vs_fbs == pytest.approx(r.capacity_trains_per_h / g.loc[(p, v, "fbs", 1)].capacity_trains_per_h, rel=1e-3)
        assert r.gain_vs_mb == pytest.approx(r.capacity_trains_per_h / g.loc[(p, v, "mb", 1)].capacity_trains_per_h, rel=1e-3)


def test_delay_bound_moves_vc_only(graded_table):
    """The T2T delay bound enters the relative-braking gap only: VC capacity falls as it grows, FBS and
    MB (computed under the same changed set) do not move at all."""
    t = graded_table
    for regime, n in (("fbs", 1), ("mb", 1)):
        _, cap = _series(t, "t2t_delay_bound_s", regime, n)
        assert len(set(cap)) == 1
    for n in (2, 3, 4):
        _, cap = _series(t, "t2t_delay_bound_s", "vc", n)
        assert all(b < a for a, b in zip(cap, cap[1:])), cap
    rows = t[t.parameter == "t2t_delay_bound_s"]
    assert not rows[rows.regime != "vc"].parameter_in_rule.any() and rows[rows.regime == "vc"].parameter_in_rule.all()


@pytest.mark.parametrize("param", ["braking_uncertainty", "position_error_m"])
def test_worse_braking_or_positions_lower_every_regime(graded_table, param):
    """More braking uncertainty (a weaker guaranteed brake, a stronger leader) and more position error
    (a longer margin, a signal approached earlier) lower the capacity of every regime: never higher,
    and lower at the end of the sweep than at its base."""
    base = getattr(load_assumptions(), param)
    for regime, n in study_units([2, 3, 4]):
        x, cap = _series(graded_table, param, regime, n)
        assert all(b <= a + 1e-9 for a, b in zip(cap, cap[1:])), (regime, n, cap)
        assert cap[-1] < cap[list(x).index(base)], (regime, n, cap)
    assert graded_table[graded_table.parameter == param].parameter_in_rule.all()


@pytest.mark.parametrize("field,value", [
    ("t2t_delay_bound_s", 2.0), ("braking_uncertainty", 0.15), ("position_error_m", 30.0), ("reaction_time_s", 1.5), ("brake_build_up_s", 5.0),
    ("position_report_period_s", 5.0), ("safety_margin_m", 150.0), ("overlap_m", 200.0), ("fixed_time_s", 6.0), ("absolute_braking", "emergency"),
    ("relative_braking", "service"), ("speed_tolerance_kmh", 10.0),
])
def test_rule_inputs_are_what_the_headways_use(graded, field, value):
    """RULE_INPUTS (the table's parameter_in_rule) is checked against the computation: changing an
    assumption changes exactly the headways of the regimes that declare it."""
    base = load_assumptions()
    units = study_units([2])
    before = capacities(graded, base, units)
    after = capacities(graded, changed(base, **{field: value}), units)
    moved = {r0["regime"] for r0, r1 in zip(before, after) if abs(r1["headway_s"] - r0["headway_s"]) > 1e-6}
    assert moved == {reg for reg, inputs in RULE_INPUTS.items() if field in inputs}


LEVEL_LINE = """\
name: level_long
title: 40 km level double track at 160 km/h, 2 km blocks (test line)
km_start: 0.0
km_end: 40.0
tracks: double
line_speed_kmh: 160
directions: {up: west -> east, down: east -> west}
default_train: regional_emu160
stations:
  - {id: W, name: West, km: 0.5, platform_length_m: 170, dwell_s: 60}
  - {id: E, name: East, km: 39.5, platform_length_m: 170, dwell_s: 60}
signalling:
  block_length_m: 2000
headway:
  measuring_points_km: [20.0, 30.0]
  release_km: {up: 12.0, down: 28.0}
"""


@pytest.fixture(scope="module")
def level(tmp_path_factory):
    path = write(tmp_path_factory.mktemp("level") / "level_long" / "line.yaml", LEVEL_LINE)
    line = load_line(path)
    return TradeoffLine(line, build_network(line), load_rolling_stock("regional_emu160"), "up", "non-stop")


def test_hand_numbers_on_a_long_level_line(level):
    """At 160 km/h on level track every regime is the uniform-speed formula, with the separation
    model's gaps (SeparationModel) and the supervision's 1.5 steps of extra dead time:
    MB  H = (D + margin + 2e + L)/v + P,        D = v·(T + 1.5Δt) + v²/(2·a_service,guaranteed)
    VC  H = MB's + (n − 1)·(L + vc_gap(v))/v   (each follower the coupled gap behind the train ahead)
    FBS H = (D + e + B + overlap + e + L)/v    (B the longest block on the stretch)."""
    base = load_assumptions()
    stock = level.stock
    sweeps = {"t2t_delay_bound_s": [0.1, 3.0], "braking_uncertainty": [0.0, 0.2], "position_error_m": [0.0, 50.0]}
    t = tradeoff_table(level, base, sweeps, [2, 4])
    assert (t.release_speed_kmh == 160.0).all()
    v = 160.0 / 3.6
    L = stock.length_m
    from vcsumo.studies.capacity import route_setup

    sig = route_setup(level.line, level.net, stock, "up", 0.5, SeparationModel(base)).full.signal_positions(level.net.topology)
    sig = [s for s in sig if 12_000.0 < s < 38_000.0]
    block = max(b - a for a, b in zip(sig, sig[1:]))
    for (param, value), g in t.groupby(["parameter", "value"]):
        a = changed(base, **{param: value})
        m = SeparationModel(a)
        cap = g.set_index(["regime", "convoy_size"]).capacity_trains_per_h

        def d_abs(dt):
            return m.absolute_gap(stock, v) - m.margin_m + 1.5 * dt * v  # v·(T + 1.5Δt) + v²/2a

        h_mb = (d_abs(0.5) + m.margin_m + L) / v + a.position_report_period_s
        h_fbs = (d_abs(0.5) + a.position_error_m + block + a.overlap_m + a.position_error_m + L) / v
        assert cap[("mb", 1)] == pytest.approx(3600.0 / h_mb, rel=1e-3), (param, value)
        assert cap[("fbs", 1)] == pytest.approx(3600.0 / h_fbs, rel=1e-3), (param, value)
        for n in (2, 4):
            h_vc = (d_abs(0.2) + m.margin_m + L) / v + a.position_report_period_s + (n - 1) * (L + m.vc_gap(stock, stock, v)) / v
            assert cap[("vc", n)] == pytest.approx(3600.0 * n / h_vc, rel=1e-3), (param, value, n)
    # the base point by hand: guaranteed service brake min(0.8·0.9, box 0.74) = 0.72 m/s² plus Davis A
    # at the bottom of its box over the heaviest mass (2160 N / 180 t), over ρ 1.06: a = 0.69057 m/s²;
    # T = 0.5 + 3/2 + 1.5·0.5 = 2.75 s; D = 44.444·2.75 + 44.444²/(2·0.69057) = 122.22 + 1430.19 = 1552.41 m
    a_f = (0.72 + 2160.0 / 180000.0) / 1.06
    d = v * 2.75 + v * v / (2.0 * a_f)
    assert d == pytest.approx(1552.41, abs=0.05)
    h_mb = (d + 50.0 + 20.0 + 75.0) / v + 2.0  # 38.192 s + 2 s report period = 40.192 s: 89.57 trains/h
    h_fbs = (d + 10.0 + block + 50.0 + 10.0 + 75.0) / v
    at_base = t[(t.parameter == "t2t_delay_bound_s") & (t.value == 0.5)].set_index("regime").capacity_trains_per_h
    assert 3600.0 / h_mb == pytest.approx(89.57, abs=0.01)
    assert at_base["mb"] == pytest.approx(3600.0 / h_mb, rel=1e-3)
    assert at_base["fbs"] == pytest.approx(3600.0 / h_fbs, rel=1e-3)


def test_breakeven_delay_is_where_vc_meets_mb(line_factory, network_factory):
    """felez_test (short trains, 100 km/h): VC's lead over MB is used up at a finite delay bound; at the
    reported bound VC's capacity equals MB's, below it VC is ahead, above it behind."""
    tl = TradeoffLine(line_factory("felez_test"), network_factory("felez_test"), load_rolling_stock("felez2019"), "up", "non-stop")
    base = load_assumptions()
    be = breakeven_delays(tl, base, [2])
    assert list(be.columns) == BREAKEVEN_COLUMNS
    d = float(be.breakeven_value.iloc[0])
    assert 0.0 < d < 30.0
    mb = capacities(tl, base, [("mb", 1)])[0]["capacity_trains_per_h"]

    def vc(x):
        return capacities(tl, changed(base, t2t_delay_bound_s=x), [("vc", 2)])[0]["capacity_trains_per_h"]

    assert vc(d - 0.1) > mb > vc(d + 0.1)
    assert vc(d) == pytest.approx(mb, rel=2e-3)


def test_cli_writes_the_files_and_checks_against_the_loop(in_tmp, capsys):
    """The command writes the tidy table, the break-even, the simulated check and the figure, and
    records the assumption set; VC n=2 simulated within 10 % of its analytic headway (issue 10)."""
    args = ["study", "tradeoff", "--line", "felez_test", "--delays", "0.5,3", "--uncertainties", "0.2", "--position-errors", "",
            "--convoy-sizes", "2,3", "--grid", "--simulate-check", "2", "--out", "to"]
    assert main(args) == 0
    out = in_tmp / "to"
    t = pd.read_csv(out / "tradeoff.csv", keep_default_na=False, na_values=[""])
    assert list(t.columns) == TRADEOFF_COLUMNS
    assert set(t.parameter) == {"t2t_delay_bound_s", "braking_uncertainty", "grid"}
    assert set(zip(t.regime, t.convoy_size)) == {("fbs", 1), ("mb", 1), ("vc", 2), ("vc", 3)}
    assert sorted(t[t.parameter == "braking_uncertainty"].value.unique()) == [0.1, 0.2]  # the base value joins the sweep
    grid = t[t.parameter == "grid"]
    assert len(grid) == 4 * 2 * 2  # (0.5, 3 s) × (±10, ±20 %) × 4 units
    check = pd.read_csv(out / "tradeoff_check.csv", keep_default_na=False, na_values=[""])
    assert len(check) == 2 and (check.error.fillna("") == "").all()
    assert check.iloc[0].value == 0.5  # the base set first, then the farthest delay bound
    for _, c in check.iterrows():
        an = t[(t.parameter == c.parameter) & (t.value == c.value) & (t.regime == "vc") & (t.convoy_size == 2)].iloc[0]
        assert c.headway_analytic_s == an.headway_s
        assert abs(c.deviation_pct) < 10.0 and c.collisions == 0
    assert (out / "tradeoff.png").stat().st_size > 20_000
    be = pd.read_csv(out / "tradeoff_breakeven.csv")
    assert list(be.convoy_size) == [2, 3]
    meta = json.loads((out / "meta.json").read_text())
    assert meta["parameters"]["assumptions"]["name"] == "etcs_typical"
    assert meta["parameters"]["assumptions"]["t2t_delay_bound_s"] == 0.5
    text = capsys.readouterr().out
    assert "trade-off — felez_test" in text and "check VC n=2 (cbc)" in text


def test_figure_is_drawn_from_the_csv_and_shows_what_the_rule_ignores(in_tmp, graded_table):
    """The plot reads only the CSV; in the delay panel FBS and MB are dashed (their rules do not use
    the delay), VC solid; the base value is marked."""
    from vcsumo.plots.tradeoff import plot_tradeoff

    graded_table.to_csv("t.csv", index=False)
    fig = plot_tradeoff(in_tmp / "t.csv", in_tmp / "t.png")
    assert (in_tmp / "t.png").stat().st_size > 20_000
    ax = fig.axes[0]
    assert "delay" in ax.get_xlabel() and ", s" in ax.get_xlabel() and "trains/h" in ax.get_ylabel()
    styles = [ln.get_linestyle() for ln in ax.lines if len(ln.get_xdata()) == len(SWEEPS["t2t_delay_bound_s"])]
    assert styles == ["--", "--", "-", "-", "-"]
    assert any(len(ln.get_xdata()) == 2 and ln.get_xdata()[0] == 0.5 == ln.get_xdata()[1] for ln in ax.lines)  # the base mark
    assert "dashed: FBS, MB — rule does not use it" in ax.get_title(loc="left")
    assert fig.axes[1].get_xlabel().startswith("braking uncertainty, ± %")


@pytest.mark.parametrize("extra,field", [
    (["--delays", "0.5,x"], "--delays"),
    (["--delays", "-1"], "--delays"),
    (["--uncertainties", "0.7"], "--uncertainties"),
    (["--position-errors", "600"], "--position-errors"),
    (["--convoy-sizes", "1,2"], "--convoy-sizes"),
    (["--simulate-check", "-1"], "--simulate-check"),
    (["--delays", "", "--uncertainties", "", "--position-errors", ""], "--delays"),
    (["--assumptions", "no_such_set"], "--assumptions"),
    (["--train", "no_such_train"], "--train"),
    (["--simulate-check", "1", "--controller", "no_such_controller"], "controller"),
])
def test_bad_inputs_give_one_line(in_tmp, capsys, extra, field):
    assert main(["study", "tradeoff", "--line", "felez_test", "--out", "bad", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and len(err.splitlines()) == 1 and field in err, err
    assert not (in_tmp / "bad").exists() and not list(in_tmp.glob("bad.partial-*"))


def test_config_bounds_are_the_assumption_sets():
    with pytest.raises(Exception, match="less than or equal to 30"):
        TradeoffConfig(line="x", delays_s=[31.0])
    assert TradeoffConfig(line="x", delays_s=[2.0, 0.5, 2.0]).delays_s == [0.5, 2.0]


def test_study_file_runs_the_same_command(in_tmp, capsys):
    study = write(in_tmp / "t.yaml", "study: tradeoff\nline: felez_test\ndelays_s: [0.5, 2]\nuncertainties: []\nposition_errors_m: [0, 20]\n"
                                      "convoy_sizes: [2]\nout: tout\n")
    assert main(["study", "run", str(study)]) == 0
    t = pd.read_csv(in_tmp / "tout" / "tradeoff.csv")
    assert set(t.parameter) == {"t2t_delay_bound_s", "position_error_m"}
    meta = json.loads((in_tmp / "tout" / "meta.json").read_text())
    assert meta["inputs"]["study"]["path"].endswith("t.yaml")
    bad = write(in_tmp / "bad.yaml", "study: tradeoff\nline: felez_test\ndelays_s: [40]\n")
    capsys.readouterr()
    assert main(["study", "run", str(bad)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "delays_s" in err and "less than or equal to 30" in err
