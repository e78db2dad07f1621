"""The campaign engine (issue 9, issue 13 faults): the result store and the runner, with real
processes, real signals, real files and a real Dask cluster (no SUMO here: tasks are small
functions of this module, so each test shows one property of the engine alone)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

from vcsumo.engine.campaign import WORKER_DIED, Outcome, Runner, Task, check_scheduler, check_workers, run_campaign
from vcsumo.engine.store import ResultStore, StoreBusy, Table, read_table
from vcsumo.errors import InputError, VcsumoError
from vcsumo.results import ResultsFolder, remove_stale_partials

MAIN = Table("main.csv", ("key", "value", "error"), "key", text=("error",))
CHILD = Table("child.csv", ("key", "item", "value"), "key", identity=("item",))


# -----------------------------------------------------------------------------------------------
# tasks (module level: they travel to worker processes by name)


def double(x):
    return 2 * x


def fail_on_three(x):
    if x == 3:
        raise ValueError("three is not allowed")
    return 2 * x


def die_on_three(arg):
    """Task 3 kills its own worker process every time (SIGKILL); every start is logged."""
    x, log = arg
    with open(log, "a") as f:
        f.write(f"{x} {os.getpid()}\n")
    if x == 3:
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(0.2)
    return 2 * x


def slow_in_folder(arg):
    """Writes a partial results folder and takes its time (a worker to be killed from outside)."""
    x, root, seconds = arg
    with ResultsFolder(Path(root) / f"t{x}", overwrite=True) as rf:
        # written whole, then renamed: a reader that sees "started" reads the pid (write_text alone
        # creates the file empty first, and a reader between the two read '': int('') failed under load)
        (rf.path / "started.tmp").write_text(str(os.getpid()))
        os.replace(rf.path / "started.tmp", rf.path / "started")
        time.sleep(seconds)
    return x


def rows_of(task: Task, out: Outcome):
    row = {"key": task.key, "value": out.value if out.ok else None, "error": out.error}
    kids = [{"key": task.key, "item": i, "value": i * (out.value or 0)} for i in range(2)] if out.ok else []
    return [row], {CHILD.name: kids}


def tasks_for(xs, fn=double):
    return [Task(f"k{x}", fn, x, f"task {x}") for x in xs]


# -----------------------------------------------------------------------------------------------
# the store


def test_a_key_is_recorded_once_and_a_cut_off_line_is_dropped(tmp_path):
    with ResultStore(tmp_path / "s", MAIN, [CHILD], kind="t") as st:
        assert st.record([{"key": "a", "value": 1, "error": ""}], {CHILD.name: [{"key": "a", "item": 0, "value": 5}]}) == 1
        assert st.record([{"key": "a", "value": 2, "error": ""}], {CHILD.name: [{"key": "a", "item": 0, "value": 9}]}) == 0
        st.record([{"key": "b", "value": 3, "error": "x\ny"}])
    main = (tmp_path / "s" / "main.csv").read_text().splitlines()
    assert main == ["key,value,error", "a,1,", "b,3,x y"]
    assert (tmp_path / "s" / "child.csv").read_text().splitlines() == ["key,item,value", "a,0,5"]
    # a kill in the middle of a write: a child row whose main row never came, and a cut line
    with open(tmp_path / "s" / "child.csv", "a") as f:
        f.write("c,0,7\n")
    with open(tmp_path / "s" / "main.csv", "a") as f:
        f.write("c,4")
    with ResultStore(tmp_path / "s", MAIN, [CHILD], kind="t") as st:
        assert st.keys == {"a", "b"}
    assert read_table(tmp_path / "s", MAIN).key.tolist() == ["a", "b"]
    assert read_table(tmp_path / "s", CHILD).key.tolist() == ["a"]


def test_duplicates_from_an_older_writer_are_kept_once(tmp_path):
    """Two batches into one folder used to append every run twice (96 rows for 48 runs)."""
    folder = tmp_path / "old"
    folder.mkdir()
    (folder / "main.csv").write_text("key,value,error\na,1,\nb,2,\na,1,\nb,2,\n")
    (folder / "child.csv").write_text("key,item,value\na,0,0\na,1,1\na,0,0\na,1,1\nb,0,0\n")
    with ResultStore(folder, MAIN, [CHILD], kind="t") as st:
        assert st.keys == {"a", "b"}
    assert len(pd.read_csv(folder / "main.csv")) == 2 and len(pd.read_csv(folder / "child.csv")) == 3


def test_a_folder_of_another_study_or_other_parameters_is_refused(tmp_path):
    with ResultStore(tmp_path / "s", MAIN, kind="capacity", params={"seed": 1, "step_s": 0.5}):
        pass
    with pytest.raises(InputError, match=r"store.json: kind: .* capacity study, not of a batch study"):
        ResultStore(tmp_path / "s", MAIN, kind="batch").open()
    with pytest.raises(InputError, match=r"store.json: parameters: .*seed 2 now, 1 in the folder"):
        ResultStore(tmp_path / "s", MAIN, kind="capacity", params={"seed": 2, "step_s": 0.5}).open()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(VcsumoError, match="exists and is not empty"):
        ResultStore(tmp_path / "other", MAIN, kind="capacity", params={}, exclusive=True).open()
    assert sorted(p.name for p in (tmp_path / "other").iterdir()) == [".vcsumo.lock", "notes.txt"]


HOLDER = """
import sys, time
from vcsumo.engine.store import ResultStore, Table
st = ResultStore(sys.argv[1], Table("main.csv", ("key", "value", "error"), "key"), kind="t").open()
print("holding", flush=True)
time.sleep(120)
"""


def test_a_second_writer_is_refused_at_once_and_a_killed_one_frees_the_folder(tmp_path):
    folder = tmp_path / "s"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "holding"
        t0 = time.monotonic()
        with pytest.raises(StoreBusy, match=rf"another vcsumo command is writing into this folder \(pid {holder.pid} "):
            ResultStore(folder, MAIN, kind="t").open()
        assert time.monotonic() - t0 < 2.0
        holder.send_signal(signal.SIGKILL)  # the kernel releases the lock of a dead holder
        holder.wait(10)
        with ResultStore(folder, MAIN, kind="t") as st:
            st.record([{"key": "a", "value": 1, "error": ""}])
        assert read_table(folder, MAIN).key.tolist() == ["a"]
    finally:
        holder.kill()
        holder.wait(10)


# -----------------------------------------------------------------------------------------------
# the runner


@pytest.mark.parametrize("bad", [0, -1, -8])
def test_workers_below_one_is_an_input_error(bad):
    with pytest.raises(InputError, match=rf"--workers: {bad}: must be 1 or more \(1 runs in this process"):
        check_workers(bad)
    assert check_workers(1) == 1 and check_workers(None) >= 1
    with pytest.raises(InputError, match="--scheduler"):
        check_scheduler("localhost:8786")


@pytest.mark.parametrize("workers", [1, 2])
def test_an_exception_is_a_failed_row_and_the_others_complete(tmp_path, workers):
    seen = []
    with Runner(workers, log_path=tmp_path / "w.log") as runner, ResultStore(tmp_path / "s", MAIN, [CHILD], kind="t") as st:
        res = run_campaign(st, tasks_for(range(1, 6), fail_on_three), runner, rows_of, lambda d, n, rows: seen.append((d, n)))
    assert (res.new, res.resumed, res.failed) == (5, 0, 1)
    df = read_table(tmp_path / "s", MAIN).set_index("key")
    assert df.loc["k3", "error"] == "ValueError: three is not allowed" and pd.isna(df.loc["k3", "value"])
    assert sorted(df.drop("k3").value) == [2, 4, 8, 10]
    assert seen[0] == (0, 5) and seen[-1] == (5, 5) and len(seen) == 6


def test_a_worker_killed_by_its_task_fails_that_task_only(tmp_path):
    """kill -9 inside one task: the task is tried once more alone, then fails with WORKER_DIED;
    every other task completes in the surviving and replacement workers."""
    log = tmp_path / "starts.log"
    tasks = [Task(f"k{x}", die_on_three, (x, str(log))) for x in range(1, 7)]
    with Runner(2, log_path=tmp_path / "w.log") as runner, ResultStore(tmp_path / "s", MAIN, kind="t") as st:
        res = run_campaign(st, tasks, runner, rows_of)
    df = read_table(tmp_path / "s", MAIN).set_index("key")
    assert res.failed == 1 and df.loc["k3", "error"] == WORKER_DIED
    assert sorted(df.drop("k3").value) == [2, 4, 8, 10, 12]
    starts = [line.split() for line in log.read_text().splitlines()]
    assert [x for x, _ in starts].count("3") == 2  # in the pool, then alone
    assert all([x for x, _ in starts].count(str(k)) == 1 for k in (1, 2, 4, 5, 6))


def test_a_worker_killed_from_outside_is_retried_and_leaves_no_partial_folder(tmp_path):
    root = tmp_path / "runs"
    root.mkdir()
    killed = []

    def killer():
        deadline = time.monotonic() + 30
        while not killed and time.monotonic() < deadline:
            for p in root.glob("t2.partial-*/started"):
                pid = int(p.read_text())
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
            time.sleep(0.01)

    th = threading.Thread(target=killer, daemon=True)
    th.start()
    tasks = [Task(f"k{x}", slow_in_folder, (x, str(root), 1.0)) for x in range(1, 4)]
    with Runner(2, log_path=tmp_path / "w.log", partial_roots=[root]) as runner, ResultStore(tmp_path / "s", MAIN, kind="t") as st:
        res = run_campaign(st, tasks, runner, rows_of)
    th.join()
    assert len(killed) == 1 and res.failed == 0
    assert sorted(read_table(tmp_path / "s", MAIN).value) == [1, 2, 3]
    assert sorted(p.name for p in root.iterdir()) == ["t1", "t2", "t3"]


def test_resume_runs_only_missing_tasks_once(tmp_path):
    with Runner(2) as runner, ResultStore(tmp_path / "s", MAIN, [CHILD], kind="t") as st:
        first = run_campaign(st, tasks_for([1, 2, 3]), runner, rows_of)
    with Runner(2) as runner, ResultStore(tmp_path / "s", MAIN, [CHILD], kind="t") as st:
        second = run_campaign(st, tasks_for([1, 2, 3, 4, 5]), runner, rows_of)
    assert (first.new, second.new, second.resumed) == (3, 2, 3)
    main, child = read_table(tmp_path / "s", MAIN), read_table(tmp_path / "s", CHILD)
    assert len(pd.read_csv(tmp_path / "s" / "main.csv")) == 5 and sorted(main.value) == [2, 4, 6, 8, 10]
    assert len(pd.read_csv(tmp_path / "s" / "child.csv")) == 10 and not child.duplicated(["key", "item"]).any()


def test_stale_partial_folders_of_dead_processes_are_removed(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        for pid in (dead.pid, alive.pid):
            (tmp_path / f"out.partial-{pid}").mkdir()
        (tmp_path / f"other.partial-{dead.pid}").mkdir()
        with ResultsFolder(tmp_path / "out") as rf:
            (rf.path / "x.csv").write_text("a\n")
        left = sorted(p.name for p in tmp_path.iterdir())
        assert left == ["other.partial-%d" % dead.pid, "out", f"out.partial-{alive.pid}"]
        assert [p.name for p in remove_stale_partials(tmp_path)] == [f"other.partial-{dead.pid}"]
    finally:
        alive.kill()
        alive.wait()


SIGTERMED = """
import sys
from pathlib import Path
from vcsumo.engine.campaign import Runner, Task, run_campaign, sigterm_as_interrupt
from vcsumo.engine.store import ResultStore

