"""Faults in the loop (issue 5 part 2): controllers that raise, return NaN or fail to converge,
corrupted messages, SUMO failing mid-run, a batch worker killed.

Faults are injected with tiny real controllers / a real channel subclass / a broken route SUMO
really cannot load; nothing of SUMO is mocked.
"""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vcsumo.control.base import Command, Observation
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.control.consensus import ConsensusController, load_cbc_params
from vcsumo.sim.offline import SpeedProfile, simulate_convoy
from vcsumo.control.faults import (
    CONTROLLER_EXCEPTION,
    CONTROLLER_FALLBACK,
    EMERGENCY_BRAKE,
    FAULT_COLUMNS,
    FAULT_MODE,
    NON_FINITE_COMMAND,
    NON_FINITE_STATE,
    SOLVER_FAILURE,
    FaultStage,
    emergency_brake_force_n,
)
from vcsumo.dynamics import brake_force_limit
from vcsumo.errors import SumoError
from vcsumo.rolling_stock import load_rolling_stock

from .conftest import DATA, ROOT, write

DT = 0.2
V0 = 40.0
CBC = load_cbc_params("cbc")  # d_min 50 m, h 1.5 s: steady gap 110 m at 40 m/s
D_MIN = CBC.gap.d_min_m
GAP0 = D_MIN + CBC.gap.headway_s * V0
ETR = load_rolling_stock("etr1000").params()
T_FAULT, T_BACK = 20.0, 24.0  # the injected fault lasts [20, 24) s
RECOVERY_S = 1.0


class FaultyController:
    """A real consensus controller that fails in [T_FAULT, T_BACK): raises or returns NaN (fault injection)."""

    def __init__(self, how: str):
        self.inner = ConsensusController(CBC)
        self.how = how
        self.calls = 0

    def make_step(self, obs: Observation) -> Command:
        self.calls += 1
        cmd = self.inner.make_step(obs)
        if T_FAULT - 1e-9 <= obs.time_s < T_BACK - 1e-9:
            if self.how == "raise":
                raise RuntimeError("injected controller failure")
            return dataclasses.replace(cmd, force_n=math.nan)
        return cmd


class CorruptingChannel(Channel):
    """A real channel whose delivered message from T0 carries a NaN position in [T_FAULT, T_BACK)."""

    def deliver(self, receiver: str, t: float):
        out = super().deliver(receiver, t)
        if T_FAULT - 1e-9 <= t < T_BACK - 1e-9 and "T0" in out:
            m = out["T0"]
            out["T0"] = dataclasses.replace(m, state=dataclasses.replace(m.state, position_m=math.nan))
        return out


def _run(factory, channel=None, leader=None, duration_s=60.0, log=None):
    leader = leader or SpeedProfile((0.0, 1e4), (V0, V0))
    return simulate_convoy(["etr1000"] * 2, factory, leader, duration_s, DT, None, [GAP0], channel=channel, recovery_s=RECOVERY_S,
                           fault_log=log)


def _check_fault_window(df: pd.DataFrame, kind: str, log: list) -> pd.DataFrame:
    f = df[df.train == "T1"].reset_index(drop=True)
    during = f[(f.time_s >= T_FAULT - 1e-9) & (f.time_s < T_BACK + RECOVERY_S - 1e-9)]
    # the fault steps and the latch after them: the emergency brake demand of the train model
    assert len(during) == round((T_BACK - T_FAULT + RECOVERY_S) / DT)
    assert (during["mode"] == FAULT_MODE).all()
    expected = [emergency_brake_force_n(ETR, v) for v in during.speed_mps]
    np.testing.assert_allclose(during.force_cmd_n, expected)
    assert (during.force_cmd_n <= -ETR.mass_kg * ETR.emergency_brake_decel_mps2).all()
    # the plant really brakes: the speed falls over the whole window (traction never resumes in the latch)
    assert (np.diff(during.speed_mps.to_numpy()) < 0).all()
    # before and after: the controller drives again
    assert (f[f.time_s < T_FAULT - 1e-9]["mode"] != FAULT_MODE).all()
    after = f[f.time_s >= T_BACK + RECOVERY_S - 1e-9]
    assert len(after) and (after["mode"] != FAULT_MODE).all() and after.force_cmd_n.max() > 0
    # safety: the gap never falls below the controller's minimum safe gap
    assert f.gap_m.min() >= D_MIN
    # one event, of the right kind, covering every faulty step
    assert len(log) == 1
    ev = log[0]
    assert (ev.train, ev.kind, ev.action) == ("T1", kind, EMERGENCY_BRAKE)
    assert ev.time_s == pytest.approx(T_FAULT) and ev.end_time_s == pytest.approx(T_BACK - DT)
    assert ev.steps == round((T_BACK - T_FAULT) / DT)
    assert df.attrs["faults"][0]["kind"] == kind and list(df.attrs["faults"][0]) == FAULT_COLUMNS
    return f


