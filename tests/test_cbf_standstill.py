"""cbf-mpc standing behind a stopped leader (unseen round of 2026-11-28).

Defect: the follower NMPC kept Felez's own spacing (d_min 4 m, d_des 10 m) under the CBF, whose
barrier keeps d = 70 m (etcs_typical: 50 m + 2 × 10 m).  Behind a stopped leader it stood 71.66 m
back and commanded traction (37.6 / 70.6 kN) into the leader for ever; the CBF's one-step-ahead check
refused every other command: 500 emergency activations in 200 s of standstill, 677 (151 s of
"emergency") in a 300 s run, cbf-cbc 1.  Now a supervised NMPC's d_min is the supervisor's d and
d_des keeps its margin above it (76 m): it holds the brake there.  The CBF itself is unchanged —
the last test shows it still refuses traction where the barrier truly fails."""

import math

import pandas as pd

from vcsumo.cli.main import main
from vcsumo.control.base import Command, Message, Observation, TrainStateMsg
from vcsumo.control.registry import StackContext, build_follower_stack
from vcsumo.rolling_stock import load_rolling_stock

from .conftest import write

EXPERIMENT = """
name: stop_cbf
step_s: 0.2
duration_s: 150.0
seeds: [1]
record_every: 1
track:
  straight: {length_m: 20000.0, speed_limit_mps: 40.0}
trains:
  - {id: L, stock: regional_emu160, position_m: 6000.0, speed_mps: 20.0}
  - {id: F, stock: regional_emu160, gap_m: coupled, speed_mps: 20.0, controller: cbf-mpc}
leader:
  driver: speed_tracker
  schedule: [[0.0, 20.0], [60.0, 0.0]]
channel: {period_s: 0.5, delay_s: 0.1, exp_rate_per_s: 5.0, loss_probability: 0.01}
"""


def test_cbf_mpc_holds_still_behind_a_stopped_leader(in_tmp, capsys):
    exp = write(in_tmp / "stop.yaml", EXPERIMENT)
    assert main(["experiment", str(exp), "--out", "e", "--no-plots"]) == 0
    t = pd.read_csv(in_tmp / "e" / "trajectories.csv")
    lead, fol = t[t.train == "L"], t[t.train == "F"].reset_index(drop=True)
    t_stop = lead[lead.speed_mps <= 0.0].time_s.min()
    assert t_stop < 100.0
    rest = fol[fol.time_s >= t_stop + 20.0]
    assert len(rest) > 100 and rest.speed_mps.max() < 0.01  # both trains stand
    em = fol.emergency.astype(bool)
    onsets = em & ~em.shift(fill_value=False)
    # main: 108 activations in these 43 s (every other step), the NMPC commanding +37.6 kN between them
    assert int(onsets[rest.index].sum()) == 0 and not em[rest.index].any()
    assert (rest.force_cmd_n <= 0.0).all()
    assert rest.gap_front_to_rear_m.min() >= 70.0  # the CBF's d


def test_the_cbf_still_refuses_traction_where_the_barrier_fails():
    stock = load_rolling_stock("regional_emu160")
    stack = build_follower_stack("cbf-mpc", StackContext(stock, stock, 0.2, ego_id="F", predecessor_id="L"))
    sup = stack.supervisor
    assert stack.d_min_m == sup.safety_distance_m == 70.0
    leader_front = 10000.0
    gap = 71.66  # where main's NMPC stood: 1.66 m outside the barrier
    s_f = leader_front - stock.length_m - gap
    msg = Message("L", 0.0, TrainStateMsg(0.0, leader_front, 0.0), stock.length_m, received_time_s=0.1)

    def obs(t: float, force_n: float) -> Observation:
        return Observation(time_s=t, step_s=0.2, ego_id="F", ego=TrainStateMsg(t, s_f, 0.0, force_n=force_n), params=stock.params(),
                           profile=None, received={"L": msg}, predecessor="L", sensed_gap_m=gap, sensed_speed_mps=0.0)

    hold = sup.filter(obs(0.2, -28400.0), Command(force_n=-28400.0, mode="mpc"))
    assert not hold.emergency and hold.force_n == -28400.0 and hold.info["cbf_barrier_m"] < 0
    push = sup.filter(obs(0.4, 4600.0), Command(force_n=70600.0, mode="mpc"))  # main's NMPC command there
    assert push.emergency and push.force_n < 0 and push.info["cbf_reason"] == "barrier"
    assert math.isclose(push.info["cbf_barrier_m"], 70.0 - gap, abs_tol=0.2)