sys.path.insert(0, sys.argv[2])
from test_engine import MAIN, rows_of, slow_in_folder

if __name__ == "__main__":
    root = Path(sys.argv[1]) / "runs"
    root.mkdir(parents=True, exist_ok=True)
    try:
        with sigterm_as_interrupt(), Runner(int(sys.argv[3]), log_path=root.parent / "w.log", partial_roots=[root]) as r, \\
                ResultStore(root.parent, MAIN, kind="t") as st:
            run_campaign(st, [Task(f"k{x}", slow_in_folder, (x, str(root), 30.0)) for x in range(4)], r, rows_of)
    except KeyboardInterrupt:
        sys.exit(143)
"""


@pytest.mark.parametrize("workers", [1, 2])
def test_sigterm_ends_the_workers_and_leaves_no_partial_folder(tmp_path, workers):
    script = tmp_path / "run.py"
    script.write_text(SIGTERMED)
    out = tmp_path / "c"
    proc = subprocess.Popen([sys.executable, str(script), str(out), str(Path(__file__).parent), str(workers)])
    try:
        deadline = time.monotonic() + 60
        while len(list((out / "runs").glob("*.partial-*/started"))) < workers and time.monotonic() < deadline:
            time.sleep(0.05)
        pids = [int(p.read_text()) for p in (out / "runs").glob("*.partial-*/started")]
        assert len(pids) == workers
        proc.send_signal(signal.SIGTERM)  # the command only, as `kill` does
        assert proc.wait(30) == 143
    finally:
        proc.kill()
    assert not list(out.rglob("*.partial-*"))
    time.sleep(0.2)
    assert not [p for p in pids if p != proc.pid and os.path.exists(f"/proc/{p}")]


# -----------------------------------------------------------------------------------------------
# Dask


def test_a_dask_scheduler_without_workers_is_reported_within_seconds():
    from distributed import LocalCluster

    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        t0 = time.monotonic()
        with pytest.raises(VcsumoError, match=rf"--scheduler: the Dask scheduler at {cluster.scheduler_address} has no workers \(waited 2 s\)"):
            with Runner(scheduler=cluster.scheduler_address, worker_wait_s=2.0):
                pass
        assert time.monotonic() - t0 < 10


def test_a_dask_cluster_that_loses_all_its_workers_stops_the_campaign(tmp_path):
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        done = []
        with Runner(scheduler=cluster.scheduler_address, worker_wait_s=3.0) as runner, ResultStore(tmp_path / "s", MAIN, kind="t") as st:
            tasks = [Task(f"k{x}", slow_in_folder, (x, str(tmp_path / "runs"), 0.5)) for x in range(20)]

            def progress(d, n, rows):
                done.append(d)
                if d == 2:
                    cluster.scale(0)

            t0 = time.monotonic()
            with pytest.raises(VcsumoError, match=r"the Dask cluster at .* has no workers left \(for 3 s\); \d+ of 20 tasks unfinished"):
                run_campaign(st, tasks, runner, rows_of, progress)
            assert time.monotonic() - t0 < 40
    rows = read_table(tmp_path / "s", MAIN)
    assert 2 <= len(rows) < 20 and (rows.error == "").all()


def test_dask_runs_tasks_with_crash_isolation(tmp_path):
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None) as cluster:
        with Runner(scheduler=cluster.scheduler_address) as runner, ResultStore(tmp_path / "s", MAIN, kind="t") as st:
            res = run_campaign(st, tasks_for(range(1, 5), fail_on_three), runner, rows_of)
    df = read_table(tmp_path / "s", MAIN).set_index("key")
    assert res.failed == 1 and df.loc["k3", "error"] == "ValueError: three is not allowed" and sorted(df.drop("k3").value) == [2, 4, 8]


def test_nothing_listening_at_the_scheduler_address_is_one_error():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    with pytest.raises(VcsumoError, match=rf"--scheduler: cannot connect to the Dask scheduler at tcp://127.0.0.1:{port}: ConnectionRefusedError"):
        with Runner(scheduler=f"tcp://127.0.0.1:{port}", connect_timeout_s=3.0):
            pass
    assert time.monotonic() - t0 < 5