def test_controller_raising_brakes_the_follower_until_it_recovers():
    log = []
    ctrl = FaultyController("raise")
    df = _run(lambda tid: ctrl, log=log)
    _check_fault_window(df, CONTROLLER_EXCEPTION, log)
    assert "RuntimeError: injected controller failure" in log[0].message
    # the controller kept being asked during the latch (its state follows the train)
    assert ctrl.calls == round(60.0 / DT) + 1


def test_controller_returning_nan_brakes_the_follower():
    log = []
    df = _run(lambda tid: FaultyController("nan"), log=log)
    _check_fault_window(df, NON_FINITE_COMMAND, log)
    assert "nan" in log[0].message


def test_nan_in_the_received_leader_message_brakes_the_follower():
    log = []
    df = _run(lambda tid: ConsensusController(CBC), channel=CorruptingChannel(ChannelConfig(period_s=DT)), log=log)
    _check_fault_window(df, NON_FINITE_STATE, log)
    assert "message from T0" in log[0].message


def test_fault_while_the_leader_brakes_keeps_the_safe_gap():
    """The leader brakes at 0.6 m/s² through the fault: the follower's emergency brake still keeps d_min."""
    log = []
    leader = SpeedProfile((0.0, T_FAULT - 1.0, T_FAULT - 1.0 + V0 / 0.6, 1e4), (V0, V0, 0.0, 0.0))
    df = _run(lambda tid: FaultyController("raise"), leader=leader, duration_s=120.0, log=log)
    f = df[df.train == "T1"]
    assert f.gap_m.min() >= D_MIN
    assert (f[(f.time_s >= T_FAULT) & (f.time_s < T_BACK)]["mode"] == FAULT_MODE).all()
    assert [e.kind for e in log] == [CONTROLLER_EXCEPTION]


class _Stub:
    """A real Controller whose command is fixed (for the stage's policy)."""

    def __init__(self, cmd):
        self.cmd = cmd

    def make_step(self, obs):
        return self.cmd


def _obs(t=0.0, v=30.0):
    from vcsumo.control.base import TrainStateMsg
    from vcsumo.sim.offline import flat_profile

    return Observation(time_s=t, step_s=DT, ego_id="F", ego=TrainStateMsg(t, 0.0, v), params=ETR, profile=flat_profile(1e4))


