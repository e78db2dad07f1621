"""UIC 406 on the one separation model: the blocking times of the batch's capacity consumption are
the regimes' analytic headways (the capacity study's rules), under the run's assumption set —
not SUMO's nominal braking with a fixed 50 m margin and a 50 m coupled gap (before)."""

import pytest

from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.regimes.base import HeadwayInputs
from vcsumo.signalling.regimes.fbs import FixedBlock
from vcsumo.signalling.regimes.mb import MovingBlock
from vcsumo.signalling.scheduled_run import at_time_zero, timetable_run
from vcsumo.signalling.separation import SeparationModel
from vcsumo.signalling.uic406 import capacity_consumption, convoy_pairs
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write

STEP_S = 0.5


def _trains(tmp_path, line, net, n=2, destination="STOP"):
    path = write(tmp_path / "t.yaml", f"name: t\nline: felez_test\nservices:\n  - {{id: T, train: felez2019, origin: ORIG, destination: {destination}, "
                 f"departure: 0, repeat: {{count: {n}, every_s: 600}}}}\n")
    tt, p = load_timetable(path, line)
    return plan_trains(tt, p, line, net.topology, dt=STEP_S)


def _inputs(model, t, net, s_a, s_b):
    run = timetable_run(at_time_zero(t), STEP_S, model)
    run = run[run.s_m >= s_a].reset_index(drop=True)  # from the departure at ORIG (the section's start)
    signals = [x for x in t.profile.signal_positions(net.topology) if s_a + 1e-3 < x < s_b - 1e-3]
    return HeadwayInputs(model, t.stock, t.profile, run, signals, STEP_S, s_check_m=s_b, route_end_m=s_b)


@pytest.mark.parametrize("changes", [{}, {"fixed_time_s": 6.0, "position_error_m": 30.0, "overlap_m": 120.0}])
def test_fbs_consumption_cycle_is_the_fixed_block_regimes_headway_per_train(tmp_path, line_factory, network_factory, changes):
    line, net = line_factory("felez_test"), network_factory("felez_test")
    model = SeparationModel(load_assumptions().model_copy(update=changes))
    trains = _trains(tmp_path, line, net)
    df = capacity_consumption(line, net.topology, trains, "fbs", model=model, step_s=STEP_S)
    row = df[(df.direction == "up") & (df.section == "ORIG-STOP")].iloc[0]
    t = trains[0]
    s_a, s_b = t.profile.s_of("main", row.from_km), t.profile.s_of("main", row.to_km)
    h = FixedBlock().analytic_headway(_inputs(model, t, net, s_a, s_b)).headway_s
    # two identical trains: the cycle is two minimum headways (reported to 0.01 s)
    assert row.trains == 2 and row.cycle_s == pytest.approx(2 * h, abs=0.02), (row.cycle_s, h)


def test_mb_consumption_cycle_is_the_moving_block_regimes_headway_within_a_virtual_block(tmp_path, line_factory, network_factory):
    line, net = line_factory("felez_test"), network_factory("felez_test")
    model = SeparationModel(load_assumptions().model_copy(update={"position_report_period_s": 5.0}))
    trains = _trains(tmp_path, line, net, destination="end")  # through STOP: the run goes on beyond the section
    df = capacity_consumption(line, net.topology, trains, "mb", model=model, step_s=STEP_S, virtual_block_m=5.0)
    row = df[(df.direction == "up") & (df.section == "ORIG-STOP")].iloc[0]
    t = trains[0]
    s_a, s_b = t.profile.s_of("main", row.from_km), t.profile.s_of("main", row.to_km)
    h = MovingBlock().analytic_headway(_inputs(model, t, net, s_a, s_b)).headway_s
    # the stairs' virtual blocks (5 m here) and the analytic profile's 50 m grid sample H(y) differently: within 1 %
    assert row.cycle_s / 2 == pytest.approx(h, rel=0.01), (row.cycle_s, h)


def test_a_set_with_stronger_assumptions_consumes_more_and_vc_keeps_the_coupled_gap(line_factory, network_factory):
    line, net = line_factory("felez_test"), network_factory("felez_test")
    tt, p = load_timetable("convoy", line)
    trains = plan_trains(tt, p, line, net.topology, dt=STEP_S)
    pairs = convoy_pairs(tt, trains)
    base = SeparationModel(load_assumptions())
    worse = SeparationModel(load_assumptions().model_copy(update={"braking_uncertainty": 0.2, "t2t_delay_bound_s": 2.0}))
    for regime in ("fbs", "mb", "vc"):
        a = capacity_consumption(line, net.topology, trains, regime, pairs, model=base, step_s=STEP_S).cycle_s.sum()
        b = capacity_consumption(line, net.topology, trains, regime, pairs, model=worse, step_s=STEP_S).cycle_s.sum()
        assert b > a, (regime, a, b)


