"""Batch experiments in real SUMO: rows, metrics, failures, resume, parallel and Dask execution."""

import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from vcsumo.studies.batch import BATCH_COLUMNS, TRAIN_COLUMNS, read_batch, run_batch
from vcsumo.delays import NO_DELAYS, DelayConfig, DelaySpec
from vcsumo.errors import InputError, VcsumoError

from .conftest import write

pytestmark = pytest.mark.sumo

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "vcsumo" / "data"
FELEZ = DATA / "routes" / "felez_test"
INFEASIBLE = """name: too_fast
line: felez_test
services:
  - {id: X, train: felez2019, origin: ORIG, destination: STOP, departure: 0, arrival: 100}
"""


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """felez_test: test + base + an infeasible timetable, fbs and mb, seeds 1 and 2, two worker processes."""
    tmp = tmp_path_factory.mktemp("batch")
    bad = write(tmp / "too_fast.yaml", INFEASIBLE)
    out = tmp / "b"
    specs = f"{FELEZ / 'test.yaml'},{FELEZ / 'base.yaml'},{bad}"
    df = run_batch("felez_test", specs, ["fbs", "mb"], [1, 2], out=out, workers=2)
    return out, df, specs


def test_one_row_per_run_and_the_failed_timetable_does_not_stop_the_batch(batch):
    out, df, _ = batch
    assert list(df.columns) == BATCH_COLUMNS
    assert len(df) == 3 * 2 * 2 and df.attrs["new_runs"] == 12 and df.attrs["resumed_runs"] == 0
    ok, failed = df[df.status == "ok"], df[df.status == "failed"]
    assert set(ok.timetable) == {"test", "base"} and len(ok) == 8
    assert set(failed.timetable) == {"too_fast"} and len(failed) == 4
    assert failed.error.str.contains("too_fast.yaml").all() and failed.error.str.contains("infeasible").all()
    assert (ok.error == "").all() and (ok.trains_arrived == ok.trains).all()
    assert (ok.collisions == 0).all() and (ok.gap_violations == 0).all()
    on_disk = pd.read_csv(out / "batch.csv")
    assert len(on_disk) == 12 and list(on_disk.columns) == BATCH_COLUMNS


def test_metrics_follow_from_the_train_rows(batch):
    out, df, _ = batch
    tr = pd.read_csv(out / "batch_trains.csv", dtype={"controller": str}, keep_default_na=False)
    assert list(tr.columns) == TRAIN_COLUMNS
    ok = df[df.status == "ok"]
    assert len(tr) == ok.trains.sum() and tr.run_key.nunique() == len(ok)
    for _, run in ok.iterrows():
        t = tr[tr.run_key == run.run_key]
        assert (t.arrival_delay_s - (t.arrival_s - t.reference_arrival_s)).abs().max() < 0.01
        assert t.primary_delay_s.sum() == pytest.approx(run.primary_delay_s, abs=0.1)
        assert (t.primary_delay_s - (t.origin_delay_s + t.dwell_extension_s)).abs().max() < 0.11
        knock = (t.arrival_delay_s - t.primary_delay_s).clip(lower=0)
        assert (t.knock_on_delay_s - knock).abs().max() < 0.01 and knock.sum() == pytest.approx(run.knock_on_delay_s, abs=0.05)
        assert (t.arrival_delay_s <= 180).mean() == pytest.approx(run.punctuality_3min_share, abs=1e-3)
        assert (t.arrival_delay_s <= 300).mean() == pytest.approx(run.punctuality_5min_share, abs=1e-3)
        assert t.arrival_delay_s.max() == pytest.approx(run.max_arrival_delay_s, abs=0.01)
        assert (t.arrival_s >= t.departure_s).all()
    # every run's health is in its row, as the run's own summary has it (a run not healthy is never a clean row)
    for _, run in ok.iterrows():
        run_dir = Path(run.run_dir) if Path(run.run_dir).is_absolute() else out / run.run_dir
        summ = json.loads((run_dir / "summary.json").read_text())
        assert str(run.healthy).lower() == str(summ["healthy"]).lower()
        for col in ("stops_skipped", "overspeed_events", "beyond_service_brakings", "authority_overruns"):
            assert int(run[col]) == summ[col]
        assert float(run.min_margin_m) == pytest.approx(summ["min_margin_m"])
        healthy = summ["trains_arrived"] == summ["trains"] and summ["stops_skipped"] == 0 and summ["gap_violations"] == 0 and summ["collisions"] == 0
        assert not (str(run.healthy).lower() == "true" and not healthy)
    # a delayed train is late by at least... nothing less than its own departure delay minus the margin
    base_margin = 210 - 186  # scheduled - minimum running time on felez_test
    assert (tr.arrival_delay_s >= tr.origin_delay_s - base_margin - 1.0).all()


