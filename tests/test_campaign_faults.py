"""Faults of whole commands (issue 13) on felez_test, in real processes with real signals:
SIGTERM and SIGKILL of batch and capacity, resuming, two writers into one folder, a Dask
scheduler that cannot run anything, every run failing, SUMO replays."""

from __future__ import annotations

import hashlib
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from vcsumo.cli.main import main

from .conftest import write

pytestmark = pytest.mark.sumo

LONG_TT = """name: long
line: felez_test
services:
  - {id: T, train: felez2019, origin: ORIG, destination: STOP, departure: 0, repeat: {count: 40, every_s: 60}}
"""
INFEASIBLE = """name: too_fast
line: felez_test
services:
  - {id: X, train: felez2019, origin: ORIG, destination: STOP, departure: 0, arrival: 100}
"""
CAPACITY = ["study", "capacity", "--line", "felez_test", "--directions", "up", "--patterns", "non-stop", "--controllers", "cbc",
            "--convoy-sizes", "1,2,3"]


def vcsumo(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "vcsumo.cli.main", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def partials(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".partial-" in p.name]


def wait_for(cond, timeout_s: float = 60.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


def alive(pid: int) -> bool:
    try:
        return "Z" not in Path(f"/proc/{pid}/stat").read_text().split()[2]
    except OSError:
        return False


def test_sigterm_of_a_batch_ends_its_workers_leaves_no_partial_folder_and_it_resumes(tmp_path):
    tt = write(tmp_path / "long.yaml", LONG_TT)
    out = tmp_path / "b"
    args = ["batch", "--line", "felez_test", "--timetables", str(tt), "--regimes", "fbs,mb", "--seeds", "2", "--workers", "2", "--out", str(out)]
    proc = vcsumo(*args)
    try:
        wait_for(lambda: len(list((out / "runs").glob("*.partial-*"))) == 2 if (out / "runs").is_dir() else False, what="two runs under way")
        workers = [int(p.name.rsplit("-", 1)[1]) for p in (out / "runs").glob("*.partial-*")]
        proc.send_signal(signal.SIGTERM)  # the command alone, as `kill PID` does
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 143 and "terminated" in err
    assert not partials(out)
    wait_for(lambda: not any(alive(p) for p in workers), 10, "workers to end")
    done = pd.read_csv(out / "batch.csv")
    assert len(done) < 4
    again = subprocess.run([sys.executable, "-m", "vcsumo.cli.main", *args], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"{4 - len(done)} run now, {len(done)} already in batch.csv" in again.stdout
    rows = pd.read_csv(out / "batch.csv")
    trains = pd.read_csv(out / "batch_trains.csv")
    assert len(rows) == 4 and rows.run_key.is_unique and (rows.status == "ok").all()
    assert len(trains) == 4 * 40 and not trains.duplicated(["run_key", "train"]).any()


def test_a_killed_capacity_study_resumes_only_its_missing_cases(tmp_path):
    """SIGKILL in the middle (its partial case folder stays behind), then the same command: the
    finished cases are kept, the missing ones run, the stale folder goes, and the table is the
    one an uninterrupted study gives."""
    out = tmp_path / "cap"
    proc = vcsumo(*CAPACITY, "--workers", "1", "--out", str(out))
    try:
        wait_for(lambda: (out / "capacity_cases.csv").is_file() and len((out / "capacity_cases.csv").read_text().splitlines()) >= 2
                 and bool(list((out / "runs").glob("*.partial-*"))), what="one case done and the next under way")
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    finally:
        proc.kill()
    stale = partials(out)
    assert stale and not (out / "capacity.csv").exists()
    before = pd.read_csv(out / "capacity_cases.csv", dtype=str, keep_default_na=False)  # the cells as written
    assert 1 <= len(before) < 4  # of fbs, mb, vc n=2, vc n=3 (vc n=1 repeats mb)
    assert main([*CAPACITY, "--workers", "2", "--out", str(out)]) == 0
    assert not partials(out)
    cases = pd.read_csv(out / "capacity_cases.csv", dtype=str, keep_default_na=False)
    assert len(cases) == 4 and cases.case_key.is_unique
    # the rows found finished are not run again
    pd.testing.assert_frame_equal(cases.iloc[: len(before)].reset_index(drop=True), before)
    resumed = pd.read_csv(out / "capacity.csv")
    assert main([*CAPACITY, "--workers", "2", "--out", str(tmp_path / "fresh")]) == 0
    fresh = pd.read_csv(tmp_path / "fresh" / "capacity.csv")
    cols = [c for c in fresh.columns if not c.endswith("_time_s")]
    pd.testing.assert_frame_equal(resumed[cols], fresh[cols])
    assert (out / "time_distance.png").stat().st_size > 10_000 and (out / "meta.json").is_file()


def test_sigterm_of_a_capacity_study_leaves_no_partial_folder(tmp_path, capsys):
    out = tmp_path / "cap"
    proc = vcsumo(*CAPACITY, "--workers", "1", "--out", str(out))
    try:
        wait_for(lambda: bool(list((out / "runs").glob("*.partial-*"))) if (out / "runs").is_dir() else False, what="a case under way")
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 143 and "terminated" in err
    assert not partials(out) and not (out / "capacity.csv").exists()
    assert main([*CAPACITY, "--workers", "1", "--out", str(out)]) == 0
    assert len(pd.read_csv(out / "capacity_cases.csv")) == 4 and len(pd.read_csv(out / "capacity.csv")) == 5


def test_a_capacity_folder_with_other_parameters_is_refused(tmp_path, capsys):
    out = tmp_path / "cap"
    args = ["study", "capacity", "--line", "felez_test", "--directions", "up", "--patterns", "non-stop", "--controllers", "", "--workers", "1"]
    assert main([*args, "--out", str(out)]) == 0
    before = sorted(p.name for p in out.rglob("*"))
    capsys.readouterr()
    assert main([*args, "--fixed-time-s", "5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{out / 'store.json'}: parameters: this folder holds a capacity study with other parameters (" in err
    assert "fixed_time_s 5.0 now, 0.0 in the folder" in err and "assumptions" in err  # the set's fixed time differs too
    assert sorted(p.name for p in out.rglob("*")) == before


def test_a_second_batch_into_the_same_folder_is_refused_while_the_first_runs(tmp_path, capsys):
    tt = write(tmp_path / "long.yaml", LONG_TT)
    out = tmp_path / "b"
    args = ["batch", "--line", "felez_test", "--timetables", str(tt), "--regimes", "fbs,mb", "--seeds", "1", "--workers", "1", "--out", str(out)]
    first = vcsumo(*args)
    try:
        wait_for(lambda: (out / ".vcsumo.lock.owner").is_file(), what="the first batch to hold the folder")
        first.send_signal(signal.SIGSTOP)  # frozen mid-batch: it holds the folder however slow the second one is
        try:
            t0 = time.monotonic()
            assert main(args) == 2
            assert time.monotonic() - t0 < 30
        finally:
            first.send_signal(signal.SIGCONT)
        err = capsys.readouterr().err
        assert f"another vcsumo command is writing into this folder (pid {first.pid} " in err and "choose another --out" in err
        first.communicate(timeout=300)
        assert first.returncode == 0
    finally:
        first.kill()
    assert main(args) == 0
    assert "0 run now, 2 already in batch.csv" in capsys.readouterr().out
    rows, trains = pd.read_csv(out / "batch.csv"), pd.read_csv(out / "batch_trains.csv")
    assert len(rows) == 2 and rows.run_key.is_unique and len(trains) == 80


def test_a_batch_in_which_every_run_fails_reports_them_and_exits_1(tmp_path, capsys):
    bad = write(tmp_path / "too_fast.yaml", INFEASIBLE)
    out = tmp_path / "b"
    assert main(["batch", "--line", "felez_test", "--timetables", str(bad), "--regimes", "fbs,mb", "--seeds", "1", "--workers", "1", "--out", str(out)]) == 1
    cap = capsys.readouterr()
    assert "failed: too_fast fbs seed 1" in cap.out and "infeasible" in cap.out
    assert "error: every run of the batch failed (2 of 2;" in cap.err and "internal error" not in cap.err
    summary = pd.read_csv(out / "report" / "batch_summary.csv")
    assert summary.failed.tolist() == [1, 1] and summary.punctuality_3min_share.isna().all()


def test_a_safety_campaign_in_which_every_run_fails_exits_1(tmp_path, capsys):
    """A controller parameter file with an unknown key is found when the runs load it: every run
    is a row with that error, the report is written, and the command says so and exits 1."""
    bad = write(tmp_path / "bad_cbc.yaml", "colour: red\n")
    code = main(["study", "safety", "--scenarios", "2", "--lines", "hcmc_line1", "--controllers", f"cbc:{bad}", "--workers", "1",
                 "--out", str(tmp_path / "s")])
    cap = capsys.readouterr()
    assert code == 1 and "error: every run of the safety campaign failed (2 of 2;" in cap.err
    assert "colour: unknown key" in cap.out and (tmp_path / "s" / "report" / "safety_summary.csv").is_file()


def test_a_capacity_study_in_which_every_case_fails_exits_1(tmp_path, capsys, monkeypatch):
    """Fault injection as in test_capacity: every case raises (in this process, --workers 1)."""
    from vcsumo.errors import VcsumoError
    from vcsumo.studies import capacity

    def run_case(*a, **k):
        raise VcsumoError("no sustainable headway found (test)")

    monkeypatch.setattr(capacity, "run_case", run_case)
    out = tmp_path / "cap"
    assert main([*CAPACITY, "--workers", "1", "--out", str(out)]) == 1
    cap = capsys.readouterr()
    assert "error: every case of the capacity study failed (5 of 5;" in cap.err
    assert cap.out.count("no sustainable headway found (test)") >= 4
    assert pd.read_csv(out / "capacity.csv").error.str.contains("no sustainable headway").all()


def test_a_batch_in_which_some_runs_fail_keeps_them_and_exits_1(tmp_path, capsys):
    """Exit 0 means every run clean: one failed run of two makes the batch exit 1, with the finished
    run kept in batch.csv and the line naming how many of how many and where."""
    bad = write(tmp_path / "too_fast.yaml", INFEASIBLE)
    out = tmp_path / "b"
    args = ["batch", "--line", "felez_test", "--timetables", f"test,{bad}", "--regimes", "fbs", "--seeds", "1", "--workers", "1", "--out", str(out)]
    assert main(args) == 1
    cap = capsys.readouterr()
    assert f"error: 1 of 2 runs of the batch is not clean (1 failed); results kept in {out / 'batch.csv'}" in cap.err
    rows = pd.read_csv(out / "batch.csv")
    assert sorted(rows.status) == ["failed", "ok"] and rows.run_key.is_unique
    assert main(args) == 1  # resumed: nothing run again, the same verdict
    assert "0 run now, 2 already in batch.csv" in capsys.readouterr().out


def test_a_capacity_study_in_which_one_case_fails_exits_1(tmp_path, capsys, monkeypatch):
    """One VC case raises (in this process, --workers 1): the other cases are kept and the study exits 1."""
    from vcsumo.errors import VcsumoError
    from vcsumo.studies import capacity

    real = capacity.run_case

    def run_case(line, net, stock, setup, case, *a, **k):
        if case.regime == "vc" and case.convoy_size == 2:
            raise VcsumoError("no sustainable headway found (test)")
        return real(line, net, stock, setup, case, *a, **k)

    monkeypatch.setattr(capacity, "run_case", run_case)
    out = tmp_path / "cap"
    assert main([*CAPACITY, "--workers", "1", "--out", str(out)]) == 1
    cap = capsys.readouterr()
    df = pd.read_csv(out / "capacity.csv")
    assert f"error: 1 of {len(df)} cases of the capacity study is not clean (1 failed); results kept in {out / 'capacity.csv'}" in cap.err
    assert (df.error.fillna("") != "").sum() == 1 and df[df.error.isna()].healthy.all()


def test_a_capacity_study_without_cases_is_an_input_error(in_tmp, capsys):
    """felez_test has no intermediate station: an all-stops study has nothing to run."""
    assert main(["study", "capacity", "--line", "felez_test", "--patterns", "all-stops", "--out", "c"]) == 2
    assert "--patterns: no case to run" in capsys.readouterr().err
    assert not any(in_tmp.iterdir())


@pytest.mark.parametrize("cmd", [
    ["batch", "--line", "felez_test", "--timetables", "test", "--regimes", "fbs", "--seeds", "1"],
    CAPACITY,
    ["study", "safety", "--scenarios", "1", "--lines", "hcmc_line1", "--controllers", "cbc"],
])
@pytest.mark.parametrize("workers", ["0", "-2"])
def test_workers_below_one_is_one_error_everywhere(in_tmp, capsys, cmd, workers):
    assert main([*cmd, "--workers", workers, "--out", "o"]) == 2
    assert f"error: --workers: {workers}: must be 1 or more (1 runs in this process" in capsys.readouterr().err
    assert not any(in_tmp.iterdir())


def test_convoy_size_zero_leaves_no_results_folder(in_tmp, capsys):
    assert main(["study", "capacity", "--line", "felez_test", "--convoy-sizes", "0"]) == 2
    assert "--convoy-sizes (item 1): 0: Input should be greater than or equal to 1" in capsys.readouterr().err
    assert not any(in_tmp.iterdir())


def test_a_scheduler_address_with_nothing_listening_is_one_error_within_seconds(in_tmp, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    assert main(["batch", "--line", "felez_test", "--timetables", "test", "--regimes", "fbs", "--seeds", "1",
                 "--scheduler", f"tcp://127.0.0.1:{port}", "--out", "b"]) == 2
    assert time.monotonic() - t0 < 30
    err = capsys.readouterr().err
    assert f"error: --scheduler: cannot connect to the Dask scheduler at tcp://127.0.0.1:{port}" in err
    assert not any(in_tmp.iterdir())  # no folder of header-only CSVs


def test_a_scheduler_without_workers_stops_a_batch_before_it_writes(in_tmp, capsys):
    from distributed import LocalCluster

    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        t0 = time.monotonic()
        assert main(["batch", "--line", "felez_test", "--timetables", "test", "--regimes", "fbs", "--seeds", "1",
                     "--scheduler", cluster.scheduler_address, "--out", "b"]) == 2
        assert time.monotonic() - t0 < 40
    assert f"the Dask scheduler at {cluster.scheduler_address} has no workers" in capsys.readouterr().err
    assert not any(in_tmp.iterdir())


def test_replaying_a_results_folder_in_sumo_keeps_the_recorded_outputs(in_tmp, capsys):
    from vcsumo.sim.sumo_paths import sumo_binary

    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "mb", "--out", "r"]) == 0
    recorded = ("tripinfo.xml", "stops.xml", "sumo_messages.log", "railsignal_vehicles.xml")
    digest = {f: hashlib.sha256((in_tmp / "r" / f).read_bytes()).hexdigest() for f in recorded}
    proc = subprocess.run([sumo_binary("sumo"), "-c", "scenario.sumocfg"], cwd=in_tmp / "r", capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert {f: hashlib.sha256((in_tmp / "r" / f).read_bytes()).hexdigest() for f in recorded} == digest
    import xml.etree.ElementTree as ET

    replay = ET.parse(in_tmp / "r" / "replay-tripinfo.xml").getroot().findall("tripinfo")
    assert len(replay) == 3  # the replay ran the same three trains, into its own files