def test_a_timetable_longer_than_the_window_is_judged_in_its_busiest_window(tmp_path, line_factory, network_factory):
    # ten trains a minute apart, then five ten minutes apart from 4,000 s: the busiest hour is the first ten alone
    # (before, all fifteen were compressed into one hour: a full day on italy_av_north was 1,017 % of an hour, now 73.9 %)
    line, net = line_factory("felez_test"), network_factory("felez_test")
    path = write(tmp_path / "two.yaml", "name: two\nline: felez_test\nservices:\n"
                 "  - {id: A, train: felez2019, origin: ORIG, destination: STOP, departure: 0, repeat: {count: 10, every_s: 60}}\n"
                 "  - {id: B, train: felez2019, origin: ORIG, destination: STOP, departure: 4000, repeat: {count: 5, every_s: 600}}\n")
    tt, p = load_timetable(path, line)
    trains = plan_trains(tt, p, line, net.topology, dt=STEP_S)
    both = capacity_consumption(line, net.topology, trains, "fbs", step_s=STEP_S)
    first = capacity_consumption(line, net.topology, [t for t in trains if t.service == "A"], "fbs", step_s=STEP_S)
    row, ref = (df[(df.direction == "up") & (df.section == "ORIG-STOP")].iloc[0] for df in (both, first))
    assert row.trains == 15 and row.trains_in_window == 10 and ref.trains_in_window == 10
    assert row.occupation_s == ref.occupation_s and row.cycle_s == ref.cycle_s and row.peak_window_start_s == ref.peak_window_start_s
    # the sparse hour alone: five trains, less
    later = capacity_consumption(line, net.topology, [t for t in trains if t.service == "B"], "fbs", step_s=STEP_S)
    assert later[(later.direction == "up") & (later.section == "ORIG-STOP")].iloc[0].occupation_s < row.occupation_s


STEEP_LINE = """name: steep
km_start: 0.0
km_end: 10.0
tracks: double
line_speed_kmh: 100
default_train: weak.yaml
stations:
  - {id: A, name: Alpha, km: 1.0, platform_length_m: 300, dwell_s: 30}
  - {id: B, name: Beta, km: 9.0, platform_length_m: 300, dwell_s: 30}
gradients:
  - {from_km: 3.0, to_km: 7.0, permille: -40.0}
signalling: {block_length_m: 1500}
"""
WEAK = """name: weak
length_m: 200.0
mass_kg: 400000.0
rotating_mass_factor: 1.05
max_speed_kmh: 100.0
max_traction_n: 200000.0
max_power_w: 3000000.0
davis_a_n: 4000.0
davis_b_n_per_mps: 50.0
davis_c_n_per_mps2: 5.0
service_brake_decel_mps2: 0.3
emergency_brake_decel_mps2: 0.5
max_jerk_mps3: 0.5
traction_lag_s: 1.0
"""


def test_a_batch_of_a_train_whose_brake_cannot_hold_it_on_a_descent_fails_its_runs_with_the_reason(tmp_path):
    # UIC 406 brakes the running profiles on the guaranteed curves: a brake (0.3 m/s² - 10 %) that cannot hold the train on
    # a 40 permille descent is 'infeasible' as in `vcsumo run`; before, the batch stopped with 'internal error ValueError'
    import pandas as pd

    from vcsumo.cli.main import main

    write(tmp_path / "steep" / "line.yaml", STEEP_LINE)
    write(tmp_path / "steep" / "weak.yaml", WEAK)
    write(tmp_path / "weak.yaml", WEAK)
    tt = write(tmp_path / "tt.yaml", "name: tt\nline: steep\nservices:\n  - {id: T, train: weak.yaml, origin: A, destination: B, departure: 0}\n")
    out = tmp_path / "b"
    code = main(["-q", "batch", "--line", str(tmp_path / "steep" / "line.yaml"), "--timetables", str(tt), "--regimes", "fbs,mb", "--seeds", "1",
                 "--workers", "1", "--out", str(out)])
    assert code == 1
    errors = pd.read_csv(out / "batch.csv")["error"].tolist()
    assert len(errors) == 2 and all(e.startswith("infeasible: train T: weak: no guaranteed service braking on a -40.0 ‰ descent") for e in errors), errors
