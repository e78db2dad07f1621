"""Tier 2 — the capacity study with a train its line cannot carry (found running ``vcsumo study
capacity --line mountain.yaml --train freight.yaml`` with a 700 m, 2,000 t freight train):

* all-stops with a train longer than the platforms: the cases ran and were reported healthy
  (22.2 trains/h) with the train standing 250 m out of 450 m platforms — ``vcsumo run`` refuses
  such a stop; now the case fails with the platforms named;
* a train that cannot start on a grade of its route: the study ran 6.5 minutes without finishing
  one case (probes of trains standing at the foot of the climb); now the case fails at once.
"""

import pandas as pd
import pytest

from vcsumo.errors import VcsumoError
from vcsumo.cli.main import main
from vcsumo.line import load_line
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel
from vcsumo.sim.network import build_network
from vcsumo.studies.capacity_route import Case, leader_run, route_setup

from .conftest import write

LINE = """
name: freightway
km_start: 0.0
km_end: 8.0
line_speed_kmh: 120
default_train: regional_emu160
stations:
  - {id: AA, name: Aa, km: 0.5, platform_length_m: 800}
  - {id: MM, name: Middle, km: 4.0, platform_length_m: 200}
  - {id: ZZ, name: Zz, km: 7.5, platform_length_m: 800}
gradients:
  - {from_km: 5.0, to_km: 6.5, permille: GRADE}
signalling: {block_length_m: 1500}
"""
FREIGHT = """
name: freight
length_m: 700.0
mass_kg: 2000000.0
rotating_mass_factor: 1.06
max_speed_kmh: 80.0
max_traction_n: 400000.0
max_power_w: 5600000.0
davis_a_n: 20000.0
davis_b_n_per_mps: 150.0
davis_c_n_per_mps2: 10.0
service_brake_decel_mps2: 0.5
emergency_brake_decel_mps2: 0.7
max_jerk_mps3: 0.3
traction_lag_s: 1.5
"""


@pytest.mark.sumo
def test_all_stops_with_a_train_longer_than_a_platform_fails_the_case(in_tmp, capsys):
    write(in_tmp / "freightway.yaml", LINE.replace("GRADE", "5.0"))
    write(in_tmp / "freight.yaml", FREIGHT)
    code = main(["study", "capacity", "--line", "freightway.yaml", "--train", str(in_tmp / "freight.yaml"), "--controllers", "", "--convoy-sizes", "1",
                 "--directions", "up", "--patterns", "all-stops", "--workers", "1", "--out", "c"])
    rows = pd.read_csv(in_tmp / "c" / "capacity.csv")
    assert len(rows) == 2 and rows["capacity_trains_per_h"].isna().all()
    assert all("700 m long, longer than the platform of 'MM' (200 m)" in e for e in rows["error"]), rows["error"].tolist()
    assert code == 1  # every case failed: said, not reported as a capacity


def test_a_train_that_cannot_start_on_a_grade_fails_the_case(tmp_path):
    # 2,000 t on 25 ‰: 2e6·9.81·0.025 = 490 kN + Davis A 20 kN > 400 kN
    line = load_line(write(tmp_path / "freightway.yaml", LINE.replace("GRADE", "25.0")))
    stock = load_rolling_stock(str(write(tmp_path / "freight.yaml", FREIGHT)))
    net = build_network(line)
    model = SeparationModel(load_assumptions())
    setup = route_setup(line, net, stock, "up", 0.5, model)
    with pytest.raises(VcsumoError, match="cannot start on the 25.0 ‰ grade"):
        leader_run(setup, stock, Case("up", "fbs", None, 1, "non-stop"), 0.5, model)
    # the other way the grade is a descent: the case runs
    down = route_setup(line, net, stock, "down", 0.5, model)
    run = leader_run(down, stock, Case("down", "fbs", None, 1, "non-stop"), 0.5, model)
    assert run["s_m"].iloc[-1] > down.full.length_m - 200.0


def test_the_headway_study_says_a_train_cannot_start_on_a_grade(tmp_path):
    """The same in ``vcsumo study headway`` (it ran 3 minutes without a result before it was stopped)."""
    from vcsumo.studies.headway import prepare_case

    line = load_line(write(tmp_path / "freightway.yaml", LINE.replace("GRADE", "25.0")))
    stock = load_rolling_stock(str(write(tmp_path / "freight.yaml", FREIGHT)))
    net = build_network(line)
    model = SeparationModel(load_assumptions())
    with pytest.raises(VcsumoError, match=r"cannot start on the 25.0 ‰ grade .* it needs 510 kN, its tractive effort is 400 kN \(up\)"):
        prepare_case(line, net, stock, "up", 0.5, 2, model)
    trains, prof, run, _, _ = prepare_case(line, net, stock, "down", 0.5, 2, model)
    assert run["s_m"].iloc[-1] > prof.length_m - 200.0


def test_convoy_members_start_outside_their_safe_separation_on_a_grade(tmp_path):
    """A VC convoy of two freight trains released on a 25 ‰ climb started 16 m inside the follower's
    safe separation (the start gap was the level-track one): every probe had 2 gap violations and
    the case was reported as 'no sustainable headway found (trains hindered at every interval)'."""
    from vcsumo.signalling.separation import RelativeBraking
    from vcsumo.studies.capacity_route import convoy_spacing, initial_convoy_gaps

    # the climb from km 3.0; the units are released on it at km 5.0, the follower 0.7 km + the gap behind
    text = LINE.replace("GRADE", "25.0").replace("{from_km: 5.0, to_km: 6.5", "{from_km: 3.0, to_km: 7.5") + "headway: {measuring_points_km: [6.0], release_km: {up: 5.0, down: 1.0}}\n"
    line = load_line(write(tmp_path / "freightway.yaml", text))
    stock = load_rolling_stock(str(write(tmp_path / "freight.yaml", FREIGHT.replace("max_traction_n: 400000.0", "max_traction_n: 800000.0"))))
    net = build_network(line)
    model = SeparationModel(load_assumptions())
    setup = route_setup(line, net, stock, "up", 0.2, model)
    gap, = initial_convoy_gaps(convoy_spacing("cbc", stock, 0.2, load_assumptions(), setup.full), model, stock, setup, 2)
    s_l = setup.release_s
    s_f = s_l - stock.length_m - gap
    # the health monitor's rule for a VC follower, where the two start
    need = RelativeBraking(model, stock, stock, setup.full).required_gap(s_f, setup.depart_speed(s_f), s_l, setup.depart_speed(s_l), model.dead_time_s)
    assert gap >= need
    assert model.vc_gap(stock, stock, setup.v0) + 20.0 < need  # the level-track start gap was inside it