def test_infeasible_command_without_a_usable_fallback_is_an_emergency():
    """An 'infeasible' command that still asks for traction is not a fallback: emergency brake."""
    st = FaultStage(_Stub(Command(force_n=1e5, infeasible=True)), ETR, recovery_s=0.0)
    cmd = st.make_step(_obs())
    assert cmd.mode == FAULT_MODE and cmd.emergency and cmd.force_n == pytest.approx(emergency_brake_force_n(ETR, 30.0))
    assert [(e.kind, e.action) for e in st.events] == [(SOLVER_FAILURE, EMERGENCY_BRAKE)]
    # the step after a fault is braked even with no recovery time, then the controller drives again
    st.controller = _Stub(Command(force_n=2e4))
    assert st.make_step(_obs(DT)).mode == FAULT_MODE
    assert st.make_step(_obs(2 * DT)).force_n == 2e4
    # a brake with a NaN plan is not usable either; a finite full brake is passed on and recorded
    st.controller = _Stub(Command(force_n=-1e5, infeasible=True, plan_positions_m=np.array([0.0, np.nan])))
    assert st.make_step(_obs(3 * DT)).mode == FAULT_MODE
    st = FaultStage(_Stub(Command(force_n=-1e5, mode="fallback", infeasible=True)), ETR)
    assert st.make_step(_obs()).force_n == -1e5
    assert [(e.kind, e.action) for e in st.events] == [(SOLVER_FAILURE, CONTROLLER_FALLBACK)] and st.emergency_steps == 0


def test_nmpc_that_cannot_converge_falls_back_to_full_braking_and_is_recorded():
    """A real follower NMPC (Felez eq. 12) limited to one SQP iteration, started 60 m behind its
    leader at 20 m/s: its terminal set 12m (leader braking at a^l = 1.25, itself at a^f = 0.75 m/s²)
needs far more than 60 m, so no plan is feasible; it falls back to
    the full service brake (its own documented fallback, a finite braking plan), the stage records
    every episode as ``solver_failure`` and the gap never falls below d_min."""
    from vcsumo.control.mpc import FollowerMPC, load_mpc_settings

    settings = load_mpc_settings(DATA / "controllers" / "mpc.yaml").model_copy(update={"sqp_max_iterations": 1})
    p = load_rolling_stock("felez2019").params()
    ctrls = {}

    def factory(tid):
        ctrls[tid] = FollowerMPC(p, settings)
        return ctrls[tid]

    log = []
    df = simulate_convoy(["felez2019"] * 2, factory, SpeedProfile((0.0, 1e4), (20.0, 20.0)), 30.0, settings.step_s, None, [60.0], fault_log=log)
    f = df[df.train == "T1"].reset_index(drop=True)
    fb = f[f["mode"] == "fallback"]
    assert ctrls["T1"].stats.infeasible == len(fb) > 10
    # the first step is infeasible: full service brake −min(M·a_br, P_br/v) (eq. 4a/4b)
    assert f["mode"].iloc[0] == "fallback"
    np.testing.assert_allclose(fb.force_cmd_n, [-float(brake_force_limit(p, v)) for v in fb.speed_mps])
    # braking, the follower only opens the gap (never below its start, far above d_min), then the NMPC recovers
    assert f.gap_m.min() >= 60.0 - 1e-9 > settings.d_min_m and f.gap_m.iloc[-1] > 80.0
    assert f["mode"].iloc[-1] == "mpc-sh" and (f["mode"] != FAULT_MODE).all()
    assert log and all(e.kind == SOLVER_FAILURE and e.action == CONTROLLER_FALLBACK and e.train == "T1" for e in log)
    assert sum(e.steps for e in log) == len(fb)
    assert "terminal_set_m" in log[0].message


# -------------------------------------------------------------------------------------------
# In SUMO


PAIR = """
name: pair
line: felez_test
services:
  - {id: L, train: felez2019, origin: ORIG, destination: STOP, departure: 0}
  - {id: F, train: felez2019, origin: ORIG, destination: STOP, departure: 0}
convoys:
  - {id: C, services: [L, F]}
"""


class RaisingAt:
    """Wraps a follower's real controller; raises in [t0, t1) (fault injection in the SUMO loop)."""

    def __init__(self, inner, t0, t1):
        self.inner, self.t0, self.t1 = inner, t0, t1

    def make_step(self, obs):
        if self.t0 <= obs.time_s < self.t1:
            raise ValueError("injected")
        return self.inner.make_step(obs)