def test_regimes_see_the_same_primary_delays_and_fbs_consumes_more_capacity(batch):
    out, df, _ = batch
    ok = df[df.status == "ok"]
    for (tt, seed), g in ok.groupby(["timetable", "seed"]):
        assert g.primary_delay_s.nunique() == 1, (tt, seed)
    tr = pd.read_csv(out / "batch_trains.csv")
    per = tr.pivot_table(index=["timetable", "seed", "train"], columns="regime", values="origin_delay_s")
    assert (per["fbs"] == per["mb"]).all()
    assert ok.groupby("seed").primary_delay_s.sum().nunique() == 2  # different seeds, different delays
    for tt, g in ok.groupby("timetable"):
        fbs = g[g.regime == "fbs"].capacity_consumption_pct.unique()
        mb = g[g.regime == "mb"].capacity_consumption_pct.unique()
        assert len(fbs) == len(mb) == 1 and fbs[0] > mb[0] > 0
        assert (g.capacity_consumption_cyclic_pct < g.capacity_consumption_pct).all()
    uic = pd.read_csv(out / "uic406.csv")
    test_fbs = uic[(uic.timetable == "test") & (uic.regime == "fbs")]
    assert ok[(ok.timetable == "test") & (ok.regime == "fbs")].capacity_consumption_pct.iloc[0] == pytest.approx(test_fbs.consumption_pct.max())
    assert df[df.status == "failed"].capacity_consumption_pct.isna().all()


def test_every_results_folder_records_inputs_versions_seed_and_wall_time(batch):
    out, df, _ = batch
    for _, run in df[df.status == "ok"].iterrows():
        folder = out / run.run_dir
        meta = json.loads((folder / "meta.json").read_text())
        assert meta["seed"] == run.seed and meta["wall_time_s"] > 0 and meta["versions"]["eclipse-sumo"]
        assert meta["inputs"]["timetable"]["sha256"] == run.timetable_sha256
        assert meta["parameters"]["regime"] == run.regime and meta["parameters"]["run_key"] == run.run_key
        for f in ("summary.csv", "stop_events.csv", "delays.csv", "trains.csv", "tripinfo.xml"):
            assert (folder / f).is_file(), f
    assert not list(out.glob("runs/*.partial-*"))
    report = out / "report"
    for f in ("batch_summary.csv", "batch_runs.csv", "uic406.csv", "batch_delays.png", "batch_punctuality.png", "meta.json"):
        assert (report / f).is_file() and (report / f).stat().st_size > 0, f
    meta = json.loads((report / "meta.json").read_text())
    assert meta["parameters"]["seeds"] == [1, 2] and "line" in meta["inputs"] and meta["parameters"]["delays"]["origin"]["mean_s"] == 120.0
    summ = pd.read_csv(report / "batch_summary.csv")
    assert len(summ) == 6 and summ.runs.tolist() == [2] * 6


def test_the_same_command_again_runs_nothing(batch, capsys):
    """Re-run: nothing runs, batch.csv is untouched, and the verdict is the same — the four failed runs
    (of twelve) make the command exit 1 with one line naming them and where they are."""
    from vcsumo.cli.main import main

    out, df, specs = batch
    before = (out / "batch.csv").read_text()
    code = main(["batch", "--line", "felez_test", "--timetables", specs, "--regimes", "fbs,mb", "--seeds", "2", "--out", str(out), "--workers", "2"])
    cap = capsys.readouterr()
    assert code == 1, cap.err
    assert "0 run now, 12 already in batch.csv" in cap.out and "4 failed" in cap.out
    assert f"error: 4 of 12 runs of the batch are not clean (4 failed); results kept in {out / 'batch.csv'}" in cap.err
    assert (out / "batch.csv").read_text() == before


