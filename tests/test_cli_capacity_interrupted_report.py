"""A capacity study stopped while it writes its report leaves no ``capacity.csv``: README says a
capacity folder without it is a stopped study waiting to be resumed, so one with it must be whole.

Found with SIGTERM on ``vcsumo study capacity --line felez_test --controllers cbc --convoy-sizes 2
--directions up --patterns non-stop --workers 1`` just after its last case (exit 143): the folder had
capacity.csv, capacity.png and time_distance.csv but no time_distance.png and no meta.json — a stopped
study that looked finished.  Ctrl-C is injected here at that moment (while the time-distance plot is
drawn); the cases are real SUMO runs, and the next command resumes them all and writes the report."""

from __future__ import annotations

import pytest

import vcsumo.plots.capacity as plots
from vcsumo.cli.main import main
from vcsumo.results import read_results_csv

CMD = ["-q", "study", "capacity", "--line", "felez_test", "--convoy-sizes", "1", "--directions", "up", "--patterns", "non-stop",
       "--workers", "1", "--out", "cap"]


@pytest.mark.sumo
def test_a_report_cut_short_leaves_no_capacity_csv_and_resumes(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(CMD) == 0
    first = read_results_csv(tmp_path / "cap" / "capacity.csv")
    (tmp_path / "cap" / "meta.json").unlink()

    def interrupted(*_a, **_k):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(plots, "plot_time_distance_stairs", interrupted)
        assert main(CMD) == 130
    assert not (tmp_path / "cap" / "capacity.csv").exists()  # a stopped study, as README says
    assert not (tmp_path / "cap" / "meta.json").exists()
    assert len(read_results_csv(tmp_path / "cap" / "capacity_cases.csv")) == 2  # the finished cases are kept

    capsys.readouterr()
    assert main(CMD) == 0  # resumes: nothing runs again, the report is written whole
    again = read_results_csv(tmp_path / "cap" / "capacity.csv")
    assert again[["regime", "capacity_trains_per_h"]].equals(first[["regime", "capacity_trains_per_h"]])
    assert (tmp_path / "cap" / "meta.json").is_file() and (tmp_path / "cap" / "time_distance.png").is_file()
    assert not list((tmp_path / "cap").glob(".tmp-*"))