@pytest.mark.sumo
def test_vc_loop_brakes_a_follower_whose_controller_raises(tmp_path):
    from vcsumo.line import load_line
    from vcsumo.sim.network import build_network
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.timetable import load_timetable, plan_trains
    from vcsumo.sim.vc_driver import make_vc_driver

    line = load_line("felez_test")
    net = build_network(line)
    tt, p = load_timetable(write(tmp_path / "pair.yaml", PAIR), line)
    trains = plan_trains(tt, p, line, net.topology, dt=0.1)
    drv = make_vc_driver(tt, p, trains, "cbc", 0.1, seed=3)
    stage = drv.followers["F"].stage
    stage.controller = RaisingAt(stage.controller, 80.0, 85.0)
    drv.record_every_s = 0.1  # a record every step
    out = tmp_path / "out"
    res = simulate(Scenario(line, net, trains, "vc", step_length_s=0.1, driver=drv), out)
    drv.write_report(out)
    s = drv.summary()
    assert res.summary["collisions"] == 0 and res.summary["gap_violations"] == 0 and res.summary["trains_arrived"] == 2
    assert s["fault_events"] == 1 and s["fault_events_controller_exception"] == 1
    assert s["fault_emergency_steps"] == 50 + 10  # 5 s of faults + the 1 s latch at 0.1 s
    faults = pd.read_csv(out / "faults.csv")
    assert list(faults.columns) == FAULT_COLUMNS
    assert faults.loc[0, "kind"] == CONTROLLER_EXCEPTION and faults.loc[0, "train"] == "F" and faults.loc[0, "steps"] == 50
    assert 80.0 <= faults.loc[0, "time_s"] < 80.2
    rec = pd.read_csv(out / "vc_followers.csv")
    win = rec[(rec.time_s >= 80.05) & (rec.time_s < 85.95)]
    assert len(win) > 50 and (win["mode"] == FAULT_MODE).all() and win.emergency.all()
    # the speed command is the emergency-braked speed: it falls every step
    assert (np.diff(win.speed_command_mps.to_numpy()) < 0).all()
    assert (rec[rec.time_s > 87.0]["mode"] != FAULT_MODE).all()


def _late_broken_train(trains):
    """A train departing at 400 s on a route with a hole: SUMO loads it mid-run and stops on the error."""
    t = trains[-1]
    return trains + [dataclasses.replace(t, id="BROKEN", depart_s=400.0, edges=[t.edges[0], t.edges[-1]], stops=[], final_stop=None)]


def _no_partials(folder: Path) -> None:
    assert not [p for p in folder.rglob("*") if ".partial-" in p.name]


@pytest.mark.sumo
def test_sumo_failing_mid_run_is_one_error_and_leaves_no_results(tmp_path):
    from vcsumo.line import load_line
    from vcsumo.sim.network import build_network
    from vcsumo.results import ResultsFolder
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.timetable import load_timetable, plan_trains

    line = load_line("felez_test")
    net = build_network(line)
    tt, p = load_timetable(DATA / "routes" / "felez_test" / "test.yaml", line)
    trains = _late_broken_train(plan_trains(tt, p, line, net.topology, dt=0.5))
    seen = []
    with pytest.raises(SumoError) as exc:
        with ResultsFolder(tmp_path / "run") as rf:
            simulate(Scenario(line, net, trains, "mb", step_length_s=0.5), rf.path, lambda t, end: seen.append(t))
    msg = str(exc.value)
    assert str(net.net_file) in msg and str(line.path) in msg
    assert "after t = 400 s" in msg and "'BROKEN' has no valid route" in msg
    assert max(seen) >= 399.0  # it failed mid-run, not at the start
    assert not (tmp_path / "run").exists()
    _no_partials(tmp_path)


@pytest.mark.sumo
def test_cli_run_with_sumo_failing_mid_run(in_tmp, capsys, monkeypatch):
    """``vcsumo run``: exit status 2, one error line naming the network, no results folder."""
    import vcsumo.timetable as timetable
    from vcsumo.cli.main import main

    real = timetable.plan_trains
    monkeypatch.setattr(timetable, "plan_trains", lambda *a, **k: _late_broken_train(real(*a, **k)))
    rc = main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "mb", "--out", "r"])
    out = capsys.readouterr()
    text = out.out + out.err
    assert rc == 2
    assert "SUMO failed during the simulation after t = 400 s" in text and "line.net.xml" in text and "Traceback" not in text
    assert not Path("r").exists()
    _no_partials(in_tmp)