def test_an_interrupted_batch_resumes_where_it_stopped(batch, tmp_path):
    out, df, specs = batch
    cut = tmp_path / "cut"
    shutil.copytree(out, cut)
    lines = (cut / "batch.csv").read_text().splitlines(keepends=True)
    lost = list(csv.reader(lines[-3:]))
    # the last two finished runs were never recorded, and a third row was cut off mid-write
    (cut / "batch.csv").write_text("".join(lines[:-3]) + lines[-3][: len(lines[-3]) // 2])
    again = run_batch("felez_test", specs, ["fbs", "mb"], [1, 2], out=cut, workers=2)
    assert again.attrs["new_runs"] == 3 and again.attrs["resumed_runs"] == 9
    keys = {row[BATCH_COLUMNS.index("run_key")] for row in lost}
    assert keys <= set(again.run_key)
    cols = [c for c in BATCH_COLUMNS if c != "wall_time_s"]
    a = df[cols].sort_values("run_key").reset_index(drop=True)
    b = again[cols].sort_values("run_key").reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b)
    tr = pd.read_csv(cut / "batch_trains.csv")
    assert not tr.duplicated(["run_key", "train"]).any() and len(tr) == df[df.status == "ok"].trains.sum()


def test_more_seeds_and_retrying_failures_run_only_what_is_missing(batch, tmp_path):
    out, df, specs = batch
    more = tmp_path / "more"
    shutil.copytree(out, more)
    tt = str(FELEZ / "test.yaml")
    d = run_batch("felez_test", tt, ["fbs"], [1, 2, 3], out=more, workers=1)
    assert d.attrs["new_runs"] == 1 and d.attrs["resumed_runs"] == 2 and list(d.seed) == [1, 2, 3]
    r = run_batch("felez_test", specs, ["fbs", "mb"], [1, 2], out=more, workers=2, retry_failed=True)
    assert r.attrs["new_runs"] == 4 and r.attrs["failed_runs"] == 4
    assert not read_batch(more).run_key.duplicated().any() and len(pd.read_csv(more / "batch.csv")) == 13


def test_more_primary_delay_means_lower_punctuality(tmp_path):
    heavy = DelayConfig(origin=DelaySpec(probability=1.0, mean_s=300.0), dwell=DelaySpec(distribution="none"))
    tt = str(FELEZ / "dense.yaml")
    res = {}
    for name, cfg in (("none", NO_DELAYS), ("default", DelayConfig()), ("heavy", heavy)):
        res[name] = run_batch("felez_test", tt, ["fbs"], [1, 2], delays=cfg, out=tmp_path / name, workers=2)
        assert (res[name].status == "ok").all()
    p = {k: v.punctuality_3min_share.mean() for k, v in res.items()}
    primary = {k: v.primary_delay_s.sum() for k, v in res.items()}
    assert primary["none"] == 0 < primary["default"] < primary["heavy"]
    assert p["none"] == 1.0 and p["none"] >= p["default"] > p["heavy"]
    assert res["none"].knock_on_delay_s.sum() == 0 and res["heavy"].knock_on_delay_s.sum() > 0
    assert res["heavy"].mean_arrival_delay_s.mean() > res["default"].mean_arrival_delay_s.mean()
    # a different delay configuration is a different run: its own key
    assert not set(res["none"].run_key) & set(res["heavy"].run_key)


def test_bad_input_is_one_clear_error(tmp_path):
    from vcsumo.cli.batch import batch_cmd

    def run(*args):
        batch_cmd.main(["--line", "felez_test", "--out", str(tmp_path / "x"), *args], standalone_mode=False)

    with pytest.raises(InputError, match=r"--regimes \(item 2\): etcs: Input should be 'fbs', 'mb' or 'vc'"):
        run("--regimes", "fbs,etcs", "--timetables", "test")
    with pytest.raises(InputError, match="--controllers: only the vc regime"):
        run("--regimes", "fbs", "--controllers", "mpc", "--timetables", "test")
    with pytest.raises(InputError, match="--timetables: unknown timetable 'nope'"):
        run("--regimes", "fbs", "--timetables", "nope")
    with pytest.raises(InputError, match="no timetable file matches"):
        run("--regimes", "fbs", "--timetables", "vcsumo/data/routes/felez_test/*.yml")
    bad = write(tmp_path / "d.yaml", "origin: {probability: 0.3, mean: 60}\n")
    with pytest.raises(InputError, match=r"d.yaml: origin.mean: unknown key"):
        run("--regimes", "fbs", "--timetables", "test", "--delay-config", str(bad))
    with pytest.raises(VcsumoError, match="--scheduler"):
        run("--regimes", "fbs", "--timetables", "test", "--scheduler", "localhost")
    assert not (tmp_path / "x").exists()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)


def test_dask_cluster_gives_the_same_rows_as_local_processes(batch, tmp_path):
    out, df, _ = batch
    dask = str(Path(sys.executable).with_name("dask"))
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, DASK_DISTRIBUTED__LOGGING__DISTRIBUTED="error")
    sched = subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0", "--no-show"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True, env=env)
    worker = None
    try:
        worker = subprocess.Popen([dask, "worker", addr, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True, env=env)
        from distributed import Client

        with Client(addr, timeout="60s") as c:  # wait until the worker has joined
            c.wait_for_workers(1, timeout=60)
        got = run_batch("felez_test", str(FELEZ / "test.yaml"), ["fbs", "mb"], [1, 2], out=tmp_path / "dask", scheduler=addr)
    finally:
        if worker is not None:
            _stop(worker)
        _stop(sched)
    assert got.attrs["new_runs"] == 4 and (got.status == "ok").all()
    cols = [c for c in BATCH_COLUMNS if c != "wall_time_s"]
    local = df[df.timetable == "test"][cols].sort_values("run_key").reset_index(drop=True)
    remote = got[cols].sort_values("run_key").reset_index(drop=True)
    pd.testing.assert_frame_equal(local, remote, check_dtype=False)
    assert all((tmp_path / "dask" / d / "meta.json").is_file() for d in got.run_dir)


def test_default_folder_is_the_same_for_the_same_command(in_tmp):
    from click.testing import CliRunner

    from vcsumo.cli.batch import batch_cmd

    args = ["--line", "felez_test", "--timetables", "test", "--regimes", "mb", "--seeds", "1", "--workers", "1"]
    first = CliRunner().invoke(batch_cmd, args, catch_exceptions=False)
    assert first.exit_code == 0 and "1 run now, 0 already" in first.output, first.output
    made = list((in_tmp / "results").iterdir())
    assert len(made) == 1 and made[0].name.startswith("batch-felez_test-")
    second = CliRunner().invoke(batch_cmd, args, catch_exceptions=False)
    assert "0 run now, 1 already in batch.csv" in second.output and list((in_tmp / "results").iterdir()) == made