BATCH_TT = """
name: {name}
line: felez_test
services:
  - {{id: T, train: felez2019, origin: ORIG, destination: STOP, departure: 0, repeat: {{count: {n}, every_s: 60}}}}
"""


@pytest.mark.sumo
def test_batch_with_a_killed_worker_keeps_the_other_runs(tmp_path):
    """SIGKILL the worker of one run every time it starts: that run becomes a failed row with the
    reason, the other runs finish, and no partial run folder is left."""
    from vcsumo.studies.batch import WORKER_DIED, read_batch, run_batch

    tts = [write(tmp_path / "tt" / f"{name}.yaml", BATCH_TT.format(name=name, n=n)) for name, n in (("two", 2), ("three", 3))]
    out = tmp_path / "batch"
    victim = "three-mb-s1-"
    kills: list[int] = []
    stop = threading.Event()

    def killer():
        while not stop.is_set():
            runs = out / "runs"
            if runs.is_dir():
                for d in runs.iterdir():
                    if d.name.startswith(victim) and ".partial-" in d.name:
                        pid = int(d.name.rsplit("-", 1)[1])
                        if pid not in kills:
                            try:
                                os.kill(pid, signal.SIGKILL)
                                kills.append(pid)
                            except ProcessLookupError:
                                pass
            time.sleep(0.005)

    th = threading.Thread(target=killer, daemon=True)
    th.start()
    try:
        df = run_batch("felez_test", [str(t) for t in tts], ["fbs", "mb"], [1], out=out, workers=2)
    finally:
        stop.set()
        th.join()
    assert len(kills) >= 2  # killed in the parallel pool, then again when run alone
    assert len(df) == 4
    bad = df[df.run_dir.str.contains(victim)]
    assert len(bad) == 1 and bad.status.iloc[0] == "failed" and bad.error.iloc[0] == WORKER_DIED
    good = df[~df.run_dir.str.contains(victim)]
    assert (good.status == "ok").all() and (good.trains_arrived == good.trains).all()
    for rd in good.run_dir:
        assert (out / rd / "summary.csv").is_file() and (out / rd / "meta.json").is_file()
    assert not any((out / "runs").glob(f"{victim}*"))
    _no_partials(out)
    assert len(read_batch(out)) == 4


ORPHAN_SCRIPT = """
import multiprocessing, os, sys, time
from concurrent.futures import ProcessPoolExecutor
from vcsumo.engine.campaign import silence_worker
def work(x):
    time.sleep(60)
    return x
if __name__ == "__main__":
    pool = ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn"), initializer=silence_worker, initargs=(sys.argv[1],))
    futures = [pool.submit(work, i) for i in range(4)]
    time.sleep(4)
    print(" ".join(str(p) for p in pool._processes), flush=True)
    os._exit(0)  # the command dies without shutting its pool down (as when it is killed)
"""


def test_workers_end_when_their_command_is_killed(tmp_path):
    """A killed study or batch leaves no worker processes running on (silence_worker's watchdog)."""
    import subprocess
    import sys
    import time

    script = tmp_path / "orphan.py"
    script.write_text(ORPHAN_SCRIPT)
    out = subprocess.run([sys.executable, str(script), str(tmp_path / "w.log")], capture_output=True, text=True, timeout=60)
    pids = [int(x) for x in out.stdout.split()]
    assert len(pids) == 2
    deadline = time.time() + 10
    alive = pids
    while alive and time.time() < deadline:
        time.sleep(0.5)
        alive = [p for p in pids if os.path.exists(f"/proc/{p}") and "Z" not in open(f"/proc/{p}/stat").read().split()[2]]
    assert not alive, f"orphaned workers still running: {alive}"
